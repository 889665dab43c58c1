"""The joint refinement stage of the identification, and what is written for the curvature sigma_h''(1).

:func:`refine_jointly` runs :func:`~dea_ros.identify.joint_fit.fit_joint` from the two-stage
result on every classified record, classifies the records again with the refined model and
repeats (at most three rounds) until the classification does not change.

:func:`decide_curvature` then says what is written for sigma_h''(1) (eq. 10): its 95 % interval
within +-50 % of its value: "identified"; below +-100 % (sign known): "poorly determined",
written as fitted with a warning; otherwise "not identified". The reported parameters and
intervals are then still those of the fit in which sigma_h''(1) and sigma_h'''(1) are free: a value
the data do not determine never steers the others (issue 21: holding it at a guess moved eta1,
eta2, eps_r on a softening membrane by several of their interval widths), and the free fit's
linearised intervals allow for it. params.yaml carries the free fit's curvature as a representative
value, flagged "not identified", and :func:`~dea_ros.identify.curvature_sensitivity.curvature_sensitivity`
says how the predictions (resonance peak, step) change with it at both ends of its interval.

One order further out, the refinement holds the Ogden shape beyond sigma_h'''(1) (the fourth and fifth
derivatives at s = 1) at the base's; :func:`~.joint_fit.held_shape_test` at its optimum says whether the data
contradict that (p < ``SHAPE_TEST_LEVEL``), and then the fit is redone with the whole shape free and reported
(``JointRounds.shape_test.outcome`` "free"); where that fit is not kept (an implausible membrane, no
improvement, a failure) the held parameters are reported with the intervals of the joint objective linearised
there with the shape free ("held, intervals with the shape free").
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import stats as scipy_stats

from ..model.parameters import MembraneParameters
from .classification import classification_kinds, classify_records, fitted_points, leave_out_for_a_round
from .curvature_sensitivity import CurvatureSensitivity, curvature_sensitivity
from .experiments import ExperimentSet, StaticData
from .joint_fit import (CURVATURE_REL_CI_LIMIT, JointFitError, JointFitResult, ShapeTest, curvature_mode, fit_joint,
                        held_shape_test)
from .static_fit import EXTENDED_COMBINATION_MATRIX, StaticFitResult

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
    #: joint None (the refinement rejected or failed): the joint objective linearised at the two-stage result
    #: (:func:`~.joint_fit.fit_joint` with ``minimise`` False), whose statistics are the reported intervals;
    #: None if it does not evaluate there (the dynamic fit's intervals, conditional on the static stage, are
    #: reported)
    two_stage_linearisation: JointFitResult | None = None
    #: the score test of the Ogden shape held beyond sigma_h'''(1) at the refinement (None: not run)
    shape_test: ShapeTest | None = None


@dataclass
class CurvatureDecision:
    """Outcome of :func:`decide_curvature`: what is written for sigma_h''(1)."""

    identified: bool | None             # True written as fitted, False base value written, None not fitted
    status: str                         # "identified", "poorly determined", "not identified", "not fitted"
    joint: JointFitResult               # the fit whose parameters and intervals are reported
    parameters: MembraneParameters
    warnings: list = field(default_factory=list)
    #: not identified: the predictions with sigma_h''(1) at the ends of its interval
    sensitivity: CurvatureSensitivity | None = None


def static_sigma(static: StaticFitResult | None, data: StaticData | None = None):
    """Weight of the static points in the joint chi-square (m): one value, or one per point.

    Where every point of ``data`` (the static fit's points) states its standard uncertainty (the laser noise
    over the square root of the samples it averages: :attr:`StaticData.std_error_m`), each point is weighted
    with its own, scaled up where the static fit's residuals scatter more than those say (a model error):
    by sqrt(chi^2 / dof) of the residuals in their units, times t_0.975(dof) / z_0.975 (the scale is then
    estimated from few points). Their errors differ: the coverage family's 0 V points at the other masses
    scatter by 0.02-0.04 um, the rig's static segments by 0.05-0.12 um; one pooled value trusted the latter
    too much and made the intervals of k1 and eps_r, which the static points carry 45-95 % of, too narrow
    (issue 21, session 19).

    Otherwise one value: the static fit's residual standard deviation s, times t_0.975(dof) / z_0.975 -- s
    comes from few points (e.g. 9 degrees of freedom), and the joint intervals, which use the quantile of the
    joint fit's many degrees of freedom, would otherwise be too narrow for the parameters the static points
    determine (sigma_h(1))."""
    if static is None:
        return 1.0
    st = static.statistics
    dof = int(st.dof) if st is not None else 0
    t_over_z = float(scipy_stats.t.ppf(0.975, dof) / scipy_stats.norm.ppf(0.975)) if dof >= 1 else 1.0
    stated = data.stated_std_m if data is not None else None
    if stated is not None and stated.size == static.residuals_m.size and dof >= 1:
        ratio = float(np.sum((static.residuals_m / stated) ** 2)) / dof
        return stated * (math.sqrt(ratio) * t_over_z if ratio > 1.0 else 1.0)
    s = float(st.residual_std) if st is not None and math.isfinite(st.residual_std) else float("nan")
    if not (math.isfinite(s) and s > 0):
        r = static.residuals_m
        s = float(np.sqrt(np.mean(r**2))) if r.size else 1e-7
    return max(s * t_over_z, 1e-9)


def curvature_fallback(static: StaticFitResult | None, params: MembraneParameters) -> np.ndarray:
    """(beta, gamma) whose curvature terms (sigma_h''(1), sigma_h'''(1)) are written when the data do
    not determine them: the base parameters' (or, without base parameters, the static fit's
    representation, eqs. 8-9)."""
    if static is not None and static.prior_beta_gamma is not None:
        return np.asarray(static.prior_beta_gamma, float)
    return np.r_[params.beta_Pa, params.gamma_Pa]


def _curvature_Pa(beta_gamma) -> float:
    """sigma_h''(1) (Pa, derivative in s) of Ogden (beta, gamma) (eq. 10)."""
    return float(EXTENDED_COMBINATION_MATRIX[2] @ np.asarray(beta_gamma, float))


def _joint_fit(start: MembraneParameters, static: StaticFitResult, experiments: ExperimentSet, points: list,
               fit_curvature, stress_terms: int, fallback_Pa: float, n_harmonics: int, progress,
               fit_slope: bool, minimise: bool = True) -> JointFitResult:
    """:func:`fit_joint` on all the data with the static fit's weights and prior (``minimise`` False: evaluated
    at ``start``, not minimised)."""
    data = experiments.all_static()
    return fit_joint(start, data, experiments.steps, points, static_sigma(static, data),
                     noise_m=experiments.sensor_noise_m, prior_beta_gamma=static.prior_beta_gamma,
                     fit_curvature=fit_curvature, fit_slope=fit_slope, curvature_fallback_Pa=fallback_Pa,
                     n_harmonics=n_harmonics, progress=progress, curvature_from_static=stress_terms >= 3,
                     minimise=minimise)


def refine_jointly(params: MembraneParameters, static: StaticFitResult, classification: list,
                   experiments: ExperimentSet, n_harmonics: int, fit_curvature, stress_terms: int,
                   progress=None, fit_slope: bool | None = None) -> JointRounds:
    """The joint refinement from ``params`` (the two-stage result), repeated with the records classified
    again until the classification does not change (module docstring). ``fit_curvature``: False never
    fits sigma_h''(1); otherwise it is fitted when there are sine records. ``fit_slope``: sigma_h'(1)
    fitted (True) or held at the start's value (False); None: fitted when the static fit fitted it
    (``stress_terms`` >= 2).

    With sine records the first round holds the curvature terms at the start's values and the records
    are classified again at its optimum before the curvature is freed: started from the two-stage result,
    whose records near a fold were solved on the branches of its parameters, the free fit could follow a
    record onto another branch and end in a local minimum that no longer fits the static points (F11 of
    the coverage family, 17 frequencies, seed 3: chi-square 5272 with 1845 on 13 static points, k1 and
    sigma_h(1) 30 standard errors off; held first: 2380, every |z| < 0.4).

    A refinement that still leaves the static points (their chi-square above the two-stage result's by
    more than :func:`_static_excess_limit`) followed a record onto another branch even so (F17, 17
    frequencies, seed 1: the record at the resonance, 1505 um RMS on the upper branch, where the model at
    the two-stage parameters has only a quasi-periodic response of 790 um; static chi-square 7.7 -> 36682,
    eta1 x1000). It is done again from the two-stage result without the records whose response the model
    there does not have (data and model kinds differ); if that leaves the static points too, or there is
    no such record, the two-stage result is reported with the reason, and with the intervals of the joint
    objective linearised there (``two_stage_linearisation``): the dynamic fit's hold the static stage's
    parameters fixed (F05, 17 frequencies: k1 at z +67)."""
    fallback = curvature_fallback(static, params)
    slope = stress_terms >= 2 if fit_slope is None else bool(fit_slope)
    fit_c = (fit_curvature is not False) and (bool(experiments.sines) or stress_terms >= 3)
    rounds = _rounds(params, static, classification, experiments, n_harmonics, fit_c, stress_terms, progress, slope,
                     fallback)
    if rounds.joint is None:
        return _two_stage_reported(rounds, static, experiments, n_harmonics, fit_c, stress_terms, slope, fallback)
    if not experiments.sines:
        return rounds
    start_chi2 = _static_chi2(static, experiments.all_static())
    if not _left_the_static_points(rounds.joint, start_chi2, static):
        return _free_the_shape(rounds, static, experiments, n_harmonics, stress_terms, slope, fallback, progress,
                               start_chi2)
    left = (f"the joint refinement left the static points (their chi-square "
            f"{rounds.joint.block_chi2.get('static', 0.0):.6g} against {start_chi2:.6g} at the two-stage result): "
            "it followed a record onto another branch")
    retry_classification = [dict(c) for c in classification]
    unreachable = [c for c in retry_classification if c["used"] != "left out"
                   and c.get("model_kind") not in (None, c.get("data_kind"))]
    for c in unreachable:
        leave_out_for_a_round(c, f"the model at the two-stage parameters has a {c.get('model_kind')} response "
                                 f"where the data show a {c.get('data_kind')} one, and the joint refinement with "
                                 "it left the static points")
    if unreachable:
        retry = _rounds(params, static, retry_classification, experiments, n_harmonics, fit_c, stress_terms,
                        progress, slope, fallback)
        retry.classification_s += rounds.classification_s
        if retry.joint is not None and not _left_the_static_points(retry.joint, start_chi2, static):
            retry.warnings = rounds.warnings + [
                f"{left}; refined again from the two-stage result without the record(s) at "
                + ", ".join(f"{c['frequency_Hz']:g} Hz" for c in unreachable) + " (the model there has no response "
                "of the kind the data show)"] + retry.warnings
            return _free_the_shape(retry, static, experiments, n_harmonics, stress_terms, slope, fallback, progress,
                                   start_chi2)
        rounds.classification_s = retry.classification_s
    rejected = JointRounds(None, params, classification, fallback, rounds.classification_s, rounds.warnings)
    return _two_stage_reported(rejected, static, experiments, n_harmonics, fit_c, stress_terms, slope, fallback,
                               f"{left}; the two-stage result is reported")


def _free_the_shape(rounds: JointRounds, static: StaticFitResult, experiments: ExperimentSet, n_harmonics: int,
                    stress_terms: int, slope: bool, fallback: np.ndarray, progress, start_chi2: float) -> JointRounds:
    """The refinement with the whole Ogden shape free where the data contradict the shape it holds beyond
    sigma_h'''(1) (:func:`~.joint_fit.held_shape_test` at its optimum; :mod:`~.joint_fit` docstring): a shape
    held at a guess steers the others (issue 21, item 1). Otherwise ``rounds`` as they are, with the test."""
    joint = rounds.joint
    if joint is None or curvature_mode(joint.names) is not True:
        return rounds
    points = fitted_points(rounds.classification, experiments)
    fallback_Pa = _curvature_Pa(fallback)
    try:
        at_fit = _joint_fit(rounds.parameters, static, experiments, points, "shape", stress_terms, fallback_Pa,
                            n_harmonics, None, slope, minimise=False)
    except JointFitError:
        return rounds
    rounds.shape_test = test = held_shape_test(joint, at_fit)
    if not test.rejects:
        return rounds
    why = (f"the data contradict the Ogden shape held beyond sigma_h'''(1) (the fourth and fifth derivatives at "
           f"the base's; score test: {test.statistic:.3g} on {test.dof} degrees of freedom, p = {test.p_value:.2g})")
    try:
        free = _joint_fit(rounds.parameters, static, experiments, points, "shape", stress_terms, fallback_Pa,
                          n_harmonics, progress, slope)
        implausible = free.parameters.plausibility_problems()
        if implausible:
            why_not = (f"the fit with them free ended at an implausible membrane ({'; '.join(implausible)}: the "
                       "data see only part of the shape)")
        elif free.cost >= joint.cost or _left_the_static_points(free, start_chi2, static):
            why_not = (f"the fit with them free did not improve on it (chi-square {free.cost:.6g} against "
                       f"{joint.cost:.6g}) or left the static points")
        else:
            rounds.warnings.append(f"{why}: refined with the whole shape free (chi-square {joint.cost:.6g} -> "
                                   f"{free.cost:.6g}); the parameters and intervals reported are that fit's")
            rounds.shape_test = dataclasses.replace(test, outcome="free")
            rounds.joint, rounds.parameters = free, free.parameters
            return rounds
    except JointFitError as exc:
        why_not = f"the fit with them free failed ({exc})"
    # the held shape's parameters, with the intervals of the objective linearised there with the whole shape
    # free (they allow for it, as a marginalisation to first order)
    rounds.warnings.append(f"{why}; {why_not}: the held shape's parameters are reported, with the intervals of the "
                           "joint objective linearised there with the whole shape free")
    rounds.shape_test = dataclasses.replace(test, outcome="held, intervals with the shape free")
    rounds.joint = at_fit
    return rounds


def _two_stage_reported(rounds: JointRounds, static: StaticFitResult, experiments: ExperimentSet,
                        n_harmonics: int, fit_c: bool, stress_terms: int, slope: bool, fallback: np.ndarray,
                        reason: str = "") -> JointRounds:
    """``rounds`` without a refinement, with the joint objective linearised at its parameters (reported)."""
    try:
        rounds.two_stage_linearisation = _joint_fit(
            rounds.parameters, static, experiments, fitted_points(rounds.classification, experiments), fit_c,
            stress_terms, _curvature_Pa(fallback), n_harmonics, None, slope, minimise=False)
        note = ("its intervals are those of the joint objective linearised there (every parameter free, the static "
                "stage's uncertainty included)")
    except JointFitError as exc:
        note = (f"its intervals are the dynamic fit's, which hold the static stage's parameters fixed and are too "
                f"narrow ({exc})")
    rounds.warnings = rounds.warnings + [f"{reason}; {note}" if reason else f"the two-stage result: {note}"]
    return rounds


def _static_chi2(static: StaticFitResult, data: StaticData | None) -> float:
    """The static points' chi-square at the static fit (the two-stage result's), with the joint fit's weights."""
    r = np.asarray(static.residuals_m, float)
    return float(np.sum((r / static_sigma(static, data)) ** 2))


def _static_excess_limit(n_points: int) -> float:
    """How much the joint refinement may raise the static points' chi-square above the two-stage result's
    before it counts as having left them: 5 per point, at least 50 (the joint fit moves the shared
    parameters by a few of the static fit's standard errors at most: a few units of chi-square)."""
    return max(50.0, 5.0 * n_points)


def _left_the_static_points(joint: JointFitResult, start_chi2: float, static: StaticFitResult) -> bool:
    return joint.block_chi2.get("static", 0.0) > start_chi2 + _static_excess_limit(np.size(static.residuals_m))


def _rounds(params: MembraneParameters, static: StaticFitResult, classification: list, experiments: ExperimentSet,
            n_harmonics: int, fit_c: bool, stress_terms: int, progress, slope: bool,
            fallback: np.ndarray) -> JointRounds:
    """The rounds of :func:`refine_jointly`: fit, classify again, until the classification stays."""
    held_first = fit_c and bool(experiments.sines)
    rounds = JointRounds(None, params, classification, fallback)
    held_chi2 = None
    for k in range(4 if held_first else 3):
        curvature = False if (held_first and k == 0) else fit_c
        pts = fitted_points(rounds.classification, experiments)
        try:
            rounds.joint = _joint_fit(rounds.parameters, static, experiments, pts, curvature, stress_terms,
                                      _curvature_Pa(fallback), n_harmonics, progress,
                                      slope)
        except JointFitError as exc:
            rounds.warnings.append(f"joint refinement failed ({exc}); the two-stage result is reported")
            rounds.joint = None
            break
        rounds.parameters = rounds.joint.parameters
        if not experiments.sines:
            break
        if held_first and k == 0:
            held_chi2 = rounds.joint.cost
        t1 = time.perf_counter()
        again = classify_records(rounds.parameters, experiments, n_harmonics, experiments.sensor_noise_m)
        rounds.classification_s += time.perf_counter() - t1
        changed = classification_kinds(again) != classification_kinds(rounds.classification)
        rounds.classification = again
        if not changed and not (held_first and k == 0):
            break
    if rounds.joint is not None and held_chi2 is not None and rounds.joint.cost > 1.001 * held_chi2:
        rounds.warnings.append(
            f"joint refinement: the fit with the curvature terms free ends at chi-square {rounds.joint.cost:.6g}, "
            f"above the {held_chi2:.6g} of the fit with them held: a local minimum on another branch of a "
            "record; the intervals assume the best fit and may not hold")
    return rounds


def _keep_free(joint: JointFitResult, params: MembraneParameters, rounds: JointRounds, experiments: ExperimentSet,
               rel: float, n_harmonics: int) -> CurvatureDecision:
    """sigma_h''(1) not identified: the free fit is reported (parameters and intervals), its curvature
    written as a representative value, and how the predictions depend on it."""
    classification = rounds.classification
    near = [c for c in classification if c["used"] != "left out"
            and c["measured_rms_m"] > 0.5 * max(x["measured_rms_m"] for x in classification)]
    hint = "" if len(near) >= 3 else " Records near the resonance peak (large amplitude) would determine it."
    written = _curvature_Pa(np.r_[params.beta_Pa, params.gamma_Pa])
    sens = curvature_sensitivity(params, joint.statistics, experiments, n_harmonics)
    warning = (
        "sigma_h''(1) (curvature of the hyperelastic stress, eq. 10) is not identified by these "
        f"data (95 % interval +-{100 * rel:.0f} % of the fitted value: sign unknown). The parameters and "
        "intervals reported are those of the fit with it free (it does not steer them); params.yaml "
        f"carries that fit's value {written / 1e3:.6g} kPa (derivative in s = lambda^2) as a "
        "representative and says 'not identified'; the report shows the resonance peak and the step "
        "with the curvature at both ends of its interval." + hint)
    return CurvatureDecision(False, "not identified", joint, params, [warning], sens)


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
    return _keep_free(joint, params, rounds, experiments, rel, n_harmonics)
