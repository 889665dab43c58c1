"""Solvers for the DEA model (no ROS): forward integration, harmonic balance, sweeps, RMS.

Each concept in one module, the compiled (numba) kernels beside what they compute, imports
pointing down the list (a module uses only those above it):

* :mod:`.jit`: numba's compile decorators and the per-user on-disk cache of the kernels.
* :mod:`.inputs`: voltage signals (step, sine, sampled) and periodic inputs.
* :mod:`.integrate`: adaptive integration and the fixed-step real-time stepper.
* :mod:`.transient`: whole-trajectory Hermite-Simpson collocation with sensitivities (identification).
* :mod:`.collocation_kernels` / :mod:`.collocation`: the collocation system of eq. 16 (spectral
  matrices, residual, Jacobian and its structured solves, scaling, the linearised guess).
* :mod:`.newton_kernels` / :mod:`.newton`: damped Newton on it, single solves with their fallbacks
  (``solve_native``) and batched ones (``solve_native_batch``).
* :mod:`.floquet_kernels` / :mod:`.floquet`: monodromy by Magnus, Floquet multipliers, stability.
* :mod:`.periodic_solution`: the periodic steady state every periodic solver returns.
* :mod:`.mousai_backend`: the paper's ``mousai.hb_time`` behind the same result type.
* :mod:`.steady_state`: one front end ``solve_periodic(method=...)``, forward integration to the
  steady state, single shooting.
* :mod:`.realised`: the realised (e.g. quasi-periodic) response by fixed-step integration.
* :mod:`.arclength_kernels`: the pseudo-arclength continuation engine, on any registered problem
  (residual and Jacobian; optionally its own corrector).
* :mod:`.sweep_kernels`: the frequency response of the collocation system as the engine's problem.
* :mod:`.branch_tracer`: one branch of the frequency response followed by the engine.
* :mod:`.sweep_results`: the result types of a sweep (points, folds, bifurcations, bands, branches).
* :mod:`.branch_analysis`: multipliers along a branch, located folds and bifurcations, maxima.
* :mod:`.branches`: branch switching at period doubling, the realised response per frequency.
* :mod:`.sweep`: ``frequency_sweep`` (set-up, bands) and ``sweep_independent``.

Why the kernel modules are apart from their Python modules: numba compiles a module's kernels
from its source and caches them keyed to that file, and the Python side (result types, fallbacks,
messages) changes far more often than the loops.
"""
from ..errors import HarmonicBalanceError, SteadyStateError
from .inputs import (
    SampledPeriodic,
    SampledVoltage,
    SinePeriodic,
    SineVoltage,
    StepVoltage,
)
from .integrate import RealTimeStepper, TimeResponse, simulate
from .newton import solve_native, solve_native_batch
from .periodic_solution import PeriodicSolution
from .steady_state import integrate_to_steady_state, solve_periodic
from .sweep import frequency_sweep, sweep_independent
from .sweep_results import SweepResult

__all__ = [
    "simulate", "RealTimeStepper", "TimeResponse", "solve_native", "solve_periodic",
    "integrate_to_steady_state", "frequency_sweep", "sweep_independent", "SweepResult",
    "PeriodicSolution", "HarmonicBalanceError", "SteadyStateError", "StepVoltage", "SineVoltage",
    "SampledVoltage", "SinePeriodic", "SampledPeriodic", "solve_native_batch",
]
