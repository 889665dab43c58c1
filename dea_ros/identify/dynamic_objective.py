"""The objective of the dynamic fit (paper section IV-C): eq. 22's residuals and their exact Jacobian.

The objective is eq. 22::

    J = w_step sum_steps sum_j e_d(j)^2  +  w_hbm sum_k (d_m,rms(f_k) - d_s,rms(f_k))^2

with e_d the simulated minus measured displacement at every sample of a step
record (eq. 23) and d_rms the RMS around the rest position (eq. 21) of the
periodic response to a sine of amplitude U at frequency f_k (eq. 24).

Simulations per objective evaluation
------------------------------------
* step: :class:`~dea_ros.solvers.transient.TransientCollocation` (whole-trajectory
  Hermite-Simpson collocation on the sample grid, ~1 nm from DOP853), warm-started
  from the previous evaluation, with exact sensitivities d d(t_j)/d ln(k1, eta1, eta2).
* frequency response, ``frequency_method="hbm"`` (default): native harmonic balance
  (:func:`~dea_ros.solvers.newton.solve_native`), continued from the previous
  evaluation's solution at the same frequency, with the exact sensitivity of d_rms
  from the collocation Jacobian (implicit function theorem: dX/dtheta = -J^-1 dR/dtheta).
* ``frequency_method="integration"``: forward integration from rest to the periodic
  steady state (:func:`~dea_ros.solvers.steady_state.integrate_to_steady_state`), as the
  paper's baseline, with forward finite differences for the Jacobian -- same optimizer,
  same data, so the speed-up of harmonic balance is measured like for like.

Weights (:func:`resolve_weights`): the paper's by default. With them and a 4.2 s step at
1 kHz, the frequency points carry ~1e-4 of the cost at the optimum: the fit is essentially a
step fit, checked at four frequencies. ``weights="noise"`` uses 1/sigma^2 per residual (laser
noise for the samples, the stated uncertainty of each RMS value), a proper chi-square in
which the precise RMS values count. Curvature: sigma_h''(1) = sum i(i-1) beta_i - i(i+1)
gamma_i is invisible to the static data (s - 1 < 1e-2) but shapes the large-amplitude
response near resonance; ``curvature_direction`` makes it a 4th parameter.
"""
from __future__ import annotations

import contextlib
import logging
import math
import time
from typing import Callable, Sequence

import numpy as np

from ..errors import DynamicFitError
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..errors import FallbackRefused, HarmonicBalanceError
from ..solvers.periodic_solution import PeriodicSolution
from ..solvers.inputs import SinePeriodic
from ..solvers.steady_state import integrate_to_steady_state
from ..solvers.transient import rest_state_derivative
from .experiments import StepData, estimate_noise_m
from .frequency_points import FrequencyPoint, periodic_rms_gradient, point_solution
from .static_fit import stress_combinations
from .step_simulation import step_solver

__all__ = ["DynamicObjective", "resolve_weights", "PAPER_WEIGHTS", "FREQUENCY_METHODS", "CURVATURE_UNIT_PA",
           ]

LOG = logging.getLogger("dea_ros.identify")

#: Weights of eq. 22 (section IV-C).
PAPER_WEIGHTS = {"step": 6.6e6, "hbm": 0.1e6}
FREQUENCY_METHODS = ("hbm", "integration")
#: Unit of the curvature coordinate of the optimizer (sigma_h''(1) in MPa).
CURVATURE_UNIT_PA = 1e6
# Where forward integration replaces a failed harmonic balance (DynamicObjective.integration_fallback):
# allowed at starts, accepted points and the result (the default); refused at a trial point of a local fit
# (FallbackRefused -> non-finite residuals, least_squares' trust region shrinks back towards the last accepted
# point, as in the joint refinement) and at the start of a creep time of the initial guess's profile scan (that
# creep time is skipped). Each integration runs to the periodic state, (1 + parameters) times per failing
# frequency: minutes on a slow-creep or softening membrane (F04 of the coverage family: 1510 s for one
# identification; F13 seeds 2-3: > 20 min; with 8 integrating trials still allowed, F13 with 17 frequencies,
# seed 2: > 10 min).


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
        self.solvers = [step_solver(static_params, s) for s in self.steps]
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
        self.rejected_trials = 0     # trial points rejected instead (FallbackRefused)
        self.integrate_failures = True       # set with the integration_fallback() context

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

    def point_rest(self, params, point: FrequencyPoint):
        """(d0, its derivative along the curvature direction) a point's RMS is about: the measured rest
        position the record states (fixed), else the model's (:meth:`rest`)."""
        if point.rest_d0_m is not None:
            return float(point.rest_d0_m), 0.0
        return self.rest(params, point.mass_kg)

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
        return sol.displacement_rms(self.point_rest(params, point)[0])

    def _frequency_part(self, params, theta, jac: bool, known_sim=None):
        """Residuals (and rows) of eq. 24. ``known_sim``: RMS values already computed at theta
        (the integration method then only adds the finite differences)."""
        sim = np.empty(len(self.points))
        rows = np.zeros((len(self.points), self.n_params))
        for k, point in enumerate(self.points):
            p = params if point.mass_kg == params.mass_kg else params.replace(mass_kg=point.mass_kg)
            d0, dd0 = self.point_rest(params, point)
            if self.frequency_method == "hbm":
                try:
                    sol = self._hbm_solve(p, k, point)
                    if jac:
                        sim[k], rows[k] = self._rms_gradient(p, sol, d0, dd0)
                    else:
                        sim[k] = sol.displacement_rms(d0)
                    continue
                except HarmonicBalanceError as exc:
                    self._hb_guess.pop(k, None)
                    self._fallback_allowed(point, exc)
                    msg = (f"harmonic balance failed at {point.frequency_Hz:g} Hz ({exc}); "
                           "used forward integration for that evaluation")
                    self.fallbacks.append(msg)
                    LOG.warning(msg)
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

    @contextlib.contextmanager
    def integration_fallback(self, allowed: bool):
        """Within the block, forward integration replaces a failed harmonic balance (``allowed``) or the
        evaluation raises FallbackRefused (module comment above ``resolve_weights``)."""
        previous, self.integrate_failures = self.integrate_failures, bool(allowed)
        try:
            yield self
        finally:
            self.integrate_failures = previous

    def _fallback_allowed(self, point: FrequencyPoint, exc: HarmonicBalanceError) -> None:
        """Raise FallbackRefused unless this evaluation may integrate."""
        if not self.integrate_failures:
            raise FallbackRefused(f"harmonic balance failed at {point.frequency_Hz:g} Hz ({exc}); "
                                  "not integrated (a trial point, or a start the scan skips)") from exc

    def trial_residuals(self, theta) -> np.ndarray:
        """:meth:`residuals` at a trial point of an optimiser (not its start: evaluate that with
        :meth:`residuals` first): where harmonic balance fails (integration refused), non-finite residuals
        (least_squares rejects the point and shrinks its trust region), counted in ``rejected_trials``."""
        try:
            return self.residuals(theta)
        except FallbackRefused as exc:
            self.rejected_trials += 1
            LOG.info("dynamic fit: trial point rejected (%s)", exc)
            return np.full(self.n_residuals, np.nan)

    def jacobian(self, theta) -> np.ndarray:
        """At an accepted point (cached from its evaluation; forward integration where harmonic balance fails
        even inside integration_fallback(False), should the cache have dropped it)."""
        try:
            return self.evaluate(theta, jacobian=True)[1]
        except FallbackRefused:
            with self.integration_fallback(True):
                return self.evaluate(theta, jacobian=True)[1]

    def cost(self, theta) -> float:
        """J of eq. 22."""
        r = self.evaluate(theta, jacobian=False)[0]
        return float(r @ r)
