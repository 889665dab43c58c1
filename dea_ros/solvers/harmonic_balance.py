"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.solvers.collocation, .newton, .floquet, .periodic_solution."""  # noqa: E501
from ..errors import HarmonicBalanceError
from .collocation import (
    CollocationSystem,
    ModelSetup,
    fourier_differentiation_matrix,
    linear_guess,
    model_setup,
    periodic_interpolation_matrix,
    resample_state,
    response_layout,
)
from .floquet import (
    MAGNUS_H_RHO,
    MAGNUS_MAX_STEPS,
    MAGNUS_MIN_STEPS,
    SYMMETRY_TOL,
    attach_floquet,
    classify_stability,
    floquet_multipliers,
    floquet_multipliers_batch,
    half_period_view,
    magnus_steps,
    monodromy_matrix,
    sorted_eigenvalues,
)
from .newton import AUTO_HARMONICS, newton_error, solve_native, solve_native_batch
from .periodic_solution import PeriodicSolution, truncation_ratios

__all__ = [
    "HarmonicBalanceError", "PeriodicSolution", "CollocationSystem", "fourier_differentiation_matrix",
    "periodic_interpolation_matrix", "solve_native", "floquet_multipliers", "floquet_multipliers_batch",
    "attach_floquet", "classify_stability", "ModelSetup", "model_setup", "newton_error", "resample_state",
    "truncation_ratios", "monodromy_matrix", "magnus_steps", "sorted_eigenvalues", "MAGNUS_H_RHO",
    "MAGNUS_MIN_STEPS", "MAGNUS_MAX_STEPS", "linear_guess", "response_layout", "half_period_view", "SYMMETRY_TOL",
    "solve_native_batch", "AUTO_HARMONICS",
]
