"""Design studies (no ROS): many designs of the DEA, each swept by harmonic balance, on any engine.

Typical use::

    from dea_ros.study import load_spec, run_study, Engine, read_results
    spec = load_spec("config/studies/a2_family.yaml")
    with Engine("dask") as engine:                  # or "serial", "processes", Engine(scheduler=ADDRESS)
        summary = run_study(spec, "out/a2_family", engine=engine)
    table = read_results(summary["results"])        # column -> array

Modules: :mod:`.spec` (the YAML spec, grid / Latin hypercube / Sobol designs), :mod:`.evaluate`
(one design: static stroke, resonance peak, folds, bands, failures), :mod:`.engine` (serial,
local processes, Dask), :mod:`.results` (chunk files, Parquet/CSV), :mod:`.runner`
(resumable runs), :mod:`.plots` (maps); the command ``dea-ros study`` is :mod:`dea_ros.cli.study`.
"""
from .engine import ENGINE_KINDS, Engine, EngineError, Progress, dask_available
from .evaluate import COLUMNS, FAILURE_REASONS, design_parameters, evaluate_chunk, evaluate_design, result_columns
from .results import parquet_available, read_results
from .runner import StudyInterrupted, run_study, study_chunks
from .spec import SpecError, StudySpec, load_spec, parse_spec

__all__ = [
    "Engine", "EngineError", "ENGINE_KINDS", "Progress", "dask_available", "COLUMNS", "FAILURE_REASONS",
    "design_parameters", "evaluate_chunk", "evaluate_design", "result_columns", "parquet_available",
    "read_results", "StudyInterrupted", "run_study", "study_chunks", "SpecError", "StudySpec", "load_spec",
    "parse_spec",
]
