"""Position control of the DEA (no ROS): model inversion, reference shaping, feedback on u^2, prediction.

* :mod:`.inverse`: static inverse (eq. 20) with the reachable range, dynamic inverse (eq. 5 solved
  for u^2) and the viscoelastic strain integrated along the reference (eq. 11);
* :mod:`.reference`: smooth references (hold, quintic moves, trajectories through points, sines)
  and the feasibility check (u^2 >= 0, voltage and slew limits);
* :mod:`.feedback`: PID on u^2 with gains by pole placement on the identified model;
* :mod:`.controller`: :class:`PositionController`, one call per laser sample;
* :mod:`.monitor`: the laser stream (stale, skipped and invalid samples, the filtered velocity) and the
  tracking error between reports;
* :mod:`.prediction`: :class:`ModelPredictor`, the displacement predicted in real time from stamped applied
  voltages (model_node);
* :mod:`.streaming`: :class:`StreamedReference`, a reference streamed as timed samples (ros2_control's
  joint commands);
* :mod:`.tracking`: :class:`ModelTracker`, the membrane's drift (electrostatic gain, static and viscoelastic
  stiffness, creep time) estimated online; :mod:`.adaptive`: the controller retuned on the tracked model;
  :mod:`.retune_worker`: that retune prepared in a long-lived worker process, off the control loop's GIL;
  :mod:`.health`: what changed, in words, with WARN/ERROR levels (/diagnostics); :mod:`.voltage_pairing`:
  laser samples paired by stamps with the applied voltage in effect then (model_node's tracker);
* :mod:`.simulation`: the closed loop against a simulated rig (noise, quantisation, amplifier), and the
  sample -> applied-voltage delay measured on recorded streams (:func:`loop_delays`).
"""
from .adaptive import (AdaptiveModel, DriftTracking, RetunePlan, RetuneRequest, apply_retune, prepare_plan,
                       prepare_retune)
from .controller import ControllerConfig, ControlOutput, PositionController
from .feedback import FeedbackGains, PIDOnU2, design_gains, loop_margins
from .health import (HealthMonitor, HealthReport, HealthThresholds, PredictionErrorStats, describe_drift,
                     describe_payload, moving_mass_ratio)
from .inverse import ModelInverse, StrainIntegrator, UnreachableReferenceError
from .monitor import SampleStream, TrackingWindow
from .prediction import ModelPredictor
from .retune_worker import RETUNE_MODES, BackgroundRetune, RetuneWorker
from .reference import (
    Feasibility,
    Hold,
    PiecewiseQuintic,
    QuinticMove,
    SineReference,
    Trajectory,
    check_trajectory,
    plan_checks,
    plan_move,
    plan_move_steps,
    trajectory_from_points,
)
from .simulation import ClosedLoopResult, SimulatedRig, loop_delays, run_closed_loop
from .streaming import StreamDecision, StreamedReference
from .tracking import ModelTracker, TrackedModel, TrackerConfig
from .voltage_pairing import APPLIED_VOLTAGE_DELAY_SAMPLES, StampedVoltagePairing

__all__ = [
    "ControllerConfig", "ControlOutput", "PositionController", "FeedbackGains", "PIDOnU2", "design_gains",
    "loop_margins", "ModelInverse", "StrainIntegrator", "UnreachableReferenceError", "Feasibility", "Hold",
    "PiecewiseQuintic", "QuinticMove", "SineReference", "Trajectory", "check_trajectory", "plan_move",
    "plan_move_steps", "plan_checks", "trajectory_from_points", "SampleStream", "TrackingWindow", "ModelPredictor",
    "ClosedLoopResult", "SimulatedRig", "run_closed_loop", "loop_delays",
    "StreamedReference", "StreamDecision",
    "ModelTracker", "TrackedModel", "TrackerConfig",
    "StampedVoltagePairing", "APPLIED_VOLTAGE_DELAY_SAMPLES",
    "DriftTracking", "AdaptiveModel", "RetunePlan", "apply_retune",
    "prepare_retune",
    "RetuneRequest", "prepare_plan", "RetuneWorker", "BackgroundRetune", "RETUNE_MODES",
    "HealthMonitor", "HealthReport", "HealthThresholds", "PredictionErrorStats", "describe_drift",
    "describe_payload", "moving_mass_ratio",
]
