"""The joint refinement stage of the identification, and what is written for the curvature sigma_h''(1).

:func:`refine_jointly` runs :func:`~dea_ros.identify.joint_fit.fit_joint` from the two-stage
result on every classified record, classifies the records again with the refined model and
repeats (at most three rounds) until the classification does not change.

:func:`decide_curvature` then says what is written for sigma_h''(1) (eq. 10): its 95 % interval
within +-50 % of its value: "identified"; below +-100 % (sign known): "poorly determined",
written as fitted with a warning; otherwise "not identified": the curvature terms are held at the
base value (both sigma_h''(1) and sigma_h'''(1), or sigma_h''(1) alone when the data reject that by
a chi-square above 9) and the intervals keep the widths of the free fit (the marginal uncertainty).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace

import numpy as np
from scipy import stats as scipy_stats

from ..model.parameters import MembraneParameters
from .classification import classification_kinds, classify_records, fitted_points
from .experiments import ExperimentSet
from .joint_fit import CURVATURE_REL_CI_LIMIT, JointFitError, JointFitResult, fit_joint
from .static_fit import EXTENDED_COMBINATION_MATRIX, OgdenRepresentation, StaticFitResult

__all__ = ["JointRounds", "CurvatureDecision", "refine_jointly", "decide_curvature", "static_sigma",
           "curvature_fallback"]


@dataclass
class JointRounds:
    """Outcome of :func:`refine_jointly`."""

    joint: JointFitResult | None        # None when the refinement failed (the warning says why)
    parameters: MembraneParameters
    classification: list
    fallback_beta_gamma: np.ndarray     # the base (beta, gamma) of the curvature terms
    classification_s: float = 0.0       # time spent classifying again
    warnings: list = field(default_factory=list)


@dataclass
class CurvatureDecision:
    """Outcome of :func:`decide_curvature`: what is written for sigma_h''(1)."""

    identified: bool | None             # True written as fitted, False base value written, None not fitted
    status: str                         # "identified", "poorly determined", "not identified", "not fitted"
    joint: JointFitResult               # the fit whose parameters and intervals are reported
    parameters: MembraneParameters
    warnings: list = field(default_factory=list)


def static_sigma(static: StaticFitResult | None) -> float:
    """Weight of the static points in the joint chi-square: the static fit's residual standard
    deviation s, times t_0.975(dof) / z_0.975 -- s comes from few points (e.g. 9 degrees of freedom),
    and the joint intervals, which use the quantile of the joint fit's many degrees of freedom,
    would otherwise be too narrow for the parameters the static points determine (sigma_h(1))."""
    if static is None:
        return 1.0
    st = static.statistics
    s = float(st.residual_std) if st is not None and math.isfinite(st.residual_std) else float("nan")
    dof = int(st.dof) if st is not None else 0
    if not (math.isfinite(s) and s > 0):
        r = static.residuals_m
        s = float(np.sqrt(np.mean(r**2))) if r.size else 1e-7
    if dof >= 1:
        s *= float(scipy_stats.t.ppf(0.975, dof) / scipy_stats.norm.ppf(0.975))
    return max(s, 1e-9)


def curvature_fallback(static: StaticFitResult | None, params: MembraneParameters) -> np.ndarray:
    """(beta, gamma) whose curvature terms (sigma_h''(1), sigma_h'''(1)) are written when the data do
    not determine them: the base parameters' (or, without base parameters, the static fit's
    representation, eqs. 8-9)."""
    if static is not None and static.prior_beta_gamma is not None:
        return np.asarray(static.prior_beta_gamma, float)
    return np.r_[params.beta_Pa, params.gamma_Pa]


def _joint_fit(start: MembraneParameters, static: StaticFitResult, experiments: ExperimentSet, points: list,
               fit_curvature, stress_terms: int, fallback_Pa: float, n_harmonics: int, progress) -> JointFitResult:
    """:func:`fit_joint` on all the data with the static fit's weight and prior."""
    return fit_joint(start, experiments.all_static(), experiments.steps, points, static_sigma(static),
                     noise_m=experiments.sensor_noise_m, prior_beta_gamma=static.prior_beta_gamma,
                     fit_curvature=fit_curvature, fit_slope=stress_terms >= 2, curvature_fallback_Pa=fallback_Pa,
                     n_harmonics=n_harmonics, progress=progress)


def refine_jointly(params: MembraneParameters, static: StaticFitResult, classification: list,
                   experiments: ExperimentSet, n_harmonics: int, fit_curvature, stress_terms: int,
                   progress=None) -> JointRounds:
    """The joint refinement from ``params`` (the two-stage result), repeated with the records classified
    again until the classification does not change (module docstring). ``fit_curvature``: False never
    fits sigma_h''(1); otherwise it is fitted when there are sine records."""
    fallback = curvature_fallback(static, params)
    fit_c = (fit_curvature is not False) and bool(experiments.sines)
    rounds = JointRounds(None, params, classification, fallback)
    for _round in range(3):
        pts = fitted_points(rounds.classification, experiments)
        try:
            rounds.joint = _joint_fit(rounds.parameters, static, experiments, pts, fit_c, stress_terms,
                                      float(EXTENDED_COMBINATION_MATRIX[2] @ fallback), n_harmonics, progress)
        except JointFitError as exc:
            rounds.warnings.append(f"joint refinement failed ({exc}); the two-stage result is reported")
            rounds.joint = None
            break
        rounds.parameters = rounds.joint.parameters
        if not experiments.sines:
            break
        t1 = time.perf_counter()
        again = classify_records(rounds.parameters, experiments, n_harmonics, experiments.sensor_noise_m)
        rounds.classification_s += time.perf_counter() - t1
        changed = classification_kinds(again) != classification_kinds(rounds.classification)
        rounds.classification = again
        if not changed:
            break
    return rounds


def _marginal_statistics(held, free):
    """Statistics of a fit with the curvature held, with every interval at least as wide as in the fit
    with it free (the marginal uncertainty, which allows for the unknown curvature), around the held
    fit's values."""
    lo, hi = np.array(held.ci_low, float), np.array(held.ci_high, float)
    se, rel = np.array(held.std_error, float), np.array(held.relative_ci, float)
    vals = np.asarray(held.values, float)
    for i, name in enumerate(held.names):
        if name not in free.names:
            continue
        j = free.names.index(name)
        if not (free.relative_ci[j] > rel[i]):
            continue
        rel[i] = free.relative_ci[j]
        se[i] = max(se[i], free.std_error[j] * abs(vals[i] / free.values[j]) if free.values[j] else free.std_error[j])
        if free.ci_low[j] > 0 and abs(np.log(free.ci_high[j] / free.values[j])
                                      + np.log(free.ci_low[j] / free.values[j])) < 1e-9:
            f_hi = free.ci_high[j] / free.values[j]           # a log parameter: multiplicative interval
            lo[i], hi[i] = vals[i] / f_hi, vals[i] * f_hi
        else:
            half = 0.5 * (free.ci_high[j] - free.ci_low[j])
            lo[i], hi[i] = vals[i] - half, vals[i] + half
    return dc_replace(held, ci_low=lo, ci_high=hi, std_error=se, relative_ci=rel)


def _set_combinations(params: MembraneParameters, combos, prior_bg) -> MembraneParameters:
    """``params`` with (beta, gamma) matching the four combinations ``combos`` (eq. 10, in s)."""
    prior = np.r_[params.beta_Pa, params.gamma_Pa] if prior_bg is None else np.asarray(prior_bg, float)
    rep = OgdenRepresentation(params.prestretch, 4, prior, matrix=EXTENDED_COMBINATION_MATRIX)
    bg = rep.beta_gamma(np.asarray(combos, float))
    return params.replace(beta_Pa=tuple(float(v) for v in bg[:3]), gamma_Pa=tuple(float(v) for v in bg[3:]))


def _with_base_curvature(params: MembraneParameters, base_bg) -> MembraneParameters:
    """``params`` with sigma_h(1), sigma_h'(1) kept and the curvature terms of ``base_bg``."""
    c = EXTENDED_COMBINATION_MATRIX @ np.r_[params.beta_Pa, params.gamma_Pa]
    base = EXTENDED_COMBINATION_MATRIX @ np.asarray(base_bg, float)
    rep = OgdenRepresentation(params.prestretch, 4, np.asarray(base_bg, float), matrix=EXTENDED_COMBINATION_MATRIX)
    bg = rep.beta_gamma([c[0], c[1], base[2], base[3]])
    return params.replace(beta_Pa=tuple(float(v) for v in bg[:3]), gamma_Pa=tuple(float(v) for v in bg[3:]))


def _hold_curvature(joint: JointFitResult, params: MembraneParameters, static: StaticFitResult,
                    rounds: JointRounds, experiments: ExperimentSet, rel: float, n_harmonics: int,
                    stress_terms: int, progress) -> CurvatureDecision:
    """sigma_h''(1) not identified: held at the base value; sigma_h'''(1) (with which it trades off at
    these amplitudes) stays free when the data reject it at base, so the data keep their fit and the
    other parameters their values; the reported values and intervals are those of this fit."""
    fallback, classification = rounds.fallback_beta_gamma, rounds.classification
    base_c2 = float(EXTENDED_COMBINATION_MATRIX[2] @ fallback)
    c_free = EXTENDED_COMBINATION_MATRIX @ np.r_[params.beta_Pa, params.gamma_Pa]
    start = _set_combinations(params, [c_free[0], c_free[1], base_c2, c_free[3]], static.prior_beta_gamma)
    chi_free = joint.cost
    pts_now = fitted_points(classification, experiments)
    # first both curvature terms at the base values: when the data accept them (chi-square
    # within 9 of the free fit) that is the written law
    held = _joint_fit(_with_base_curvature(params, fallback), static, experiments, pts_now, False, stress_terms,
                      base_c2, n_harmonics, progress)
    how = "both curvature terms at the base values"
    if held.cost - chi_free > 9.0:
        held = _joint_fit(start, static, experiments, pts_now, "third", stress_terms, base_c2, n_harmonics, progress)
        how = "sigma_h''(1) at the base value, sigma_h'''(1) refitted (the data reject both at base)"
    held.statistics = _marginal_statistics(held.statistics, joint.statistics)
    refit_note = (f" Written with {how}: chi-square {held.cost - chi_free:+.3g} against the free "
                  "fit; the 95 % intervals keep the widths of the free fit (they allow for the "
                  "unknown curvature).")
    held.warnings = joint.warnings + [w for w in held.warnings if w not in joint.warnings]
    near = [c for c in classification if c["used"] != "left out"
            and c["measured_rms_m"] > 0.5 * max(x["measured_rms_m"] for x in classification)]
    hint = "" if len(near) >= 3 else " Records near the resonance peak (large amplitude) would determine it."
    warning = (
        "sigma_h''(1) (curvature of the hyperelastic stress, eq. 10) is not identified by these "
        f"data (95 % interval +-{100 * rel:.0f} % of the fitted value: sign unknown): params.yaml "
        f"carries the base value {EXTENDED_COMBINATION_MATRIX[2] @ fallback / 1e3:.6g} kPa "
        "(derivative in s = lambda^2) and says 'not identified'; the other parameters' intervals "
        "allow for its uncertainty." + refit_note + hint)
    return CurvatureDecision(False, "not identified", held, held.parameters, [warning])


def decide_curvature(rounds: JointRounds, static: StaticFitResult, experiments: ExperimentSet, n_harmonics: int,
                     stress_terms: int, progress=None) -> CurvatureDecision:
    """What is written for sigma_h''(1) after the joint refinement ``rounds`` (module docstring)."""
    joint, params = rounds.joint, rounds.parameters
    if not joint.curvature_fitted:
        return CurvatureDecision(None, "not fitted", joint, params)
    k = joint.names.index("sigma_h''(1)_Pa")
    rel = float(joint.statistics.relative_ci[k])
    if rel <= CURVATURE_REL_CI_LIMIT:
        return CurvatureDecision(True, "identified", joint, params)
    if rel < 1.0:
        return CurvatureDecision(True, "poorly determined", joint, params, [
            f"sigma_h''(1) is poorly determined by these data "
            f"(95 % interval +-{100 * rel:.0f} % of its "
            "value, sign known): written as fitted, flagged in params.yaml; records near the "
            "resonance peak (large amplitude) would pin it down"])
    return _hold_curvature(joint, params, static, rounds, experiments, rel, n_harmonics, stress_terms, progress)
