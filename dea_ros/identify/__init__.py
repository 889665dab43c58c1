"""Parameter identification (paper section IV): experiments, static and dynamic fits, evaluation, report.

Typical use::

    from dea_ros.identify import load_experiment_set, identify, write_report
    result = identify(load_experiment_set("data/A1"))          # or identify(data, refine="none")
    write_report(result, "out/A1")          # params.yaml, report.md, result.json, figures

One concept per module; imports point down the list (a module uses only those above it)::

    experiments/        the data: data classes (data), the on-disk format (manifest, csv_io),
                        column checks (checks), sampled records and eq. 21 (records), data quality
    protocols           the experiment protocols identifier_node runs (a timed schedule)
    bag_experiments     experiments cut from a recorded rig session (a rosbag2 MCAP bag)
    metrics             error indices (Tables III-IV), parameter statistics
    static_fit          eqs. 19-20: the identifiable stress combinations and eps_r
    frequency_points    a frequency point of eq. 24, its periodic solution and d_rms gradient
    dynamic_objective   eq. 22's residuals and exact Jacobian (steps: collocation; sines: harmonic balance)
    dynamic_fit         eqs. 22-24: k1, eta1, eta2 (the paper's stage 1): initial guess, optimisers
    joint_fit           every identifiable parameter at once, statistical weights
    classification      what every sine record shows and what it is fitted with
    refinement          the joint refinement stage and what is written for sigma_h''(1)
    evaluation          the fitted model against all the data (Evaluation, a result object)
    uncertainty         Monte Carlo bands of the frequency response and its peak
    result              IdentificationResult (what identify returns; to_dict is result.json)
    pipeline            identify(): IdentificationOptions and the stage functions
    report/             views of the result: params.yaml, report.md (one function per section), figures
    synth               synthetic experiment sets of a known membrane
    from_bag            a bag -> experiments -> identify -> params.yaml and report (identifier_node)
    many                many inputs on an engine (any object with map_unordered), a summary table

"""
from ..errors import (
    DynamicFitError,
    ExperimentError,
    IdentificationError,
    StaticFitError,
)
from .dynamic_fit import PAPER_FREQUENCIES_HZ, DynamicFitResult, fit_dynamic
from .dynamic_objective import PAPER_WEIGHTS, DynamicObjective
from .evaluation import Evaluation, evaluate
from .experiments import (
    ExperimentSet,
    SineData,
    SineSeries,
    StaticData,
    StepData,
    data_warnings,
    load_experiment_set,
    write_experiment_set,
)
from .metrics import ParameterStatistics, parameter_statistics, resonance_peak_Hz, step_error_indices
from .pipeline import IdentificationOptions, identify
from .report import write_report
from .result import IdentificationResult
from .static_fit import StaticFitResult, fit_static
from .synth import synthesize, synthesize_experiments

__all__ = [
    "ExperimentError", "ExperimentSet", "StaticData", "StepData", "SineData", "SineSeries",
    "load_experiment_set", "write_experiment_set", "data_warnings",
    "StaticFitError", "StaticFitResult", "fit_static",
    "DynamicFitError", "DynamicFitResult", "DynamicObjective", "fit_dynamic", "PAPER_FREQUENCIES_HZ",
    "PAPER_WEIGHTS",
    "ParameterStatistics", "parameter_statistics", "step_error_indices", "resonance_peak_Hz",
    "IdentificationError", "IdentificationResult", "IdentificationOptions", "identify", "evaluate", "Evaluation",
    "write_report", "synthesize", "synthesize_experiments",
]
