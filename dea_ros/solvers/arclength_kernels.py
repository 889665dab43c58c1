"""The compiled pseudo-arclength continuation engine, on any problem that implements its protocol.

A problem is a family of equations R(z, p) = 0 in n unknowns z and one parameter p (for the
frequency sweep: the scaled collocation values and p = ln omega). The engine follows a branch of
solutions y = (z, p) by predictor (along the unit tangent) / corrector (Newton on R = 0 plus the
arclength condition wz tz.(z - z_pred) + tp (p - p_pred) = 0) steps of adaptive length, in the norm
|dz|^2 wz + dp^2, so turning points (folds) are passed, not stopped at:

* a step whose corrector fails halves h, and so does one that turns the tangent by more than 10
  degrees (a large step could jump across a narrow S-shaped loop); h then grows by 1.5 / 1.0 / 0.6
  after <= 3 / <= 5 / more corrector iterations, up to h_max;
* requested parameter values ``p_grid`` that a step crosses are solved at fixed p from the step's
  cubic Hermite interpolant (:func:`hermite_seed`);
* a sign change of the tangent's p-component is a fold (a new segment of the branch);
* the loop stops when the branch leaves [p_lo, p_hi] moving outwards, after ``max_steps``, when the
  step underflows, or when the problem says its branch turned back (:func:`problem_turned_back`).

The protocol. numba dispatches on the problem's type at compile time: a problem is an instance of
a ``collections.namedtuple`` class registered with :func:`register_problem`, which supplies (as
compiled functions) its residual and Jacobian, and optionally its own corrector, fixed-p solver,
tangent and stop test (the frequency sweep supplies all, solved by the structured reduction of
:mod:`.collocation_kernels`; see :mod:`.sweep_kernels`). Without them the engine's dense ones are
used (:func:`dense_correct`, :func:`dense_solve_at`, :func:`dense_tangent`): any problem with a
residual and a Jacobian can be continued. The stubs ``problem_*`` below only name the protocol;
calling them from Python raises. Why not pass the functions as arguments: numba compiles a kernel
per function argument and never finds those specialisations in its on-disk cache (their cache keys
hold process-specific identities; measured with numba 0.68), while dispatch on a registered
namedtuple type is cached like any kernel.

Caching. numba keeps one cache index per kernel, with the argument types of all its specialisations
pickled by reference; a process that cannot import one of those types cannot load any of them. So
the engine's entry points (:func:`trace_branch`, :func:`correct`, :func:`solve_at`, :func:`tangent`)
exist twice: compiled into the on-disk cache for the problem types registered with ``cache=True``
(dea_ros's own, importable everywhere) and compiled in each process for any other (a problem defined
in a script or a test); the helpers that take the problem are inlined or never cached.
"""
from __future__ import annotations

import math

import numpy as np
from numba import types
from numba.extending import overload

from .jit import jit, jit_inline, jit_uncached

__all__ = [
    "problem_residual_jacobian", "problem_correct", "problem_solve_at", "problem_tangent", "problem_turned_back",
    "register_problem", "dense_correct", "dense_solve_at", "dense_tangent", "never_turned_back", "converges_below",
    "hermite_seed", "inner", "trace_branch", "correct", "solve_at", "tangent", "TRACE_STEP_UNDERFLOW",
    "TRACE_MAX_STEPS", "STEP_P", "STEP_TP", "STEP_H", "STEP_SEGMENT", "GRID_INDEX", "GRID_P", "GRID_ITERATIONS",
    "GRID_SEGMENT", "GRID_STEP", "GRID_FRACTION",
]

#: Outcome codes of :func:`trace_branch` (0: left the range, stopped or ran out of steps normally).
TRACE_STEP_UNDERFLOW = 1
TRACE_MAX_STEPS = 2
#: Columns of the per-step and per-grid-point tables of :func:`trace_branch`.
STEP_P, STEP_TP, STEP_H, STEP_SEGMENT = range(4)
GRID_INDEX, GRID_P, GRID_ITERATIONS, GRID_SEGMENT, GRID_STEP, GRID_FRACTION = range(6)


# ------------------------------------------------------------------------------- protocol
def problem_residual_jacobian(problem, z, p):
    """(R (n,), dR/dz (n, n), dR/dp (n,)) at (z, p). Protocol: implemented per problem type."""
    raise NotImplementedError("a protocol function of the compiled continuation engine (register_problem)")


def problem_correct(problem, z_pred, p_pred, tz, tp, wz, tol, max_iter):
    """The corrector from the predicted point: (ok, z, p, iterations, t), t (n + 1) the unnormalised next
    tangent (see :func:`dense_correct`). Protocol: implemented per problem type."""
    raise NotImplementedError("a protocol function of the compiled continuation engine (register_problem)")


def problem_solve_at(problem, seed, p, tol, max_iter):
    """Newton at fixed p from ``seed``: (z, iterations, status), status 0 when converged. Protocol."""
    raise NotImplementedError("a protocol function of the compiled continuation engine (register_problem)")


def problem_tangent(problem, z, p, tz, tp, wz):
    """(t (n + 1), ok): the bordered system [[dR/dz, dR/dp], [wz tz^T, tp]] t = e_n solved. Protocol."""
    raise NotImplementedError("a protocol function of the compiled continuation engine (register_problem)")


def problem_turned_back(problem, z_prev, z_new):
    """True when the branch should stop after the step from z_prev to z_new. Protocol."""
    raise NotImplementedError("a protocol function of the compiled continuation engine (register_problem)")


def _is_instance(problem, problem_type) -> bool:
    """Typing-time test: ``problem`` is the numba type of instances of the namedtuple class problem_type."""
    return isinstance(problem, types.BaseNamedTuple) and problem.instance_class is problem_type


def register_problem(problem_type, residual_jacobian, correct_fn=None, solve_at_fn=None, tangent_fn=None,
                     turned_back_fn=None, cache: bool = False) -> None:
    """Let the engine continue instances of the namedtuple class ``problem_type``.

    The functions are compiled (:func:`~dea_ros.solvers.jit.jit`) with the signatures of the
    ``problem_*`` stubs; the optional ones default to the dense :func:`dense_correct`,
    :func:`dense_solve_at`, :func:`dense_tangent` (built on ``residual_jacobian``) and
    :func:`never_turned_back`. ``cache``: compile the engine for this type into the on-disk cache, only
    for a type of an importable module of dea_ros (numba's cache index pickles the type by reference: one
    another process cannot import would break every process that reads the index); otherwise the engine
    is compiled for it in each process.
    """
    if cache:
        _CACHED_TYPES.add(problem_type)
    correct_fn = dense_correct if correct_fn is None else correct_fn
    solve_at_fn = dense_solve_at if solve_at_fn is None else solve_at_fn
    tangent_fn = dense_tangent if tangent_fn is None else tangent_fn
    turned_back_fn = never_turned_back if turned_back_fn is None else turned_back_fn

    @overload(problem_residual_jacobian)
    def _residual_jacobian(problem, z, p):
        if _is_instance(problem, problem_type):
            return lambda problem, z, p: residual_jacobian(problem, z, p)

    @overload(problem_correct)
    def _correct(problem, z_pred, p_pred, tz, tp, wz, tol, max_iter):
        if _is_instance(problem, problem_type):
            return lambda problem, z_pred, p_pred, tz, tp, wz, tol, max_iter: correct_fn(
                problem, z_pred, p_pred, tz, tp, wz, tol, max_iter)

    @overload(problem_solve_at)
    def _solve_at(problem, seed, p, tol, max_iter):
        if _is_instance(problem, problem_type):
            return lambda problem, seed, p, tol, max_iter: solve_at_fn(problem, seed, p, tol, max_iter)

    @overload(problem_tangent)
    def _tangent(problem, z, p, tz, tp, wz):
        if _is_instance(problem, problem_type):
            return lambda problem, z, p, tz, tp, wz: tangent_fn(problem, z, p, tz, tp, wz)

    @overload(problem_turned_back)
    def _turned_back(problem, z_prev, z_new):
        if _is_instance(problem, problem_type):
            return lambda problem, z_prev, z_new: turned_back_fn(problem, z_prev, z_new)


# ----------------------------------------------------------------- dense problem functions
@jit
def converges_below(snorm, prev_snorm, tol):
    """True when Newton, whose last two steps had max-norms ``prev_snorm`` then ``snorm``, converges
    quadratically (the step shrank more than tenfold) and its next step, ||s_k||^3 / ||s_k-1||^2 by that
    rate, is below tol / 10: the iterate after the last step is then within tol, and the step that would
    confirm it is skipped (the corrector's; ``prev_snorm`` 0 before the second step: never)."""
    return snorm < 0.1 * prev_snorm and snorm * snorm * snorm < 0.1 * tol * prev_snorm * prev_snorm


@jit_uncached
def _bordered_matrix(problem, z, p, tz, tp, wz):
    """(R, [[dR/dz, dR/dp], [wz tz^T, tp]]) at (z, p)."""
    n = z.shape[0]
    r, jac, dr = problem_residual_jacobian(problem, z, p)
    big = np.empty((n + 1, n + 1))
    big[:n, :n] = jac
    big[:n, n] = dr
    big[n, :n] = wz * tz
    big[n, n] = tp
    return r, big


@jit_uncached
def _unit_vector(n):
    """e_n of length n + 1."""
    out = np.zeros(n + 1)
    out[n] = 1.0
    return out


@jit_uncached
def dense_correct(problem, z_pred, p_pred, tz, tp, wz, tol, max_iter):
    """Newton on [R(z, p); wz tz.(z - z_pred) + tp (p - p_pred)] = 0 by dense LU: (ok, z, p, iterations, t).

    Gives up (ok False) on a singular matrix, a non-finite or > 10 step, or after ``max_iter``;
    converged when the max-norm of the step is below max(tol, 1e-9), or when the next one is predicted
    below it (:func:`converges_below`; counted with the step it makes unneeded). t is the bordered
    system of the last matrix built solved for e_n (the next tangent, unnormalised).
    """
    n = z_pred.shape[0]
    zc = z_pred.copy()
    pc = p_pred
    t = _unit_vector(n)
    prev_snorm = 0.0
    for it in range(1, max_iter + 1):
        r, big = _bordered_matrix(problem, zc, pc, tz, tp, wz)
        rhs = np.empty(n + 1)
        rhs[:n] = r
        rhs[n] = wz * np.dot(tz, zc - z_pred) + tp * (pc - p_pred)
        try:
            step = np.linalg.solve(big, rhs)
            t = np.linalg.solve(big, _unit_vector(n))
        except Exception:  # noqa: BLE001 - numba raises on an exactly singular matrix
            return False, zc, pc, it, t
        zc = zc - step[:n]
        pc -= step[n]
        snorm = np.max(np.abs(step))
        if not np.isfinite(snorm) or snorm > 10.0:
            return False, zc, pc, it, t
        if snorm < max(tol, 1e-9):
            return True, zc, pc, it, t
        if converges_below(snorm, prev_snorm, max(tol, 1e-9)):
            return True, zc, pc, it + 1, t
        prev_snorm = snorm
    return False, zc, pc, max_iter, t


@jit_uncached
def dense_solve_at(problem, seed, p, tol, max_iter):
    """Newton on R(z, p) = 0 at fixed p from ``seed`` by dense LU: (z, iterations, status), status 0 when
    the max-norm of the full step fell below ``tol``, 1 on a singular or non-finite step, 4 after
    ``max_iter``."""
    z = seed.copy()
    for it in range(1, max_iter + 1):
        r, jac, _dr = problem_residual_jacobian(problem, z, p)
        try:
            step = np.linalg.solve(jac, r)
        except Exception:  # noqa: BLE001 - singular
            return z, it, 1
        z = z - step
        snorm = np.max(np.abs(step))
        if not np.isfinite(snorm):
            return z, it, 1
        if snorm <= tol:
            return z, it, 0
    return z, max_iter, 4


@jit_uncached
def dense_tangent(problem, z, p, tz, tp, wz):
    """(t, ok): [[dR/dz, dR/dp], [wz tz^T, tp]] t = e_n by dense LU (ok False when singular)."""
    _r, big = _bordered_matrix(problem, z, p, tz, tp, wz)
    try:
        return np.linalg.solve(big, _unit_vector(z.shape[0])), True
    except Exception:  # noqa: BLE001 - singular
        return _unit_vector(z.shape[0]), False


@jit_uncached
def never_turned_back(problem, z_prev, z_new):
    """The default stop test: never."""
    return False


# ------------------------------------------------------------------------------- the engine
@jit
def hermite_seed(z0, tz0, p0, tp0, z1, tz1, p1, tp1, ds, p_target, out):
    """Starting point (into ``out``) for the Newton solve at p_target between two branch points: the cubic
    Hermite interpolant of the branch in its arclength s over the step (length ``ds``; points z, p and unit
    tangents tz, tp at both ends), at the s where its p equals p_target (Newton on the cubic from the
    linear fraction). Error O(ds^4) against O(ds^2) for the straight line, so the solve needs about one
    iteration less; the straight line when the cubic's p is not monotonic there."""
    frac = (p_target - p0) / (p1 - p0)
    t = frac
    for _ in range(6):
        t2 = t * t
        t3 = t2 * t
        pt = (2.0 * t3 - 3.0 * t2 + 1.0) * p0 + (t3 - 2.0 * t2 + t) * ds * tp0 + (3.0 * t2 - 2.0 * t3) * p1 \
            + (t3 - t2) * ds * tp1
        dpt = (6.0 * t2 - 6.0 * t) * p0 + (3.0 * t2 - 4.0 * t + 1.0) * ds * tp0 + (6.0 * t - 6.0 * t2) * p1 \
            + (3.0 * t2 - 2.0 * t) * ds * tp1
        if dpt * (p1 - p0) <= 0.0:   # not monotonic here: the straight line
            t = -1.0
            break
        t -= (pt - p_target) / dpt
    if not 0.0 <= t <= 1.0:
        for i in range(z0.shape[0]):
            out[i] = z0[i] + frac * (z1[i] - z0[i])
        return
    t2 = t * t
    t3 = t2 * t
    h00 = 2.0 * t3 - 3.0 * t2 + 1.0
    h10 = (t3 - 2.0 * t2 + t) * ds
    h01 = 3.0 * t2 - 2.0 * t3
    h11 = (t3 - t2) * ds
    for i in range(z0.shape[0]):
        out[i] = h00 * z0[i] + h10 * tz0[i] + h01 * z1[i] + h11 * tz1[i]


@jit
def _sign(x):
    return (x > 0.0) - (x < 0.0)


@jit
def inner(wz, a_z, a_p, b_z, b_p):
    """The arclength inner product wz a_z.b_z + a_p b_p of the continuation."""
    acc = 0.0
    for i in range(a_z.shape[0]):
        acc += a_z[i] * b_z[i]
    return wz * acc + a_p * b_p


@jit
def _grow_rows(a, rows):
    """a (r, c) copied into a new (rows, c) array (rows >= r)."""
    out = np.empty((rows, a.shape[1]))
    out[:a.shape[0]] = a
    return out


@jit_inline
def _solve_crossings(problem, step, z, tz, p, tp, z_new, tz_new, p_new, tp_new, ds, p_grid, segment, tol, g_z,
                     g_table, n_grid):
    """Solve the values of ``p_grid`` that the step number ``step`` from p to p_new crosses (in the
    direction of travel; Newton, 30 iterations, from :func:`hermite_seed`) and append the converged ones
    to g_z / g_table (rows GRID_*). Returns (g_z, g_table, n_grid), the tables grown when full."""
    if p_new == p:
        return g_z, g_table, n_grid
    n_p = p_grid.shape[0]
    lo = min(p, p_new)
    hi = max(p, p_new)
    seed = np.empty(z.shape[0])
    for jj in range(n_p):
        g = jj if p_new > p else n_p - 1 - jj
        pg = p_grid[g]
        inside = (lo < pg <= hi) if p_new > p else (lo <= pg < hi)
        if not inside:
            continue
        frac = (pg - p) / (p_new - p)
        hermite_seed(z, tz, p, tp, z_new, tz_new, p_new, tp_new, ds, pg, seed)
        zg, it_g, g_status = problem_solve_at(problem, seed, pg, tol, 30)
        if g_status != 0:
            continue
        if n_grid == g_z.shape[0]:
            g_z = _grow_rows(g_z, 2 * n_grid)
            g_table = _grow_rows(g_table, 2 * n_grid)
        g_z[n_grid] = zg
        g_table[n_grid, GRID_INDEX] = g
        g_table[n_grid, GRID_P] = pg
        g_table[n_grid, GRID_ITERATIONS] = it_g
        g_table[n_grid, GRID_SEGMENT] = segment
        g_table[n_grid, GRID_STEP] = step
        g_table[n_grid, GRID_FRACTION] = frac
        n_grid += 1
    return g_z, g_table, n_grid


@jit
def _append_point(zs, tzs, table, count, z_new, tz_new, p_new, tp_new, segment, ds):
    """Append a branch point (and the arclength ds of the step to it, in the previous row); returns the
    (grown) tables."""
    if count == zs.shape[0]:
        zs = _grow_rows(zs, 2 * count)
        tzs = _grow_rows(tzs, 2 * count)
        table = _grow_rows(table, 2 * count)
    table[count - 1, STEP_H] = ds
    zs[count] = z_new
    tzs[count] = tz_new
    table[count, STEP_P] = p_new
    table[count, STEP_TP] = tp_new
    table[count, STEP_SEGMENT] = segment
    return zs, tzs, table


@jit
def _append_fold(folds, n_folds, k):
    """Append step k to the fold steps (grown when full)."""
    if n_folds == folds.shape[0]:
        grown = np.empty(2 * n_folds, dtype=np.int64)
        grown[:n_folds] = folds
        folds = grown
    folds[n_folds] = k
    return folds


@jit
def _unit(t, wz):
    """t = (tz, tp) (n + 1) normalised in the arclength norm: (tz, tp)."""
    n = t.shape[0] - 1
    tz = t[:n]
    tp = t[n]
    norm = math.sqrt(inner(wz, tz, tp, tz, tp))
    return tz / norm, tp / norm


def _trace_branch(problem, z, p, tz, tp, p_lo, p_hi, max_steps, h0, h_max, p_grid, wz, tol):
    """The compiled loop of :func:`trace_branch`."""
    n = z.shape[0]
    zs, tzs, table = np.empty((256, n)), np.empty((256, n)), np.empty((256, 4))
    folds = np.empty(256, dtype=np.int64)
    g_z, g_table = np.empty((64, n)), np.empty((64, 6))
    count, n_folds, n_grid, segment, steps, status = 1, 0, 0, 0, 0, 0
    zs[0], tzs[0] = z, tz
    table[0, STEP_P], table[0, STEP_TP], table[0, STEP_SEGMENT] = p, tp, 0
    z, tz = z.copy(), tz.copy()
    z_pred = np.empty(n)
    h = h0
    max_turn_cos = math.cos(math.radians(10.0))
    stopped = False
    while True:
        if steps >= max_steps:
            status = TRACE_MAX_STEPS
            break
        if (p >= p_hi and tp > 0) or (p <= p_lo and tp < 0):
            break
        steps += 1
        for i in range(n):
            z_pred[i] = z[i] + h * tz[i]
        ok, z_new, p_new, iters, t = problem_correct(problem, z_pred, p + h * tp, tz, tp, wz, tol, 12)
        if not ok:
            h *= 0.5
            if h < 1e-7:
                status = TRACE_STEP_UNDERFLOW
                break
            continue
        tz_new, tp_new = _unit(t, wz)
        if inner(wz, tz, tp, tz_new, tp_new) < max_turn_cos and h > 1e-6:
            h *= 0.5
            continue
        k = count - 1
        ds = inner(wz, tz, tp, z_new - z, p_new - p)    # the step's arclength
        g_z, g_table, n_grid = _solve_crossings(problem, k, z, tz, p, tp, z_new, tz_new, p_new, tp_new, ds, p_grid,
                                                segment, tol, g_z, g_table, n_grid)
        if _sign(tp_new) != _sign(tp) and tp != 0.0:
            folds = _append_fold(folds, n_folds, k)
            n_folds += 1
            segment += 1
        zs, tzs, table = _append_point(zs, tzs, table, count, z_new, tz_new, p_new, tp_new, segment, ds)
        count += 1
        flipped = problem_turned_back(problem, z, z_new)
        z, p, tz, tp = z_new, p_new, tz_new, tp_new
        if flipped:
            stopped = True
            break
        h = min(h * (1.5 if iters <= 3 else (1.0 if iters <= 5 else 0.6)), h_max)
    return (status, p, steps, stopped, zs[:count], tzs[:count], table[:count], folds[:n_folds], g_z[:n_grid],
            g_table[:n_grid])


# -------------------------------------------------------------- entry points from Python
def _correct(problem, z_pred, p_pred, tz, tp, wz, tol, max_iter):
    return problem_correct(problem, z_pred, p_pred, tz, tp, wz, tol, max_iter)


def _solve_at(problem, seed, p, tol, max_iter):
    return problem_solve_at(problem, seed, p, tol, max_iter)


def _tangent(problem, z, p, tz, tp, wz):
    return problem_tangent(problem, z, p, tz, tp, wz)


_ENTRY_POINTS = (_trace_branch, _correct, _solve_at, _tangent)
#: The engine's entry points compiled into the on-disk cache (for the problem types registered with
#: ``cache=True``) and in each process (for the others).
_CACHED, _UNCACHED = tuple(jit(fn) for fn in _ENTRY_POINTS), tuple(jit_uncached(fn) for fn in _ENTRY_POINTS)
_CACHED_TYPES: set = set()


def _compiled(problem) -> tuple:
    """The entry points (trace_branch, correct, solve_at, tangent) compiled for ``problem``'s type."""
    return _CACHED if type(problem) in _CACHED_TYPES else _UNCACHED


def trace_branch(problem, z, p, tz, tp, p_lo, p_hi, max_steps, h0, h_max, p_grid, wz, tol):
    """Follow the branch of ``problem`` from (z, p) along the unit tangent (tz, tp) (module docstring);
    the first step is h0 long, the corrector gets 12 iterations.

    Returns (status, p_at_end, steps, stopped, zs, tzs, step_table, fold_steps, grid_z, grid_table):
    status 0 or one of the TRACE_* codes; zs, tzs (K + 1, n) the branch points and unit tangents;
    step_table (K + 1, 4) with the columns STEP_* (STEP_H: the arclength of the step from row k, in
    row k; the last row's is unset); grid_z (G, n) and grid_table (G, 6, columns GRID_*) the solutions at
    the crossed grid values; stopped: the problem's stop test ended the branch.
    """
    return _compiled(problem)[0](problem, z, p, tz, tp, p_lo, p_hi, max_steps, h0, h_max, p_grid, wz, tol)


def correct(problem, z_pred, p_pred, tz, tp, wz, tol, max_iter):
    """:func:`problem_correct` of ``problem``."""
    return _compiled(problem)[1](problem, z_pred, p_pred, tz, tp, wz, tol, max_iter)


def solve_at(problem, seed, p, tol, max_iter):
    """:func:`problem_solve_at` of ``problem``."""
    return _compiled(problem)[2](problem, seed, p, tol, max_iter)


def tangent(problem, z, p, tz, tp, wz):
    """:func:`problem_tangent` of ``problem``."""
    return _compiled(problem)[3](problem, z, p, tz, tp, wz)
