"""The frequency response of the collocation system (eq. 16) as a problem of the arclength engine.

The unknowns are the scaled collocation values z of one response period and p = ln omega of the
response frequency; the equations are the collocation residual R(z, e^p) of
:mod:`.collocation_kernels`. The branch's corrector, tangent and fixed-frequency Newton solve the
bordered and plain Jacobians by the structured reduction (M unknowns instead of 3M); a
period-doubled branch stops when its odd-harmonic part turns back (it came back through the T/2
orbit). :class:`CollocationBranch` is registered with :func:`.arclength_kernels.register_problem`
when this module is imported.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from .arclength_kernels import converges_below, register_problem
from .collocation_kernels import (
    circulant_inverse,
    collocation_residual_jacobian,
    fill_collocation,
    max_abs,
    second_derivative_column,
    structured_solve_into,
    trig_tables,
)
from .jit import jit
from .newton_kernels import newton_with_tables

__all__ = ["CollocationBranch", "collocation_branch", "bordered_corrector", "bordered_tangent"]

#: The arclength problem of one branch: u^2 (V^2) at the M collocation phases, the model constants,
#: the state scales, the reference rate (1/s), the differentiation matrix D, the tables of M
#: (:func:`.collocation_kernels.trig_tables`, :func:`.collocation_kernels.second_derivative_column`), the
#: odd-harmonic projector (M, M) and whether the branch stops when its odd-harmonic part turns back.
CollocationBranch = namedtuple("CollocationBranch", ["u2", "constants", "scale", "rate_ref", "dmat", "cos_t", "sin_t",
                                                     "d2col", "podd", "stop_on_odd_flip"])


def collocation_branch(u2, constants, scale, rate_ref, dmat, odd_projector=None) -> CollocationBranch:
    """The :class:`CollocationBranch` of a collocation system under u^2 (``odd_projector``: stop when the
    odd-harmonic part it projects on turns back)."""
    u2 = np.ascontiguousarray(u2, dtype=float)
    dmat = np.ascontiguousarray(dmat, dtype=float)
    cos_t, sin_t = trig_tables(u2.shape[0])
    podd = np.zeros((1, 1)) if odd_projector is None else np.ascontiguousarray(odd_projector, dtype=float)
    return CollocationBranch(u2, tuple(float(c) for c in constants), np.asarray(scale, dtype=float), float(rate_ref),
                             dmat, cos_t, sin_t, second_derivative_column(dmat), podd, odd_projector is not None)


@jit
def bordered_corrector(z_pred, p_pred, tz, tp, wz, u2, constants, scale, rate_ref, dmat, tol, max_iter):
    """:func:`_corrector` with the tables of m computed (flat arguments: the cheapest call from Python)."""
    cos_t, sin_t = trig_tables(u2.shape[0])
    return _corrector(z_pred, p_pred, tz, tp, wz, u2, constants, scale, rate_ref, dmat, tol, max_iter, cos_t, sin_t,
                      second_derivative_column(dmat))


@jit
def _corrector(z_pred, p_pred, tz, tp, wz, u2, constants, scale, rate_ref, dmat, tol, max_iter, cos_t, sin_t,
               d2col):
    """Pseudo-arclength corrector of the continuation (p = ln omega): (ok, z, p, iterations, t).

    Newton on [R(z, e^p); wz tz.(z - z_pred) + tp (p - p_pred)] = 0, each step by the structured
    reduction of the bordered system (:func:`structured_solve_into`); gives up (ok False) on a singular
    matrix, a non-finite or > 10 step, or after max_iter; converged when the step is below
    max(tol, 1e-9), or when the next step is predicted below it (:func:`converges_below`; the iterations
    then count that step, so the step control sees the same numbers). t (n + 1) is the next tangent,
    unnormalised: the bordered system of the last matrix built (at the last iterate before the final
    step) solved for e_n, as :func:`bordered_tangent` there (the same numbers: one elimination for both
    right-hand sides). The tables of m (``cos_t``, ``sin_t``, ``d2col``) are given.
    """
    n = z_pred.shape[0]
    m = u2.shape[0]
    zc = z_pred.copy()
    pc = p_pred
    r = np.empty(n)
    e = np.empty((3, 3, m))
    drate = np.empty(n)
    wvec = np.empty(n)
    for i in range(n):
        wvec[i] = wz * tz[i]
    rhs = np.empty(n + 1)
    t = np.empty(n + 1)
    prev_snorm = 0.0
    for it in range(1, max_iter + 1):
        omega = math.exp(pc)
        wr = omega / rate_ref
        fill_collocation(zc, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
        g = 0.0
        for i in range(n):
            g += tz[i] * (zc[i] - z_pred[i])
        g = wz * g + tp * (pc - p_pred)
        rhs[:n] = r
        rhs[n] = g
        t[:] = 0.0
        t[n] = 1.0
        cinv = circulant_inverse(wr, e[1, 1, 0], cos_t, sin_t)
        if not structured_solve_into(e, wr, dmat, d2col, cinv, drate, wvec, tp, rhs, True, t, True):
            return False, zc, pc, it, t
        for i in range(n):
            zc[i] -= rhs[i]
        pc -= rhs[n]
        snorm = max_abs(rhs)
        if not np.isfinite(snorm) or snorm > 10.0:
            return False, zc, pc, it, t
        if snorm < max(tol, 1e-9):
            return True, zc, pc, it, t
        if converges_below(snorm, prev_snorm, max(tol, 1e-9)):   # counted with the step it makes unneeded
            return True, zc, pc, it + 1, t
        prev_snorm = snorm
    return False, zc, pc, max_iter, t


@jit
def bordered_tangent(z, p, tz, tp, wz, u2, constants, scale, rate_ref, dmat):
    """(t, ok): the solution of [[J(z, e^p), dR/dp], [wz tz^T, tp]] t = e_n (the unnormalised tangent of
    the continuation), by the structured reduction; ok False when the bordered matrix is singular."""
    n = z.shape[0]
    m = u2.shape[0]
    r = np.empty(n)
    e = np.empty((3, 3, m))
    drate = np.empty(n)
    omega = math.exp(p)
    wr = omega / rate_ref
    fill_collocation(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
    wvec = np.empty(n)
    for i in range(n):
        wvec[i] = wz * tz[i]
    t = np.zeros(n + 1)
    t[n] = 1.0
    cos_t, sin_t = trig_tables(m)
    ok = structured_solve_into(e, wr, dmat, second_derivative_column(dmat),
                               circulant_inverse(wr, e[1, 1, 0], cos_t, sin_t), drate, wvec, tp, t, True, t, False)
    return t, ok


@jit
def _odd_norm_and_dot(z_a, z_b, podd, m):
    """|odd(a)|, |odd(b)|, odd(a).odd(b) of the odd-harmonic parts (projector podd per state) of z_a, z_b."""
    na = 0.0
    nb = 0.0
    dot = 0.0
    for i in range(3):
        for k in range(m):
            pa = 0.0
            pb = 0.0
            for j in range(m):
                pa += z_a[i * m + j] * podd[k, j]
                pb += z_b[i * m + j] * podd[k, j]
            na += pa * pa
            nb += pb * pb
            dot += pa * pb
    return math.sqrt(na), math.sqrt(nb), dot


@jit
def _residual_jacobian(problem, z, p):
    """(R, dR/dz, dR/dp) at (z, p = ln omega)."""
    b = problem
    return collocation_residual_jacobian(z, math.exp(p), b.u2, b.constants, b.scale, b.rate_ref, b.dmat)


@jit
def _correct(problem, z_pred, p_pred, tz, tp, wz, tol, max_iter):
    """:func:`_corrector` on the branch."""
    b = problem
    return _corrector(z_pred, p_pred, tz, tp, wz, b.u2, b.constants, b.scale, b.rate_ref, b.dmat, tol, max_iter,
                      b.cos_t, b.sin_t, b.d2col)


@jit
def _solve_at(problem, seed, p, tol, max_iter):
    """Newton at omega = e^p (:func:`.newton_kernels.newton_with_tables`): (z, iterations, status)."""
    b = problem
    z, it, _res, status = newton_with_tables(seed, math.exp(p), b.u2, b.constants, b.scale, b.rate_ref, b.dmat, tol,
                                             max_iter, b.cos_t, b.sin_t, b.d2col)
    return z, it, status


@jit
def _tangent(problem, z, p, tz, tp, wz):
    """:func:`bordered_tangent` on the branch."""
    b = problem
    return bordered_tangent(z, p, tz, tp, wz, b.u2, b.constants, b.scale, b.rate_ref, b.dmat)


@jit
def _turned_back(problem, z_prev, z_new):
    """The odd-harmonic part turned back from z_prev to z_new (a period-doubled branch came back through the
    T/2 orbit; not the start's noise: its norm above 1e-6 sqrt(n))."""
    if not problem.stop_on_odd_flip:
        return False
    na, nb, dot = _odd_norm_and_dot(z_prev, z_new, problem.podd, problem.u2.shape[0])
    return na > 1e-6 * math.sqrt(z_new.shape[0]) and dot < -0.5 * na * nb


register_problem(CollocationBranch, _residual_jacobian, _correct, _solve_at, _tangent, _turned_back, cache=True)
