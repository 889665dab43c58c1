"""Compiled damped Newton on the collocation equations (eq. 16): single, cold (from the linearised
response) and batched solves, and the errors their outcome codes stand for.

Each Newton step is solved by the structured reduction of
:func:`~dea_ros.solvers.collocation_kernels.structured_solve_into` (M unknowns instead of 3M); a
backtracking line search halves the step up to 12 times until the max-norm of the scaled residual
falls; converged when the full step is below ``tol`` (scaled units).
"""
from __future__ import annotations

import numpy as np

from ..errors import HarmonicBalanceError
from .collocation_kernels import (
    fill_collocation,
    linearised_response,
    max_abs,
    circulant_inverse,
    second_derivative_column,
    state_equation_at,
    structured_solve_into,
    trig_tables,
)
from .jit import jit

__all__ = ["STATUS_MESSAGES", "newton_error", "newton", "newton_with_tables", "solve_cold", "solve_batch"]


#: Newton outcome codes returned by :func:`newton` (0 converged) and their messages.
STATUS_MESSAGES = {
    1: "singular harmonic-balance Jacobian (a fold?)",
    2: "harmonic-balance Newton step is not finite",
    3: "line search failed",
    4: "no convergence",
}


def newton_error(status: int, iterations: int, residual: float, max_iter: int) -> HarmonicBalanceError:
    """The error for a Newton outcome code of :func:`newton` (``status`` > 0)."""
    if status == 3:
        return HarmonicBalanceError(
            f"line search failed after {iterations} Newton iterations (scaled residual {residual:.3g})")
    if status == 4:
        return HarmonicBalanceError(
            f"no convergence in {max_iter} Newton iterations (scaled residual {residual:.3g}); "
            "try more iterations, a better initial guess, or continuation (sweep)")
    return HarmonicBalanceError(STATUS_MESSAGES[status])


@jit
def newton(z0, omega, u2, constants, scale, rate_ref, dmat, tol, max_iter):
    """Damped Newton on the collocation equations: (z, iterations, scaled residual, status).

    status 0: converged (full step below tol); otherwise a key of :data:`STATUS_MESSAGES`. The Newton
    steps are solved by the structured reduction (:func:`structured_solve_into`).
    """
    cos_t, sin_t = trig_tables(u2.shape[0])
    return newton_with_tables(z0, omega, u2, constants, scale, rate_ref, dmat, tol, max_iter, cos_t, sin_t,
                              second_derivative_column(dmat))


@jit
def newton_with_tables(z0, omega, u2, constants, scale, rate_ref, dmat, tol, max_iter, cos_t, sin_t, d2col):
    """:func:`newton` with the tables of m (:func:`trig_tables`, :func:`second_derivative_column`) given."""
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
    fill_collocation(z, omega, u2, constants, scale, rate_ref, dmat, r, e, drate)
    cinv = circulant_inverse(wr, e[1, 1, 0], cos_t, sin_t)
    rnorm = max_abs(r)
    for it in range(1, max_iter + 1):
        step[:] = r
        if not structured_solve_into(e, wr, dmat, d2col, cinv, drate, drate, 0.0, step, False, step, False):
            return z, it, rnorm, 1
        snorm = max_abs(step)
        if not np.isfinite(snorm):
            return z, it, rnorm, 2
        lam = 1.0
        ok = False
        rn_new = rnorm
        for _ls in range(12):
            for i in range(n):
                z_new[i] = z[i] - lam * step[i]
            fill_collocation(z_new, omega, u2, constants, scale, rate_ref, dmat, r_new, e_new, drate)
            rn_new = max_abs(r_new)
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


@jit
def solve_cold(x_eq, b3, u2, u2_mean, omega, constants, scale, rate_ref, dmat, tol, max_iter):
    """The linearised response (:func:`.collocation_kernels.linearised_response`) as the guess, then :func:`newton`:
    (z, iterations, residual, status)."""
    am = np.empty((3, 3))
    state_equation_at(constants, x_eq[0], x_eq[1], x_eq[2], u2_mean, am)
    x0 = linearised_response(x_eq, am, b3, u2, u2_mean, omega)
    m = u2.shape[0]
    z0 = np.empty(3 * m)
    for i in range(3):
        for k in range(m):
            z0[i * m + k] = x0[i, k] / scale[i]
    return newton(z0, omega, u2, constants, scale, rate_ref, dmat, tol, max_iter)


@jit
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
