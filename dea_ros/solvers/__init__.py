"""Solvers for the DEA model (no ROS): forward integration, harmonic balance, sweeps, RMS.

* :mod:`.inputs`: voltage signals (step, sine, sampled) and periodic inputs.
* :mod:`.integrate`: adaptive integration and the fixed-step real-time stepper.
* :mod:`.harmonic_balance`: native HBM (collocation, eq. 16) with Floquet stability.
* :mod:`.mousai_backend`: the paper's ``mousai.hb_time`` behind the same result type.
* :mod:`.steady_state`: one front end ``solve_periodic(method=...)`` and forward integration to steady state.
* :mod:`.continuation`: frequency sweeps with arclength continuation, folds, branch switching at
  period doubling, bands and the realised response, the resonance peak on the branch.
* :mod:`.realised`: the realised (e.g. quasi-periodic) response by fixed-step integration.
"""
from .continuation import SweepResult, frequency_sweep, sweep_independent
from .harmonic_balance import HarmonicBalanceError, PeriodicSolution, solve_native
from .inputs import (
    SampledPeriodic,
    SampledVoltage,
    SinePeriodic,
    SineVoltage,
    StepVoltage,
)
from .integrate import RealTimeStepper, TimeResponse, simulate
from .steady_state import SteadyStateError, integrate_to_steady_state, solve_periodic

__all__ = [
    "simulate", "RealTimeStepper", "TimeResponse", "solve_native", "solve_periodic",
    "integrate_to_steady_state", "frequency_sweep", "sweep_independent", "SweepResult",
    "PeriodicSolution", "HarmonicBalanceError", "SteadyStateError", "StepVoltage", "SineVoltage",
    "SampledVoltage", "SinePeriodic", "SampledPeriodic",
]
