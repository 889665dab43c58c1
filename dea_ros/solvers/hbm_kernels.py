"""Compiled inner loops of the native harmonic balance (optional numba; same answers as the numpy path).

A collocation Newton solve of N = 4 is 27 unknowns and a few thousand floating-point operations;
written with numpy it costs hundreds of microseconds of call overhead. These functions are the
same algorithms written as plain loops: with numba installed (``pip install dea_ros[fast]``, or
Ubuntu's ``python3-numba``) they are compiled on first use (cached on disk) and the solvers in
:mod:`dea_ros.solvers.harmonic_balance` and :mod:`dea_ros.solvers.continuation` call them;
without numba, or with the environment variable ``DEA_ROS_NUMBA=0``, the solvers keep their
vectorised numpy path. Both paths implement the same equations (collocation residual and
Jacobian of eq. 16, damped Newton, linearised initial guess, 4th-order Magnus monodromy) and
agree to rounding (checked by test/solvers/test_hbm_kernels.py). One difference of method: the
compiled Newton and pseudo-arclength steps solve their linear systems by a reduction that uses
the pattern of eq. 18 (see "structured linear solves" below: M unknowns instead of 3M), the numpy
path by dense LU; the solutions are the same to rounding.

The model is :func:`dea_ros.model.dynamics.state_equation` compiled as it is (one definition).
Every kernel works in the scaled variables of
:class:`~dea_ros.solvers.harmonic_balance.CollocationSystem`: z = x / scale, state-major.
"""
from __future__ import annotations

import math
import os
import warnings

import numpy as np

from ..model.dynamics import state_equation


def _import_numba():
    """numba, or None when it is not installed (it is optional: the numpy path needs nothing)."""
    try:
        import numba
    except ImportError:  # pragma: no cover - depends on the installation
        return None
    return numba


numba = _import_numba()

__all__ = [
    "available", "enabled", "set_enabled", "jit", "STATUS_MESSAGES",
    "collocation_residual_jacobian", "newton", "bordered_corrector", "bordered_tangent", "structured_solve",
    "linear_guess", "spectral_radius3", "solve_cold", "LAPACK_FROM", "solve_batch", "max_spectral_radius",
    "monodromy", "monodromy_batch", "eigenvalues3", "hermite_seed", "converges_below", "GAUSS_NODES",
    "trace_branch", "TRACE_STEP_UNDERFLOW", "TRACE_MAX_STEPS",
]

_enabled = numba is not None and os.environ.get("DEA_ROS_NUMBA", "1").strip() not in ("0", "false", "no")
_checked = False
_failure = None   # why the kernels could not run (then the numpy path is used)


def available() -> bool:
    """True when numba is installed (the kernels can be compiled)."""
    return numba is not None


def enabled() -> bool:
    """True when the solvers use the compiled kernels (numba installed, not disabled, and they compile).

    The first call compiles (or loads from the on-disk cache) every kernel and runs it on a small
    problem; a numba too old for one of them is reported once (a warning) and the numpy path is
    used from then on.
    """
    global _enabled, _checked, _failure
    if _enabled and not _checked:
        _checked = True
        try:
            _self_check()
        except Exception as exc:  # noqa: BLE001 - any numba failure: fall back, say why
            _enabled = False
            _failure = (f"numba {getattr(numba, '__version__', '?')} could not run the harmonic-balance kernels "
                        f"({type(exc).__name__}: {str(exc)[:300]})")
            warnings.warn(f"dea_ros: {_failure}; using the numpy path (same results, slower)", RuntimeWarning,
                          stacklevel=2)
    return _enabled


def set_enabled(flag: bool) -> bool:
    """Switch the compiled kernels on or off (e.g. to compare with the numpy path); returns the old state."""
    global _enabled
    if flag and numba is None:
        raise RuntimeError("numba is not installed: pip install numba (or apt install python3-numba)")
    old = enabled()
    if flag and _failure is not None:
        raise RuntimeError(_failure)
    _enabled = bool(flag)
    return old


def jit(fn):
    """``fn`` compiled by numba (no Python objects, cached on disk, IEEE arithmetic as written); ``fn``
    itself without numba."""
    if numba is None:
        return fn
    try:
        return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)
    except RuntimeError:  # no writable cache location (package and user cache read-only): compile each run
        return numba.njit(cache=False, nogil=True, error_model="numpy")(fn)


def jit_inline(fn):
    """``fn`` compiled by numba and inlined into its compiled callers (numba IR level): small helpers in
    loops that must vectorise (LLVM leaves calls in a loop scalar); ``fn`` itself without numba."""
    if numba is None:
        return fn
    return numba.njit(inline="always", nogil=True, error_model="numpy")(fn)


_jit = jit
_model = jit(state_equation)
_model_inline = jit_inline(state_equation)   # the same f and df/dx, for the vectorised Magnus loop

#: Newton outcome codes returned by :func:`newton` (0 converged) and their messages.
STATUS_MESSAGES = {
    1: "singular harmonic-balance Jacobian (a fold?)",
    2: "harmonic-balance Newton step is not finite",
    3: "line search failed",
    4: "no convergence",
}

#: Gauss-Legendre nodes of the 2-point rule on [0, 1] (4th-order Magnus).
GAUSS_NODES = (0.5 - math.sqrt(3.0) / 6.0, 0.5 + math.sqrt(3.0) / 6.0)


@_jit
def _max_abs(v):
    """max |v_i|, NaN if any entry is NaN (as numpy's max)."""
    out = 0.0
    for i in range(v.shape[0]):
        a = abs(v[i])
        if a > out or a != a:
            out = a
            if a != a:
                return a
    return out


@_jit
def _eliminate(a, b, b2, two):
    """Solve a x = b (and a x2 = b2 when ``two``) by Gaussian elimination with partial pivoting (a, b, b2
    overwritten; x in b, x2 in b2; each right-hand side sees the same operations as alone).

    Returns False on an exactly zero pivot (what LAPACK reports as singular).
    """
    n = a.shape[0]
    for col in range(n):
        p = col
        best = abs(a[col, col])
        for row in range(col + 1, n):
            v = abs(a[row, col])
            if v > best:
                best = v
                p = row
        if best == 0.0:
            return False
        if p != col:
            for k in range(col, n):
                t = a[col, k]
                a[col, k] = a[p, k]
                a[p, k] = t
            t = b[col]
            b[col] = b[p]
            b[p] = t
            if two:
                t = b2[col]
                b2[col] = b2[p]
                b2[p] = t
        piv = a[col, col]
        for row in range(col + 1, n):
            fct = a[row, col] / piv
            if fct != 0.0:
                for k in range(col + 1, n):
                    a[row, k] -= fct * a[col, k]
                b[row] -= fct * b[col]
                if two:
                    b2[row] -= fct * b2[col]
    _back_substitute(a, b)
    if two:
        _back_substitute(a, b2)
    return True


@_jit
def _back_substitute(a, b):
    """Solve the upper triangle of a into b (b overwritten)."""
    n = a.shape[0]
    for row in range(n - 1, -1, -1):
        acc = b[row]
        for k in range(row + 1, n):
            acc -= a[row, k] * b[k]
        b[row] = acc / a[row, row]


@_jit
def _solve_inplace(a, b):
    """Solve a x = b by Gaussian elimination with partial pivoting (a, b overwritten; x in b).

    Returns False on an exactly zero pivot (what LAPACK reports as singular).
    """
    return _eliminate(a, b, b, False)


#: Above this size the linear systems go to LAPACK (faster blocked code); below, the loop above (less overhead).
LAPACK_FROM = 40


@_jit
def _solve_into(a, b, b2, two):
    """Solve a x = b into b (and a x2 = b2 into b2 when ``two``; a may be overwritten); False when a is
    singular."""
    if a.shape[0] < LAPACK_FROM:
        return _eliminate(a, b, b2, two)
    try:
        x = np.linalg.solve(a, b)
        if two:
            b2[:] = np.linalg.solve(a, b2)
    except Exception:  # numba raises on an exactly singular matrix
        return False
    b[:] = x
    return True


@_jit
def _fill(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate):
    """Scaled collocation residual into r (3M,), omega X D^T (scaled) into drate, and the Jacobian's
    point-diagonal entries into e (3, 3, M): e[i, j, k] = -(df_i/dx_j at point k) scale_j / (scale_i
    rate_ref). The whole Jacobian is omega / rate_ref kron(I3, D) plus these (:func:`_dense_jacobian`)."""
    m = u2.shape[0]
    x = np.empty((3, m))
    for i in range(3):
        for k in range(m):
            x[i, k] = z[i * m + k] * scale[i]
    res_scale = np.empty(3)
    block = np.empty((3, 3))
    for i in range(3):
        res_scale[i] = 1.0 / (scale[i] * rate_ref)
        for col in range(3):
            block[i, col] = scale[col] / (scale[i] * rate_ref)
    a = np.empty((3, 3))
    for k in range(m):
        f0, f1, f2 = _unpack(constants, x[0, k], x[1, k], x[2, k], u2[k], a)
        for i in range(3):
            fi = f0 if i == 0 else (f1 if i == 1 else f2)
            acc = 0.0
            for j in range(m):
                acc += x[i, j] * dmat[k, j]
            rate = omega * acc
            drate[i * m + k] = rate * res_scale[i]
            r[i * m + k] = (rate - fi) * res_scale[i]
            for col in range(3):
                e[i, col, k] = -a[i, col] * block[i, col]


@_jit
def _dense_jacobian(e, wr, dmat, jac):
    """The dense scaled collocation Jacobian wr kron(I3, D) + point-diagonal entries e, into jac (3M, 3M)."""
    m = dmat.shape[0]
    jac[:, :] = 0.0
    for i in range(3):
        for k in range(m):
            for j in range(m):
                jac[i * m + k, i * m + j] = wr * dmat[k, j]
    for i in range(3):
        for col in range(3):
            for k in range(m):
                jac[i * m + k, col * m + k] += e[i, col, k]


# ------------------------------------------------------------------ structured linear solves
# The collocation Jacobian of eq. 16 for this model has a pattern the dense LU ignores. With the
# states (d, eps1, v) and J = wr kron(I3, D) + point-diagonal entries e (:func:`_fill`), eq. 18 gives
# e00 = e01 = e12 = 0 (d' = v; eps1' = a (lambda(d) - 1 - eps1)), e02 = -scale_v / (scale_d rate_ref)
# and e11 = a / rate_ref constant. So for J x = r, with M-vectors x = (x0, x1, x2):
#   row 0: wr D x0 + e02 x2 = r0                       ->  x2 = (r0 - wr D x0) / e02
#   row 1: e10 x0 + (wr D + e11 I) x1 = r1             ->  x1 = C (r1 - e10 x0),  C = (wr D + e11 I)^-1
#   row 2: e20 x0 + e21 x1 + (wr D + e22) x2 = r2      ->  S x0 = rho(r)
# with S = e20 - e21 C e10 - (wr D + e22) wr D / e02 and rho(r) = r2 - e21 C r1 - (wr D + e22) r0 / e02
# (diagonal entries written as vectors). D and C are circulant (D is the Fourier differentiation on
# equispaced points: C has the eigenvalues 1 / (e11 + i wr kappa), kappa = -N..N), so C costs M N
# operations and S an M x M LU instead of the 3M x 3M one: (3M)^3 / 3 -> M^3 / 3 flops, the same
# solution to rounding. The pseudo-arclength system [[J, b], [w^T, tp]] is reduced the same way to
# an (M + 1) x (M + 1) system (bordered S), so it stays regular at folds where S is singular.
# test/solvers/test_hbm_kernels.py checks the pattern of eq. 18 and the solves against dense LU.


@_jit
def _trig_tables(m):
    """cos, sin (m, N) of kappa theta_q for theta_q = 2 pi q / m, kappa = 1..N (N = (m - 1) / 2)."""
    nh = (m - 1) // 2
    base_c = np.empty(m)
    base_s = np.empty(m)
    for j in range(m):
        ang = 2.0 * math.pi * j / m
        base_c[j] = math.cos(ang)
        base_s[j] = math.sin(ang)
    cos_t = np.empty((m, nh))
    sin_t = np.empty((m, nh))
    for q in range(m):
        j = 0
        for kap in range(1, nh + 1):
            j += q
            if j >= m:
                j -= m
            cos_t[q, kap - 1] = base_c[j]
            sin_t[q, kap - 1] = base_s[j]
    return cos_t, sin_t


@_jit
def _circulant_inverse(wr, e11, cos_t, sin_t):
    """First column c of C = (wr D + e11 I)^-1: C[k, l] = c[(k - l) mod m]."""
    m, nh = cos_t.shape
    c = np.empty(m)
    for q in range(m):
        acc = 1.0 / e11
        for kap in range(1, nh + 1):
            wk = wr * kap
            acc += 2.0 * (e11 * cos_t[q, kap - 1] + wk * sin_t[q, kap - 1]) / (e11 * e11 + wk * wk)
        c[q] = acc / m
    return c


@_jit
def _wrap(q, m):
    """q mod m for -m <= q < m (no integer division: this is in the innermost loops)."""
    return q + m if q < 0 else q


@_jit
def _second_derivative_column(dmat):
    """First column of D^2 (circulant as D)."""
    m = dmat.shape[0]
    d2 = np.empty(m)
    for q in range(m):
        acc = 0.0
        for j in range(m):
            acc += dmat[q, j] * dmat[j, 0]
        d2[q] = acc
    return d2


@_jit
def _reduce_rhs(e, wr, dmat, cinv, v, out):
    """rho(v) = v2 - e21 C v1 - (wr D + e22) v0 / e02 into out (m,)."""
    m = dmat.shape[0]
    e02 = e[0, 2, 0]
    for k in range(m):
        c1 = 0.0
        d0 = 0.0
        for jj in range(m):
            c1 += cinv[_wrap(k - jj, m)] * v[m + jj]
            d0 += dmat[k, jj] * v[jj]
        out[k] = v[2 * m + k] - e[2, 1, k] * c1 - (wr * d0 + e[2, 2, k] * v[k]) / e02


@_jit
def _expand(e, wr, dmat, cinv, bvec, bordered, rhs, y):
    """The full solution (x0, x1, x2[, dp]) into rhs from the reduced one y (x0[, dp]) (see above)."""
    m = dmat.shape[0]
    e02 = e[0, 2, 0]
    dp = y[m] if bordered else 0.0
    t1 = np.empty(m)
    x1 = np.empty(m)
    x2 = np.empty(m)
    for jj in range(m):
        t1[jj] = rhs[m + jj] - e[1, 0, jj] * y[jj]
        if bordered:
            t1[jj] -= bvec[m + jj] * dp
    for k in range(m):
        acc1 = 0.0
        accd = 0.0
        for jj in range(m):
            acc1 += cinv[_wrap(k - jj, m)] * t1[jj]
            accd += dmat[k, jj] * y[jj]
        x1[k] = acc1
        r0 = rhs[k] - bvec[k] * dp if bordered else rhs[k]
        x2[k] = (r0 - wr * accd) / e02
    for k in range(m):
        rhs[k] = y[k]
        rhs[m + k] = x1[k]
        rhs[2 * m + k] = x2[k]
    if bordered:
        rhs[3 * m] = dp


@_jit
def _bordered_row_rhs(e, wvec, rhs, q1, m):
    """The reduced bordered row's right-hand side: g - sum_j q1_j rhs1_j + wvec2_j rhs0_j / e02."""
    e02 = e[0, 2, 0]
    g = rhs[3 * m]
    for jj in range(m):
        g -= q1[jj] * rhs[m + jj] + wvec[2 * m + jj] * rhs[jj] / e02
    return g


@_jit
def _structured_solve(e, wr, dmat, d2col, cinv, bvec, wvec, tp, rhs, bordered, rhs2, two):
    """Solve J x = rhs, or the bordered [[J, bvec], [wvec^T, tp]] x = rhs when ``bordered``, into rhs
    (3M or 3M + 1) by the reduction above, and the same system with rhs2 into rhs2 when ``two`` (one
    reduced matrix and elimination for both); False when the reduced matrix is singular."""
    m = dmat.shape[0]
    e02 = e[0, 2, 0]
    ms = m + 1 if bordered else m
    a = np.empty((ms, ms))
    y = np.empty(ms)
    y2 = np.empty(ms if two else 0)
    _reduce_rhs(e, wr, dmat, cinv, rhs, y)
    if two:
        _reduce_rhs(e, wr, dmat, cinv, rhs2, y2)
    wr2 = wr * wr
    for k in range(m):
        for jj in range(m):
            q = _wrap(k - jj, m)
            a[k, jj] = -e[2, 1, k] * cinv[q] * e[1, 0, jj] - (wr2 * d2col[q] + e[2, 2, k] * wr * dmat[k, jj]) / e02
        a[k, k] += e[2, 0, k]
    if bordered:
        rb = np.empty(m)
        _reduce_rhs(e, wr, dmat, cinv, bvec, rb)
        corner = tp
        q1v = np.empty(m)
        for k in range(m):
            a[k, m] = rb[k]
        for jj in range(m):
            q1 = 0.0
            dtw2 = 0.0
            for k in range(m):
                q1 += cinv[_wrap(k - jj, m)] * wvec[m + k]
                dtw2 += dmat[k, jj] * wvec[2 * m + k]
            q1v[jj] = q1
            a[m, jj] = wvec[jj] - e[1, 0, jj] * q1 - wr * dtw2 / e02
            corner -= q1 * bvec[m + jj] + wvec[2 * m + jj] * bvec[jj] / e02
        a[m, m] = corner
        y[m] = _bordered_row_rhs(e, wvec, rhs, q1v, m)
        if two:
            y2[m] = _bordered_row_rhs(e, wvec, rhs2, q1v, m)
    if not _solve_into(a, y, y2, two):
        return False
    _expand(e, wr, dmat, cinv, bvec, bordered, rhs, y)
    if two:
        _expand(e, wr, dmat, cinv, bvec, bordered, rhs2, y2)
    return True


@_jit
def structured_solve(z, omega, u2, constants, scale, rate_ref, dmat, rhs):
    """x with J(z, omega) x = rhs by the structured reduction (for tests: compare with a dense solve)."""
    m = u2.shape[0]
    r = np.empty(3 * m)
    drate = np.empty(3 * m)
    e = np.empty((3, 3, m))
    _fill(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
    cos_t, sin_t = _trig_tables(m)
    wr = omega / rate_ref
    x = rhs.copy()
    cinv = _circulant_inverse(wr, e[1, 1, 0], cos_t, sin_t)
    ok = _structured_solve(e, wr, dmat, _second_derivative_column(dmat), cinv, drate, drate, 0.0, x, False, x,
                           False)
    return x, ok


@_jit
def collocation_residual_jacobian(z, omega, u2, constants, scale, rate_ref, dmat):
    """(r, jac, dr/dln omega) of :meth:`CollocationSystem.residual_and_jacobian` at z (scaled)."""
    n = z.shape[0]
    m = u2.shape[0]
    r = np.empty(n)
    jac = np.empty((n, n))
    drate = np.empty(n)
    e = np.empty((3, 3, m))
    _fill(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
    _dense_jacobian(e, omega / rate_ref, dmat, jac)
    return r, jac, drate


@_jit
def newton(z0, omega, u2, constants, scale, rate_ref, dmat, tol, max_iter):
    """Damped Newton of :meth:`CollocationSystem.newton`: (z, iterations, scaled residual, status).

    status 0: converged (full step below tol); otherwise a key of :data:`STATUS_MESSAGES`. The Newton
    steps are solved by the structured reduction (:func:`_structured_solve`).
    """
    cos_t, sin_t = _trig_tables(u2.shape[0])
    return _newton(z0, omega, u2, constants, scale, rate_ref, dmat, tol, max_iter, cos_t, sin_t,
                   _second_derivative_column(dmat))


@_jit
def _newton(z0, omega, u2, constants, scale, rate_ref, dmat, tol, max_iter, cos_t, sin_t, d2col):
    """:func:`newton` with the tables of m (:func:`_trig_tables`, :func:`_second_derivative_column`) given."""
    n = z0.shape[0]
    m = u2.shape[0]
    z = z0.copy()
    z_new = np.empty(n)
    r = np.empty(n)
    e = np.empty((3, 3, m))
    r_new = np.empty(n)
    e_new = np.empty((3, 3, m))
    drate = np.empty(n)
    step = np.empty(n)
    wr = omega / rate_ref
    _fill(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
    cinv = _circulant_inverse(wr, e[1, 1, 0], cos_t, sin_t)
    rnorm = _max_abs(r)
    for it in range(1, max_iter + 1):
        step[:] = r
        if not _structured_solve(e, wr, dmat, d2col, cinv, drate, drate, 0.0, step, False, step, False):
            return z, it, rnorm, 1
        snorm = _max_abs(step)
        if not np.isfinite(snorm):
            return z, it, rnorm, 2
        lam = 1.0
        ok = False
        rn_new = rnorm
        for _ls in range(12):
            for i in range(n):
                z_new[i] = z[i] - lam * step[i]
            _fill(z_new, omega, u2, constants, scale, rate_ref, dmat, r_new, e_new, drate)
            rn_new = _max_abs(r_new)
            if np.isfinite(rn_new) and (rn_new < rnorm or rn_new < 1e-13 or lam * snorm < tol):
                ok = True
                break
            lam *= 0.5
        if not ok:
            return z, it, rnorm, 3
        z, z_new = z_new, z
        r, r_new = r_new, r
        e, e_new = e_new, e
        rnorm = rn_new
        if lam == 1.0 and snorm <= tol:
            return z, it, rnorm, 0
    return z, max_iter, rnorm, 4


@_jit
def converges_below(snorm, prev_snorm, tol):
    """True when Newton, whose last two steps had max-norms ``prev_snorm`` then ``snorm``, converges
    quadratically (the step shrank more than tenfold) and its next step, ||s_k||^3 / ||s_k-1||^2 by that
    rate, is below tol / 10: the iterate after the last step is then within tol, and the step that would
    confirm it is skipped (the corrector's; ``prev_snorm`` 0 before the second step: never)."""
    return snorm < 0.1 * prev_snorm and snorm * snorm * snorm < 0.1 * tol * prev_snorm * prev_snorm


@_jit
def bordered_corrector(z_pred, p_pred, tz, tp, wz, u2, constants, scale, rate_ref, dmat, tol, max_iter):
    """Pseudo-arclength corrector of the continuation (p = ln omega): (ok, z, p, iterations, t).

    Newton on [R(z, e^p); wz tz.(z - z_pred) + tp (p - p_pred)] = 0, each step by the structured
    reduction of the bordered system (:func:`_structured_solve`); gives up (ok False) on a singular
    matrix, a non-finite or > 10 step, or after max_iter; converged when the step is below
    max(tol, 1e-9), or when the next step is predicted below it (:func:`converges_below`; the iterations
    then count that step, so the step control sees the same numbers). t (n + 1) is the next tangent,
    unnormalised: the bordered system of the last matrix built (at the last iterate before the final
    step) solved for e_n, as :func:`bordered_tangent` there (the same numbers: one elimination for both
    right-hand sides).
    """
    cos_t, sin_t = _trig_tables(u2.shape[0])
    return _corrector(z_pred, p_pred, tz, tp, wz, u2, constants, scale, rate_ref, dmat, tol, max_iter, cos_t, sin_t,
                      _second_derivative_column(dmat))


@_jit
def _corrector(z_pred, p_pred, tz, tp, wz, u2, constants, scale, rate_ref, dmat, tol, max_iter, cos_t, sin_t,
               d2col):
    """:func:`bordered_corrector` with the tables of m given."""
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
        _fill(zc, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
        g = 0.0
        for i in range(n):
            g += tz[i] * (zc[i] - z_pred[i])
        g = wz * g + tp * (pc - p_pred)
        rhs[:n] = r
        rhs[n] = g
        t[:] = 0.0
        t[n] = 1.0
        cinv = _circulant_inverse(wr, e[1, 1, 0], cos_t, sin_t)
        if not _structured_solve(e, wr, dmat, d2col, cinv, drate, wvec, tp, rhs, True, t, True):
            return False, zc, pc, it, t
        for i in range(n):
            zc[i] -= rhs[i]
        pc -= rhs[n]
        snorm = _max_abs(rhs)
        if not np.isfinite(snorm) or snorm > 10.0:
            return False, zc, pc, it, t
        if snorm < max(tol, 1e-9):
            return True, zc, pc, it, t
        if converges_below(snorm, prev_snorm, max(tol, 1e-9)):   # counted with the step it makes unneeded
            return True, zc, pc, it + 1, t
        prev_snorm = snorm
    return False, zc, pc, max_iter, t


@_jit
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
    _fill(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
    wvec = np.empty(n)
    for i in range(n):
        wvec[i] = wz * tz[i]
    t = np.zeros(n + 1)
    t[n] = 1.0
    cos_t, sin_t = _trig_tables(m)
    ok = _structured_solve(e, wr, dmat, _second_derivative_column(dmat),
                           _circulant_inverse(wr, e[1, 1, 0], cos_t, sin_t), drate, wvec, tp, t, True, t, False)
    return t, ok


#: Outcome codes of :func:`trace_branch` (0: left the range, stopped or ran out of steps normally).
TRACE_STEP_UNDERFLOW = 1
TRACE_MAX_STEPS = 2


@_jit
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


@_jit
def _sign(x):
    return (x > 0.0) - (x < 0.0)


@_jit
def _inner(wz, a_z, a_p, b_z, b_p):
    """The arclength inner product |dz|^2 wz + dp^2 of the continuation."""
    acc = 0.0
    for i in range(a_z.shape[0]):
        acc += a_z[i] * b_z[i]
    return wz * acc + a_p * b_p


@_jit
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


@_jit
def _grow_rows(a, rows):
    """a (r, c) copied into a new (rows, c) array (rows >= r)."""
    out = np.empty((rows, a.shape[1]))
    out[:a.shape[0]] = a
    return out


#: Columns of the per-step and per-grid-point tables of :func:`trace_branch`.
STEP_P, STEP_TP, STEP_H, STEP_SEGMENT = range(4)
GRID_INDEX, GRID_P, GRID_ITERATIONS, GRID_SEGMENT, GRID_STEP, GRID_FRACTION = range(6)


@_jit
def trace_branch(z, p, tz, tp, p_lo, p_hi, max_steps, h0, h_max, p_grid, u2, constants, scale, rate_ref, dmat,
                 wz, tol, podd, stop_on_odd_flip):
    """The pseudo-arclength loop of ``continuation._Tracer.trace`` (same steps, same decisions), compiled.

    From (z, p) along the unit tangent (tz, tp), p = ln omega: predictor h, corrector
    (:func:`bordered_corrector`, 12 iterations), unit tangent where the corrector built its last
    matrix (solved there with the step); a step that fails halves h, one that turns the tangent by more
    than 10 degrees too; h grows by 1.5 / 1.0 / 0.6 after <= 3 / <= 5 / more iterations, up to
    h_max. Grid values ``p_grid`` crossed by a step are solved by :func:`newton` (30 iterations) from
    the step's cubic Hermite interpolant (:func:`hermite_seed`). Stops when the branch leaves
    [p_lo, p_hi] moving outwards, after ``max_steps``, or (``stop_on_odd_flip``) when the odd-harmonic
    part (projector ``podd``) turns back (the period-doubled branch returned to the T/2 orbit).

    Returns (status, p_at_end, steps, stopped, zs, tzs, step_table, fold_steps, grid_z, grid_table):
    status 0 or one of the TRACE_* codes; zs, tzs (K + 1, n) the branch points and unit tangents;
    step_table (K + 1, 4) with the columns STEP_* (STEP_H: the arclength of the step from row k, in
    row k; the last row's is unset); grid_z (G, n) and grid_table (G, 6, columns GRID_*) the solutions at
    the crossed grid values.
    """
    n = z.shape[0]
    m = u2.shape[0]
    cap = 256
    zs = np.empty((cap, n))
    tzs = np.empty((cap, n))
    table = np.empty((cap, 4))
    folds = np.empty(cap, dtype=np.int64)
    g_z = np.empty((64, n))
    g_table = np.empty((64, 6))
    count = 1
    n_folds = 0
    n_grid = 0
    zs[0] = z
    tzs[0] = tz
    table[0, STEP_P] = p
    table[0, STEP_TP] = tp
    table[0, STEP_SEGMENT] = 0
    z = z.copy()
    tz = tz.copy()
    z_pred = np.empty(n)
    seed = np.empty(n)
    segment = 0
    h = h0
    max_turn_cos = math.cos(math.radians(10.0))
    steps = 0
    stopped = False
    status = 0
    odd_floor = 1e-6 * math.sqrt(n)
    n_p = p_grid.shape[0]
    cos_t, sin_t = _trig_tables(m)
    d2col = _second_derivative_column(dmat)
    while True:
        if steps >= max_steps:
            status = TRACE_MAX_STEPS
            break
        if (p >= p_hi and tp > 0) or (p <= p_lo and tp < 0):
            break
        steps += 1
        for i in range(n):
            z_pred[i] = z[i] + h * tz[i]
        ok, z_new, p_new, iters, t = _corrector(z_pred, p + h * tp, tz, tp, wz, u2, constants, scale, rate_ref,
                                                dmat, tol, 12, cos_t, sin_t, d2col)
        if not ok:
            h *= 0.5
            if h < 1e-7:
                status = TRACE_STEP_UNDERFLOW
                break
            continue
        tz_new = t[:n]
        tp_new = t[n]
        norm = math.sqrt(_inner(wz, tz_new, tp_new, tz_new, tp_new))
        tz_new = tz_new / norm
        tp_new = tp_new / norm
        if _inner(wz, tz, tp, tz_new, tp_new) < max_turn_cos and h > 1e-6:
            h *= 0.5
            continue
        k = count - 1
        ds = _inner(wz, tz, tp, z_new - z, p_new - p)    # the step's arclength
        if p_new != p:
            lo = min(p, p_new)
            hi = max(p, p_new)
            for jj in range(n_p):
                g = jj if p_new > p else n_p - 1 - jj
                pg = p_grid[g]
                inside = (lo < pg <= hi) if p_new > p else (lo <= pg < hi)
                if not inside:
                    continue
                frac = (pg - p) / (p_new - p)
                hermite_seed(z, tz, p, tp, z_new, tz_new, p_new, tp_new, ds, pg, seed)
                zg, it_g, _res, g_status = _newton(seed, math.exp(pg), u2, constants, scale, rate_ref, dmat, tol, 30,
                                                   cos_t, sin_t, d2col)
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
                g_table[n_grid, GRID_STEP] = k
                g_table[n_grid, GRID_FRACTION] = frac
                n_grid += 1
        if _sign(tp_new) != _sign(tp) and tp != 0.0:
            if n_folds == folds.shape[0]:
                grown = np.empty(2 * n_folds, dtype=np.int64)
                grown[:n_folds] = folds
                folds = grown
            folds[n_folds] = k
            n_folds += 1
            segment += 1
        if count == zs.shape[0]:
            zs = _grow_rows(zs, 2 * count)
            tzs = _grow_rows(tzs, 2 * count)
            table = _grow_rows(table, 2 * count)
        table[k, STEP_H] = ds
        zs[count] = z_new
        tzs[count] = tz_new
        table[count, STEP_P] = p_new
        table[count, STEP_TP] = tp_new
        table[count, STEP_SEGMENT] = segment
        count += 1
        flipped = False
        if stop_on_odd_flip:
            na, nb, dot = _odd_norm_and_dot(z, z_new, podd, m)
            flipped = na > odd_floor and dot < -0.5 * na * nb
        z, p, tz, tp = z_new, p_new, tz_new, tp_new
        if flipped:
            stopped = True
            break
        h = min(h * (1.5 if iters <= 3 else (1.0 if iters <= 5 else 0.6)), h_max)
    return (status, p, steps, stopped, zs[:count], tzs[:count], table[:count], folds[:n_folds], g_z[:n_grid],
            g_table[:n_grid])


@_jit
def linear_guess(x_eq, a, b3, u2, u2_mean, omega):
    """Periodic response (3, M) of x' = A (x - x_eq) + b (u2 - mean) with b = (0, 0, b3), by a DFT.

    ``a`` is df/dx at the equilibrium x_eq under the mean u^2 (:func:`harmonic_balance.linear_guess`).
    """
    m = u2.shape[0]
    nh = (m - 1) // 2
    out = np.empty((3, m))
    for i in range(3):
        for k in range(m):
            out[i, k] = 0.0
    lhs = np.empty((3, 3), dtype=np.complex128)
    rhs = np.empty(3, dtype=np.complex128)
    for n in range(nh + 1):
        w = 0.0 + 0.0j
        for k in range(m):
            ang = 2.0 * math.pi * ((n * k) % m) / m
            w += (u2[k] - u2_mean) * complex(math.cos(ang), -math.sin(ang))
        for i in range(3):
            for j in range(3):
                lhs[i, j] = -a[i, j]
            lhs[i, i] += 1j * n * omega
            rhs[i] = 0.0
        rhs[2] = b3 * w
        if not _solve_inplace(lhs, rhs):
            for i in range(3):
                rhs[i] = 0.0
        weight = (1.0 if n == 0 else 2.0) / m
        for k in range(m):
            ang = 2.0 * math.pi * ((n * k) % m) / m
            e = complex(math.cos(ang), math.sin(ang))
            for i in range(3):
                out[i, k] += weight * (rhs[i] * e).real
    for i in range(3):
        for k in range(m):
            out[i, k] += x_eq[i]
    return out


@_jit
def solve_cold(x_eq, b3, u2, u2_mean, omega, constants, scale, rate_ref, dmat, tol, max_iter):
    """Linearised guess (:func:`linear_guess`) then :func:`newton`: (z, iterations, residual, status)."""
    am = np.empty((3, 3))
    _unpack(constants, x_eq[0], x_eq[1], x_eq[2], u2_mean, am)
    x0 = linear_guess(x_eq, am, b3, u2, u2_mean, omega)
    m = u2.shape[0]
    z0 = np.empty(3 * m)
    for i in range(3):
        for k in range(m):
            z0[i * m + k] = x0[i, k] / scale[i]
    return newton(z0, omega, u2, constants, scale, rate_ref, dmat, tol, max_iter)


@_jit
def solve_batch(z0, x_eq, b3, u2, u2_mean, omega, constants, scale, rate_ref, dmat, tol, max_iter):
    """Many independent solves: from z0 (B, 3M) or, when z0 has no rows, from the linearised guesses
    about x_eq (B, 3) with gains b3 (B,); u2 (B, M), u2_mean (B,), omega (B,).
    Returns z (B, 3M), iterations (B,), residuals (B,), statuses (B,)."""
    nb, m = u2.shape
    z = np.empty((nb, 3 * m))
    its = np.empty(nb, dtype=np.int64)
    res = np.empty(nb)
    status = np.empty(nb, dtype=np.int64)
    for b in range(nb):
        if z0.shape[0] == 0:
            zb, itb, rb, sb = solve_cold(x_eq[b], b3[b], u2[b], u2_mean[b], omega[b], constants, scale, rate_ref,
                                         dmat, tol, max_iter)
        else:
            zb, itb, rb, sb = newton(z0[b], omega[b], u2[b], constants, scale, rate_ref, dmat, tol, max_iter)
        z[b] = zb
        its[b] = itb
        res[b] = rb
        status[b] = sb
    return z, its, res, status


@_jit
def _scaled_jacobian(constants, d, e, v, u2, scale, h, out):
    """h S^-1 (df/dx) S at one point into out (3, 3)."""
    _unpack(constants, d, e, v, u2, out)
    for i in range(3):
        for j in range(3):
            out[i, j] *= h * scale[j] / scale[i]


@_jit
def _unpack(constants, d, e, v, u2, jac):
    """df/dx at one point into jac (3, 3); returns f as three floats (static tuple indices only)."""
    f, a = _model(constants, d, e, v, u2)
    (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = a
    jac[0, 0], jac[0, 1], jac[0, 2] = j00, j01, j02
    jac[1, 0], jac[1, 1], jac[1, 2] = j10, j11, j12
    jac[2, 0], jac[2, 1], jac[2, 2] = j20, j21, j22
    return f[0], f[1], f[2]


@_jit
def max_spectral_radius(states, u2_nodes, constants, scale, every):
    """Largest |eigenvalue| of S^-1 (df/dx) S over the nodes 0, every, 2 every, ... of each state.

    ``states`` (B, 3, M), ``u2_nodes`` (B, M); returns (B,) (the step control of the Magnus scheme).
    """
    nb, _three, m = states.shape
    out = np.empty(nb)
    a = np.empty((3, 3))
    for b in range(nb):
        best = 0.0
        for k in range(0, m, every):
            _scaled_jacobian(constants, states[b, 0, k], states[b, 1, k], states[b, 2, k], u2_nodes[b, k],
                             scale, 1.0, a)
            best = max(best, spectral_radius3(a))
        out[b] = best
    return out


@_jit
def _cbrt(x):
    return math.copysign(abs(x) ** (1.0 / 3.0), x)


@_jit
def _eigenvalues3(a):
    """The eigenvalues of a real 3x3 matrix ``a`` as three complex numbers (unsorted), as LAPACK's dgeev
    gives them: real ones with zero imaginary part, a complex pair exactly conjugate, + imaginary part
    first. From the characteristic cubic: one real root by Cardano / the trigonometric form, polished by
    Newton on the cubic, the other two from the deflated quadratic (measured on 1,741 monodromies of four
    sweeps: within 1.2e-11 of numpy's eigvals, 4e-12 for the largest modulus; clustered roots are the
    least accurate for both)."""
    tr = a[0, 0] + a[1, 1] + a[2, 2]
    minors = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0] + a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
              + a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
    det = (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
           + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))
    # lambda^3 + c2 lambda^2 + c1 lambda + c0
    c2, c1, c0 = -tr, minors, -det
    shift = -c2 / 3.0
    p = c1 - c2 * c2 / 3.0
    q = 2.0 * c2 ** 3 / 27.0 - c2 * c1 / 3.0 + c0
    disc = 0.25 * q * q + p * p * p / 27.0
    if disc > 0.0:
        sq = math.sqrt(disc)
        r = _cbrt(-0.5 * q + sq) + _cbrt(-0.5 * q - sq) + shift
    else:
        rr = math.sqrt(max(-p / 3.0, 0.0))
        if rr == 0.0:
            r = shift
        else:   # the largest of three real roots
            r = 2.0 * rr * math.cos(math.acos(min(1.0, max(-1.0, -0.5 * q / (rr * rr * rr)))) / 3.0) + shift
    for _ in range(3):
        f = ((r + c2) * r + c1) * r + c0
        df = (3.0 * r + 2.0 * c2) * r + c1
        if df == 0.0:
            break
        r -= f / df
    b = c2 + r             # the other two: x^2 + b x + c
    c = c1 + r * b
    half_disc = 0.25 * b * b - c
    if half_disc < 0.0:
        im = math.sqrt(-half_disc)
        return complex(-0.5 * b, im), complex(-0.5 * b, -im), complex(r, 0.0)
    x1 = -0.5 * b - math.copysign(math.sqrt(half_disc), b)
    return complex(x1, 0.0), complex(c / x1 if x1 != 0.0 else 0.0, 0.0), complex(r, 0.0)


@_jit
def spectral_radius3(a):
    """max |eigenvalue| of a real 3x3 matrix (:func:`_eigenvalues3`)."""
    w0, w1, w2 = _eigenvalues3(a)
    return max(abs(w0), abs(w1), abs(w2))


@_jit
def _eigenvalues3_into(a, out):
    """:func:`_eigenvalues3` into ``out`` (3,), sorted by decreasing modulus (stable: a pair keeps its
    + imaginary part first)."""
    out[0], out[1], out[2] = _eigenvalues3(a)
    for i in range(1, 3):
        j = i
        while j > 0 and abs(out[j]) > abs(out[j - 1]):
            t = out[j]
            out[j] = out[j - 1]
            out[j - 1] = t
            j -= 1


@_jit
def eigenvalues3(mats):
    """Eigenvalues (B, 3) of real 3x3 matrices (B, 3, 3), sorted by decreasing modulus
    (:func:`_eigenvalues3_into`)."""
    out = np.empty((mats.shape[0], 3), dtype=np.complex128)
    for b in range(mats.shape[0]):
        _eigenvalues3_into(mats[b], out[b])
    return out


@jit_inline
def _t9(a0, a1, a2, a3, a4, a5, a6, a7, a8):
    return (a0, a1, a2, a3, a4, a5, a6, a7, a8)


@jit_inline
def _mul9(a, b):
    """Product of 3x3 matrices held as row-major 9-tuples."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return (a0 * b0 + a1 * b3 + a2 * b6, a0 * b1 + a1 * b4 + a2 * b7, a0 * b2 + a1 * b5 + a2 * b8,
            a3 * b0 + a4 * b3 + a5 * b6, a3 * b1 + a4 * b4 + a5 * b7, a3 * b2 + a4 * b5 + a5 * b8,
            a6 * b0 + a7 * b3 + a8 * b6, a6 * b1 + a7 * b4 + a8 * b7, a6 * b2 + a7 * b5 + a8 * b8)


@jit_inline
def _lin9(alpha, a, beta, b):
    """alpha a + beta b for 9-tuples."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return (alpha * a0 + beta * b0, alpha * a1 + beta * b1, alpha * a2 + beta * b2,
            alpha * a3 + beta * b3, alpha * a4 + beta * b4, alpha * a5 + beta * b5,
            alpha * a6 + beta * b6, alpha * a7 + beta * b7, alpha * a8 + beta * b8)


#: Coefficients b_k of the [6/6] Pade approximant of exp: p(x) = sum b_k x^k, exp(x) ~ p(x) / p(-x).
PADE6 = (1.0, 1.0 / 2.0, 5.0 / 44.0, 1.0 / 66.0, 1.0 / 792.0, 1.0 / 15840.0, 1.0 / 665280.0)


@jit_inline
def _expm9(x):
    """exp(x) of a 3x3 matrix (9-tuple) of norm <= ~1 by the [6/6] Pade approximant (V - U)^-1 (V + U),
    U = x (b1 + b3 x^2 + b5 x^4), V = b0 + b2 x^2 + b4 x^4 + b6 x^6. Relative error against
    scipy.linalg.expm: rounding at norm 0.5, ~2e-13 at norm 1 (the 12th-order Taylor polynomial used
    before: ~1e-10). The numpy path's twin is ``harmonic_balance._expm3``."""
    b0, b1, b2, b3, b4, b5, b6 = PADE6
    x2 = _mul9(x, x)
    x4 = _mul9(x2, x2)
    x6 = _mul9(x4, x2)
    u_in = _lin9(b3, x2, b5, x4)
    u_in = (u_in[0] + b1, u_in[1], u_in[2], u_in[3], u_in[4] + b1, u_in[5], u_in[6], u_in[7], u_in[8] + b1)
    u = _mul9(x, u_in)
    v = _lin9(1.0, _lin9(b2, x2, b4, x4), b6, x6)
    v = (v[0] + b0, v[1], v[2], v[3], v[4] + b0, v[5], v[6], v[7], v[8] + b0)
    q0, q1, q2, q3, q4, q5, q6, q7, q8 = _lin9(1.0, v, -1.0, u)
    # (V - U)^-1 by its adjugate (V - U ~ I: well conditioned)
    c0 = q4 * q8 - q5 * q7
    c3 = q5 * q6 - q3 * q8
    c6 = q3 * q7 - q4 * q6
    inv_det = 1.0 / (q0 * c0 + q1 * c3 + q2 * c6)
    inv = (c0 * inv_det, (q2 * q7 - q1 * q8) * inv_det, (q1 * q5 - q2 * q4) * inv_det,
           c3 * inv_det, (q0 * q8 - q2 * q6) * inv_det, (q2 * q3 - q0 * q5) * inv_det,
           c6 * inv_det, (q1 * q6 - q0 * q7) * inv_det, (q0 * q4 - q1 * q3) * inv_det)
    return _mul9(inv, _lin9(1.0, v, 1.0, u))


@jit_inline
def _jac9(constants, d, e, v, u2, rt):
    """(df/dx)_ij rt_ij at one point as a 9-tuple (rt_ij = h scale_j / scale_i)."""
    _f, a = _model_inline(constants, d, e, v, u2)
    (j0, j1, j2), (j3, j4, j5), (j6, j7, j8) = a
    return (j0 * rt[0], j1 * rt[1], j2 * rt[2], j3 * rt[3], j4 * rt[4], j5 * rt[5], j6 * rt[6], j7 * rt[7],
            j8 * rt[8])


@_jit
def _gauss_point_states(state, cos_phases, sin_phases):
    """(3, P) values at the phases with cosines / sines ``cos_phases``, ``sin_phases`` (P,) of the
    trigonometric interpolant through the M collocation values ``state`` (3, M): mean + sum over the
    harmonics n of a_n cos(n theta) + b_n sin(n theta), cos / sin (n theta) by rotation (the loops over
    the points are innermost: they vectorise)."""
    m = state.shape[1]
    nh = (m - 1) // 2
    npt = cos_phases.shape[0]
    cos_table = np.empty(m)
    sin_table = np.empty(m)
    for j in range(m):
        cos_table[j] = math.cos(2.0 * math.pi * j / m)
        sin_table[j] = math.sin(2.0 * math.pi * j / m)
    coef = np.zeros((nh + 1, 6))   # per harmonic n: a_n of (d, eps1, v), then b_n
    w = 2.0 / m
    for n in range(1, nh + 1):
        j = 0                      # (n k) mod m
        for k in range(m):
            ck = cos_table[j] * w
            sk = sin_table[j] * w
            for i in range(3):
                coef[n, i] += state[i, k] * ck
                coef[n, 3 + i] += state[i, k] * sk
            j += n
            if j >= m:
                j -= m
    mean_d = 0.0
    mean_e = 0.0
    mean_v = 0.0
    for k in range(m):
        mean_d += state[0, k]
        mean_e += state[1, k]
        mean_v += state[2, k]
    out = np.empty((3, npt))
    d = out[0]
    e = out[1]
    v = out[2]
    for g in range(npt):
        d[g] = mean_d / m
        e[g] = mean_e / m
        v[g] = mean_v / m
    cn = cos_phases.copy()
    sn = sin_phases.copy()
    for n in range(1, nh + 1):
        a0, a1, a2, b0, b1, b2 = coef[n, 0], coef[n, 1], coef[n, 2], coef[n, 3], coef[n, 4], coef[n, 5]
        for g in range(npt):
            c = cn[g]
            s = sn[g]
            d[g] += a0 * c + b0 * s
            e[g] += a1 * c + b1 * s
            v[g] += a2 * c + b2 * s
            cn[g] = c * cos_phases[g] - s * sin_phases[g]
            sn[g] = s * cos_phases[g] + c * sin_phases[g]
    return out


@_jit
def monodromy(state, cos_phases, sin_phases, u2, h, constants, scale):
    """Monodromy (3, 3) over one period by the 4th-order Magnus scheme, in scaled coordinates.

    ``cos_phases``, ``sin_phases`` (2S,) are the cosines and sines of the phases of the two Gauss
    points of the S steps (first points of all steps, then second points), ``u2`` the input squared
    there, ``h`` the step (s). The state is evaluated by its trigonometric interpolant through the M
    collocation values; exp(Omega) by the [6/6] Pade approximant (:func:`_expm9`).
    """
    steps = cos_phases.shape[0] // 2
    xg = _gauss_point_states(state, cos_phases, sin_phases)
    rt = _t9(h * scale[0] / scale[0], h * scale[1] / scale[0], h * scale[2] / scale[0],
             h * scale[0] / scale[1], h * scale[1] / scale[1], h * scale[2] / scale[1],
             h * scale[0] / scale[2], h * scale[1] / scale[2], h * scale[2] / scale[2])
    c3 = math.sqrt(3.0) / 12.0
    # exp(Omega_s) of all steps first (independent: this loop vectorises), then their ordered product
    ex = np.empty((9, steps))
    for s in range(steps):
        a1 = _jac9(constants, xg[0, s], xg[1, s], xg[2, s], u2[s], rt)
        q = s + steps
        a2 = _jac9(constants, xg[0, q], xg[1, q], xg[2, q], u2[q], rt)
        om = _lin9(0.5, _lin9(1.0, a1, 1.0, a2), c3, _lin9(1.0, _mul9(a2, a1), -1.0, _mul9(a1, a2)))
        e = _expm9(om)
        ex[0, s] = e[0]
        ex[1, s] = e[1]
        ex[2, s] = e[2]
        ex[3, s] = e[3]
        ex[4, s] = e[4]
        ex[5, s] = e[5]
        ex[6, s] = e[6]
        ex[7, s] = e[7]
        ex[8, s] = e[8]
    total = _t9(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    for s in range(steps):   # later steps multiply from the left
        total = _mul9(_t9(ex[0, s], ex[1, s], ex[2, s], ex[3, s], ex[4, s], ex[5, s], ex[6, s], ex[7, s], ex[8, s]),
                      total)
    out = np.empty((3, 3))
    out[0, 0], out[0, 1], out[0, 2], out[1, 0], out[1, 1], out[1, 2], out[2, 0], out[2, 1], out[2, 2] = total
    return out


@_jit
def monodromy_batch(states, steps, h, cos_flat, sin_flat, u2_flat, start, constants, scale):
    """Monodromies (B, 3, 3) of many solutions in one call: :func:`monodromy` of item b with
    ``steps[b]`` steps of ``h[b]`` s, the cosines and sines of its Gauss phases and its input squared
    read from ``cos_flat`` / ``sin_flat`` / ``u2_flat`` at ``start[b]`` (2 steps[b] values: shared by
    items with the same waveform and step count)."""
    nb = states.shape[0]
    out = np.empty((nb, 3, 3))
    for b in range(nb):
        lo = start[b]
        hi = lo + 2 * steps[b]
        out[b] = monodromy(states[b], cos_flat[lo:hi], sin_flat[lo:hi], u2_flat[lo:hi], h[b], constants, scale)
    return out


def _self_check() -> None:
    """Compile (or load) every kernel with the argument types the solvers pass, on a tiny problem."""
    constants = (2.9e-4, 0.02, -0.019, 4.0e7, 1.07, 3.5e4, 9.81, -2.2e5, -2.3e5, 9.0e5, 5.2e5, -5.0e5, -2.6e5)
    scale = np.array([3e-3, 3e-2, 0.2])
    m = 5
    k = np.arange(m)
    diff = k[:, None] - k[None, :]
    with np.errstate(divide="ignore"):
        dmat = 0.5 * (-1.0) ** diff / np.sin(np.pi * diff / m)
    dmat[k, k] = 0.0
    u2 = np.full(m, 1e6)
    x_eq = np.array([3e-3, 0.03, 0.0])
    z, _it, _res, _status = solve_cold(x_eq, -1e-4, u2, 1e6, 10.0, constants, scale, 60.0, dmat, 1e-10, 5)
    newton(z, 10.0, u2, constants, scale, 60.0, dmat, 1e-10, 2)
    solve_batch(np.empty((0, 3 * m)), x_eq[None], np.array([-1e-4]), u2[None], np.array([1e6]), np.array([10.0]),
                constants, scale, 60.0, dmat, 1e-10, 2)
    solve_batch(z[None], np.empty((0, 3)), np.empty(0), u2[None], np.array([1e6]), np.array([10.0]),
                constants, scale, 60.0, dmat, 1e-10, 2)
    bordered_corrector(z, math.log(10.0), z, 1.0, 0.1, u2, constants, scale, 60.0, dmat, 1e-10, 2)
    bordered_tangent(z, math.log(10.0), z, 1.0, 0.1, u2, constants, scale, 60.0, dmat)
    structured_solve(z, 10.0, u2, constants, scale, 60.0, dmat, np.ones(3 * m))
    t = np.zeros(3 * m)
    hermite_seed(z, z, 0.0, 1.0, z, z, 1.0, 1.0, 1.0, 0.5, np.empty(3 * m))
    for stop in (False, True):
        trace_branch(z, math.log(10.0), t, 1.0, 0.0, math.log(10.5), 3, 0.01, 0.02, np.array([math.log(10.2)]), u2,
                     constants, scale, 60.0, dmat, 1.0 / (3 * m), 1e-10, np.eye(m), stop)
    for n in (3, LAPACK_FROM + 1):   # both branches of the small dense solver, one and two right-hand sides
        for two in (False, True):
            _solve_into(np.eye(n), np.ones(n), np.ones(n), two)
    state = (z.reshape(3, m) * scale[:, None])
    max_spectral_radius(state[None], u2[None], constants, scale, 1)
    eigenvalues3(np.eye(3)[None] * np.ones((2, 1, 1)))
    max_spectral_radius(state[None], np.broadcast_to(u2, (1, m)), constants, scale, 3)
    phases = np.linspace(0.0, 6.0, 8)
    monodromy(state, np.cos(phases), np.sin(phases), np.full(8, 1e6), 1e-3, constants, scale)
    monodromy_batch(state[None], np.array([4]), np.array([1e-3]), np.cos(phases), np.sin(phases), np.full(8, 1e6),
                    np.array([0]), constants, scale)
    collocation_residual_jacobian(z, 10.0, u2, constants, scale, 60.0, dmat)
