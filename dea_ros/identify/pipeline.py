"""The whole identification as a sequence of stages: static fit -> dynamic fit -> classification -> joint
refinement -> evaluation -> uncertainty.

:func:`identify` runs the two-step procedure of the paper (section IV): the static parameters
from the rest displacements (eqs. 19-20, :func:`_static_stage`), then k1, eta1, eta2 from the step
and frequency responses with the static parameters fixed (eqs. 22-24, :func:`_paper_stage`). Then
every sine record is classified (:mod:`~dea_ros.identify.classification`): what the record shows
from its samples and what the model at the current parameters realises there; each record is
fitted with the matching solution or left out with a warning (:func:`_classification_stage`). The
joint refinement (:mod:`~dea_ros.identify.refinement`) then fits every identifiable parameter at
once with statistical weights, so that the reported intervals include the uncertainty of the
static stage; the classification is repeated with the refined model until it does not change.
sigma_h''(1) is written only when the data determine it; otherwise params.yaml carries the base
value and says "not identified" (:func:`_refinement_stage`).

The evaluation (:func:`~dea_ros.identify.evaluation.evaluate`) checks the fitted model against
*all* the data with the accurate solvers and computes the metrics of Tables III-IV; quality
checks turn a model that does not reproduce the data within the noise into warnings, never a
silent fit. On request, Monte Carlo confidence bands of the frequency response follow
(:mod:`~dea_ros.identify.uncertainty`).

How to identify is an :class:`IdentificationOptions`; ``identify(data, refine="none")`` builds one
from keywords. The stages share one :class:`_Run` (the fits so far, warnings, timings).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ..errors import IdentificationError
from ..model.parameters import MembraneParameters
from .classification import classify_records, record_kinds
from .determination import determine_parameters
from .dynamic_fit import DynamicFitResult, fit_dynamic, select_fit_frequencies
from .evaluation import Evaluation, evaluate
from .experiments import ExperimentSet, data_warnings
from .joint_fit import CURVATURE_REL_CI_LIMIT, JointFitResult
from .refinement import decide_curvature, refine_jointly
from .result import IdentificationResult, reported_statistics
from .static_fit import StaticFitResult, fit_static, static_curvature_test, stress_combinations
from .step_simulation import simulate_step
from .uncertainty import response_bands

__all__ = ["IdentificationOptions", "identify"]


@dataclass(frozen=True)
class IdentificationOptions:
    """How to identify (the options of ``dea-ros identify``; the defaults are the command's).

    Stage 1 (the paper): ``static_method`` "lsq" (bounded least squares on the identifiable
    combinations) or "paper" (Nelder-Mead on eq. 19); ``dynamic_method`` "lsq" or "paper";
    ``frequency_method`` "hbm" (harmonic balance) or "integration"; ``weights`` "paper" (eq. 22 with
    w_step = 6.6e6, w_hbm = 0.1e6), "noise" (1/sigma^2) or a dict; ``fit_frequencies_Hz`` (default
    the paper's four in the data, "all", or a list); records classified as not periodic at T/2 are
    left out of it. ``stress_terms``: stress combinations of the static fit (2: sigma_h(1) and
    sigma_h'(1); 1 when there are too few static points). ``joint_slope``: sigma_h'(1) in the joint
    refinement -- None: fitted there when the static fit fits it (``stress_terms`` >= 2); True: fitted
    there even when the static fit holds it (one mass on the rig: the step and the sines determine it,
    the staircase alone does not). ``refine``: "joint" (default) refines
    every identifiable parameter jointly with statistical weights on all classified records (the
    final parameters and intervals); "none" stops after the paper's two stages.
    ``fit_curvature``: identify sigma_h''(1) -- "auto" in the joint refinement when there are sine
    records; True also in stage 1 (with noise weights); False never. ``evaluate_fit``: compare
    the result with every experiment (metrics, curves, quality warnings). ``uncertainty_samples``
    > 0: Monte Carlo confidence bands of the frequency response and the resonance peak over the
    final covariance (:func:`~dea_ros.identify.uncertainty.response_band`, one per sine data set
    and amplitude).
    """

    static_method: str = "lsq"
    frequency_method: str = "hbm"
    dynamic_method: str = "lsq"
    fit_frequencies_Hz: Any = None
    n_harmonics: int = 8
    weights: Any = "paper"
    stress_terms: int = 2
    joint_slope: bool | None = None
    evaluate_fit: bool = True
    fit_curvature: Any = "auto"
    refine: str = "joint"
    uncertainty_samples: int = 0

    def __post_init__(self):
        if self.refine not in ("joint", "none"):
            raise ValueError(f"refine: 'joint' or 'none', got {self.refine!r}")

    @classmethod
    def build(cls, options: IdentificationOptions | None = None, **values) -> IdentificationOptions:
        """``options`` (default: the defaults) with the keyword ``values`` replaced."""
        if options is None:
            return cls(**values)
        return dataclasses.replace(options, **values) if values else options


@dataclass
class _Run:
    """One identification in progress: what the stages have found so far, warnings and timings."""

    experiments: ExperimentSet
    options: IdentificationOptions
    progress: Callable[[dict], None] | None
    warnings: list
    stress_terms: int
    timings: dict = field(default_factory=dict)
    params: MembraneParameters | None = None
    static: StaticFitResult | None = None
    dynamic: DynamicFitResult | None = None
    joint: JointFitResult | None = None
    #: no refinement (rejected or failed): the joint objective linearised at the reported two-stage result
    two_stage_linearisation: JointFitResult | None = None
    classification: list = field(default_factory=list)
    stage1_freqs: list = field(default_factory=list)      # the frequency points of the paper's fit
    direction: np.ndarray | None = None                    # sigma_h''(1) in stage 1 (fit_curvature True)
    curvature_identified: bool | None = None
    curvature_status: str = "not fitted"
    curvature_sensitivity: Any = None                      # CurvatureSensitivity (not identified)
    shape_test: Any = None                                 # joint_fit.ShapeTest of the refinement


# --------------------------------------------------------------------------- stages
def _static_stage(run: _Run) -> None:
    """Static parameters from the rest displacements (eqs. 19-20), or the base parameters without them."""
    exp, opt = run.experiments, run.options
    template = exp.template_parameters()
    if exp.static:
        t0 = time.perf_counter()
        data = exp.all_static()
        loaded = int(np.count_nonzero(data.mass_kg > 0))
        if opt.static_method == "lsq" and loaded < run.stress_terms + 3 and run.stress_terms > 1:
            # too few points for sigma_h(1), sigma_h'(1) and eps_r with residual freedom left
            run.stress_terms = 1
            run.warnings.append(
                f"{data.source}: only {loaded} static point(s) with a mass; fitting sigma_h(1) and eps_r only, "
                "sigma_h'(1) is taken from the " + ("base parameters" if exp.base_parameters is not None
                                                    else "representation (eqs. 8-9)")
                + " -- add zero-voltage points at several masses to identify it"
            )
        run.static = fit_static(data, template, method=opt.static_method, stress_terms=run.stress_terms,
                                prior_from_template=exp.base_parameters is not None, progress=run.progress)
        _free_static_curvature_if_determined(run, data, template)
        run.timings["static_fit"] = time.perf_counter() - t0
        run.params = run.static.parameters
    elif exp.base_parameters is not None:
        run.params = template
    else:
        raise IdentificationError(
            "no static experiment and no base parameters file: beta, gamma and eps_r are unknown; add "
            "static points (mass, voltage, displacement) or reference a parameters file in the manifest"
        )


def _free_static_curvature_if_determined(run: _Run, data, template: MembraneParameters) -> None:
    """The static fit again with sigma_h''(1) free; kept when the rest displacements determine it
    (:func:`~.static_fit.static_curvature_test`), so that a curvature the data contradict is not held at
    the representation's value (issue 21, item 1). Only for the default least-squares fit with two stress
    terms and enough points, and not when sigma_h''(1) is never to be fitted or is fitted in stage 1."""
    opt = run.options
    if opt.static_method != "lsq" or run.stress_terms != 2 or opt.fit_curvature != "auto" or data.n_points < 7:
        return
    free = fit_static(data, template, method="lsq", stress_terms=3,
                      prior_from_template=run.experiments.base_parameters is not None)
    test = static_curvature_test(run.static, free, rel_ci_limit=CURVATURE_REL_CI_LIMIT)
    if test.needed:
        free.warnings.append(test.note())
        run.static, run.stress_terms = free, 3


def _stage1_fit(run: _Run, static_params: MembraneParameters, freqs: list, **extra) -> DynamicFitResult:
    """The paper's dynamic fit (eqs. 22-24) on the steps and the sine records at ``freqs``."""
    opt, exp = run.options, run.experiments
    return fit_dynamic(static_params, exp.steps, exp.sines if freqs else [],
                       fit_frequencies_Hz=freqs if freqs else None, method=opt.dynamic_method,
                       frequency_method=opt.frequency_method, weights=opt.weights, n_harmonics=opt.n_harmonics,
                       progress=run.progress, noise_m=exp.sensor_noise_m, **extra)


def _refit_with_curvature(run: _Run) -> None:
    """sigma_h''(1) moved in stage 1: refit sigma_h(1), sigma_h'(1), eps_r with it fixed, then polish."""
    exp, opt, first = run.experiments, run.options, run.dynamic
    curvature = float(stress_combinations(first.parameters.beta_Pa, first.parameters.gamma_Pa)[2])
    run.static = fit_static(exp.all_static(), exp.template_parameters(), method=opt.static_method,
                            stress_terms=run.stress_terms, curvature_Pa=curvature,
                            prior_from_template=exp.base_parameters is not None)
    run.dynamic = _stage1_fit(run, run.static.parameters, run.stage1_freqs,
                              curvature_direction=run.static.curvature_direction(), initial=first.parameters)
    run.dynamic.initial = first.initial
    run.dynamic.n_evaluations += first.n_evaluations
    run.dynamic.starts = first.starts + run.dynamic.starts


def _paper_stage(run: _Run) -> None:
    """Stage 1, the paper's dynamic fit (eqs. 22-24), on the records periodic at T/2 (as far as known)."""
    exp, opt = run.experiments, run.options
    data_kinds = record_kinds(exp, exp.sensor_noise_m)   # what the sampled records show, before any fit
    t0 = time.perf_counter()
    stage1_curvature = opt.fit_curvature is True
    static = run.static
    run.direction = static.curvature_direction() if (stage1_curvature and static is not None) else None
    if stage1_curvature and (run.direction is None or run.stress_terms != 2 or static.method != "lsq"):
        raise IdentificationError("fit_curvature needs the least-squares static fit (static_method='lsq') "
                                  "with sigma_h(1) and sigma_h'(1) fitted (stress_terms=2, enough static points)")
    stage1_points = select_fit_frequencies(exp.sines, opt.fit_frequencies_Hz)
    dropped = [pt for pt in stage1_points
               if data_kinds.get((pt.source, round(pt.frequency_Hz, 9)), "periodic") != "periodic"]
    run.stage1_freqs = [pt.frequency_Hz for pt in stage1_points if pt not in dropped]
    for pt in dropped:
        run.warnings.append(f"{pt.source}: the record at {pt.frequency_Hz:g} Hz is "
                            f"{data_kinds[(pt.source, round(pt.frequency_Hz, 9))]}, not periodic at T/2: left out "
                            "of the paper's fit (eq. 24 assumes the T/2 orbit)")
    run.dynamic = _stage1_fit(run, run.params, run.stage1_freqs, start=exp.base_parameters,
                              curvature_direction=run.direction)
    if run.direction is not None:
        _refit_with_curvature(run)
    run.timings["dynamic_fit"] = time.perf_counter() - t0
    run.timings["dynamic_fit_step_simulations"] = run.dynamic.time_step_s
    run.timings["dynamic_fit_frequency_response"] = run.dynamic.time_frequency_s
    run.params = run.dynamic.parameters
    run.warnings += run.dynamic.warnings


def _classification_stage(run: _Run) -> None:
    """Every sine record classified with the model of stage 1; a record of stage 1 that the model (or the
    data) says is not periodic at T/2 was fitted with the wrong orbit: stage 1 again without it."""
    exp, opt = run.experiments, run.options
    t0 = time.perf_counter()
    if exp.sines:
        run.classification = classify_records(run.params, exp, opt.n_harmonics, exp.sensor_noise_m)
        wrong = {(c["source"], round(c["frequency_Hz"], 9)) for c in run.classification if c["used"] != "periodic"}
        kept = [f for f in run.stage1_freqs if not any((s.source, round(f, 9)) in wrong for s in exp.sines)]
        if len(kept) < len(run.stage1_freqs) and run.direction is None and (kept or exp.steps):
            for f in sorted(set(run.stage1_freqs) - set(kept)):
                run.warnings.append(f"{f:g} Hz: not periodic at T/2 for the model after stage 1 (a period-doubled "
                                    "or quasi-periodic response): stage 1 repeated without it "
                                    "(eq. 24 assumes the T/2 orbit)")
            redo = _stage1_fit(run, run.params if run.static is None else run.static.parameters, kept,
                               start=exp.base_parameters)
            redo.n_evaluations += run.dynamic.n_evaluations
            run.dynamic = redo
            run.params = redo.parameters
            run.warnings += [w for w in redo.warnings if w not in run.warnings]
            run.classification = classify_records(run.params, exp, opt.n_harmonics, exp.sensor_noise_m)
    run.timings["classification"] = time.perf_counter() - t0


def _refinement_stage(run: _Run) -> None:
    """The joint refinement and the curvature decision (least-squares static fit only), or what the
    paper's two stages leave undetermined."""
    exp, opt, static = run.experiments, run.options, run.static
    if opt.refine == "joint" and static is not None and static.method == "lsq":
        t0 = time.perf_counter()
        rounds = refine_jointly(run.params, static, run.classification, exp, opt.n_harmonics, opt.fit_curvature,
                                run.stress_terms, run.progress, fit_slope=opt.joint_slope)
        run.timings["classification"] += rounds.classification_s
        run.warnings += rounds.warnings
        run.params, run.classification, run.joint = rounds.parameters, rounds.classification, rounds.joint
        run.two_stage_linearisation = rounds.two_stage_linearisation
        run.shape_test = rounds.shape_test
        run.timings["joint_fit"] = time.perf_counter() - t0
        if rounds.joint is not None:
            run.warnings += rounds.joint.warnings
            decision = decide_curvature(rounds, static, exp, opt.n_harmonics, run.stress_terms, run.progress)
            run.joint, run.params = decision.joint, decision.parameters
            run.curvature_identified, run.curvature_status = decision.identified, decision.status
            run.curvature_sensitivity = decision.sensitivity
            run.warnings += decision.warnings
    elif exp.sines:
        if opt.refine == "joint":
            run.warnings.append("joint refinement skipped: it needs the least-squares static fit "
                                "(static_method='lsq'); "
                                "the two-stage result is reported")
        if not run.dynamic.curvature_fitted:
            run.curvature_identified, run.curvature_status = False, "not identified"
            run.warnings.append(
                "sigma_h''(1) (curvature of the hyperelastic stress, eq. 10) is not identified: the static "
                "deflections cannot see it and this fit did not use it; params.yaml says 'not identified'")


def _classification_warnings(run: _Run) -> None:
    """The notes of the classification and the records left out of the fit."""
    for c in run.classification:
        if c.get("note"):
            run.warnings.append(f"{c['source']}: {c['frequency_Hz']:g} Hz: {c['note']}")
        if c["used"] == "left out":
            run.warnings.append(f"{c['source']}: the record at {c['frequency_Hz']:g} Hz is left out of the fit: "
                                f"{c.get('reason', '')}")


def _transient_solver_difference_um(run: _Run, evaluation: Evaluation) -> float | None:
    """The fast transient solver of the fit against the evaluation's accurate steps (max, um)."""
    if not evaluation.steps:
        return None
    if run.dynamic is not None and run.joint is None:
        fast = run.dynamic.step_simulated_m
    else:
        fast = [simulate_step(run.params, st) for st in run.experiments.steps]
    return max(float(np.max(np.abs(f - c.simulated_m))) * 1e6 for f, c in zip(fast, evaluation.steps))


def _evaluation_stage(run: _Run) -> Evaluation:
    """The final parameters against every experiment, with the classification of the joint refinement."""
    t0 = time.perf_counter()
    final_class = run.classification if (run.classification and run.joint is not None) else None
    evaluation = evaluate(run.params, run.experiments, run.options.n_harmonics, classification=final_class)
    evaluation.transient_solver_max_difference_um = _transient_solver_difference_um(run, evaluation)
    run.warnings += evaluation.warnings
    run.timings["evaluation"] = time.perf_counter() - t0
    return evaluation


def _uncertainty_stage(run: _Run, evaluation: Evaluation, engine) -> list:
    """Monte Carlo confidence bands of the frequency response over the final covariance."""
    t0 = time.perf_counter()
    statistics = reported_statistics(run.joint, run.two_stage_linearisation, run.dynamic)
    peaks = {(s.sine.source, r["amplitude_V"], r.get("offset_V", 0.0)): r.get("simulated_peak_Hz")
             for s in evaluation.sines for r in s.resonance}
    bands, warnings = response_bands(run.params, statistics, run.experiments, int(run.options.uncertainty_samples),
                                     run.options.n_harmonics, engine, peaks)
    run.warnings += warnings
    run.timings["uncertainty"] = time.perf_counter() - t0
    return bands


def _options_used(run: _Run) -> dict:
    """The options as the identification applied them (result.json ``options``)."""
    opt, dynamic, joint = run.options, run.dynamic, run.joint
    return {"static_method": opt.static_method, "dynamic_method": opt.dynamic_method,
            "frequency_method": opt.frequency_method, "n_harmonics": opt.n_harmonics,
            "stress_terms": run.stress_terms, "fit_frequencies_Hz": opt.fit_frequencies_Hz,
            "fit_curvature": bool(dynamic is not None and dynamic.curvature_fitted)
            or bool(joint is not None and joint.curvature_fitted),
            "weights": opt.weights if isinstance(opt.weights, (str, type(None))) else dict(opt.weights),
            "refine": opt.refine if joint is not None else "none", "uncertainty_samples": int(opt.uncertainty_samples)}


def _determination(run: _Run) -> list:
    """Per parameter: status, interval and the records that determine it (the joint objective's Jacobian)."""
    joint = run.joint if run.joint is not None else run.two_stage_linearisation
    if joint is not None:
        return determine_parameters(joint.statistics, joint.jacobian, joint.row_records)
    stats = run.dynamic.statistics if run.dynamic is not None else (
        run.static.statistics if run.static is not None else None)
    return determine_parameters(stats)


# --------------------------------------------------------------------------- identification
def identify(experiments: ExperimentSet, options: IdentificationOptions | None = None, *,
             progress: Callable[[dict], None] | None = None, engine=None, **option_values) -> IdentificationResult:
    """Identify all parameters of ``experiments`` (see the module docstring).

    ``options``: an :class:`IdentificationOptions` (default: its defaults); keyword ``option_values``
    (e.g. ``refine="none"``) replace single options. ``progress``: called with one dict per event of
    the fits. ``engine``: an open :class:`~dea_ros.study.engine.Engine` for the batches of the
    uncertainty bands (default: this process).
    """
    options = IdentificationOptions.build(options, **option_values)
    t_start = time.perf_counter()
    run = _Run(experiments, options, progress, list(data_warnings(experiments)), options.stress_terms)
    _static_stage(run)
    curvature_written = None
    if experiments.steps or experiments.sines:
        _paper_stage(run)
        _classification_stage(run)
        _refinement_stage(run)
        _classification_warnings(run)
        curvature_written = float(stress_combinations(run.params.beta_Pa, run.params.gamma_Pa)[2])
    if run.static is not None:
        run.warnings = run.static.warnings + run.warnings
    evaluation = _evaluation_stage(run) if options.evaluate_fit else Evaluation()
    bands = _uncertainty_stage(run, evaluation, engine) if options.uncertainty_samples and experiments.sines else []
    run.timings["identification_total"] = time.perf_counter() - t_start
    seen = set()
    unique = [w for w in run.warnings if not (w in seen or seen.add(w))]   # duplicates dropped, order kept
    return IdentificationResult(experiments, run.params, run.static, run.dynamic, evaluation, run.timings, unique,
                                _options_used(run), joint=run.joint,
                                two_stage_linearisation=run.two_stage_linearisation, classification=run.classification,
                                curvature_identified=run.curvature_identified,
                                curvature_written_Pa=curvature_written, curvature_status=run.curvature_status,
                                uncertainty=bands, determination=_determination(run),
                                curvature_sensitivity=run.curvature_sensitivity, shape_test=run.shape_test)
