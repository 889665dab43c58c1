"""One front end for the periodic steady state: native HBM, mousai HBM, or forward integration.

``solve_periodic(params, periodic_input, method=...)`` returns a
:class:`~dea_ros.solvers.periodic_solution.PeriodicSolution` whatever the method:

* ``"native"``: :func:`~dea_ros.solvers.newton.solve_native` (default),
* ``"mousai"``: :func:`~dea_ros.solvers.mousai_backend.solve_mousai` (the paper's solver),
* ``"integration"``: :func:`integrate_to_steady_state`, brute-force forward
  integration from the static equilibrium until the periodic state is reached.

Convergence criterion of the forward integration (stated in the benchmarks):
the state at the start of each period (the Poincare map P_k) is tracked in
scaled units (d, eps1, d' divided by their typical sizes). With
delta_k = |P_k - P_{k-1}|_inf and the observed contraction rho = delta_k /
delta_{k-1}, the distance to the periodic orbit is estimated as
delta_k rho / (1 - rho) (geometric convergence, the slow viscoelastic pole
makes rho close to 1). Integration stops when that estimate is below ``tol``
for two consecutive periods; if ``max_time_s`` of simulated time passes first,
:class:`SteadyStateError` is raised.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.integrate import solve_ivp

from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..errors import SteadyStateError
from .collocation import model_setup
from .floquet import SYMMETRY_TOL, attach_floquet, floquet_multipliers, half_period_view
from .inputs import PeriodicInput
from .mousai_backend import solve_mousai
from .newton import solve_native
from .periodic_solution import PeriodicSolution

__all__ = ["solve_periodic", "integrate_to_steady_state", "shoot_periodic_orbit", "SteadyStateError", "METHODS"]

METHODS = ("native", "mousai", "integration")


def integrate_to_steady_state(
    params: MembraneParameters,
    periodic_input: PeriodicInput,
    tol: float = 1e-7,
    rtol: float = 1e-9,
    max_time_s: float = 600.0,
    x0=None,
    samples_per_period: int = 257,
    method: str = "DOP853",
    stability: bool = False,
) -> PeriodicSolution:
    """Periodic steady state by forward integration (see the module docstring for the criterion).

    Starts from the static equilibrium at u = 0 (the paper's set-up) unless
    ``x0`` is given. The returned solution samples the last period at
    ``samples_per_period`` (odd) points; ``iterations`` is the number of
    periods integrated and ``extra`` holds the simulated time and RHS calls.
    """
    if samples_per_period % 2 == 0:
        samples_per_period += 1
    t_start = time.perf_counter()
    setup = model_setup(params)
    model, scale = setup.model, setup.scale
    period = 1.0 / periodic_input.frequency_Hz
    omega = periodic_input.omega
    if x0 is None:
        x = np.asarray(static_equilibrium(params, 0.0).state, float).reshape(3)
    else:
        x = np.asarray(x0, float).reshape(3).copy()
    atol = 1e-10 * scale

    def fun(t, y):
        u = periodic_input.at_phase(omega * t)
        return np.stack(model.rhs_u2(y[0], y[1], y[2], u * u))

    last_sol, deltas, nfev, n_periods = _integrate_until_periodic(fun, x, period, scale, tol, rtol, atol,
                                                                  max_time_s, method)
    if last_sol is None:
        raise SteadyStateError(
            f"no periodic steady state within {max_time_s:g} s simulated at "
            f"f = {periodic_input.frequency_Hz:g} Hz (last change {deltas[-1]:.3g} in scaled units); "
            "raise max_time_s or use harmonic balance"
        )
    sol, t_last = last_sol
    times = t_last + period * np.arange(samples_per_period) / samples_per_period
    state = sol.sol(times)
    out = PeriodicSolution(
        frequency_Hz=periodic_input.frequency_Hz,
        periodic_input=periodic_input,
        state=state,
        period_divisor=1,
        n_harmonics=(samples_per_period - 1) // 2,
        method="integration",
        iterations=n_periods,
        residual=float(deltas[-1]),
        wall_time_s=0.0,
        extra={"simulated_time_s": t_last + period, "rhs_calls": nfev},
    )
    if stability:
        attach_floquet(model, out, scale=scale)
    out.wall_time_s = time.perf_counter() - t_start
    return out


def _integrate_until_periodic(fun, x, period, scale, tol, rtol, atol, max_time_s, method) -> tuple:
    """Integrate x' = fun(t, x) in chunks of about 1 s until the Poincare map has converged (module docstring):
    (dense solution and start of the last period, or None after ``max_time_s``; the scaled changes
    delta_k of the map; RHS calls; periods integrated)."""
    periods_per_chunk = max(1, int(np.ceil(1.0 / period)))
    t0 = 0.0
    boundaries = [x / scale]
    deltas: list[float] = []
    ok_streak = 0
    nfev = 0
    n_periods = 0
    while t0 < max_time_s:
        t1 = t0 + periods_per_chunk * period
        sol = solve_ivp(fun, (t0, t1), x, method=method, rtol=rtol, atol=atol, dense_output=True)
        if not sol.success:
            raise SteadyStateError(f"integration failed at t = {t0:.3f} s: {sol.message}")
        nfev += sol.nfev
        for k in range(1, periods_per_chunk + 1):
            tk = t0 + k * period
            pk = sol.sol(tk) / scale
            deltas.append(float(np.max(np.abs(pk - boundaries[-1]))))
            boundaries.append(pk)
            n_periods += 1
            if len(deltas) >= 3:
                rho = deltas[-1] / deltas[-2] if deltas[-2] > 0 else 0.0
                est = deltas[-1] * rho / (1.0 - rho) if rho < 1.0 else np.inf
                est = max(est, deltas[-1] * 1e-3)
                ok_streak = ok_streak + 1 if est < tol else 0
                if ok_streak >= 2:
                    return (sol, tk - period), deltas, nfev, n_periods
        x = sol.y[:, -1]
        t0 = t1
    return None, deltas, nfev, n_periods


def shoot_periodic_orbit(
    params: MembraneParameters,
    periodic_input: PeriodicInput,
    x0,
    rtol: float = 1e-10,
    tol: float = 1e-10,
    max_iter: int = 10,
    samples_per_period: int = 513,
) -> PeriodicSolution:
    """The periodic orbit of period T (the excitation period) through a guess ``x0`` at phase 0,
    by single shooting on the adaptive integrator (DOP853): Newton on P(x) = x, P the one-period
    flow map, with the monodromy matrix from the variational equations (analytic df/dx)
    integrated alongside; converged when the scaled mismatch |P(x) - x| is below ``tol``.

    Independent of harmonic balance (only the start may come from it): the reference the
    harmonic-balance branches are tested against, also where the orbit is unstable. The result
    samples the orbit at ``samples_per_period`` phases; ``multipliers`` are the eigenvalues of the
    monodromy over T (and, for a T/2-periodic orbit of a T/2-periodic u^2, ``half_period_multipliers``
    judge its stability, see :func:`~dea_ros.solvers.floquet.attach_floquet`).
    Raises :class:`SteadyStateError` when Newton does not converge.
    """
    t_start = time.perf_counter()
    setup = model_setup(params)
    model, scale = setup.model, setup.scale
    period = 1.0 / periodic_input.frequency_Hz
    omega = periodic_input.omega
    atol = np.r_[1e-12 * scale, np.full(9, 1e-12)]

    def u2_at(t):
        u = periodic_input.at_phase(omega * t)
        return u * u

    def fun(t, y):
        u2 = u2_at(t)
        f, a = model.rhs_and_jacobian_u2(y[0], y[1], y[2], u2)
        mono = y[3:].reshape(3, 3)
        amat = np.array([[float(np.asarray(a[i][j])) for j in range(3)] for i in range(3)])
        return np.r_[np.asarray(f, float), (amat @ mono).reshape(-1)]

    x = np.asarray(x0, float).reshape(3).copy()
    mismatch = np.full(3, np.inf)
    for it in range(1, max_iter + 1):
        sol = solve_ivp(fun, (0.0, period), np.r_[x, np.eye(3).reshape(-1)], method="DOP853",
                        rtol=rtol, atol=atol)
        if not sol.success:
            raise SteadyStateError(f"shooting integration failed at {periodic_input.frequency_Hz:g} Hz: "
                                   f"{sol.message}")
        mono = sol.y[3:, -1].reshape(3, 3)
        mismatch = sol.y[:3, -1] - x
        if np.max(np.abs(mismatch / scale)) < tol:
            break
        x = x - np.linalg.solve(mono - np.eye(3), mismatch)
    else:
        raise SteadyStateError(f"shooting did not converge at {periodic_input.frequency_Hz:g} Hz "
                               f"(mismatch {np.max(np.abs(mismatch / scale)):.3g} scaled)")
    if samples_per_period % 2 == 0:
        samples_per_period += 1
    times = period * np.arange(samples_per_period) / samples_per_period
    dense = solve_ivp(lambda t, y: np.asarray(model.rhs_u2(y[0], y[1], y[2], u2_at(t)), float),
                      (0.0, period), x, method="DOP853", rtol=rtol, atol=1e-12 * scale, t_eval=times)
    out = PeriodicSolution(
        frequency_Hz=periodic_input.frequency_Hz, periodic_input=periodic_input, state=dense.y,
        period_divisor=1, n_harmonics=(samples_per_period - 1) // 2, method="shooting", iterations=it,
        residual=float(np.max(np.abs(mismatch / scale))), wall_time_s=0.0,
    )
    out.multipliers = np.linalg.eigvals(mono)
    out.multipliers = out.multipliers[np.argsort(-np.abs(out.multipliers))]
    if periodic_input.u2_half_periodic() and out.odd_harmonic_ratio() < SYMMETRY_TOL * 10:
        out.half_period_multipliers = floquet_multipliers(model, half_period_view(out), scale=scale)
    out.wall_time_s = time.perf_counter() - t_start
    return out


def solve_periodic(
    params: MembraneParameters,
    periodic_input: PeriodicInput,
    method: str = "native",
    n_harmonics: int = 8,
    x_guess=None,
    stability: bool = True,
    **options,
) -> PeriodicSolution:
    """Periodic steady state with the chosen method (``native``, ``mousai`` or ``integration``)."""
    if method == "native":
        return solve_native(params, periodic_input, n_harmonics, x_guess=x_guess,
                            stability=stability, **options)
    if method == "mousai":
        return solve_mousai(params, periodic_input, n_harmonics, x_guess=x_guess,
                            stability=stability, **options)
    if method == "integration":
        return integrate_to_steady_state(params, periodic_input, stability=stability, **options)
    raise ValueError(f"method: choose one of {METHODS}, got {method!r}")
