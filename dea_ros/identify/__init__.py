"""Parameter identification (paper section IV): experiments, static and dynamic fits, metrics, report.

Typical use::

    from dea_ros.identify import load_experiment_set, identify, write_report
    result = identify(load_experiment_set("data/A1"))
    write_report(result, "out/A1")          # params.yaml, report.md, figures

Modules: :mod:`.experiments` (data and on-disk format), :mod:`.static_fit` (eqs. 19-20),
:mod:`.dynamic_fit` (eqs. 22-24), :mod:`.metrics`, :mod:`.pipeline`, :mod:`.report`,
:mod:`.synth` (synthetic data), :mod:`.commands` (CLI).
"""
from .dynamic_fit import (
    PAPER_FREQUENCIES_HZ,
    PAPER_WEIGHTS,
    DynamicFitError,
    DynamicFitResult,
    DynamicObjective,
    fit_dynamic,
)
from .experiments import (
    ExperimentError,
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
from .pipeline import IdentificationError, IdentificationResult, evaluate, identify
from .report import write_report
from .static_fit import StaticFitError, StaticFitResult, fit_static
from .synth import synthesize, synthesize_experiments

__all__ = [
    "ExperimentError", "ExperimentSet", "StaticData", "StepData", "SineData", "SineSeries",
    "load_experiment_set", "write_experiment_set", "data_warnings",
    "StaticFitError", "StaticFitResult", "fit_static",
    "DynamicFitError", "DynamicFitResult", "DynamicObjective", "fit_dynamic", "PAPER_FREQUENCIES_HZ",
    "PAPER_WEIGHTS",
    "ParameterStatistics", "parameter_statistics", "step_error_indices", "resonance_peak_Hz",
    "IdentificationError", "IdentificationResult", "identify", "evaluate",
    "write_report", "synthesize", "synthesize_experiments",
]
