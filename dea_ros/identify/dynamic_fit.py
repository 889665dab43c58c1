"""Dynamic fit (paper section IV-C, eqs. 22-24): k1, eta1, eta2 from step and frequency responses.

The objective is eq. 22::

    J = w_step sum_steps sum_j e_d(j)^2  +  w_hbm sum_k (d_m,rms(f_k) - d_s,rms(f_k))^2

with e_d the simulated minus measured displacement at every sample of a step
record (eq. 23) and d_rms the RMS around the rest position (eq. 21) of the
periodic response to a sine of amplitude U at frequency f_k (eq. 24). Defaults
are the paper's: w_step = 6.6e6, w_hbm = 0.1e6, f_k = 0.2, 8.3, 11.2 and 40 Hz
(those present in the data; all data frequencies when none is).

Simulations per objective evaluation
------------------------------------
* step: :class:`~dea_ros.solvers.transient.TransientCollocation` (whole-trajectory
  Hermite-Simpson collocation on the sample grid, ~1 nm from DOP853), warm-started
  from the previous evaluation, with exact sensitivities d d(t_j)/d ln(k1, eta1, eta2).
* frequency response, ``frequency_method="hbm"`` (default): native harmonic balance
  (:func:`~dea_ros.solvers.harmonic_balance.solve_native`), continued from the previous
  evaluation's solution at the same frequency, with the exact sensitivity of d_rms
  from the collocation Jacobian (implicit function theorem: dX/dtheta = -J^-1 dR/dtheta).
* ``frequency_method="integration"``: forward integration from rest to the periodic
  steady state (:func:`~dea_ros.solvers.steady_state.integrate_to_steady_state`), as the
  paper's baseline, with forward finite differences for the Jacobian -- same optimizer,
  same data, so the speed-up of harmonic balance is measured like for like.

Optimizers: ``method="lsq"`` (default), ``scipy.optimize.least_squares`` (trust-region
reflective) over ln(k1, eta1, eta2) with the analytic Jacobian; ``method="paper"``,
Nelder-Mead on eq. 22 over k1/1e7, eta1/1e8, eta2/1e4 with xatol = fatol = 5e-2.

Weights (:func:`resolve_weights`): the paper's by default. With them and a 4.2 s step at
1 kHz, the frequency points carry ~1e-4 of the cost at the optimum: the fit is essentially a
step fit, checked at four frequencies. ``weights="noise"`` uses 1/sigma^2 per residual (laser
noise for the samples, the stated uncertainty of each RMS value), a proper chi-square in
which the precise RMS values count. Curvature: sigma_h''(1) = sum i(i-1) beta_i - i(i+1)
gamma_i is invisible to the static data (s - 1 < 1e-2) but shapes the large-amplitude
response near resonance; ``curvature_direction`` makes it a 4th parameter (sensible with
noise weights and frequencies near the resonance; the statistics say when it is not determined).

Initial guess (no trial and error): the oscillation after the step gives its frequency
(FFT peak) and decay rate (log envelope); with the fitted static parameters the model
linearised at the post-step equilibrium turns them into k1 and eta2 for any relaxation
time tau = eta1/k1, and a scan of tau over 1e-2..1e2 s with the full objective picks the
start(s). Without a step, the resonance peak of the sine data gives the frequency.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares, minimize

from ..model.dynamics import DEAModel
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..solvers.harmonic_balance import HarmonicBalanceError, PeriodicSolution
from ..solvers.inputs import SinePeriodic
from ..solvers.steady_state import SteadyStateError, integrate_to_steady_state
from ..solvers.transient import TransientCollocation, TransientError, rest_state_derivative
from .experiments import SineData, StepData, estimate_noise_m
from .frequency_points import FrequencyPoint, periodic_rms_gradient, point_solution
from .metrics import ParameterStatistics, parameter_statistics
from .static_fit import stress_combinations
from ..errors import DynamicFitError

__all__ = [
    "DynamicFitResult",
    "DynamicFitError",
    "DynamicObjective",
    "fit_dynamic",
    "select_fit_frequencies",
    "initial_guess",
    "PAPER_FREQUENCIES_HZ",
    "PAPER_WEIGHTS",
    "PAPER_NORMALISATION",
    "FREQUENCY_METHODS",
    "DYNAMIC_METHODS",
    "PARAMETER_BOUNDS",
    "CURVATURE_UNIT_PA",
    "resolve_weights",
]

LOG = logging.getLogger("dea_ros.identify")

PAPER_FREQUENCIES_HZ = (0.2, 8.3, 11.2, 40.0)
#: Weights of eq. 22 (section IV-C).
PAPER_WEIGHTS = {"step": 6.6e6, "hbm": 0.1e6}
#: Normalisation of k1, eta1, eta2 in the paper's Nelder-Mead.
PAPER_NORMALISATION = (1e7, 1e8, 1e4)
FREQUENCY_METHODS = ("hbm", "integration")
DYNAMIC_METHODS = ("lsq", "paper")
NAMES = ("k1_Pa", "eta1_Pa_s", "eta2_Pa_s")
#: Unit of the curvature coordinate of the optimizer (sigma_h''(1) in MPa).
CURVATURE_UNIT_PA = 1e6
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
                           s.inputs[k] if s.inputs else None)
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


def resolve_weights(weights, steps: Sequence[StepData], points: Sequence[FrequencyPoint],
                    noise_m: float | None = None):
    """Weights of eq. 22 as (description, sqrt weight per step, sqrt weight per frequency point).

    * ``None`` or ``"paper"``: w_step = 6.6e6 per step sample, w_hbm = 0.1e6 per frequency (the paper).
    * a dict ``{"step": w, "hbm": w}``: those (missing keys: the paper's).
    * ``"noise"``: statistical weights 1/sigma^2 -- sigma = the laser noise (``noise_m``, else
      estimated from each step's pre-step baseline) for the step samples and the
      ``d_rms_std_m`` column for the RMS values -- so that J is a chi-square and the
      frequency data carry the weight their precision deserves.
    """
    if weights is None or (isinstance(weights, str) and weights == "paper"):
        w = dict(PAPER_WEIGHTS)
        return ("paper", w), [math.sqrt(w["step"])] * len(steps), np.full(len(points), math.sqrt(w["hbm"]))
    if isinstance(weights, dict):
        w = dict(PAPER_WEIGHTS)
        unknown = set(weights) - set(w)
        if unknown:
            raise ValueError(f"weights: unknown key(s) {sorted(unknown)}; use 'step' and 'hbm'")
        w.update({k: float(v) for k, v in weights.items()})
        if min(w.values()) < 0:
            raise ValueError(f"weights: must be >= 0, got {w}")
        return ("custom", w), [math.sqrt(w["step"])] * len(steps), np.full(len(points), math.sqrt(w["hbm"]))
    if weights != "noise":
        raise ValueError(f"weights: 'paper', 'noise' or a dict, got {weights!r}")
    sq_steps = []
    for step in steps:
        sigma = noise_m if noise_m is not None else estimate_noise_m(step)
        if sigma is None or sigma <= 0:
            raise DynamicFitError(
                f"{step.source}: weights='noise' needs the laser noise: give sensor_noise_m in the manifest "
                "(the estimate from the record failed)"
            )
        sq_steps.append(1.0 / sigma)
    sq_points = []
    for p in points:
        if p.measured_std_m is None:
            raise DynamicFitError(
                f"{p.source}: weights='noise' needs the column d_rms_std_m (standard uncertainty of each RMS "
                "value); add it or use the paper's weights"
            )
        sq_points.append(1.0 / p.measured_std_m)
    return ("noise", {"step_sigma_m": [1 / x for x in sq_steps], "rms_sigma_m": [1 / x for x in sq_points]}), \
        sq_steps, np.asarray(sq_points, float)


class DynamicObjective:
    """Residuals of eq. 22 and their Jacobian w.r.t. theta = ln(k1, eta1, eta2).

    ``residuals(theta)`` = [sqrt(w_step) (d_sim - d_meas) for every step sample,
    sqrt(w_hbm) (rms_sim - rms_meas) for every frequency point], so that
    ``sum(residuals**2)`` is the cost J of eq. 22. Evaluations are cached per theta
    (the Jacobian of an evaluated point is free), timed per part and counted.
    """

    def __init__(
        self,
        static_params: MembraneParameters,
        steps: Sequence[StepData],
        frequency_points: Sequence[FrequencyPoint],
        weights: dict | None = None,
        frequency_method: str = "hbm",
        n_harmonics: int = 8,
        progress: Callable[[dict], None] | None = None,
        integration_options: dict | None = None,
        curvature_direction=None,
        noise_m: float | None = None,
    ):
        if frequency_method not in FREQUENCY_METHODS:
            raise ValueError(f"frequency_method: choose one of {FREQUENCY_METHODS}, got {frequency_method!r}")
        self.base = static_params
        self.steps = list(steps)
        self.points = list(frequency_points)
        self.weights, self.sq_w_steps, self.sq_w_points = resolve_weights(
            weights, self.steps, self.points, noise_m)
        self.frequency_method = frequency_method
        self.n_harmonics = int(n_harmonics)
        self.progress = progress
        self.integration_options = dict(integration_options or {})
        self.solvers = [TransientCollocation(s.time_s, s.voltage_V, hold=s.voltage_hold) for s in self.steps]
        # Optional 4th parameter: sigma_h''(1) moved along a (beta, gamma) direction (in MPa).
        self.direction = None
        self.base_beta_gamma = np.r_[static_params.beta_Pa, static_params.gamma_Pa]
        if curvature_direction is not None:
            self.direction = np.asarray(curvature_direction, float).reshape(6) * CURVATURE_UNIT_PA
        self.n_params = 3 if self.direction is None else 4
        self.masses = sorted({p.mass_kg for p in self.points})
        self._rest_cache: dict = {}
        self._hb_guess: dict[int, np.ndarray] = {}
        self._cache: dict[bytes, tuple] = {}
        self.n_evaluations = 0
        self.n_jacobians = 0
        self.time_step_s = 0.0
        self.time_frequency_s = 0.0
        self.history: list[dict] = []
        self.fallbacks: list[str] = []

    # -------------------------------------------------------------- parameters
    def parameters(self, theta) -> MembraneParameters:
        theta = np.asarray(theta, float)
        k1, eta1, eta2 = np.exp(theta[:3])
        changes = {"k1_Pa": float(k1), "eta1_Pa_s": float(eta1), "eta2_Pa_s": float(eta2)}
        if self.direction is not None:
            bg = self.base_beta_gamma + theta[3] * self.direction
            changes["beta_Pa"] = tuple(float(v) for v in bg[:3])
            changes["gamma_Pa"] = tuple(float(v) for v in bg[3:])
        return self.base.replace(**changes)

    def start_vector(self, k1_Pa, eta1_Pa_s, eta2_Pa_s) -> np.ndarray:
        """theta for given k1, eta1, eta2 (curvature coordinate 0: the static fit's beta/gamma)."""
        theta = np.log([k1_Pa, eta1_Pa_s, eta2_Pa_s])
        return theta if self.direction is None else np.r_[theta, 0.0]

    def rest(self, params, mass_kg: float):
        """Rest displacement at 0 V (d0 of eq. 21) and its derivative along the curvature direction."""
        key = (mass_kg, params.beta_Pa, params.gamma_Pa)
        hit = self._rest_cache.get(key)
        if hit is None:
            p = params if mass_kg == params.mass_kg else params.replace(mass_kg=mass_kg)
            d0 = float(static_equilibrium(p, 0.0).displacement_m)
            dd0 = (float(rest_state_derivative(p, 0.0, self.direction[None, :], d0)[0, 0])
                   if self.direction is not None else 0.0)
            if len(self._rest_cache) > 32:
                self._rest_cache.clear()
            hit = self._rest_cache[key] = (d0, dd0)
        return hit

    @property
    def n_residuals(self) -> int:
        return sum(s.n_samples for s in self.steps) + len(self.points)

    # -------------------------------------------------------------- parts
    def _step_part(self, params, jac: bool):
        res, rows = [], []
        sims = []
        for step, solver, sq_w in zip(self.steps, self.solvers, self.sq_w_steps):
            p = params if step.mass_kg == params.mass_kg else params.replace(mass_kg=step.mass_kg)
            sol = solver.solve(p, sensitivities=jac,
                               stress_directions=None if self.direction is None else self.direction[None, :])
            sims.append(sol.displacement_m)
            res.append(sq_w * (sol.displacement_m - step.displacement_m))
            if jac:
                rows.append(sq_w * sol.displacement_sensitivity_m.T)
        return res, rows, sims

    def _hbm_solve(self, params, k: int, point: FrequencyPoint) -> PeriodicSolution:
        sol = point_solution(params, point, self.n_harmonics, self._hb_guess.get(k))
        self._hb_guess[k] = sol.state
        return sol

    def _rms_gradient(self, params, sol: PeriodicSolution, d0: float, dd0: float) -> tuple[float, np.ndarray]:
        """d_rms (eq. 21) and its gradient w.r.t. theta at a harmonic-balance solution."""
        dirs = None if self.direction is None else self.direction[None, :]
        return periodic_rms_gradient(params, sol, d0, np.atleast_1d(dd0)[: 0 if dirs is None else 1], dirs)

    def _integration_rms(self, params, point: FrequencyPoint) -> float:
        sine = point.periodic_input or SinePeriodic(point.amplitude_V, point.frequency_Hz)
        p = params if point.mass_kg == params.mass_kg else params.replace(mass_kg=point.mass_kg)
        with np.errstate(over="ignore", invalid="ignore"):  # rejected trial steps of DOP853
            sol = integrate_to_steady_state(p, sine, **self.integration_options)
        return sol.displacement_rms(self.rest(params, point.mass_kg)[0])

    def _frequency_part(self, params, theta, jac: bool, known_sim=None):
        """Residuals (and rows) of eq. 24. ``known_sim``: RMS values already computed at theta
        (the integration method then only adds the finite differences)."""
        sim = np.empty(len(self.points))
        rows = np.zeros((len(self.points), self.n_params))
        for k, point in enumerate(self.points):
            p = params if point.mass_kg == params.mass_kg else params.replace(mass_kg=point.mass_kg)
            d0, dd0 = self.rest(params, point.mass_kg)
            if self.frequency_method == "hbm":
                try:
                    sol = self._hbm_solve(p, k, point)
                    if jac:
                        sim[k], rows[k] = self._rms_gradient(p, sol, d0, dd0)
                    else:
                        sim[k] = sol.displacement_rms(d0)
                    continue
                except HarmonicBalanceError as exc:
                    msg = (f"harmonic balance failed at {point.frequency_Hz:g} Hz ({exc}); "
                           "used forward integration for that evaluation")
                    self.fallbacks.append(msg)
                    LOG.warning(msg)
                    self._hb_guess.pop(k, None)
            sim[k] = known_sim[k] if known_sim is not None else self._integration_rms(p, point)
            if jac:  # forward differences in theta
                h = 1e-4
                for j in range(self.n_params):
                    tj = np.array(theta, float)
                    tj[j] += h
                    rows[k, j] = (self._integration_rms(self.parameters(tj), point) - sim[k]) / h
        res = self.sq_w_points * (sim - np.array([p.measured_rms_m for p in self.points]))
        return res, self.sq_w_points[:, None] * rows, sim

    # -------------------------------------------------------------- evaluate
    def evaluate(self, theta, jacobian: bool = True):
        """(residuals, jacobian or None, details) at theta; cached."""
        theta = np.asarray(theta, float)
        key = theta.tobytes()
        hit = self._cache.get(key)
        if hit is not None and (hit[1] is not None or not jacobian):
            return hit
        params = self.parameters(theta)
        known = hit[2]["simulated_rms_m"] if hit is not None else None
        t0 = time.perf_counter()
        step_res, step_rows, step_sims = self._step_part(params, jacobian)
        t1 = time.perf_counter()
        freq_res, freq_rows, freq_sims = (self._frequency_part(params, theta, jacobian, known)
                                          if self.points else
                                          (np.empty(0), np.zeros((0, self.n_params)), np.empty(0)))
        t2 = time.perf_counter()
        self.time_step_s += t1 - t0
        self.time_frequency_s += t2 - t1
        if hit is None:
            self.n_evaluations += 1
        if jacobian:
            self.n_jacobians += 1
        res = np.concatenate(step_res + [freq_res])
        jac = np.vstack(step_rows + [freq_rows]) if jacobian else None
        details = {"step_simulated_m": step_sims, "simulated_rms_m": freq_sims,
                   "step_cost": float(sum(r @ r for r in step_res)), "frequency_cost": float(freq_res @ freq_res)}
        cost = float(res @ res)
        if hit is None:  # a new point (not the Jacobian of a point already evaluated)
            record = {"stage": "dynamic", "evaluation": self.n_evaluations, "iteration": self.n_evaluations,
                      "cost": cost,
                      "k1_Pa": params.k1_Pa, "eta1_Pa_s": params.eta1_Pa_s, "eta2_Pa_s": params.eta2_Pa_s}
            if self.direction is not None:
                record["sigma_h''(1)_Pa"] = float(stress_combinations(params.beta_Pa, params.gamma_Pa)[2])
            self.history.append(record)
            LOG.debug("dynamic fit evaluation %d: J = %.6g (k1 %.5g Pa, eta1 %.5g Pa s, eta2 %.5g Pa s)",
                      self.n_evaluations, cost, params.k1_Pa, params.eta1_Pa_s, params.eta2_Pa_s)
            if self.progress:
                self.progress(record)
        out = (res, jac, details)
        if len(self._cache) > 64:
            self._cache.clear()
        self._cache[key] = out
        return out

    def residuals(self, theta) -> np.ndarray:
        # With harmonic balance the sensitivities cost little: compute them with every
        # evaluation (least_squares asks for the Jacobian at accepted points).
        return self.evaluate(theta, jacobian=self.frequency_method == "hbm")[0]

    def jacobian(self, theta) -> np.ndarray:
        return self.evaluate(theta, jacobian=True)[1]

    def cost(self, theta) -> float:
        """J of eq. 22."""
        r = self.evaluate(theta, jacobian=False)[0]
        return float(r @ r)


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


def initial_guess(objective: DynamicObjective, taus_s=None) -> tuple[list[np.ndarray], dict]:
    """Data-derived starts for theta = ln(k1, eta1, eta2) (see the module docstring).

    Returns (starts sorted by cost, info).
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
    lo = np.log([b[0] for b in PARAMETER_BOUNDS.values()])
    hi = np.log([b[1] for b in PARAMETER_BOUNDS.values()])
    candidates = []
    w2 = omega**2 + alpha**2
    for tau in taus:
        wt2 = (omega * tau) ** 2
        kv = (w2 - k_s) * (1.0 + wt2) / wt2           # G k1 from the stored-stiffness part
        if kv <= 0.0:
            kv = 0.05 * k_s
        k1 = kv / g
        c_ve = kv * tau / (1.0 + wt2)                   # damping of the Maxwell branch
        c_2 = max(2.0 * alpha - c_ve, 0.05 * 2.0 * alpha)
        eta2 = c_2 / g
        theta = objective.start_vector(*np.exp(np.clip(np.log([k1, k1 * tau, eta2]), lo + 1e-6, hi - 1e-6)))
        try:
            cost = objective.cost(theta)
        except (TransientError, HarmonicBalanceError, SteadyStateError, FloatingPointError) as exc:
            LOG.debug("initial guess: tau %.3g s failed (%s)", tau, exc)
            continue
        candidates.append((cost, float(tau), theta))
    if not candidates:
        raise DynamicFitError("dynamic fit: every initial-guess simulation failed; check the static "
                              "parameters and the data (is the mass right?)")
    candidates.sort(key=lambda c: c[0])
    info["scan"] = [{"tau_s": tau, "cost": cost} for cost, tau, _ in sorted(candidates, key=lambda c: c[1])]
    # Starts: the best scan point and the best one that is not its neighbour (another valley).
    starts = [candidates[0][2]]
    taus_sorted = sorted(c[1] for c in candidates)
    for cost, tau, theta in candidates[1:]:
        i0 = taus_sorted.index(candidates[0][1])
        i1 = taus_sorted.index(tau)
        if abs(i1 - i0) > 1:
            # a separate local minimum of the scan?
            neighbours = [c for c in candidates if abs(taus_sorted.index(c[1]) - i1) == 1]
            if all(cost <= c[0] for c in neighbours) and cost < 10.0 * candidates[0][0]:
                starts.append(theta)
                break
    return starts, info


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
    names = NAMES + (("sigma_h''(1)_Pa",) if objective.n_params == 4 else ())
    lo, hi = _bounds(objective.n_params)
    best = None
    start_log = []

    def describe(theta):
        p = objective.parameters(theta)
        out = {n: float(getattr(p, n)) for n in NAMES}
        if objective.n_params == 4:
            out["sigma_h''(1)_Pa"] = float(stress_combinations(p.beta_Pa, p.gamma_Pa)[2])
        return out

    for x0 in starts:
        x0 = np.clip(x0, lo + 1e-6, hi - 1e-6)
        if method == "lsq":
            sol = least_squares(objective.residuals, x0, jac=objective.jacobian, bounds=(lo, hi),
                                method="trf", x_scale=1.0, ftol=1e-9, xtol=1e-9, gtol=1e-10,
                                max_nfev=max_evaluations)
            theta, cost, msg, ok = sol.x, float(sol.fun @ sol.fun), sol.message, sol.status > 0
        else:
            norm = np.array(PAPER_NORMALISATION)

            def nm_cost(y):
                if np.any(y <= 0):
                    return 1e30
                return objective.cost(np.log(y * norm))

            opts = {"xatol": 5e-2, "fatol": 5e-2, "maxfev": max_evaluations * 5}
            opts.update(nelder_mead_options or {})
            sol = minimize(nm_cost, np.exp(x0) / norm, method="Nelder-Mead", options=opts)
            theta = np.log(np.clip(sol.x, 1e-300, None) * norm)
            cost, msg, ok = float(sol.fun), sol.message, bool(sol.success)
        start_log.append({"start": describe(x0), "end": describe(theta),
                          "cost": cost, "message": str(msg), "success": ok})
        if best is None or cost < best[1]:
            best = (theta, cost, ok, msg)
    theta, cost, ok, msg = best
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
        parameters=params, method=method, frequency_method=frequency_method, frequency_points=points,
        simulated_rms_m=np.asarray(details["simulated_rms_m"]), step_simulated_m=details["step_simulated_m"],
        cost=float(res @ res), step_cost=details["step_cost"], frequency_cost=details["frequency_cost"],
        statistics=stats, initial=info, n_evaluations=objective.n_evaluations,
        n_jacobians=objective.n_jacobians, wall_time_s=time.perf_counter() - t0,
        time_step_s=objective.time_step_s, time_frequency_s=objective.time_frequency_s,
        history=objective.history, warnings=warnings, starts=start_log,
        curvature_fitted=objective.n_params == 4, weights=objective.weights,
    )
