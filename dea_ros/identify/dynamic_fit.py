"""Dynamic fit (paper section IV-C, eqs. 22-24): k1, eta1, eta2 from step and frequency responses.

Minimises eq. 22 (:class:`~dea_ros.identify.dynamic_objective.DynamicObjective`: the step samples of
eq. 23 and the RMS values of eq. 24, harmonic balance or forward integration, exact Jacobian) with
the static parameters fixed. Defaults are the paper's: w_step = 6.6e6, w_hbm = 0.1e6, f_k = 0.2,
8.3, 11.2 and 40 Hz (those present in the data; all data frequencies when none is;
:func:`select_fit_frequencies`).

Optimizers: ``method="lsq"`` (default), ``scipy.optimize.least_squares`` (trust-region
reflective) over ln(k1, eta1, eta2) with the analytic Jacobian; ``method="paper"``,
Nelder-Mead on eq. 22 over k1/1e7, eta1/1e8, eta2/1e4 with xatol = fatol = 5e-2.
``curvature_direction`` makes sigma_h''(1) a 4th parameter (sensible with noise weights and
frequencies near the resonance; the statistics say when it is not determined).

Initial guess (no trial and error): the oscillation after the step gives its frequency
(FFT peak) and decay rate (log envelope); with the fitted static parameters the model
linearised at the post-step equilibrium turns them into k1 and eta2 for any relaxation
time tau = eta1/k1; for each tau of a log grid over 1e-2..1e2 s, eq. 22 is minimised over k1 and
eta2 with tau held (the profile of the cost over the creep time), and the profile's minima are the
starts. Without a step, the resonance peak of the sine data gives the frequency.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares, minimize

from ..errors import DynamicFitError
from ..model.dynamics import DEAModel
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..errors import FallbackRefused, HarmonicBalanceError
from ..solvers.steady_state import SteadyStateError
from ..solvers.transient import TransientError
from .dynamic_objective import CURVATURE_UNIT_PA, PAPER_WEIGHTS, DynamicObjective
from .experiments import SineData, StepData, estimate_noise_m
from .frequency_points import FrequencyPoint
from .metrics import ParameterStatistics, parameter_statistics
from .static_fit import stress_combinations

__all__ = [
    "DynamicFitResult",
    "DynamicFitError",
    "fit_dynamic",
    "select_fit_frequencies",
    "initial_guess",
    "PAPER_FREQUENCIES_HZ",
    "PAPER_NORMALISATION",
    "DYNAMIC_METHODS",
    "PARAMETER_BOUNDS",
]

LOG = logging.getLogger("dea_ros.identify")

PAPER_FREQUENCIES_HZ = (0.2, 8.3, 11.2, 40.0)
#: Normalisation of k1, eta1, eta2 in the paper's Nelder-Mead.
PAPER_NORMALISATION = (1e7, 1e8, 1e4)
DYNAMIC_METHODS = ("lsq", "paper")
NAMES = ("k1_Pa", "eta1_Pa_s", "eta2_Pa_s")
#: Search box of the optimizers (Pa, Pa s, Pa s).
PARAMETER_BOUNDS = {"k1_Pa": (1e3, 1e11), "eta1_Pa_s": (1e1, 1e13), "eta2_Pa_s": (1e-1, 1e9)}


def select_fit_frequencies(sines: Sequence[SineData], fit_frequencies_Hz=None,
                           rel_tol: float = 1e-6) -> list[FrequencyPoint]:
    """The frequency points used in eq. 22.

    ``None``: the paper's 0.2, 8.3, 11.2, 40 Hz that are present in the data, or all
    data frequencies when none is; ``"all"``: every data frequency; a list: exactly
    those (each must be in the data).
    """
    rows = [FrequencyPoint(float(f), float(a), float(r), s.mass_kg, s.source,
                           None if s.d_rms_std_m is None else float(s.d_rms_std_m[k]),
                           s.inputs[k] if s.inputs else None, rest_d0_m=s.rest_d0(k))
            for s in sines
            for k, (f, a, r) in enumerate(zip(s.frequency_Hz, s.amplitude_V, s.d_rms_m))]
    if not rows:
        return []

    def find(f):
        return [p for p in rows if abs(p.frequency_Hz - f) <= rel_tol * max(f, 1e-12)]

    if isinstance(fit_frequencies_Hz, str):
        if fit_frequencies_Hz != "all":
            raise ValueError(f"fit_frequencies_Hz: None, 'all' or a list of Hz, got {fit_frequencies_Hz!r}")
        return sorted(rows, key=lambda p: p.frequency_Hz)
    if fit_frequencies_Hz is None:
        chosen = [p for f in PAPER_FREQUENCIES_HZ for p in find(f)]
        return sorted(chosen or rows, key=lambda p: p.frequency_Hz)
    chosen = []
    available = sorted({p.frequency_Hz for p in rows})
    for f in fit_frequencies_Hz:
        hit = find(float(f))
        if not hit:
            raise DynamicFitError(
                f"fit frequency {float(f):g} Hz is not in the sine data; available: "
                + ", ".join(f"{x:g}" for x in available)
            )
        chosen += hit
    return sorted(chosen, key=lambda p: p.frequency_Hz)


# --------------------------------------------------------------------------- initial guess
def _oscillation_from_step(step: StepData):
    """(frequency Hz, decay rate 1/s) of the oscillation after the step, or None."""
    k0 = step.step_index
    t = step.time_s[k0:] - step.time_s[k0]
    d = step.displacement_m[k0:]
    fs = 1.0 / step.sample_period_s
    use = t <= min(2.0, t[-1])
    if np.count_nonzero(use) < 32:
        return None
    seg_t, seg = t[use], d[use]
    seg = seg - np.polyval(np.polyfit(seg_t, seg, 2), seg_t)
    nfft = 1 << int(math.ceil(math.log2(seg.size * 8)))
    spec = np.abs(np.fft.rfft(seg * np.hanning(seg.size), nfft))
    freqs = np.fft.rfftfreq(nfft, 1.0 / fs)
    band = (freqs > 1.0) & (freqs < 0.45 * fs)
    if not np.any(band):
        return None
    k = int(np.argmax(np.where(band, spec, 0.0)))
    if 0 < k < spec.size - 1:
        a, b, c = spec[k - 1], spec[k], spec[k + 1]
        shift = 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) != 0 else 0.0
        f_osc = (k + shift) * fs / nfft
    else:
        f_osc = freqs[k]
    # Decay: RMS of the oscillation (d minus its one-period moving average) per period.
    period_n = max(int(round(fs / f_osc)), 2)
    kernel = np.ones(period_n) / period_n
    smooth = np.convolve(d, kernel, mode="same")
    osc = d - smooth
    n_win = (osc.size - period_n) // period_n
    if n_win < 3:
        return f_osc, None
    centers, amps = [], []
    for j in range(n_win):
        w = osc[period_n // 2 + j * period_n: period_n // 2 + (j + 1) * period_n]
        centers.append(t[period_n // 2 + j * period_n + period_n // 2])
        amps.append(math.sqrt(2.0) * float(np.std(w)))
    centers, amps = np.array(centers), np.array(amps)
    noise = estimate_noise_m(step) or 0.0
    good = amps > 4.0 * noise + 1e-12
    # use the leading run of windows above the noise
    if not good[0] or np.count_nonzero(good) < 3:
        return f_osc, None
    stop = int(np.argmin(good)) if not np.all(good) else good.size
    stop = max(stop, 3)
    slope = np.polyfit(centers[:stop], np.log(amps[:stop]), 1)[0]
    return f_osc, float(max(-slope, 1e-3))


def _linearisation(params: MembraneParameters, voltage_V: float, mass_kg: float):
    """(K_s, G) per unit mass at the static equilibrium: omega^2 = K_s + G k1, damping 2 alpha = G eta2."""
    p = params.replace(mass_kg=mass_kg)
    eq = static_equilibrium(p, float(voltage_V))
    d = float(eq.displacement_m)
    model = DEAModel.from_parameters(p)
    k_s = float(eq.stiffness_N_per_m) / mass_kg
    s = 1.0 + d * d / model.l0_sq
    phi = d / (model.l0_sq * math.sqrt(s))
    g = model.force_gain * d / s * phi
    return k_s, g


def _profile_at_tau(objective: DynamicObjective, theta0: np.ndarray, log_tau: float, max_nfev: int,
                    integrate_start: bool = True):
    """(cost, theta): eq. 22 minimised over ln k1 and ln eta2 with the creep time eta1/k1 held at
    exp(``log_tau``) (the profile of the cost over the creep time), from ``theta0``. Where harmonic balance
    fails, the start integrates if ``integrate_start`` (else FallbackRefused); trial points never do (rejected)."""
    lo, hi = _bounds(objective.n_params)
    rest = np.asarray(theta0[3:], float)

    def full(x):
        return np.r_[x[0], x[0] + log_tau, x[1], rest]

    def jac(x):
        j = objective.jacobian(full(x))
        return np.c_[j[:, 0] + j[:, 1], j[:, 2]]

    x_lo = np.array([max(lo[0], lo[1] - log_tau), lo[2]]) + 1e-6
    x_hi = np.array([min(hi[0], hi[1] - log_tau), hi[2]]) - 1e-6
    x0 = np.clip([theta0[0], theta0[2]], x_lo, x_hi)
    with objective.integration_fallback(integrate_start):
        objective.residuals(full(x0))   # the start (cached)
    with objective.integration_fallback(False):
        sol = least_squares(lambda x: objective.trial_residuals(full(x)), x0, jac=jac, bounds=(x_lo, x_hi),
                            method="trf", x_scale=1.0, ftol=1e-6, xtol=1e-6, max_nfev=max_nfev)
    return float(sol.fun @ sol.fun), full(sol.x)


def _profile_scan(objective: DynamicObjective, starts: list, profile_evaluations: int, integrate_starts: bool
                  ) -> tuple[list, list]:
    """The profile at each (tau, theta) of ``starts``: the (cost, tau, theta) found, and the taus skipped
    because harmonic balance failed at their start and ``integrate_starts`` is False."""
    candidates, skipped = [], []
    for tau, theta in starts:
        try:
            cost, theta = _profile_at_tau(objective, theta, math.log(tau), profile_evaluations, integrate_starts)
        except FallbackRefused as exc:
            LOG.debug("initial guess: tau %.3g s skipped (%s)", tau, exc)
            skipped.append(tau)
            continue
        except (TransientError, HarmonicBalanceError, SteadyStateError, FloatingPointError) as exc:
            LOG.debug("initial guess: tau %.3g s failed (%s)", tau, exc)
            continue
        candidates.append((cost, tau, theta))
    return candidates, skipped


def initial_guess(objective: DynamicObjective, taus_s=None, profile_evaluations: int = 12
                  ) -> tuple[list[np.ndarray], dict]:
    """Data-derived starts for theta = ln(k1, eta1, eta2) (see the module docstring).

    For every creep time tau of a log grid (1e-2..1e2 s), the linearised oscillation gives k1 and
    eta2, and eq. 22 is then minimised over ln k1 and ln eta2 at that tau (a profile of the cost
    over the creep time, ``profile_evaluations`` evaluations each). The profile, not the raw
    linearised starts, decides: on long-creep membranes (tau 10-30 s) the linearised start has a
    cost 10-100 x the truth's while the profiled cost is lowest near the true tau; ranking the raw
    starts sent the fit into the basin of tau ~ 0.2 s with eta2 at its bound.

    Returns (starts sorted by profiled cost, info).
    """
    params = objective.base
    info: dict = {}
    osc = None
    step = None
    if objective.steps:
        step = max(objective.steps, key=lambda s: abs(s.final_V - s.initial_V))
        osc = _oscillation_from_step(step)
    if osc is not None:
        f_osc, alpha = osc
        voltage, mass = step.final_V, step.mass_kg
        info["source"] = "step oscillation"
    elif objective.points:
        pts = sorted(objective.points, key=lambda p: p.frequency_Hz)
        peak = max(pts, key=lambda p: p.measured_rms_m)
        f_osc, alpha = 2.0 * peak.frequency_Hz, None   # u^2 forces at 2 f (eq. 6)
        voltage, mass = peak.amplitude_V / math.sqrt(2.0), peak.mass_kg
        info["source"] = "resonance peak of the sine data"
    else:
        raise DynamicFitError("dynamic fit: no step and no sine data")
    omega = 2.0 * math.pi * f_osc
    if alpha is None:
        alpha = 0.02 * omega
    k_s, g = _linearisation(params, voltage, mass)
    info.update({"oscillation_Hz": f_osc, "decay_rate_per_s": alpha})
    taus = np.logspace(-2, 2, 9) if taus_s is None else np.asarray(taus_s, float)
    lo, hi = _bounds(3)
    w2 = omega**2 + alpha**2
    starts = []
    for tau in taus:
        wt2 = (omega * tau) ** 2
        kv = (w2 - k_s) * (1.0 + wt2) / wt2           # G k1 from the stored-stiffness part
        if kv <= 0.0:
            kv = 0.05 * k_s
        k1 = kv / g
        c_ve = kv * tau / (1.0 + wt2)                   # damping of the Maxwell branch
        c_2 = max(2.0 * alpha - c_ve, 0.05 * 2.0 * alpha)
        eta2 = c_2 / g
        starts.append((float(tau), objective.start_vector(
            *np.exp(np.clip(np.log([k1, k1 * tau, eta2]), lo + 1e-6, hi - 1e-6)))))
    # The scan without forward integration: a creep time at whose start harmonic balance fails is skipped
    # (integrating there cost minutes per start on slow-creep membranes); only if every one is, with it.
    candidates, skipped = _profile_scan(objective, starts, profile_evaluations, False)
    if not candidates and skipped:
        candidates, _ = _profile_scan(objective, [s for s in starts if s[0] in skipped], profile_evaluations,
                                      True)
    elif skipped:
        info["scan_skipped_tau_s"] = skipped
    if not candidates:
        raise DynamicFitError("dynamic fit: every initial-guess simulation failed; check the static "
                              "parameters and the data (is the mass right?)")
    by_tau = sorted(candidates, key=lambda c: c[1])
    info["scan"] = [{"tau_s": tau, "cost": cost} for cost, tau, _ in by_tau]
    # Starts: the profile's local minima over tau, lowest first (at most three).
    minima = [c for i, c in enumerate(by_tau)
              if all(c[0] <= n[0] for n in by_tau[max(i - 1, 0):i + 2])]
    minima.sort(key=lambda c: c[0])
    minima = [c for c in minima if c[0] < 10.0 * minima[0][0]]
    return [c[2] for c in minima[:3]], info


# --------------------------------------------------------------------------- fit
@dataclass
class DynamicFitResult:
    """Outcome of :func:`fit_dynamic`."""

    parameters: MembraneParameters
    method: str
    frequency_method: str
    frequency_points: list
    simulated_rms_m: np.ndarray
    step_simulated_m: list
    cost: float                 # J of eq. 22
    step_cost: float
    frequency_cost: float
    statistics: ParameterStatistics | None
    initial: dict
    n_evaluations: int
    n_jacobians: int
    wall_time_s: float
    time_step_s: float
    time_frequency_s: float
    history: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    starts: list = field(default_factory=list)
    curvature_fitted: bool = False
    weights: tuple = ("paper", dict(PAPER_WEIGHTS))
    #: trial points of the scan and the local fits rejected where harmonic balance failed (not integrated)
    rejected_trials: int = 0

    @property
    def fit_frequencies_Hz(self) -> np.ndarray:
        return np.array([p.frequency_Hz for p in self.frequency_points])

    @property
    def measured_rms_m(self) -> np.ndarray:
        return np.array([p.measured_rms_m for p in self.frequency_points])


def _bounds(n_params: int):
    lo = np.log([b[0] for b in PARAMETER_BOUNDS.values()])
    hi = np.log([b[1] for b in PARAMETER_BOUNDS.values()])
    if n_params == 4:  # sigma_h''(1) coordinate in MPa
        lo, hi = np.r_[lo, -1e4], np.r_[hi, 1e4]
    return lo, hi


def fit_dynamic(
    static_params: MembraneParameters,
    steps: Sequence[StepData],
    sines: Sequence[SineData],
    method: str = "lsq",
    frequency_method: str = "hbm",
    fit_frequencies_Hz=None,
    weights: dict | None = None,
    n_harmonics: int = 8,
    start: MembraneParameters | None = None,
    progress: Callable[[dict], None] | None = None,
    max_evaluations: int = 200,
    nelder_mead_options: dict | None = None,
    curvature_direction=None,
    initial: MembraneParameters | None = None,
    noise_m: float | None = None,
) -> DynamicFitResult:
    """Fit k1, eta1, eta2 (eqs. 22-24) with the static parameters fixed.

    ``curvature_direction`` (lsq only): a (beta, gamma) direction that changes sigma_h''(1) by
    1 Pa per unit while keeping sigma_h(1), sigma_h'(1) (from
    :meth:`StaticFitResult.curvature_direction`); sigma_h''(1) is then a 4th parameter. The
    static data cannot see it (deflections < 1.3 mm), but the large oscillations near
    resonance do. ``start`` (optional) adds a start (e.g. a base parameters file) to the
    data-derived ones; ``initial`` replaces them (no scan; used to polish a previous fit).
    ``max_evaluations`` bounds the objective evaluations of each local optimisation.
    """
    if method not in DYNAMIC_METHODS:
        raise ValueError(f"method: choose one of {DYNAMIC_METHODS}, got {method!r}")
    if method == "paper":
        curvature_direction = None  # the paper's three parameters only
    t0 = time.perf_counter()
    points = select_fit_frequencies(sines, fit_frequencies_Hz)
    if not steps and not points:
        raise DynamicFitError("dynamic fit needs at least one step or sine experiment")
    n_needed = 3 if curvature_direction is None else 4
    if not steps and len(points) < n_needed:
        raise DynamicFitError(
            f"dynamic fit without a step response needs >= {n_needed} sine frequencies for {n_needed} "
            f"parameters, got {len(points)}"
        )
    objective = DynamicObjective(static_params, steps, points, weights, frequency_method, n_harmonics,
                                 progress, curvature_direction=curvature_direction, noise_m=noise_m)
    if initial is not None:
        starts = [objective.start_vector(initial.k1_Pa, initial.eta1_Pa_s, initial.eta2_Pa_s)]
        info = {"source": "previous fit"}
    else:
        starts, info = initial_guess(objective)
        if start is not None:
            starts.append(objective.start_vector(start.k1_Pa, start.eta1_Pa_s, start.eta2_Pa_s))
    lo, hi = _bounds(objective.n_params)
    best = None
    start_log = []
    for x0 in starts:
        x0 = np.clip(x0, lo + 1e-6, hi - 1e-6)
        theta, cost, msg, ok = _optimise(objective, x0, method, lo, hi, max_evaluations, nelder_mead_options)
        start_log.append({"start": _describe(objective, x0), "end": _describe(objective, theta),
                          "cost": cost, "message": str(msg), "success": ok})
        if best is None or cost < best[1]:
            best = (theta, cost, ok, msg)
    theta, cost, ok, msg = best
    result = _dynamic_result(objective, theta, method, lo, hi, ok, msg)
    result.initial, result.starts, result.wall_time_s = info, start_log, time.perf_counter() - t0
    return result


def _describe(objective: DynamicObjective, theta) -> dict:
    """k1, eta1, eta2 (and sigma_h''(1)) at ``theta``."""
    p = objective.parameters(theta)
    out = {n: float(getattr(p, n)) for n in NAMES}
    if objective.n_params == 4:
        out["sigma_h''(1)_Pa"] = float(stress_combinations(p.beta_Pa, p.gamma_Pa)[2])
    return out


def _optimise(objective: DynamicObjective, x0, method: str, lo, hi, max_evaluations: int,
              nelder_mead_options: dict | None) -> tuple:
    """(theta, cost, message, converged) of one local optimisation from ``x0``: least squares with the
    exact Jacobian ("lsq") or the paper's Nelder-Mead on normalised k1, eta1, eta2 ("paper")."""
    if method == "lsq":
        objective.residuals(x0)   # the start (cached): integrated where harmonic balance fails, never rejected
        with objective.integration_fallback(False):
            sol = least_squares(objective.trial_residuals, x0, jac=objective.jacobian, bounds=(lo, hi),
                                method="trf", x_scale=1.0, ftol=1e-9, xtol=1e-9, gtol=1e-10,
                                max_nfev=max_evaluations)
        return sol.x, float(sol.fun @ sol.fun), sol.message, sol.status > 0
    norm = np.array(PAPER_NORMALISATION)

    def nm_cost(y):
        if np.any(y <= 0):
            return 1e30
        return objective.cost(np.log(y * norm))

    opts = {"xatol": 5e-2, "fatol": 5e-2, "maxfev": max_evaluations * 5}
    opts.update(nelder_mead_options or {})
    sol = minimize(nm_cost, np.exp(x0) / norm, method="Nelder-Mead", options=opts)
    theta = np.log(np.clip(sol.x, 1e-300, None) * norm)
    return theta, float(sol.fun), sol.message, bool(sol.success)


def _dynamic_result(objective: DynamicObjective, theta, method: str, lo, hi, ok: bool, msg) -> DynamicFitResult:
    """The result at the optimum ``theta``: parameters, linearised statistics, warnings (no timing, starts)."""
    names = NAMES + (("sigma_h''(1)_Pa",) if objective.n_params == 4 else ())
    res, jac, details = objective.evaluate(theta, jacobian=True)
    params = objective.parameters(theta)
    values = np.exp(theta[:3])
    is_log = [True, True, True]
    if objective.n_params == 4:
        values = np.r_[values, stress_combinations(params.beta_Pa, params.gamma_Pa)[2]]
        jac = jac.copy()
        jac[:, 3] /= CURVATURE_UNIT_PA
        is_log.append(False)
    stats = parameter_statistics(jac, res, names, values, log_parameters=is_log, context="dynamic fit")
    warnings = list(stats.warnings)
    if not ok:
        warnings.append(f"dynamic fit ({method}) did not report convergence: {msg}")
    at_bound = [n for n, t, a, b in zip(names, theta, lo, hi) if t - a < 1e-3 or b - t < 1e-3]
    if at_bound:
        warnings.append(f"dynamic fit: {', '.join(at_bound)} ended at the search bound; the data do not "
                        "constrain it (or the model cannot reproduce the data)")
    warnings += sorted(set(objective.fallbacks))
    return DynamicFitResult(
        parameters=params, method=method, frequency_method=objective.frequency_method,
        frequency_points=objective.points,
        simulated_rms_m=np.asarray(details["simulated_rms_m"]), step_simulated_m=details["step_simulated_m"],
        cost=float(res @ res), step_cost=details["step_cost"], frequency_cost=details["frequency_cost"],
        statistics=stats, initial={}, n_evaluations=objective.n_evaluations,
        n_jacobians=objective.n_jacobians, wall_time_s=0.0,
        time_step_s=objective.time_step_s, time_frequency_s=objective.time_frequency_s,
        history=objective.history, warnings=warnings,
        curvature_fitted=objective.n_params == 4, weights=objective.weights,
        rejected_trials=objective.rejected_trials,
    )
