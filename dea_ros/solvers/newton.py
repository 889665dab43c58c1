"""Damped Newton on the collocation system: single solves with their fallbacks, and batched solves.

:func:`solve_native` solves the collocation equations of eq. 16 (:mod:`.collocation`) at one
frequency from a given guess or the linearised response, falling back to an amplitude homotopy and
then a frequency continuation from f/4 (both with Newton at each stage); ``n_harmonics="auto"``
raises N until the truncation indicator is small. :func:`solve_native_batch` solves many inputs in
one compiled call (the fast path of identification). Newton runs compiled
(:mod:`.newton_kernels`): each step by the structured reduction of the Jacobian, a backtracking
line search, converged when the scaled step is below ``tol``; failure raises
:class:`~dea_ros.errors.HarmonicBalanceError`. Stability (Floquet multipliers) is attached on
request (:mod:`.floquet`).
"""
from __future__ import annotations

import time

import numpy as np

from ..errors import HarmonicBalanceError
from ..model.parameters import MembraneParameters
from .collocation import linear_guess, model_setup, resample_state, response_layout
from .floquet import attach_floquet, attach_floquet_all
from .inputs import PeriodicInput, input_groups, squared_input_rows
from .newton_kernels import newton_error, solve_batch, solve_cold
from .periodic_solution import PeriodicSolution

__all__ = ["AUTO_HARMONICS", "newton_error", "solve_native", "solve_native_batch"]

AUTO_HARMONICS = (4, 6, 8, 12, 16, 24, 32)


def solve_native(
    params: MembraneParameters,
    periodic_input: PeriodicInput,
    n_harmonics: int | str = 8,
    x_guess: np.ndarray | None = None,
    tol: float = 1e-10,
    max_iter: int = 40,
    use_symmetry: bool = True,
    stability: bool = True,
    auto_tol: float = 1e-4,
) -> PeriodicSolution:
    """Periodic steady state by native harmonic balance.

    ``x_guess`` (3, M) in physical units may seed Newton (continuation);
    otherwise the linearised response is used, and on failure an amplitude
    homotopy (the input scaled from 25 % to 100 %) and then a frequency
    continuation from f/4 are tried before giving up.

    ``n_harmonics="auto"`` raises N through 4, 6, 8, 12, 16, 24, 32 (each
    solution seeding the next) until :attr:`PeriodicSolution.truncation_ratio`
    is below ``auto_tol`` (default 1e-4).
    """
    if isinstance(n_harmonics, str):
        return _solve_auto(params, periodic_input, n_harmonics, x_guess, tol, max_iter, use_symmetry, stability,
                           auto_tol)
    t0 = time.perf_counter()
    setup = model_setup(params)
    divisor, m = response_layout(periodic_input, n_harmonics, use_symmetry)
    system = setup.system(m)
    omega = periodic_input.omega * divisor
    u2 = periodic_input.at_phase(system.phases / divisor) ** 2
    z, res, total_it, err = _direct_solves(setup, system, u2, omega, x_guess, tol, max_iter)
    if z is None:
        z, res, total_it, err = _amplitude_homotopy(params, periodic_input, divisor, setup, system, u2, omega, tol,
                                                    max_iter, total_it, err)
    if z is None:
        f = periodic_input.frequency_Hz
        try:
            z, it, res = _continue_up_in_frequency(setup, system, periodic_input, divisor, m, f, tol, max_iter)
            total_it += it
        except HarmonicBalanceError as exc:
            raise HarmonicBalanceError(
                f"harmonic balance failed at f = {f:g} Hz with N = {n_harmonics}: {err}; "
                f"frequency continuation: {exc}"
            ) from None
    sol = PeriodicSolution(
        frequency_Hz=periodic_input.frequency_Hz, periodic_input=periodic_input, state=system.unscale(z),
        period_divisor=divisor, n_harmonics=int(n_harmonics), method="native", iterations=total_it, residual=res,
        wall_time_s=0.0,
    )
    if stability:
        attach_floquet(setup.model, sol, scale=setup.scale)
    sol.wall_time_s = time.perf_counter() - t0
    return sol


def _solve_auto(params, periodic_input, n_harmonics, x_guess, tol, max_iter, use_symmetry, stability, auto_tol):
    """:func:`solve_native` with ``n_harmonics="auto"``: N through :data:`AUTO_HARMONICS`."""
    if n_harmonics != "auto":
        raise ValueError(f"n_harmonics: an integer >= 1 or 'auto', got {n_harmonics!r}")
    t_auto = time.perf_counter()
    guess, sol, iters = x_guess, None, 0
    for n in AUTO_HARMONICS:
        sol = solve_native(params, periodic_input, n, x_guess=guess, tol=tol, max_iter=max_iter,
                           use_symmetry=use_symmetry, stability=False)
        iters += sol.iterations
        guess = sol.state
        if sol.truncation_ratio < auto_tol:
            break
    if stability:
        setup = model_setup(params)
        attach_floquet(setup.model, sol, scale=setup.scale)
    sol.iterations = iters
    sol.wall_time_s = time.perf_counter() - t_auto
    return sol


def _direct_solves(setup, system, u2, omega, x_guess, tol, max_iter) -> tuple:
    """Newton from the guess (when given), else from the linearised response (guess and Newton in one
    compiled call): (z or None, scaled residual, iterations spent, the last error)."""
    total_it = 0
    m = system.m
    if x_guess is not None:
        x_guess = np.asarray(x_guess, float)
        if x_guess.shape != (3, m):
            x_guess = resample_state(x_guess, m)
        try:
            z, it, res = system.newton(system.to_z(x_guess), omega, u2, tol=tol, max_iter=max_iter)
            return z, res, it, None
        except HarmonicBalanceError:
            total_it += max_iter
    u2_mean = float(np.mean(u2))
    x_eq = setup.equilibrium_state(u2_mean)
    z, it, res, status = solve_cold(
        x_eq, float(setup.model.input_gain_u2(x_eq[0])), u2, u2_mean, float(omega), system.constants,
        system.scale, system.rate_ref, system.d_theta, float(tol), int(max_iter))
    if status == 0:
        return z, res, total_it + it, None
    return None, res, total_it + max_iter, newton_error(status, it, res, max_iter)


def _amplitude_homotopy(params, periodic_input, divisor, setup, system, u2, omega, tol, max_iter, total_it,
                        err) -> tuple:
    """Newton along the amplitude of u^2 - mean(u^2) scaled from 25 % to 100 %: (z or None, residual,
    iterations spent, the errors so far)."""
    mean_u2 = float(np.mean(u2))
    z = system.to_z(linear_guess(params, periodic_input, divisor, system.m, setup))
    res = float("nan")
    try:
        for frac in (0.25, 0.5, 0.75, 0.9, 1.0):
            z, it, res = system.newton(z, omega, mean_u2 + frac * (u2 - mean_u2), tol=tol, max_iter=max_iter)
            total_it += it
    except HarmonicBalanceError as exc:
        return None, res, total_it, f"{err}; amplitude homotopy: {exc}"
    return z, res, total_it, err


def _continue_up_in_frequency(setup, system, periodic_input, divisor, m, f, tol, max_iter):
    """Natural continuation from f/4 (linearised guess there) up to f; the step halves on failure.

    A homotopy of Newton in the frequency, the last fallback of a cold solve; not the arclength engine on
    purpose: at a fold it jumps to whatever solution Newton finds at the next frequency where the
    engine would follow the branch, and the two give different solutions of under-resolved equations
    (A2, N = 2, 9.5 Hz: 1.30 mm in 103 Newton iterations here, 15.3 mm after 1183 branch steps there).

    Returns (z, iterations, scaled residual) at f. Raises HarmonicBalanceError.
    """
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = periodic_input.at_phase(phases / divisor) ** 2
    f_cur = 0.25 * f
    start = periodic_input.with_frequency(f_cur)
    z = system.to_z(linear_guess(setup.params, start, divisor, m, setup))
    z, iters, res = system.newton(z, 2.0 * np.pi * f_cur * divisor, u2, tol=tol, max_iter=max_iter)
    step = 0.1 * f
    while f_cur < f:
        f_next = min(f, f_cur + step)
        try:
            z_new, it, res = system.newton(z, 2.0 * np.pi * f_next * divisor, u2, tol=tol, max_iter=max_iter)
        except HarmonicBalanceError:
            step *= 0.5
            if step < 1e-4 * f:
                raise HarmonicBalanceError(f"no solution continued past {f_cur:.6g} Hz (a fold?)") from None
            continue
        iters += it
        z, f_cur = z_new, f_next
        step = min(1.5 * step, 0.1 * f)
    return z, iters, res


def solve_native_batch(
    params: MembraneParameters,
    periodic_inputs,
    n_harmonics: int = 8,
    x_guesses=None,
    tol: float = 1e-10,
    max_iter: int = 40,
    use_symmetry: bool = True,
    stability: bool = False,
) -> list[PeriodicSolution]:
    """Solve many periodic inputs (e.g. a list of frequencies) in one compiled call.

    All inputs must share the symmetry (all sines without offset, or none). The Python overhead is
    paid once for the batch: this is the fast path for identification, where every objective
    evaluation needs the RMS at several frequencies. Each item is the same Newton iteration as
    :func:`solve_native` from its guess (``x_guesses``) or its linearised response; an item that does
    not converge is re-solved alone with :func:`solve_native` (with its fallbacks); errors propagate
    as :class:`HarmonicBalanceError`.
    """
    t0 = time.perf_counter()
    inputs = list(periodic_inputs)
    if not inputs:
        return []
    setup = model_setup(params)
    layouts = {response_layout(inp, n_harmonics, use_symmetry) for inp in inputs}
    if len(layouts) != 1:
        raise ValueError("periodic_inputs: mix of symmetric and non-symmetric inputs; batch them separately")
    divisor, m = layouts.pop()
    system = setup.system(m)
    nb = len(inputs)
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = squared_input_rows(input_groups(inputs, [divisor] * nb), lambda div: phases / div)   # (B, M)
    omega = np.array([inp.omega * divisor for inp in inputs])                       # (B,)
    u2_mean = np.mean(u2, axis=1)
    if x_guesses is None:
        x_eq = np.empty((nb, 3))
        for value in np.unique(u2_mean):  # one equilibrium per distinct mean (one for equal amplitudes)
            x_eq[u2_mean == value] = setup.equilibrium_state(float(value))
        b3 = np.asarray(setup.model.input_gain_u2(x_eq[:, 0]), dtype=float)
        z0 = np.empty((0, 3 * m))
    else:
        x0 = np.stack([g if np.shape(g) == (3, m) else resample_state(np.asarray(g, float), m) for g in x_guesses])
        x_eq, b3 = np.empty((0, 3)), np.empty(0)
        z0 = np.ascontiguousarray((x0 / system.scale[None, :, None]).reshape(nb, 3 * m))
    zf, iterations, residual, status = solve_batch(
        z0, x_eq, b3, np.ascontiguousarray(u2), u2_mean, np.asarray(omega, dtype=float), system.constants,
        system.scale, system.rate_ref, system.d_theta, float(tol), int(max_iter))
    return _batch_results(params, setup, system, inputs, n_harmonics, divisor, zf, iterations, residual,
                          status != 0, tol, max_iter, use_symmetry, stability, t0)


def _batch_results(params, setup, system, inputs, n_harmonics, divisor, zf, iterations, residual, failed, tol,
                   max_iter, use_symmetry, stability, t0):
    """Solutions of a batch (failed items re-solved alone), with stability on request."""
    nb = len(inputs)
    m = system.m
    states = np.asarray(zf).reshape(nb, 3, m) * system.scale[None, :, None]
    iterations, residual = np.asarray(iterations).tolist(), np.asarray(residual, dtype=float).tolist()
    results = []
    for k, inp in enumerate(inputs):
        if failed[k]:
            sol = solve_native(params, inp, n_harmonics, tol=tol, max_iter=max_iter,
                               use_symmetry=use_symmetry, stability=False)
        else:
            sol = PeriodicSolution(
                frequency_Hz=inp.frequency_Hz, periodic_input=inp, state=states[k], period_divisor=divisor,
                n_harmonics=int(n_harmonics), method="native-batch", iterations=int(iterations[k]),
                residual=float(residual[k]), wall_time_s=0.0,
            )
        results.append(sol)
    if stability:
        attach_floquet_all(setup.model, results, setup.scale)
    wall = time.perf_counter() - t0
    for sol in results:
        sol.extra["batch_wall_time_s"] = wall
        sol.wall_time_s = wall / nb
    return results
