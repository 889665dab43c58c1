"""Joint refinement: every identifiable parameter at once, with statistical weights.

The paper's procedure fits in two stages (static parameters from the rest positions, then k1,
eta1, eta2 with them frozen, eqs. 19-24). Freezing the first stage hides its uncertainty from
the second, and the paper's weights make eq. 22 a step fit: the intervals of the second stage
do not cover the truth. The joint refinement starts from the two-stage result and minimises one
chi-square over all the data,

    chi^2 = sum_static ((d_model - d)/s_static)^2 + sum_steps ((d_model(t_j) - d_j)/sigma)^2
            + sum_sines ((d_rms,model - d_rms)/sigma_rms)^2,

over theta = (sigma_h(1), sigma_h'(1)[, sigma_h''(1)], eps_r, ln k1, ln eta1, ln eta2), with
s_static each static point's standard uncertainty where the data state it (the laser noise over the
square root of its samples, scaled up where the static fit's residuals scatter more), else the residual
standard deviation of the static fit (:func:`~.refinement.static_sigma`), sigma the laser noise (the
manifest's ``sensor_noise_m`` or the estimate from each record) and sigma_rms the stated
uncertainty of each RMS value (``d_rms_std_m``; otherwise estimated from the residuals). The
stress combinations are those of eq. 10 with derivatives in s = lambda^2 (the static fit's
coordinates), written as Ogden beta/gamma by the static fit's representation (closest to the
base parameters, or the minimum-norm mu_i of eqs. 8-9).

Every residual has an exact Jacobian: the static points by implicit differentiation of eq. 20,
the steps by the collocation sensitivities (ln k1, ln eta1, ln eta2, the (beta, gamma) direction
of each stress combination, eps_r), the RMS values by the implicit function theorem on the
harmonic-balance equations of the solution each record is fitted with (T/2 periodic or
period-doubled; quasi-periodic records are left out by the caller). The 95 % intervals come from
the linearised covariance of the chi-square (t quantile, s^2 = chi^2 / dof).

sigma_h''(1) (the curvature of the hyperelastic stress) is invisible to the static data of most
membranes (where large deflections do determine it, the static fit frees it and so does this fit,
``curvature_from_static``) and is fitted from the large oscillations near resonance; so is the next
term, sigma_h'''(1): at
1.5 mm RMS (s - 1 up to 0.03) and 0.03 um uncertainty of an RMS value a wrong third derivative
alone moves the response near the peak by 40 standard deviations, so it is fitted with the
curvature (a nuisance parameter: the intervals of the others allow for it). sigma_h''(1) is
reported as identified when its 95 % interval is within +-``curvature_rel_ci_limit`` (50 %) of
its value; otherwise the result says so (``curvature_identified`` False) and the caller decides
(the pipeline writes it flagged "poorly determined" while its sign is known, else the base value).
The four combinations are matched exactly by the (beta, gamma) closest to the
base parameters' (or, without them, to the start's), as in the static fit's representation.

That holds the two remaining directions of the Ogden shape (the fourth and fifth derivatives at s = 1) at
the base's. Where the data are precise enough to see them, that guess steers the others (the coverage
family's F13 with two passes: sigma_h''(1) +5 % at z +17, eps_r, eta1 and eta2 at z +1.8..+2.7; with the
truth's shape every |z| <= 1.6). ``fit_curvature="shape"`` frees them too (all six Ogden coefficients);
:func:`held_shape_test` says when the data call for it, and :mod:`~.refinement` then refits (or, where the
free fit is not kept, reports the held parameters with the intervals linearised with the shape free).
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import stats as scipy_stats
from scipy.optimize import least_squares

from ..model.equilibrium import NoEquilibriumError, static_equilibrium
from ..model.parameters import MembraneParameters
from ..errors import HarmonicBalanceError
from ..solvers.transient import TransientError, rest_state_derivative
from .dynamic_fit import PARAMETER_BOUNDS
from .experiments import StaticData, StepData, estimate_noise_m
from .frequency_points import FrequencyPoint, periodic_rms_gradient, point_solution, rms_reference_m
from .metrics import ParameterStatistics, parameter_statistics
from .static_fit import (EXTENDED_COMBINATION_MATRIX, SHAPE_COMBINATION_MATRIX, STRESS_NAMES, OgdenRepresentation,
                         static_displacement_jacobian)
from .step_simulation import step_solver
from ..errors import JointFitError

LOG = logging.getLogger("dea_ros.identify")

__all__ = ["JointFitResult", "JointObjective", "fit_joint", "JointFitError",
           "CURVATURE_REL_CI_LIMIT", "JOINT_NAMES", "CURVATURE_BOUND_PA", "MATERIAL_NAMES",
           "ShapeTest", "held_shape_test", "SHAPE_TEST_LEVEL", "curvature_mode"]

#: sigma_h''(1) counts as identified when its 95 % CI half-width is below this fraction of its value.
CURVATURE_REL_CI_LIMIT = 0.5
#: Names of the joint parameters (the curvature terms sigma_h''(1), sigma_h'''(1) only when fitted).
#: The material parameters (after the stress combinations, static_fit.STRESS_NAMES).
MATERIAL_NAMES = ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s")
JOINT_NAMES = STRESS_NAMES[:4] + MATERIAL_NAMES
_UNITS = (1e5, 1e5, 1e6, 1e7, 1e8, 1e9)   # optimizer units of the stress combinations (Pa)
_STRESS_BOUND = (np.inf, np.inf, 5e8, 5e9, np.inf, np.inf)   # |sigma_h''(1)|, |sigma_h'''(1)| search bounds (Pa)
#: :func:`held_shape_test` calls for the free shape below this p-value
SHAPE_TEST_LEVEL = 0.01
#: |sigma_h''(1)| bound of the search (Pa, derivative in s): the plausible range of the curvature.
CURVATURE_BOUND_PA = _STRESS_BOUND[2]


@dataclass
class JointFitResult:
    """Outcome of :func:`fit_joint`."""

    parameters: MembraneParameters
    statistics: ParameterStatistics
    names: tuple
    curvature_fitted: bool
    curvature_identified: bool
    curvature_fallback_Pa: float       # the base value written when sigma_h''(1) is not identified
    cost: float                        # chi-square at the optimum
    dof: int
    block_chi2: dict                   # chi-square per data kind
    sigmas: dict                       # the standard deviations used as weights
    frequency_points: list
    simulated_rms_m: np.ndarray
    n_evaluations: int
    wall_time_s: float
    warnings: list = field(default_factory=list)
    message: str = ""
    #: weighted Jacobian at the optimum, d residual / d parameter in the statistics' units (ln for
    #: k1, eta1, eta2), one row per residual; ``row_records`` names the record of each row
    jacobian: np.ndarray | None = None
    row_records: tuple = ()
    residuals: np.ndarray | None = None    # the weighted residuals there, rows as ``jacobian``

    @property
    def fit_frequencies_Hz(self) -> np.ndarray:
        return np.array([p.frequency_Hz for p in self.frequency_points])

    def value(self, name: str) -> float:
        return float(self.statistics.values[self.statistics.names.index(name)])

    def as_dict(self) -> dict:
        return {"names": list(self.names), "curvature_fitted": self.curvature_fitted,
                "curvature_identified": self.curvature_identified,
                "curvature_fallback_Pa": self.curvature_fallback_Pa, "chi2": self.cost, "dof": self.dof,
                "chi2_per_dof": self.cost / max(self.dof, 1), "block_chi2": dict(self.block_chi2),
                "sigmas": self.sigmas, "fit_frequencies_Hz": [float(f) for f in self.fit_frequencies_Hz],
                "fit_kinds": [p.kind for p in self.frequency_points],
                "evaluations": self.n_evaluations, "wall_time_s": self.wall_time_s,
                "statistics": self.statistics.as_dict(), "message": self.message}


class JointObjective:
    """Weighted residuals of all data and their Jacobian w.r.t. the joint parameters (module docstring)."""

    def __init__(self, start: MembraneParameters, static: StaticData | None, steps: Sequence[StepData],
                 points: Sequence[FrequencyPoint], static_sigma_m, step_sigmas_m, point_sigmas_m,
                 prior_beta_gamma=None, fit_curvature: bool | str = True, n_harmonics: int = 8,
                 fit_slope: bool = True):
        self.start = start
        self.static = static
        self.steps = list(steps)
        self.points = list(points)
        sigma = np.asarray(static_sigma_m, float)                  # one value, or one per static point
        self.static_sigma = sigma if static is None else np.broadcast_to(sigma, (static.n_points,))
        self.step_sigmas = np.asarray(step_sigmas_m, float)
        self.point_sigmas = np.asarray(point_sigmas_m, float)
        self.n_harmonics = int(n_harmonics)
        start_bg = np.r_[start.beta_Pa, start.gamma_Pa]
        prior = start_bg if prior_beta_gamma is None else np.asarray(prior_beta_gamma, float)
        # four combinations matched exactly, the two remaining Ogden directions held closest to the
        # base parameters (or to the start's representation without base parameters)
        # ("shape": all six, the representation exact)
        self.matrix = SHAPE_COMBINATION_MATRIX if fit_curvature == "shape" else EXTENDED_COMBINATION_MATRIX
        self.rep = OgdenRepresentation(start.prestretch, len(self.matrix), prior, matrix=self.matrix)
        self.fit_curvature = fit_curvature
        self.combos0 = self.matrix @ start_bg
        first = [0, 1] if fit_slope else [0]       # sigma_h'(1) held when the static data cannot see it
        if fit_curvature == "third":       # sigma_h''(1) held at the start's value, sigma_h'''(1) free
            self.stress_index = first + [3]
        elif fit_curvature == "shape":
            self.stress_index = first + [2, 3, 4, 5]
        else:
            self.stress_index = first + ([2, 3] if fit_curvature else [])
        self.names = tuple(STRESS_NAMES[i] for i in self.stress_index) + MATERIAL_NAMES
        gain = self.rep.gain                                         # (6, 4)
        self.directions = gain[:, self.stress_index].T               # (q, 6) per Pa of each combination
        self.solvers = [step_solver(start, s) for s in self.steps]
        self._guesses: dict = {}
        self._cache: dict = {}
        self.n_evaluations = 0
        self.rejected_steps = 0                  # trial points whose orbits did not solve

    # ------------------------------------------------------------------ parameters
    def theta0(self) -> np.ndarray:
        p = self.start
        stress = [self.combos0[i] / _UNITS[i] for i in self.stress_index]
        return np.r_[stress, p.relative_permittivity, np.log([p.k1_Pa, p.eta1_Pa_s, p.eta2_Pa_s])]

    def parameters(self, theta) -> MembraneParameters:
        theta = np.asarray(theta, float)
        q = len(self.stress_index)
        combos = self.combos0.copy()
        for j, i in enumerate(self.stress_index):
            combos[i] = theta[j] * _UNITS[i]
        bg = self.rep.beta_gamma(combos)
        k1, eta1, eta2 = np.exp(theta[q + 1:q + 4])
        return self.start.replace(beta_Pa=tuple(float(v) for v in bg[:3]), gamma_Pa=tuple(float(v) for v in bg[3:]),
                                  relative_permittivity=float(theta[q]), k1_Pa=float(k1), eta1_Pa_s=float(eta1),
                                  eta2_Pa_s=float(eta2))

    def bounds(self):
        b = np.array([_STRESS_BOUND[i] / _UNITS[i] for i in self.stress_index])
        lo = np.r_[-b, 1.0, np.log([b_[0] for b_ in PARAMETER_BOUNDS.values()])]
        hi = np.r_[b, 50.0, np.log([b_[1] for b_ in PARAMETER_BOUNDS.values()])]
        lo[0] = 1e-3  # sigma_h(1) > 0: a pre-tensioned membrane
        return lo, hi

    # ------------------------------------------------------------------ residuals
    def evaluate(self, theta):
        """(residuals, Jacobian (n, P), details); cached per theta."""
        theta = np.asarray(theta, float)
        key = theta.tobytes()
        if key in self._cache:
            return self._cache[key]
        self.n_evaluations += 1
        p = self.parameters(theta)
        q = len(self.stress_index)
        n_par = q + 4
        units = np.r_[[_UNITS[i] for i in self.stress_index], 1.0, 1.0, 1.0, 1.0]
        res, rows = [], []
        details = {"blocks": {}}
        # -- static points (eq. 20)
        if self.static is not None:
            d = np.zeros(self.static.n_points)
            for m in np.unique(self.static.mass_kg):
                sel = self.static.mass_kg == m
                d[sel] = static_equilibrium(p, self.static.voltage_V[sel], mass_kg=float(m)).displacement_m
            jac7 = static_displacement_jacobian(p, self.static, d)                 # (n, 7)
            block = np.zeros((d.size, n_par))
            block[:, :q] = jac7[:, :6] @ self.directions.T
            block[:, q] = jac7[:, 6]
            r = (d - self.static.displacement_m) / self.static_sigma
            res.append(r)
            rows.append(block / self.static_sigma[:, None])
            details["static_predicted_m"] = d
            details["blocks"]["static"] = float(r @ r)
        # -- steps (eq. 23)
        sims = []
        chi_steps = 0.0
        for step, solver, sigma in zip(self.steps, self.solvers, self.step_sigmas):
            ps = p if step.mass_kg == p.mass_kg else p.replace(mass_kg=step.mass_kg)
            sol = solver.solve(ps, sensitivities=True, stress_directions=self.directions, permittivity=True)
            sens = sol.displacement_sensitivity_m                          # (3 + q + 1, K)
            block = np.zeros((step.n_samples, n_par))
            block[:, :q] = sens[3:3 + q].T
            block[:, q] = sens[3 + q]
            block[:, q + 1:] = sens[:3].T
            r = (sol.displacement_m - step.displacement_m) / sigma
            res.append(r)
            rows.append(block / sigma)
            sims.append(sol.displacement_m)
            chi_steps += float(r @ r)
        details["step_simulated_m"] = sims
        if self.steps:
            details["blocks"]["steps"] = chi_steps
        # -- RMS values (eqs. 21, 24)
        sim = np.zeros(len(self.points))
        if self.points:
            block = np.zeros((len(self.points), n_par))
            for k, pt in enumerate(self.points):
                pp = p if pt.mass_kg == p.mass_kg else p.replace(mass_kg=pt.mass_kg)
                d0 = rms_reference_m(pp, pt)
                # the measured rest position is fixed; the model's moves with the stress
                dd0 = None if pt.rest_d0_m is not None else np.r_[
                    rest_state_derivative(pp, 0.0, self.directions, d0)[:, 0], 0.0]
                sol = point_solution(pp, pt, self.n_harmonics, self._guesses.get(k))
                self._guesses[k] = sol.state
                rms, grad = periodic_rms_gradient(pp, sol, d0, dd0, self.directions, permittivity=True)
                sim[k] = rms
                block[k, :q] = grad[3:3 + q]
                block[k, q] = grad[3 + q]
                block[k, q + 1:] = grad[:3]
            r = (sim - np.array([pt.measured_rms_m for pt in self.points])) / self.point_sigmas
            res.append(r)
            rows.append(block / self.point_sigmas[:, None])
            details["blocks"]["frequency"] = float(r @ r)
        details["simulated_rms_m"] = sim
        out_res = np.concatenate(res)
        out_jac = np.vstack(rows) * units[None, :]
        out = (out_res, out_jac, details)
        if len(self._cache) > 16:
            self._cache.clear()
        self._cache[key] = out
        return out

    def residuals(self, theta):
        return self.evaluate(theta)[0]

    def jacobian(self, theta):
        return self.evaluate(theta)[1]

    def physical_jacobian(self, theta) -> np.ndarray:
        """The weighted Jacobian in the statistics' units: d residual / d stress combination (per Pa),
        eps_r, ln k1, ln eta1, ln eta2 (the optimiser's stress units divided out)."""
        jac = self.evaluate(theta)[1].copy()
        for j, i in enumerate(self.stress_index):
            jac[:, j] /= _UNITS[i]
        return jac


def _sigmas(static_fit_residual_std: float | None, steps, points, noise_m):
    step_s = []
    for step in steps:
        s = noise_m if noise_m is not None else estimate_noise_m(step)
        if s is None or s <= 0:
            raise JointFitError(f"{step.source}: the laser noise is unknown (give sensor_noise_m in the manifest)")
        step_s.append(float(s))
    point_s = [p.measured_std_m for p in points]
    return step_s, point_s


def fit_joint(
    start: MembraneParameters,
    static: StaticData | None,
    steps: Sequence[StepData],
    points: Sequence[FrequencyPoint],
    static_sigma_m,   # m: one value, or one per static point
    noise_m: float | None = None,
    prior_beta_gamma=None,
    fit_curvature: bool | str = True,
    fit_slope: bool = True,
    curvature_fallback_Pa: float | None = None,
    n_harmonics: int = 8,
    max_evaluations: int = 60,
    curvature_rel_ci_limit: float = CURVATURE_REL_CI_LIMIT,
    progress: Callable[[dict], None] | None = None,
    curvature_from_static: bool = False,
    minimise: bool = True,
) -> JointFitResult:
    """Refine all identifiable parameters jointly (module docstring), starting from ``start``.

    ``points`` are the frequency points with their ``kind`` (periodic or period-doubled; leave the
    quasi-periodic ones out) and ``measured_std_m`` (None: estimated from the residuals of a first
    pass). ``fit_curvature``: include sigma_h''(1) and sigma_h'''(1) (when sine data exist); "third":
    only sigma_h'''(1), sigma_h''(1) held at the start's value; "shape": the whole Ogden shape (the fourth
    and fifth derivatives too, module docstring). ``curvature_fallback_Pa``:
    the value the caller will write when it is not identified (reported only). ``curvature_from_static``:
    the static points determine sigma_h''(1) (:func:`~.static_fit.static_curvature_test`), so the curvature
    terms are fitted even without sine records (held, they would bias the others).

    ``minimise`` False: the objective evaluated at ``start``, not minimised -- its residuals, Jacobian and
    linearised statistics there, every parameter free. For a start that is not refined (the refinement
    rejected, :func:`~.refinement.refine_jointly`): the two-stage result's intervals with the static stage's
    uncertainty in them. The dynamic fit's intervals hold eps_r and the stress combinations at the static fit's
    values (a conditional covariance): with 17 sine frequencies they can be 100 times too narrow (the coverage
    family's F05, 17 frequencies: k1 0.21 % off at z +67). s^2 = chi^2 / dof at the start, above the optimum's:
    wider, not narrower, than at a minimum.
    """
    t0 = time.perf_counter()
    points = list(points)
    if not steps and not points:
        raise JointFitError("joint refinement needs a step or sine experiment")
    step_s, point_s = _sigmas(None, steps, points, noise_m)
    estimated_rms_sigma = any(s is None for s in point_s)
    warnings = []
    if estimated_rms_sigma:
        point_s = [s if s is not None else 1e-7 for s in point_s]
    if not points and not curvature_from_static:
        fit_curvature = False

    def objective_from(first: MembraneParameters, rms_sigmas) -> JointObjective:
        return JointObjective(first, static, steps, points, static_sigma_m, step_s, rms_sigmas, prior_beta_gamma,
                              fit_curvature, n_harmonics, fit_slope)

    objective = objective_from(start, point_s)
    lo, hi = objective.bounds()

    def solve(obj: JointObjective):
        if minimise:
            return _least_squares(obj, lo, hi, max_evaluations, progress)
        return _NotMinimised(np.clip(obj.theta0(), lo + 1e-9, hi - 1e-9))

    try:
        sol = solve(objective)
        if estimated_rms_sigma and points:
            # no stated uncertainty of the RMS values: their scatter about the fit estimates it
            sig = _scatter_sigma(objective, sol.x, point_s)
            point_s = [s if p.measured_std_m is None else p.measured_std_m for s, p in
                       zip([sig] * len(points), points)]
            objective = objective_from(objective.parameters(sol.x), point_s)
            sol = solve(objective)
            warnings.append(f"the RMS values have no stated uncertainty (column d_rms_std_m): weighted by their "
                            f"scatter about the {'fit' if minimise else 'start'}, {sig * 1e6:.3g} um")
    except (HarmonicBalanceError, TransientError, NoEquilibriumError, FloatingPointError) as exc:
        raise JointFitError(f"joint refinement failed: {exc}" if minimise else
                            f"the joint objective does not evaluate at the start: {exc}") from None
    sigmas = {"static_m": _static_sigma_value(static_sigma_m), "step_m": list(step_s),
              "rms_m": [float(s) for s in point_s]}
    return _joint_result(objective, sol, lo, hi, sigmas, warnings, curvature_fallback_Pa, curvature_rel_ci_limit, t0)


@dataclass
class _NotMinimised:
    """The start :func:`fit_joint` evaluates without minimising, in the shape of scipy's least-squares result."""

    x: np.ndarray
    success: bool = True
    message: str = "evaluated at the start, not minimised"


def _static_sigma_value(static_sigma_m):
    """The static points' weight as the result states it: one value (m), or the list of the points' own."""
    sig = np.asarray(static_sigma_m, float)
    return float(sig) if sig.ndim == 0 else [float(v) for v in sig]


def _least_squares(obj: JointObjective, lo, hi, max_evaluations: int, progress):
    """scipy's trust-region least squares on ``obj`` from its start, reporting every evaluation.

    A trial point at which the model cannot reproduce a record at all (a record's orbit does not
    solve: a fold of the branch between the current point and the trial; or a loaded static point
    has no equilibrium) gets non-finite residuals, so that the trust
    region shrinks towards the converged point (a continuation in the parameters) instead of ending
    the refinement; the start itself must solve."""
    n_res = obj.residuals(np.clip(obj.theta0(), lo + 1e-9, hi - 1e-9)).size

    def fun(x):
        seeds = dict(obj._guesses)
        try:
            r = obj.residuals(x)
        except (HarmonicBalanceError, NoEquilibriumError, TransientError) as exc:
            LOG.info("joint refinement: trial step rejected (%s)", exc)
            obj._guesses = seeds                 # keep the branch of the last converged point
            obj.rejected_steps += 1
            return np.full(n_res, np.nan)
        if progress:
            progress({"stage": "joint", "evaluation": obj.n_evaluations, "cost": float(r @ r)})
        return r

    return least_squares(fun, np.clip(obj.theta0(), lo + 1e-9, hi - 1e-9), jac=obj.jacobian, bounds=(lo, hi),
                         method="trf", x_scale="jac", ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=max_evaluations)


def curvature_mode(names) -> bool | str:
    """The ``fit_curvature`` of a joint fit whose parameters are ``names`` (the inverse of
    :class:`JointObjective`'s naming): "shape", True, "third" or False."""
    if STRESS_NAMES[4] in names:
        return "shape"
    if STRESS_NAMES[2] in names:
        return True
    return "third" if STRESS_NAMES[3] in names else False


@dataclass(frozen=True)
class ShapeTest:
    """The score test of the Ogden shape a joint fit holds (the fourth and fifth derivatives of sigma_h at
    s = 1, :func:`held_shape_test`)."""

    statistic: float        # the chi-square decrease a Gauss-Newton step with them free predicts, over s^2
    dof: int                # the held directions (2)
    p_value: float
    #: what was reported (:func:`~.refinement.refine_jointly`): "held" (the test does not reject), "free" (the
    #: fit with the whole shape free), "held, intervals with the shape free" (that fit not kept: the held
    #: parameters with the intervals of the objective linearised there with the shape free)
    outcome: str = "held"

    @property
    def rejects(self) -> bool:
        """The data contradict the held shape (p below ``SHAPE_TEST_LEVEL``)."""
        return self.p_value < SHAPE_TEST_LEVEL

    def as_dict(self) -> dict:
        return {"statistic": self.statistic, "dof": self.dof, "p_value": self.p_value, "rejects": self.rejects,
                "outcome": self.outcome}


def held_shape_test(fit: JointFitResult, shape: JointFitResult) -> ShapeTest:
    """Does the shape ``fit`` holds steer it? ``fit``: a joint fit (four stress combinations at most);
    ``shape``: the joint objective with the whole shape free, evaluated at ``fit``'s parameters, not
    minimised (:func:`fit_joint` with ``fit_curvature="shape"``, ``minimise=False``): the same residuals, with
    the held directions' columns beside the fitted ones. The score (Lagrange multiplier) statistic: the
    decrease of chi-square the linearised model predicts when the held directions are freed, over s^2 =
    chi^2 / dof of ``fit``; chi-square distributed with as many degrees of freedom as directions held."""
    r = np.asarray(shape.residuals, float)
    jac = np.asarray(shape.jacobian, float)
    norms = np.linalg.norm(jac, axis=0)
    jac = jac / np.where(norms > 0, norms, 1.0)
    kept = [k for k, n in enumerate(shape.names) if n in fit.names]

    def explained(columns) -> float:
        coef, *_ = np.linalg.lstsq(jac[:, columns], r, rcond=None)
        fitted = jac[:, columns] @ coef
        return float(fitted @ fitted)

    s2 = fit.cost / max(fit.dof, 1)
    decrease = max(explained(list(range(jac.shape[1]))) - explained(kept), 0.0)
    dof = len(shape.names) - len(kept)
    statistic = decrease / s2 if s2 > 0 else math.inf
    return ShapeTest(float(statistic), dof, float(scipy_stats.chi2.sf(statistic, dof)))


def _scatter_sigma(objective: JointObjective, theta, point_s) -> float:
    """The standard deviation of the RMS values about the fit at ``theta`` (m)."""
    n_f = len(point_s)
    res = objective.residuals(theta)
    r_f = res[-n_f:] * np.asarray(point_s)
    sig = math.sqrt(float(r_f @ r_f) / max(n_f - 1, 1))
    return max(sig, 1e-9)


def _row_records(objective: JointObjective) -> tuple:
    """The record of each residual row, in the order of :meth:`JointObjective.evaluate`."""
    rows = []
    if objective.static is not None:
        rows += ["static points"] * objective.static.n_points
    for k, step in enumerate(objective.steps):
        rows += [f"step {k + 1} ({step.source})"] * step.n_samples
    rows += [f"sine {pt.frequency_Hz:g} Hz ({pt.source})" for pt in objective.points]
    return tuple(rows)


def _joint_result(objective: JointObjective, sol, lo, hi, sigmas: dict, warnings: list, curvature_fallback_Pa,
                  curvature_rel_ci_limit: float, t0: float) -> JointFitResult:
    """The result at the optimum ``sol``: parameters, linearised statistics, warnings."""
    res, _jac, details = objective.evaluate(sol.x)
    jac_phys = objective.physical_jacobian(sol.x)
    params = objective.parameters(sol.x)
    q = len(objective.stress_index)
    combos = objective.matrix @ np.r_[params.beta_Pa, params.gamma_Pa]
    values = np.r_[[combos[i] for i in objective.stress_index], params.relative_permittivity,
                   params.k1_Pa, params.eta1_Pa_s, params.eta2_Pa_s]
    stats = parameter_statistics(jac_phys, res, objective.names, values,
                                 log_parameters=[False] * (q + 1) + [True] * 3, context="joint fit")
    warnings += stats.warnings
    if objective.rejected_steps:
        warnings.append(f"joint refinement: {objective.rejected_steps} trial step(s) rejected where the model could "
                        "not solve a record (an orbit past a fold, a static point without equilibrium); the trust "
                        "region shrank")
    identified = False
    if "sigma_h''(1)_Pa" in objective.names:
        k = objective.names.index("sigma_h''(1)_Pa")
        identified = bool(np.isfinite(stats.relative_ci[k]) and stats.relative_ci[k] <= curvature_rel_ci_limit)
    if not sol.success:
        warnings.append(f"joint refinement did not report convergence: {sol.message}")
    at_bound = [n for n, x, a, b in zip(objective.names, sol.x, lo, hi) if x - a < 1e-6 or b - x < 1e-6]
    if at_bound:
        warnings.append(f"joint refinement: {', '.join(at_bound)} ended at the search bound")
    dof = max(res.size - len(values), 1)
    return JointFitResult(
        jacobian=jac_phys, row_records=_row_records(objective), residuals=np.asarray(res, float),
        parameters=params, statistics=stats, names=objective.names,
        curvature_fitted="sigma_h''(1)_Pa" in objective.names,
        curvature_identified=identified,
        curvature_fallback_Pa=float(curvature_fallback_Pa) if curvature_fallback_Pa is not None else float("nan"),
        cost=float(res @ res), dof=dof, block_chi2=details["blocks"], sigmas=sigmas,
        frequency_points=objective.points, simulated_rms_m=details["simulated_rms_m"],
        n_evaluations=objective.n_evaluations, wall_time_s=time.perf_counter() - t0, warnings=warnings,
        message=str(sol.message),
    )
