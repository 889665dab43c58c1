"""Compiled kernels of the collocation system (eq. 16): residual, Jacobian and its structured solves.

The unknowns are the scaled collocation values z = x / scale, state-major (the layout of
:class:`~dea_ros.solvers.collocation.CollocationSystem`). :func:`fill_collocation` evaluates the
scaled residual and the point-diagonal part of the Jacobian; the whole Jacobian is
omega / rate_ref kron(I3, D) plus that part. The Newton steps and the pseudo-arclength systems are
solved by a reduction that uses the pattern of eq. 18 (see "structured linear solves" below: M
unknowns instead of 3M). Also here: the small dense solver those reductions end in and the
linearised periodic response that starts a cold Newton solve (:func:`linearised_response`).

The model is :func:`dea_ros.model.dynamics.state_equation` compiled as it is (one definition).
"""
from __future__ import annotations

import math

import numpy as np

from ..model.dynamics import state_equation
from .jit import jit

__all__ = [
    "max_abs", "solve_inplace", "LAPACK_FROM", "state_equation_at", "fill_collocation", "trig_tables",
    "circulant_inverse", "second_derivative_column", "structured_solve_into", "structured_solve",
    "collocation_residual_jacobian", "linearised_response",
]

_state_equation = jit(state_equation)


@jit
def max_abs(v):
    """max |v_i|, NaN if any entry is NaN (as numpy's max)."""
    out = 0.0
    for i in range(v.shape[0]):
        a = abs(v[i])
        if a > out or a != a:
            out = a
            if a != a:
                return a
    return out


@jit
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


@jit
def _back_substitute(a, b):
    """Solve the upper triangle of a into b (b overwritten)."""
    n = a.shape[0]
    for row in range(n - 1, -1, -1):
        acc = b[row]
        for k in range(row + 1, n):
            acc -= a[row, k] * b[k]
        b[row] = acc / a[row, row]


@jit
def solve_inplace(a, b):
    """Solve a x = b by Gaussian elimination with partial pivoting (a, b overwritten; x in b).

    Returns False on an exactly zero pivot (what LAPACK reports as singular).
    """
    return _eliminate(a, b, b, False)


#: Above this size the linear systems go to LAPACK (faster blocked code); below, the loop above (less overhead).
LAPACK_FROM = 40


@jit
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


@jit
def state_equation_at(constants, d, e, v, u2, jac):
    """df/dx at one point into jac (3, 3); returns f as three floats (static tuple indices only)."""
    f, a = _state_equation(constants, d, e, v, u2)
    (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = a
    jac[0, 0], jac[0, 1], jac[0, 2] = j00, j01, j02
    jac[1, 0], jac[1, 1], jac[1, 2] = j10, j11, j12
    jac[2, 0], jac[2, 1], jac[2, 2] = j20, j21, j22
    return f[0], f[1], f[2]


@jit
def fill_collocation(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate):
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
        f0, f1, f2 = state_equation_at(constants, x[0, k], x[1, k], x[2, k], u2[k], a)
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


@jit
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
# states (d, eps1, v) and J = wr kron(I3, D) + point-diagonal entries e (:func:`fill_collocation`), eq. 18 gives
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
# test/solvers/test_collocation_kernels.py checks the pattern of eq. 18 and the solves against dense LU.


@jit
def trig_tables(m):
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


@jit
def circulant_inverse(wr, e11, cos_t, sin_t):
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


@jit
def _wrap(q, m):
    """q mod m for -m <= q < m (no integer division: this is in the innermost loops)."""
    return q + m if q < 0 else q


@jit
def second_derivative_column(dmat):
    """First column of D^2 (circulant as D)."""
    m = dmat.shape[0]
    d2 = np.empty(m)
    for q in range(m):
        acc = 0.0
        for j in range(m):
            acc += dmat[q, j] * dmat[j, 0]
        d2[q] = acc
    return d2


@jit
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


@jit
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


@jit
def _bordered_row_rhs(e, wvec, rhs, q1, m):
    """The reduced bordered row's right-hand side: g - sum_j q1_j rhs1_j + wvec2_j rhs0_j / e02."""
    e02 = e[0, 2, 0]
    g = rhs[3 * m]
    for jj in range(m):
        g -= q1[jj] * rhs[m + jj] + wvec[2 * m + jj] * rhs[jj] / e02
    return g


@jit
def structured_solve_into(e, wr, dmat, d2col, cinv, bvec, wvec, tp, rhs, bordered, rhs2, two):
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


@jit
def structured_solve(z, omega, u2, constants, scale, rate_ref, dmat, rhs):
    """x with J(z, omega) x = rhs by the structured reduction (for tests: compare with a dense solve)."""
    m = u2.shape[0]
    r = np.empty(3 * m)
    drate = np.empty(3 * m)
    e = np.empty((3, 3, m))
    fill_collocation(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
    cos_t, sin_t = trig_tables(m)
    wr = omega / rate_ref
    x = rhs.copy()
    cinv = circulant_inverse(wr, e[1, 1, 0], cos_t, sin_t)
    ok = structured_solve_into(e, wr, dmat, second_derivative_column(dmat), cinv, drate, drate, 0.0, x, False,
                               x, False)
    return x, ok


@jit
def collocation_residual_jacobian(z, omega, u2, constants, scale, rate_ref, dmat):
    """(r, jac, dr/dln omega) at z (scaled): :meth:`.collocation.CollocationSystem.residual_and_jacobian`."""
    n = z.shape[0]
    m = u2.shape[0]
    r = np.empty(n)
    jac = np.empty((n, n))
    drate = np.empty(n)
    e = np.empty((3, 3, m))
    fill_collocation(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
    _dense_jacobian(e, omega / rate_ref, dmat, jac)
    return r, jac, drate


@jit
def linearised_response(x_eq, a, b3, u2, u2_mean, omega):
    """Periodic response (3, M) of x' = A (x - x_eq) + b (u2 - mean) with b = (0, 0, b3), by a DFT.

    ``a`` is df/dx at the equilibrium x_eq under the mean u^2 (:func:`.collocation.linear_guess`).
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
        if not solve_inplace(lhs, rhs):
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
