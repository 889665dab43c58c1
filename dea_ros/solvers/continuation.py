"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.solvers.sweep and dea_ros.solvers.sweep_results."""  # noqa: E501
from ..errors import ContinuationError
from .branch_analysis import END_TOL
from .sweep import H_MAX, LOCATE_STEP_FACTOR, frequency_sweep, period_doubled_solution, sweep_independent
from .sweep_results import (
    KINDS,
    PRIMARY,
    Band,
    Bifurcation,
    Branch,
    Fold,
    Response,
    SweepPoint,
    SweepResult,
    classify_point,
    stability_segments,
)

__all__ = [
    "SweepPoint", "Fold", "Bifurcation", "Response", "Band", "Branch", "SweepResult", "frequency_sweep",
    "ContinuationError", "sweep_independent", "KINDS", "period_doubled_solution", "PRIMARY", "END_TOL",
    "stability_segments", "H_MAX", "LOCATE_STEP_FACTOR", "classify_point",
]
