"""Floquet stability of periodic solutions: monodromy by the 4th-order Magnus scheme, multipliers, classification.

The Floquet multipliers of a periodic solution are the eigenvalues of its monodromy matrix, the
product over one response period of exp(Omega_k), Omega_k the 4th-order Magnus expansion on the
trigonometric interpolant of the solution (compiled: :mod:`.floquet_kernels`), in the scaled
coordinates of the collocation system (the multipliers do not depend on them). A period doubling
(odd harmonics of the excitation appearing) shows up as a multiplier leaving the unit circle
through -1; a full-period solution that is the symmetric T/2 orbit of a T/2-periodic u^2 is judged
over T/2 (:func:`attach_floquet`). :func:`classify_stability` names the way a solution is unstable.
Solutions are read by attribute (``state``, ``periodic_input``, ``period_divisor``, ...: a
:class:`~dea_ros.solvers.periodic_solution.PeriodicSolution`).
"""
from __future__ import annotations

import functools

import numpy as np

from ..model.dynamics import DEAModel
from .collocation import periodic_interpolation_matrix
from .floquet_kernels import GAUSS_NODES, eigenvalues3, max_spectral_radius, monodromy, monodromy_batch
from .inputs import PeriodicInput, input_groups, squared_input_rows

__all__ = [
    "classify_stability", "MAGNUS_H_RHO", "MAGNUS_MIN_STEPS", "MAGNUS_MAX_STEPS", "magnus_steps",
    "monodromy_matrix", "monodromies", "sorted_eigenvalues", "floquet_multipliers", "floquet_multipliers_batch",
    "half_period_view", "SYMMETRY_TOL", "symmetric_full_period", "attach_floquet", "attach_floquet_all",
]


#: Default Magnus step rule of :func:`monodromy_matrix`: h rho(A) <= MAGNUS_H_RHO, from MAGNUS_MIN_STEPS to
#: MAGNUS_MAX_STEPS steps per response period. Measured against single shooting (variational equations,
#: DOP853 at rtol 1e-10): |mu| to ~5e-6 next to the A2 resonance (4.7e-6 at 9.584 Hz, 1.4e-7 at 18.4 Hz),
#: the error falling as h^4.
MAGNUS_H_RHO, MAGNUS_MIN_STEPS, MAGNUS_MAX_STEPS = 0.5, 48, 8192


#: A full-period solution whose odd harmonics are below this fraction is the symmetric (T/2) orbit.
SYMMETRY_TOL = 1e-5


#: (input code, step count) pairs are coded as code * _STEPS_CODE + steps (step counts stay far below: at
#: most MAGNUS_MAX_STEPS times the continuation's location factor).
_STEPS_CODE = 1 << 24


def classify_stability(multipliers) -> str:
    """Name the way a periodic solution is (un)stable from its Floquet multipliers.

    * ``stable``: all |mu| < 1.
    * ``unstable (saddle)``: an odd number of real multipliers > 1 (the middle
      branch between two folds of a hysteresis loop).
    * ``unstable (real pair)``: an even number of real multipliers > 1 (no
      turning point; typically a complex pair that met on the real axis).
    * ``unstable (period-doubling)``: a real multiplier < -1 (odd harmonics of
      the excitation grow: the response period doubles).
    * ``unstable (torus)``: a complex pair outside the unit circle (the
      response becomes modulated / quasi-periodic).
    """
    if multipliers is None:
        return "unknown"
    mu = np.asarray(multipliers)
    outside = mu[np.abs(mu) >= 1.0]
    if outside.size == 0:
        return "stable"
    real = np.abs(outside.imag) <= 1e-9 * np.abs(outside)
    if np.any(real & (outside.real < 0)):
        return "unstable (period-doubling)"
    if np.any(~real):
        return "unstable (torus)"
    return "unstable (saddle)" if np.count_nonzero(real) % 2 else "unstable (real pair)"


@functools.lru_cache(maxsize=256)
def _gauss_phases(steps: int) -> tuple:
    """(phases, their cosines, their sines): the phases 2 pi (k + g) / steps (rad) of the two Gauss
    points g of the Magnus steps k = 0..steps-1 over one response period, all first points, then
    all second points (read-only arrays, shared)."""
    phase = np.arange(2 * steps, dtype=float)
    phase[:steps] += GAUSS_NODES[0]
    phase[steps:] += GAUSS_NODES[1] - steps
    phase *= 2.0 * np.pi / steps
    out = (phase, np.cos(phase), np.sin(phase))
    for a in out:
        a.flags.writeable = False
    return out


def monodromies(model: DEAModel, states: np.ndarray, periods_s: np.ndarray, steps: np.ndarray,
                groups: tuple, scale: np.ndarray) -> np.ndarray:
    """Monodromies (B, 3, 3) by the compiled 4th-order Magnus scheme, one kernel call: solution b
    (collocation values ``states[b]`` over the response period ``periods_s[b]`` of its input in
    ``groups`` (:func:`.inputs.input_groups`)) in ``steps[b]`` steps. The input at the Gauss phases is
    evaluated once per distinct waveform, divisor and step count."""
    steps = np.asarray(steps, dtype=np.int64)
    codes, reps = groups
    pairs, inverse = np.unique(codes * _STEPS_CODE + steps, return_inverse=True)
    cos_parts, sin_parts, u2_parts = [], [], []
    for pair in pairs.tolist():
        inp, divisor = reps[pair // _STEPS_CODE]
        phase, cos_phase, sin_phase = _gauss_phases(pair % _STEPS_CODE)
        cos_parts.append(cos_phase)
        sin_parts.append(sin_phase)
        u2_parts.append(inp.at_phase(phase / divisor) ** 2)
    offsets = np.concatenate([[0], np.cumsum(2 * (pairs % _STEPS_CODE))[:-1]]).astype(np.int64)
    return monodromy_batch(
        np.ascontiguousarray(states, dtype=float), steps, np.asarray(periods_s, dtype=float) / steps,
        np.concatenate(cos_parts), np.concatenate(sin_parts), np.concatenate(u2_parts), offsets[inverse.ravel()],
        model.constants, np.asarray(scale, dtype=float))


def _magnus_steps_for(rate, period_s):
    """The default Magnus step count(s) for spectral radius ``rate`` (1/s) over ``period_s`` (scalars or
    arrays)."""
    need = np.ceil(np.asarray(rate) * period_s / MAGNUS_H_RHO)
    return np.clip(need, MAGNUS_MIN_STEPS, MAGNUS_MAX_STEPS).astype(np.int64)


def magnus_steps(model: DEAModel, sol, scale: np.ndarray | None = None) -> int:
    """The default number of Magnus steps of :func:`monodromy_matrix` for ``sol`` (see MAGNUS_H_RHO)."""
    m = sol.n_points
    scale = np.ones(3) if scale is None else np.asarray(scale, dtype=float)
    u2_nodes = sol.periodic_input.at_phase((2.0 * np.pi / (m * sol.period_divisor)) * np.arange(m)) ** 2
    state = np.ascontiguousarray(sol.state, dtype=float)
    rate = float(max_spectral_radius(state[None], u2_nodes[None], model.constants, scale, 1)[0])
    return int(_magnus_steps_for(rate, sol.response_period_s))


def monodromy_matrix(model: DEAModel, sol, steps: int | None = None, scale: np.ndarray | None = None) -> np.ndarray:
    """Monodromy over the response period (4th-order Magnus), in scaled coordinates.

    The multipliers are invariant under the scaling. ``steps`` defaults to :func:`magnus_steps`
    (h rho(A) <= 0.5, rho the spectral radius along the orbit, at least 48).
    """
    scale = np.ones(3) if scale is None else np.asarray(scale, dtype=float)
    state = np.ascontiguousarray(sol.state, dtype=float)
    if steps is None:
        steps = magnus_steps(model, sol, scale)
    h = sol.response_period_s / steps
    phase, cos_phase, sin_phase = _gauss_phases(steps)   # the Gauss phases 2 pi (k + g) / steps
    u2 = sol.periodic_input.at_phase(phase / sol.period_divisor) ** 2
    # (copies: the kernel is compiled for writeable arrays)
    return monodromy(state, np.array(cos_phase), np.array(sin_phase), u2, h, model.constants, scale)


def sorted_eigenvalues(mats: np.ndarray) -> np.ndarray:
    """Eigenvalues (B, 3) of monodromies (B, 3, 3), sorted by decreasing modulus (compiled:
    :func:`.floquet_kernels.eigenvalues3`, ~1 us a matrix; numpy's eigvals to ~1e-11). Raises
    numpy.linalg.LinAlgError for matrices with NaN or inf, as eigvals does."""
    mats = np.asarray(mats, dtype=float)
    if not np.all(np.isfinite(mats)):
        raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
    return eigenvalues3(np.ascontiguousarray(mats))


def floquet_multipliers(model: DEAModel, sol, steps: int | None = None,
                        scale: np.ndarray | None = None) -> np.ndarray:
    """Floquet multipliers over the response period, sorted by decreasing modulus."""
    return sorted_eigenvalues(monodromy_matrix(model, sol, steps, scale)[None])[0]


def half_period_view(sol):
    """A full-period solution that is T/2-periodic, seen over T/2 (divisor 2, even harmonics kept)."""
    n_half = max(1, (sol.n_points - 1) // 4)
    m_half = 2 * n_half + 1
    phases = np.pi * np.arange(m_half) / m_half   # phi / 2 for phi on the half-period grid
    state = sol.state @ periodic_interpolation_matrix(sol.n_points, phases).T
    return type(sol)(
        frequency_Hz=sol.frequency_Hz, periodic_input=sol.periodic_input, state=state,
        period_divisor=2 * sol.period_divisor, n_harmonics=n_half, method=sol.method,
        iterations=sol.iterations, residual=sol.residual, wall_time_s=0.0,
    )


def symmetric_full_period(sol) -> bool:
    """A full-period solution that is the symmetric T/2 orbit of a T/2-periodic u^2 (see attach_floquet)."""
    return bool(sol.period_divisor == 1 and sol.n_points >= 5 and sol.periodic_input.u2_half_periodic()
                and sol.odd_harmonic_ratio() < SYMMETRY_TOL)


def attach_floquet(model: DEAModel, sol, scale: np.ndarray | None = None):
    """Set ``sol.multipliers`` (over its response period) and, for a full-period solution that is
    the symmetric T/2 orbit of a T/2-periodic u^2, ``sol.half_period_multipliers`` (over T/2).

    Over T a multiplier mu of the half-period map appears squared: the period-doubling
    multiplier -1.05 becomes +1.10 and would read as a saddle; judged over T/2 it is named
    for what it is (``unstable (period-doubling)``).
    """
    sol.multipliers = floquet_multipliers(model, sol, scale=scale)
    sol.half_period_multipliers = None
    if symmetric_full_period(sol):
        sol.half_period_multipliers = floquet_multipliers(model, half_period_view(sol), scale=scale)
    return sol


def attach_floquet_all(model: DEAModel, sols: list, scale: np.ndarray) -> None:
    """:func:`attach_floquet` on many solutions, the eigenvalues in one stacked call (same results)."""
    if not sols:
        return
    # step counts as magnus_steps chooses them, all solutions at once
    scale = np.asarray(scale, dtype=float)
    states = np.stack([sol.state for sol in sols])
    m = states.shape[2]
    groups = input_groups([sol.periodic_input for sol in sols], [sol.period_divisor for sol in sols])
    u2_nodes = squared_input_rows(groups, lambda divisor: (2.0 * np.pi / (m * divisor)) * np.arange(m))
    rates = max_spectral_radius(states, u2_nodes, model.constants, scale, 1)
    periods = np.array([sol.response_period_s for sol in sols])
    mats = monodromies(model, states, periods, _magnus_steps_for(rates, periods), groups, scale)
    mu = sorted_eigenvalues(mats)
    for sol, mu_k in zip(sols, mu):
        sol.multipliers = mu_k
        sol.half_period_multipliers = None
        if symmetric_full_period(sol):
            sol.half_period_multipliers = floquet_multipliers(model, half_period_view(sol), scale=scale)


def floquet_multipliers_batch(model: DEAModel, states, response_periods_s, periodic_input: PeriodicInput,
                              divisor: int, scale: np.ndarray | None = None, h_rho: float = 1.0,
                              min_steps: int = 16) -> np.ndarray:
    """Floquet multipliers of many solutions of one waveform at once: (B, 3), decreasing modulus.

    ``states`` (B, 3, M) are collocation values over the response periods ``response_periods_s``
    (B,) of ``periodic_input`` seen with ``divisor``. Same 4th-order Magnus scheme as
    :func:`monodromy_matrix`, coarser by default (h rho(A) <= 1, at least 16 steps, rounded up
    to one of 8 counts per octave, at most 12.5 % more, so solutions share the quadrature points):
    multipliers to ~1e-5, enough to detect where stability changes (the continuation then
    locates those points with :func:`floquet_multipliers`).
    """
    x_all = np.ascontiguousarray(states, dtype=float)
    periods = np.asarray(response_periods_s, float).reshape(-1)
    nb, _, m = x_all.shape
    scale = np.ones(3) if scale is None else np.asarray(scale, dtype=float)
    if nb == 0:
        return np.empty((nb, 3), dtype=complex)
    node_phase = 2.0 * np.pi * np.arange(m) / m
    u2_nodes = periodic_input.at_phase(node_phase / divisor) ** 2
    rate = max_spectral_radius(x_all, np.broadcast_to(u2_nodes, (nb, m)), model.constants, scale, 3)
    need = np.clip(np.ceil(rate * periods / h_rho), min_steps, 8192)
    quantum = 2.0 ** np.maximum(np.floor(np.log2(need)) - 3, 0)       # 8 step counts per octave
    steps_of = (np.ceil(need / quantum) * quantum).astype(int)
    one_group = (np.zeros(nb, dtype=np.int64), [(periodic_input, divisor)])
    return sorted_eigenvalues(monodromies(model, x_all, periods, steps_of, one_group, scale))
