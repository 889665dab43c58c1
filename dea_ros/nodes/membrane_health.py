"""Node side of membrane health and online model tracking (position_controller_node, model_node).

The nodes declare the parameters (:func:`declare_health_parameters`), feed every sample through
:class:`ControllerHealth` (the controller's tracker and retuning) or :class:`ObserverHealth`
(model_node: the same tracker and window fit on applied voltage and measured displacement, without the
retune, and the prediction error), and
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
    DriftTracking,
    HealthMonitor,
    HealthThresholds,
    APPLIED_VOLTAGE_DELAY_SAMPLES,
    PredictionErrorStats,
    StampedVoltagePairing,
    TrackerConfig,
)
from ..errors import ParameterError
from .common import declare_bool, declare_float, declare_int, declare_str

__all__ = ["declare_health_parameters", "ControllerHealth", "ObserverHealth", "diagnostic_level"]


def declare_health_parameters(node, tracking_default: bool, retunes: bool = False) -> None:
    declare_bool(node, "track_model", tracking_default,
                 "track the membrane's drift online (electrostatic gain, stiffness, creep time)"
                 + ("; the controller's feedforward and gains follow it" if retunes else ""))
    if not retunes:   # model_node: the controller's window fit, without its retune
        declare_str(node, "window_fit_worker", "thread",
                    "where the window fit of the tracked drift runs: 'thread' (a helper thread of the node), "
                    "'process' (a worker process started with the node), 'off' (the EKF alone)")
        declare_float(node, "window_fit_period_s", 2.0,
                      "a window fit every this many seconds of laser samples (as the controller's retune), s",
                      0.1, 600.0)
        declare_float(node, "window_fit_timeout_s", 10.0,
                      "a window fit not done within this time is dropped (process: the worker replaced), s",
                      0.05, 600.0)
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

    Raises ParameterError (a ValueError) for an unknown ``retune_worker``.
    """

    def __init__(self, node, ctl, sample_period_s: float):
        p = node.get_parameter
        self.enabled = bool(p("track_model").value)
        self.adaptive = AdaptiveModel(ctl, TrackerConfig(sample_period_s=sample_period_s), enabled=self.enabled)
        self.monitor = HealthMonitor(thresholds_from(node))
        mode = str(p("retune_worker").value)
        if mode not in RETUNE_MODES:
            raise ParameterError(f"parameter 'retune_worker': one of {', '.join(RETUNE_MODES)}, got {mode!r}")
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
    """model_node: the drift tracked on (measured d, applied voltage) with the controller's window fit
    (:class:`DriftTracking` off the callback: :class:`BackgroundRetune`), and the prediction error statistics.

    Each laser sample is paired by stamps with the applied voltage in effect at its stamp
    (:class:`StampedVoltagePairing`: the amplifier's outputs held from their stamps on), so the tracker has
    ``voltage_delay_samples`` 0 (:data:`APPLIED_VOLTAGE_DELAY_SAMPLES`), not the controller's 1 (its command
    acts a sample later). Raises ParameterError (a ValueError) for an unknown ``window_fit_worker``.
    """

    def __init__(self, node, params, sample_period_s: float):
        p = node.get_parameter
        self.enabled = bool(p("track_model").value)
        self.sample_period_s = float(sample_period_s)
        config = TrackerConfig(sample_period_s=sample_period_s, voltage_delay_samples=APPLIED_VOLTAGE_DELAY_SAMPLES)
        self.tracking = DriftTracking(params, config, float(p("window_fit_period_s").value), enabled=self.enabled)
        mode = str(p("window_fit_worker").value)
        if mode not in RETUNE_MODES:
            raise ParameterError(f"parameter 'window_fit_worker': one of {', '.join(RETUNE_MODES)}, got {mode!r}")
        self.fits = BackgroundRetune(self.tracking, mode, float(p("window_fit_timeout_s").value), nice=10)
        self.monitor = HealthMonitor(thresholds_from(node))
        self.errors = PredictionErrorStats()   # since the last status (each report clears it)
        self.pairing = StampedVoltagePairing()
        self.samples_observed = 0              # laser samples since start (monotonic)
        self.samples_tracked = 0               # of them paired with their voltage and handed to the tracker
        self.logger = node.get_logger()
        self.failures_logged = 0

    @property
    def tracker(self):
        return self.tracking.tracker

    def voltage(self, t_ns: int, voltage_V: float) -> None:
        """An applied voltage (the amplifier's output, V), stamped t_ns when applied (kept only when tracking)."""
        if self.enabled:
            self._track(self.pairing.add_voltage(t_ns, voltage_V))

    def observe(self, t_ns: int, measured_m: float, predicted_m: float) -> None:
        """A laser sample stamped t_ns: the prediction error now; the tracker once the voltage at t_ns is known."""
        self.samples_observed += 1
        self.errors.add(measured_m, predicted_m)
        if self.enabled:   # without tracking nothing is paired (the laser callback runs at up to 2 kHz)
            self._track(self.pairing.add_sample(t_ns, measured_m))

    def restart_stamps(self) -> None:
        """The clock jumped back: forget the buffered stamps (the tracker keeps its estimate)."""
        self.pairing.clear()

    def _track(self, pairs) -> None:
        """The tracker's clock is the sample count (laser stamps may jump, its period does not)."""
        fits = self.fits
        for measured_m, voltage_V in pairs:
            self.samples_tracked += 1
            fits.observe(self.samples_tracked * self.sample_period_s, measured_m, voltage_V)
        if fits.failures != self.failures_logged:        # rare: a dead or late worker
            self.failures_logged = fits.failures
            self.logger.warning(f"no window fit this time ({fits.failures} so far): {fits.last_failure}",
                                throttle_duration_sec=5.0)

    def status(self, t_s: float):
        tr = self.tracker.result()
        report = self.monitor.assess(t_s, tr.ratios if self.enabled else None, self.errors)
        values = [("track_model", str(self.enabled)), ("tracker_updates", tr.updates),
                  ("window_fit_worker", self.fits.describe()), ("window_fits", self.fits.applied),
                  ("window_fits_informative", self.tracker.fits), ("window_fit_failures", self.fits.failures),
                  ("laser_samples", self.samples_observed), ("laser_samples_tracked", self.samples_tracked),
                  ("stale_stamps", self.pairing.stale_samples + self.pairing.stale_voltages)] + report.values
        self.errors.clear()
        return diagnostic_level(report.level), report.message, values

    def close(self) -> None:
        self.fits.close()
