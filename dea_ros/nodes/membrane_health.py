"""Node side of membrane health and online model tracking (position_controller_node, model_node).

The nodes declare the parameters (:func:`declare_health_parameters`), feed every sample through
:class:`ControllerHealth` (the controller's tracker and retuning) or :class:`ObserverHealth`
(model_node: a tracker on applied voltage and measured displacement, and the prediction error), and
publish :meth:`status` as a second DiagnosticStatus "<node>: membrane health" on /diagnostics.
The computation is the core's (:mod:`dea_ros.control.tracking`, :mod:`~dea_ros.control.adaptive`,
:mod:`~dea_ros.control.health`, the retune off the loop :mod:`~dea_ros.control.retune_worker`); here:
parameters, logging of failed retunes, message levels.
"""
from __future__ import annotations

from ..control import (
    RETUNE_MODES,
    AdaptiveModel,
    BackgroundRetune,
    HealthMonitor,
    HealthThresholds,
    ModelTracker,
    PredictionErrorStats,
    TrackerConfig,
)
from .common import declare_bool, declare_float, declare_int, declare_str

__all__ = ["declare_health_parameters", "ControllerHealth", "ObserverHealth", "diagnostic_level"]


def declare_health_parameters(node, tracking_default: bool, retunes: bool = False) -> None:
    declare_bool(node, "track_model", tracking_default,
                 "track the membrane's drift online (electrostatic gain, stiffness, creep time)"
                 + ("; the controller's feedforward and gains follow it" if tracking_default else ""))
    if retunes:       # the controller
        declare_str(node, "retune_worker", "process",
                    "where a retune (window fit + gain design) is prepared: 'process' (a worker process started "
                    "at configure, off the control loop's GIL), 'thread' (a thread of the node), 'off' (never)")
        declare_float(node, "retune_timeout_s", 10.0,
                      "a retune not prepared within this time is dropped and the worker process replaced, s",
                      0.05, 600.0)
        declare_int(node, "retune_worker_nice", 10,
                    "niceness added to the worker process: the control loop gets a contended CPU first", 0, 19)
    declare_float(node, "health_warn_scale", 1.0,
                  "WARN thresholds of the tracked ratios x this (defaults: gain, static stiffness 2 %; "
                  "k1 15 %; creep time 30 %)", 0.1, 100.0)
    declare_float(node, "health_error_scale", 1.0,
                  "ERROR thresholds x this (defaults: 10 %, 10 %, 40 %, 60 %)", 0.1, 100.0)
    declare_float(node, "health_prediction_warn_m", 5e-6, "WARN above this RMS prediction error, m", 1e-9, 1.0)
    declare_float(node, "health_prediction_error_m", 20e-6, "ERROR above this RMS prediction error, m", 1e-9, 1.0)
    declare_float(node, "health_persistence_s", 3.0, "a deviation must last this long to be reported, s",
                  0.0, 600.0)


def thresholds_from(node) -> HealthThresholds:
    p = node.get_parameter
    return HealthThresholds.scaled(float(p("health_warn_scale").value), float(p("health_error_scale").value),
                                   prediction_rms_warn_m=float(p("health_prediction_warn_m").value),
                                   prediction_rms_error_m=float(p("health_prediction_error_m").value),
                                   persistence_s=float(p("health_persistence_s").value))


def diagnostic_level(level: int) -> bytes:
    """diagnostic_msgs/DiagnosticStatus.level (a byte) from 0/1/2."""
    return bytes([int(level)])


class ControllerHealth:
    """position_controller_node: tracker + retuning of its PositionController (off the loop) + health.

    Raises ValueError for an unknown ``retune_worker``.
    """

    def __init__(self, node, ctl, sample_period_s: float):
        p = node.get_parameter
        self.enabled = bool(p("track_model").value)
        self.adaptive = AdaptiveModel(ctl, TrackerConfig(sample_period_s=sample_period_s), enabled=self.enabled)
        self.monitor = HealthMonitor(thresholds_from(node))
        mode = str(p("retune_worker").value)
        if mode not in RETUNE_MODES:
            raise ValueError(f"parameter 'retune_worker': one of {', '.join(RETUNE_MODES)}, got {mode!r}")
        self.retune = BackgroundRetune(self.adaptive, mode, float(p("retune_timeout_s").value),
                                       nice=int(p("retune_worker_nice").value))
        self.logger = node.get_logger()
        self.failures_logged = 0

    def observe(self, t_s: float, measured_m: float, out) -> None:
        """Every control step (after ctl.update): track, start a due retune, apply a finished one."""
        retune = self.retune
        retune.observe(t_s, measured_m, out)
        if retune.failures != self.failures_logged:     # rare: a dead or late worker
            self.failures_logged = retune.failures
            self.logger.warning(f"no retune this time ({retune.failures} so far): {retune.last_failure}",
                                throttle_duration_sec=5.0)

    def status(self, t_s: float, reference_m: float | None):
        """(level byte, message, values) for /diagnostics."""
        tr = self.adaptive.tracker.result()
        ctl = self.adaptive.ctl
        retune = self.retune
        report = self.monitor.assess(t_s, tr.ratios if self.enabled else None, None, reference_m,
                                     ctl.reachable_range_m)
        values = [("track_model", str(self.enabled)), ("tracker_updates", tr.updates),
                  ("tracker_skipped", tr.skipped), ("retunes", self.adaptive.retunes),
                  ("retune_worker", retune.describe()), ("retune_plans", retune.applied),
                  ("retune_failures", retune.failures), ("retune_last_failure", retune.last_failure),
                  ("force_balance_residual_rms", f"{tr.residual_rms:.3e}")] + report.values
        return diagnostic_level(report.level), report.message, values

    def close(self) -> None:
        self.retune.close()


class ObserverHealth:
    """model_node: a tracker on (measured d, applied voltage) and the prediction error statistics."""

    def __init__(self, node, params, sample_period_s: float):
        self.enabled = bool(node.get_parameter("track_model").value)
        self.tracker = ModelTracker(params, TrackerConfig(sample_period_s=sample_period_s))
        self.tracker.enabled = self.enabled
        self.monitor = HealthMonitor(thresholds_from(node))
        self.errors = PredictionErrorStats()   # since the last status (each report clears it)
        self.samples_observed = 0              # laser samples since start (monotonic)

    def observe(self, measured_m: float, predicted_m: float, voltage_V: float) -> None:
        self.samples_observed += 1
        self.errors.add(measured_m, predicted_m)
        if self.enabled:
            self.tracker.update(measured_m, voltage_V)

    def status(self, t_s: float):
        tr = self.tracker.result()
        report = self.monitor.assess(t_s, tr.ratios if self.enabled else None, self.errors)
        values = [("track_model", str(self.enabled)), ("tracker_updates", tr.updates),
                  ("laser_samples", self.samples_observed)] + report.values
        self.errors.clear()
        return diagnostic_level(report.level), report.message, values
