"""model_node: predicts the displacement from the applied voltage in real time.

Subscribes ``voltage`` (sensor_msgs/BatteryState, the amplifier's applied voltage),
advances the model with the core's predictor (:class:`dea_ros.control.prediction.ModelPredictor`:
the fixed-step RK4 stepper with exact updates at input stamps), and publishes
``displacement_predicted`` (sensor_msgs/Range, m):

* on every voltage message: the model is advanced to the message stamp with the
  previous voltage held (zero-order hold, like the DAQ), the new voltage is
  latched and the prediction is published with the message's stamp (so
  prediction and measurement line up in a bag);
* a timer at ``rate_hz`` keeps publishing with the held voltage (extrapolated,
  stamped "now") when no voltage message came for ``input_timeout_s`` (at least two
  periods): the input stopped, or is slower than that.

Header stamps never go backwards: a prediction is published only if its stamp is later
than the last one published. A voltage message older than an extrapolation already
published (it arrived late) still updates the model exactly (re-integrated from the
previous input), but its prediction is not published: the next one, newer, includes it.
Such inputs are counted (``superseded_inputs`` on /diagnostics); ``input_timeout_s``
(default 50 ms) keeps them rare: inputs delayed less than that are never superseded. If the clock jumps back by
more than ``max_catch_up_s`` (simulated time restarted), the model starts over from there.

Membrane health: model_node also subscribes ``displacement`` (sensor_msgs/Range, the laser) and
publishes a second DiagnosticStatus "<node>: membrane health": the prediction error (measured minus
predicted displacement: mean, RMS, max over each report) and, with ``track_model``, the membrane's
drift tracked online from the applied voltage and the measured displacement, in words with WARN/ERROR
levels (:mod:`.membrane_health`: ``health_*`` parameters; ``health_sample_period_s`` the laser's sample
period). The tracking is position_controller_node's (:class:`dea_ros.control.DriftTracking`: the
:class:`~dea_ros.control.ModelTracker` EKF per laser sample plus the windowed least squares of the last
10 s, absorbed the same way, without the retune), so both nodes report the same drift on the same data.
Each laser sample is paired by stamps with the applied voltage in effect at its stamp (the amplifier's
outputs held from their stamps on, :class:`~dea_ros.control.StampedVoltagePairing`, whatever order the
two topics arrive in), with no further delay (the controller's tracker delays its command by a sample).
The window fit (~0.1 s) never runs in a callback: every ``window_fit_period_s`` (default 2 s) of laser
samples it is handed to ``window_fit_worker`` ('thread', default: a helper thread; 'process': a worker
process started with the node, nice 10; 'off': the EKF alone, slow on k1 and the creep time), and a
fit not back within ``window_fit_timeout_s`` is dropped (counted as ``window_fit_failures``).

Parameters: ``params_file`` (a preset name LP1/A1/A2 or a parameters YAML, e.g.
an identified params.yaml), ``rate_hz``, ``dt_s`` (integration step, default
1/rate_hz), ``max_catch_up_s``, ``input_timeout_s``. Services: ``~/reset`` (std_srvs/Trigger: back to
the static equilibrium at the held voltage), ``~/reload`` (reload params_file).
Falling behind (a tick later than 2 periods, or a catch-up longer than
``max_catch_up_s``) is counted, logged (throttled) and reported on /diagnostics.
"""
from __future__ import annotations

import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import BatteryState, Range
from std_srvs.srv import Trigger

from ..control import ModelPredictor
from ..errors import ParameterError
from ..model import load_parameters
from ..solvers.integrate import RealTimeStepper
from .common import (
    SENSOR_QOS,
    TOPIC_DISPLACEMENT,
    TOPIC_DISPLACEMENT_PREDICTED,
    TOPIC_VOLTAGE,
    declare_float,
    declare_str,
    make_range,
    publish_diagnostic,
    stamp_to_ns,
)
from .membrane_health import ObserverHealth, declare_health_parameters
from .runner import run_node

__all__ = ["ModelNode", "main"]


class ModelNode(Node):
    health = None   # created in __init__; None on a node whose start-up was refused before (destroy_node)

    def __init__(self, **kwargs):
        super().__init__("model_node", **kwargs)
        self.params_file = declare_str(self, "params_file", "A2",
                                       "membrane preset (LP1, A1, A2) or path to a parameters YAML")
        self.rate_hz = declare_float(self, "rate_hz", 1000.0, "publication rate without input, Hz", 1.0, 20000.0)
        dt = declare_float(self, "dt_s", 0.0, "RK4 step, s (0: 1/rate_hz)", 0.0, 0.01)
        self.dt_s = dt if dt > 0 else 1.0 / self.rate_hz
        self.max_catch_up_s = declare_float(self, "max_catch_up_s", 1.0,
                                            "longest gap integrated in one go; longer gaps reset the model", 0.0, 60.0)
        self.input_timeout_s = max(2.0 / self.rate_hz, declare_float(
            self, "input_timeout_s", 0.05, "extrapolate (timer) only after this long without voltage input, s "
            "(at least 2/rate_hz)", 0.0, 60.0))
        self.frame_id = declare_str(self, "frame_id", "dea_model", "frame_id of the predictions")
        self.predictor = ModelPredictor(self._load_parameters(self.params_file), self.dt_s, self.max_catch_up_s,
                                        on_gap_reset=self._report_gap_reset)
        declare_health_parameters(self, tracking_default=True)
        self.health_period_s = declare_float(self, "health_sample_period_s", 0.001,
                                             "sample period of the laser (displacement), s", 1e-5, 0.1)
        self.health = ObserverHealth(self, self.predictor.params, self.health_period_s)
        self.superseded_inputs = 0              # inputs older than the last published prediction
        self.last_published_ns: int | None = None
        self.last_tick_ns: int | None = None     # clock at the previous timer tick (detects jumps back)
        self.last_input_ns: int | None = None    # clock when the latest input (or the start) was seen
        self.late_ticks = 0
        self.published = 0
        self.max_compute_s = 0.0
        self.pub = self.create_publisher(Range, TOPIC_DISPLACEMENT_PREDICTED, SENSOR_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(BatteryState, TOPIC_VOLTAGE, self.on_voltage, SENSOR_QOS)
        self.create_subscription(Range, TOPIC_DISPLACEMENT, self.on_displacement, SENSOR_QOS)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.create_service(Trigger, "~/reload", self.on_reload)
        self.timer = self.create_timer(1.0 / self.rate_hz, self.on_timer)
        self.create_timer(1.0, self.publish_diagnostics)
        self.get_logger().info(
            f"model {self.stepper.params.name} from '{self.params_file}', RK4 dt {self.dt_s * 1e3:g} ms, "
            f"publishing {self.pub.topic_name}"
        )

    # ------------------------------------------------------------ model
    @property
    def stepper(self) -> RealTimeStepper:
        """The core's RK4 stepper (inside the predictor)."""
        return self.predictor.stepper

    @property
    def voltage_V(self) -> float:
        """The held voltage, V."""
        return self.predictor.voltage_V

    @staticmethod
    def _load_parameters(source: str):
        try:
            return load_parameters(source)
        except (ParameterError, FileNotFoundError) as exc:
            raise SystemExit(f"model_node: parameter 'params_file': {exc}") from None

    def _report_gap_reset(self, gap_ns: int, voltage_V: float) -> None:
        self.get_logger().warning(
            f"gap of {gap_ns * 1e-9:.3f} s in the voltage input: model reset to equilibrium at "
            f"{voltage_V:.1f} V",
            throttle_duration_sec=5.0,
        )

    def now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def publish_prediction(self, t_ns: int) -> bool:
        """Publish the current state stamped t_ns, unless a prediction at or after t_ns is out already."""
        if self.last_published_ns is not None and t_ns <= self.last_published_ns:
            return False
        self.pub.publish(make_range(self.stepper.displacement_m, t_ns, self.frame_id))
        self.last_published_ns = t_ns
        self.published += 1
        return True

    # --------------------------------------------------------- callbacks
    def on_voltage(self, msg: BatteryState) -> None:
        t0 = time.perf_counter()
        u = float(msg.voltage) if msg.present else 0.0
        if not math.isfinite(u):
            return
        t_ns = stamp_to_ns(msg.header.stamp)
        self.health.voltage(t_ns, u)
        if not self.predictor.input(t_ns, u):
            return
        self.last_input_ns = self.now_ns()
        if not self.publish_prediction(t_ns):
            self.superseded_inputs += 1
        self.max_compute_s = max(self.max_compute_s, time.perf_counter() - t0)

    def on_displacement(self, msg: Range) -> None:
        """A laser sample: the prediction error and the drift tracker (membrane health)."""
        self.health.observe(stamp_to_ns(msg.header.stamp), float(msg.range), self.stepper.displacement_m)

    def on_timer(self) -> None:
        now = self.now_ns()
        previous, self.last_tick_ns = self.last_tick_ns, now
        predictor = self.predictor
        if previous is not None and now < previous - self.max_catch_up_s * 1e9:
            self.get_logger().warning(
                f"clock jumped back by {(previous - now) * 1e-9:.3f} s: model restarted at {self.voltage_V:.1f} V")
            predictor.restart()
            self.health.restart_stamps()
            self.last_published_ns = self.last_input_ns = None
        if predictor.model_time_ns is None:
            predictor.start_clock(now)
            self.last_input_ns = now
            return
        if self.last_input_ns is None:
            self.last_input_ns = now
        quiet_s = (now - self.last_input_ns) * 1e-9
        if quiet_s > self.input_timeout_s and predictor.behind_s(now) > 0.5 / self.rate_hz:
            # no input for a while: extrapolate with the held voltage
            if previous is not None and (now - previous) * 1e-9 > 2.0 / self.rate_hz:
                self.late_ticks += 1  # this tick came more than two periods after the previous one
            predictor.extrapolate(now)
            self.publish_prediction(now)

    def on_reset(self, _req, resp):
        self.predictor.reset()
        resp.success = True
        resp.message = f"model reset to the static equilibrium at {self.voltage_V:.1f} V"
        return resp

    def on_reload(self, _req, resp):
        source = self.get_parameter("params_file").value
        try:
            self.predictor.replace_model(load_parameters(source))
        except (ParameterError, FileNotFoundError, ValueError) as exc:
            resp.success = False
            resp.message = f"params_file '{source}': {exc}"
            return resp
        self.health.close()
        self.health = ObserverHealth(self, self.predictor.params, self.health_period_s)
        resp.success = True
        resp.message = f"loaded {self.stepper.params.name} from '{source}'"
        return resp

    def destroy_node(self):
        if self.health is not None:
            self.health.close()      # the window fit's helper thread or worker process
        return super().destroy_node()

    def publish_diagnostics(self) -> None:
        predictor = self.predictor
        publish_diagnostic(
            self, self.diag_pub, f"{self.get_name()}: model", predictor.params.name,
            DiagnosticStatus.WARN if self.late_ticks or predictor.resets_for_gaps else DiagnosticStatus.OK,
            "falling behind" if self.late_ticks else "ok",
            [("published", self.published), ("late_ticks", self.late_ticks),
             ("resets_for_gaps", predictor.resets_for_gaps), ("stale_inputs", predictor.stale_inputs),
             ("superseded_inputs", self.superseded_inputs),
             ("max_compute_ms", f"{self.max_compute_s * 1e3:.3f}"), ("voltage_V", f"{self.voltage_V:.1f}"),
             ("displacement_m", f"{self.stepper.displacement_m:.9f}")],
        )
        level, message, values = self.health.status(self.now_ns() * 1e-9)
        publish_diagnostic(self, self.diag_pub, f"{self.get_name()}: membrane health", predictor.params.name,
                           level, message, values)


def main(args=None) -> None:
    """``ros2 run dea_ros model_node``."""
    run_node(ModelNode, args)


if __name__ == "__main__":
    main()
