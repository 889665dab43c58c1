"""position_controller_node: commands the mass by displacement with the identified model inside.

A lifecycle node (``ros2 lifecycle set /dea/position_controller_node configure|activate|...``);
unconfigured and inactive it publishes nothing. Active, on every laser sample it runs one step of
:class:`dea_ros.control.PositionController` (model feedforward + PID on u^2) and publishes the
voltage for amplifier_node, whose safety limits (maximum, slew, watchdog) still apply.

Topics (relative: namespace ``/dea`` in the launch files; SI units):

* subscribes ``displacement`` (sensor_msgs/Range, ``range`` in m, + downwards, stamped with the
  acquisition time): the measurement; the control step runs in its callback, on the newest sample
  only (best effort, depth 1: a late node skips samples instead of acting on old ones; counted as
  ``skipped_samples``);
* subscribes ``displacement_setpoint`` (std_msgs/Float64, m): a target position, answered at once --
  within 2 um of the reachable range's ends (or beyond them by at most that) clamped to the usable range,
  further out refused with the range in the message -- and shaped by the sample loop (one planner
  check per sample, the current reference held meanwhile) into the fastest move the actuator can follow;
  samples flagged implausible by the laser node (``range`` NaN) or outside [min_range, max_range] are
  skipped (``invalid_samples``), and the controller never (re)starts on a reading far outside its range
  (``implausible_starts``);
* subscribes ``joint_trajectory`` (trajectory_msgs/JointTrajectory, one prismatic joint
  ``joint_name``, positions in m = displacement): followed through its points (C^2 spline or quintic
  Hermite segments); refused as a whole when the actuator cannot follow it; an empty trajectory
  stops at the current reference;
* subscribes ``joint_commands_topic`` (default ``joint_commands``; sensor_msgs/JointState as ros2_control's
  topic-based hardware interfaces publish it at the controller manager's rate: joint ``joint_name``,
  position = d in m, velocity in m/s used as feedforward when present): each sample becomes the
  reference (:class:`dea_ros.control.StreamedReference`: followed when the actuator can, shaped like
  a setpoint when it jumps, refused outside the range; NaN commands, sent before a controller claims
  the joint, are ignored and counted);
* publishes ``voltage_cmd`` (std_msgs/Float64, V), ``joint_states`` (sensor_msgs/JointState, the
  measured position in m and a filtered velocity in m/s, at ``joint_states_rate_hz``) and the
  tracking error and state on ``/diagnostics``; with ``publish_stamped_command`` also
  ``~/command_stamped`` (sensor_msgs/BatteryState: the command in ``voltage``, stamped with the
  acquisition time of the sample it answers; for latency measurements and bags); with
  ``lockstep_ack`` (simulated time) ``~/tick_done`` (std_msgs/Header) after each command, so that
  mock_hardware_node's lockstep waits for the controller as it does for the identifier.

Loss of the laser stream for ``sensor_timeout_s``: the node stops commanding (the amplifier's
watchdog then ramps the voltage down), aborts a running trajectory and reports ERROR; when samples
come back it restarts from the measured position and moves to the setpoint it was heading for (a
setpoint being planned or moved to survives the dropout; an aborted trajectory: the reference it held).

Parameters: ``params_file`` (the identifier's params.yaml or a preset), ``margin`` /
``max_voltage_V`` (as amplifier_node: the controller never commands more), ``slew_rate_V_per_s``
(the amplifier's), ``sample_period_s``, ``loop_delay_s``, ``max_sensitivity``,
``max_noise_gain`` (feedback design rule), ``min_move_time_s``, ``feedforward``, ``feedback``,
``sensor_timeout_s``, ``joint_name``, ``joint_commands_topic``, ``joint_states_rate_hz``, ``autostart``;
membrane health (:mod:`.membrane_health`): ``track_model`` (online tracking of the membrane's drift; the
feedforward and the gains follow the tracked model; false: the identified model throughout),
``retune_worker`` ('process': the window fit and gain design run in a worker process started at configure,
off the control loop's GIL, replaced when it dies or is later than ``retune_timeout_s``: no retune that time,
counted as ``retune_failures``; 'thread': in a thread of the node; 'off'), ``retune_worker_nice``,
``health_warn_scale``, ``health_error_scale``, ``health_prediction_warn_m``, ``health_prediction_error_m``,
``health_persistence_s``. The second DiagnosticStatus "<node>: membrane health" says what changed in words,
with the tracked ratios and the reachable range.
"""
from __future__ import annotations

import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import BatteryState, JointState, Range
from std_msgs.msg import Float64, Header
from trajectory_msgs.msg import JointTrajectory

from ..control import (
    ControllerConfig,
    PositionController,
    SampleStream,
    StreamedReference,
    TrackingWindow,
    UnreachableReferenceError,
    trajectory_from_points,
)
from ..errors import ParameterError, SafetyConfigError
from ..model import load_parameters
from .common import (
    COMMAND_QOS,
    SENSOR_QOS,
    TOPIC_DISPLACEMENT,
    TOPIC_VOLTAGE_CMD,
    declare_bool,
    declare_float,
    declare_str,
    make_voltage_state,
    publish_diagnostic,
    s_to_stamp,
    stamp_to_s,
)
from .joint_commands import parse_joint_command
from .membrane_health import ControllerHealth, declare_health_parameters
from .runner import run_nodes

__all__ = ["PositionControllerNode", "main", "TOPIC_SETPOINT", "TOPIC_TRAJECTORY", "TOPIC_JOINT_STATES"]

#: the control step acts on the newest sample only: a backlog of older samples would only add delay
LATEST_ONLY_QOS = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST, depth=1,
                             durability=DurabilityPolicy.VOLATILE)

TOPIC_SETPOINT = "displacement_setpoint"
TOPIC_TRAJECTORY = "joint_trajectory"
TOPIC_JOINT_STATES = "joint_states"
#: ros2_control's joint commands: the newest one only (the interfaces publish reliable, keep last 1)
JOINT_COMMAND_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=1,
                               durability=DurabilityPolicy.VOLATILE)


class PositionControllerNode(LifecycleNode):
    def __init__(self, **kwargs):
        super().__init__("position_controller_node", **kwargs)
        declare_str(self, "params_file", "A2", "identified parameters YAML (identifier output) or preset LP1/A1/A2")
        declare_float(self, "margin", 0.9, "fraction of the breakdown voltage allowed (as amplifier_node)", 0.05, 1.0)
        declare_float(self, "max_voltage_V", 0.0,
                      "largest command, V (0: margin x breakdown field x thickness; above it is refused)", 0.0, 30000.0)
        declare_float(self, "slew_rate_V_per_s", 100000.0, "the amplifier's slew limit, V/s", 1.0, 1e7)
        declare_float(self, "sample_period_s", 0.001, "laser sample period = control period, s", 1e-5, 0.1)
        declare_float(self, "loop_delay_s", 0.001,
                      "laser acquisition -> voltage applied (latency + amplifier update), s", 0.0, 0.05)
        declare_float(self, "max_sensitivity", 1.6, "feedback design: largest |1/(1+L)|", 1.1, 4.0)
        declare_float(self, "max_noise_gain", 0.2,
                      "feedback design: RMS position error per RMS laser noise", 0.01, 2.0)
        declare_float(self, "min_move_time_s", 0.02, "shortest shaped setpoint move, s", 0.001, 10.0)
        declare_float(self, "feedforward_slew_fraction", 0.9, "share of the slew limit references may use", 0.05, 1.0)
        declare_bool(self, "feedforward", True, "model feedforward (eq. 5 inverted); false: static inverse only")
        declare_bool(self, "feedback", True, "PID on u^2")
        declare_float(self, "sensor_timeout_s", 0.05, "stop commanding after this long without a laser sample, s",
                      0.002, 10.0)
        declare_str(self, "joint_name", "dea_joint", "the prismatic joint (URDF) carried by joint_states/trajectories")
        declare_str(self, "joint_commands_topic", "joint_commands",
                    "sensor_msgs/JointState commands of ros2_control's topic-based hardware interface")
        declare_float(self, "joint_states_rate_hz", 100.0, "joint_states publication rate, Hz", 0.1, 2000.0)
        declare_float(self, "diagnostics_rate_hz", 1.0, "diagnostics rate, Hz", 0.1, 50.0)
        declare_bool(self, "lockstep_ack", False,
                     "simulated time: publish ~/tick_done (std_msgs/Header, the sample's stamp) after each command, "
                     "for mock_hardware_node's lockstep_topics")
        declare_bool(self, "publish_stamped_command", False,
                     "also publish ~/command_stamped (BatteryState: the command stamped with its sample's time)")
        declare_health_parameters(self, tracking_default=True, retunes=True)
        self.ctl: PositionController | None = None
        self.health: ControllerHealth | None = None
        self.active = False
        self.sample_period_s = float(self.p("sample_period_s"))   # (again at configure)
        self._reset_runtime()
        self.voltage_pub = self.joint_pub = self.diag_pub = self.stamped_pub = self.ack_pub = None
        self.own_subs = []
        self.own_timers = []

    # ------------------------------------------------------------------ helpers
    def p(self, name):
        return self.get_parameter(name).value

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _reset_runtime(self) -> None:
        self.state = "inactive"
        self.stream = SampleStream(self.sample_period_s)   # the laser samples (control/monitor)
        self.window = TrackingWindow()              # tracking error between diagnostics
        self.last_receipt_s: float | None = None    # node clock at the receipt of the latest sample, s
        self.last_output = None
        self.pending_setpoint: float | None = None
        self.resume_target: float | None = None
        self.commands = 0
        self.sensor_losses = 0
        self.refused = 0
        self.last_refusal = ""
        self.last_accept = ""
        self.max_compute_s = 0.0
        self.implausible_starts = 0
        self.joint_stream = StreamedReference()   # ros2_control's joint commands
        self.joint_commands = 0
        self.nan_joint_commands = 0

    def make_config(self, params) -> ControllerConfig:
        """The controller's settings from the parameters (the voltage ceiling from the membrane)."""
        return ControllerConfig.for_membrane(
            params, margin=float(self.p("margin")), max_voltage_V=float(self.p("max_voltage_V")),
            slew_rate_V_per_s=float(self.p("slew_rate_V_per_s")),
            sample_period_s=float(self.p("sample_period_s")),
            loop_delay_s=float(self.p("loop_delay_s")),
            feedforward=bool(self.p("feedforward")),
            feedback=bool(self.p("feedback")),
            max_sensitivity=float(self.p("max_sensitivity")),
            max_noise_gain=float(self.p("max_noise_gain")),
            min_move_time_s=float(self.p("min_move_time_s")),
            feedforward_slew_fraction=float(self.p("feedforward_slew_fraction")),
        )

    # --------------------------------------------------------------- lifecycle
    def on_configure(self, state) -> TransitionCallbackReturn:
        source = self.p("params_file")
        try:
            params = load_parameters(source)
            self.ctl = PositionController(params, self.make_config(params))
            self.health = ControllerHealth(self, self.ctl, float(self.p("sample_period_s")))  # starts the worker
        except (ParameterError, FileNotFoundError, SafetyConfigError, ValueError) as exc:
            self.get_logger().error(f"configure failed: parameter 'params_file' ({source!r}), limits or "
                                    f"retune_worker: {exc}")
            self.ctl = None
            return TransitionCallbackReturn.FAILURE
        self.voltage_pub = self.create_lifecycle_publisher(Float64, TOPIC_VOLTAGE_CMD, COMMAND_QOS)
        self.joint_pub = self.create_lifecycle_publisher(JointState, TOPIC_JOINT_STATES, 10)
        self.diag_pub = self.create_lifecycle_publisher(DiagnosticArray, "/diagnostics", 10)
        if self.p("lockstep_ack"):
            self.ack_pub = self.create_lifecycle_publisher(Header, "~/tick_done", 10)
        if self.p("publish_stamped_command"):
            self.stamped_pub = self.create_lifecycle_publisher(BatteryState, "~/command_stamped", SENSOR_QOS)
        # the loop's messages are built once and refilled per sample (a message constructor costs more than
        # the control step's arithmetic: BatteryState ~30 us in rclpy)
        self.cmd_msg = Float64()
        self.stamped_msg = make_voltage_state(0.0, 0, True, "dea_controller")
        self.ack_msg = Header(frame_id=self.get_name())
        self.own_subs = [
            self.create_subscription(Range, TOPIC_DISPLACEMENT, self.on_displacement, LATEST_ONLY_QOS),
            self.create_subscription(Float64, TOPIC_SETPOINT, self.on_setpoint, COMMAND_QOS),
            self.create_subscription(JointTrajectory, TOPIC_TRAJECTORY, self.on_trajectory, COMMAND_QOS),
            self.create_subscription(JointState, self.p("joint_commands_topic"), self.on_joint_command,
                                     JOINT_COMMAND_QOS),
        ]
        self.sample_period_s = float(self.p("sample_period_s"))
        timeout = float(self.p("sensor_timeout_s"))
        self.own_timers = [
            self.create_timer(max(timeout / 4.0, 0.001), self.check_sensor),
            self.create_timer(1.0 / float(self.p("joint_states_rate_hz")), self.publish_joint_state),
            self.create_timer(1.0 / float(self.p("diagnostics_rate_hz")), self.publish_diagnostics),
        ]
        lo, hi = self.ctl.reachable_range_m
        self.get_logger().info(
            f"configured: model {params.name} from '{source}', reachable {lo * 1e6:.1f}-{hi * 1e6:.1f} um "
            f"(0-{self.ctl.max_voltage_V:.0f} V); feedback: {self.ctl.gains.describe()}")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self._reset_runtime()
        self.state = "waiting for the laser"
        self.active = True
        self.get_logger().info("active: holding the first measured position, following setpoints and trajectories")
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.active = False
        if self.ctl is not None:
            self.ctl.stop()
        self.state = "inactive"
        self.get_logger().info("inactive: no commands (the amplifier watchdog ramps the voltage down)")
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self.active = False
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state) -> TransitionCallbackReturn:
        self.active = False
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def _teardown(self) -> None:
        self.active = False
        for t in self.own_timers:
            self.destroy_timer(t)
        for s in self.own_subs:
            self.destroy_subscription(s)
        for pub in (self.voltage_pub, self.joint_pub, self.diag_pub, self.stamped_pub, self.ack_pub):
            if pub is not None:
                self.destroy_publisher(pub)
        self.own_timers, self.own_subs = [], []
        self.voltage_pub = self.joint_pub = self.diag_pub = self.stamped_pub = self.ack_pub = None
        self.ctl = None
        if self.health is not None:
            self.health.close()
            self.health = None

    def shutdown_safely(self) -> None:
        """SIGINT/SIGTERM: stop commanding (the amplifier ramps down on its own)."""
        self.active = False

    # ---------------------------------------------------------------- references
    def _refuse(self, what: str, exc: Exception) -> None:
        self.refused += 1
        self.last_refusal = f"{what}: {exc}"
        # throttled: a robot streaming references at 100 Hz must not flood the log (every refusal is
        # counted and the last one is on /diagnostics)
        self.get_logger().error(f"refused {what}: {exc}", throttle_duration_sec=1.0)

    def _accept(self, text: str) -> None:
        self.last_accept = text
        self.get_logger().info(text, throttle_duration_sec=1.0)  # the last one is on /diagnostics

    def on_setpoint(self, msg: Float64) -> None:
        if not self.active or self.ctl is None:
            return
        target = float(msg.data)
        try:       # answered at once: clamped at the ends or refused with the range; planned by the loop
            if self.ctl.started:
                self._accept(self.ctl.request_setpoint(self._ref_time(), target))
                return
            target, note = self.ctl.clamp_setpoint(target)   # applied when the first plausible sample arrives
            self.pending_setpoint = target
            self._accept(f"setpoint {target * 1e6:.1f} um pending until the laser streams"
                         + (f" ({note})" if note else ""))
        except UnreachableReferenceError as exc:
            self._refuse("setpoint", exc)

    def _ref_time(self) -> float:
        """Time at which a new reference starts, on the controller's time base (the laser stamps).

        The latest sample's stamp plus one period (the next sample); the ROS clock before any sample.
        """
        if self.stream.last_t_s is None:
            return self.now_s()
        return self.stream.last_t_s + self.sample_period_s

    def on_trajectory(self, msg: JointTrajectory) -> None:
        if not self.active or self.ctl is None:
            return
        if not self.ctl.started:
            self._refuse("trajectory", RuntimeError("no laser sample yet: the controller has not started"))
            return
        name = self.p("joint_name")
        names = list(msg.joint_names)
        if name not in names:
            self._refuse("trajectory", ValueError(
                f"joint_names {names} do not contain '{name}' (parameter joint_name); send one prismatic joint"))
            return
        j = names.index(name)
        now = self._ref_time()
        d0, v0, a0 = self.ctl.reference_at(now)
        if len(msg.points) == 0:
            self._accept(self.ctl.set_setpoint(now, d0) + " (empty trajectory: stop)")
            return
        stamp = stamp_to_s(msg.header.stamp)     # ROS time; the laser stamps are on the same clock
        start = now if stamp == 0.0 or stamp < now else stamp
        try:
            points = [_joint_point(k, pt, j, len(names), start) for k, pt in enumerate(msg.points)]
            traj = trajectory_from_points(now, (d0, v0, a0), points)
            self._accept(self.ctl.set_trajectory(now, traj))
        except (ValueError, UnreachableReferenceError) as exc:
            self._refuse("trajectory", exc)

    def on_joint_command(self, msg: JointState) -> None:
        """ros2_control's command (topic-based hardware interface): one sample of a streamed reference."""
        if not self.active or self.ctl is None:
            return
        try:
            cmd = parse_joint_command(msg, self.p("joint_name"))
        except ValueError as exc:
            self._refuse("joint command", exc)
            return
        if cmd is None:
            return                                  # not addressed to this joint
        if not cmd.valid:
            self.nan_joint_commands += 1            # the interface's command before a controller claims the joint
            return
        if not self.ctl.started:
            self._refuse("joint command", RuntimeError("no laser sample yet: the controller has not started"))
            return
        try:
            decision = self.joint_stream.command(self.ctl, self._ref_time(), cmd.position_m, cmd.velocity_m_per_s)
        except UnreachableReferenceError as exc:
            self._refuse("joint command", exc)
            return
        self.joint_commands += 1
        if decision.kind == "shaped":
            self._accept(decision.text)

    # -------------------------------------------------------------------- loop
    def on_displacement(self, msg: Range) -> None:
        if not self.active or self.ctl is None:
            return
        t0 = time.perf_counter()
        d = float(msg.range)
        t = stamp_to_s(msg.header.stamp)
        # NaN: flagged implausible by the laser node; outside [min_range, max_range] (when set): not a measurement
        lo, hi = float(msg.min_range), float(msg.max_range)
        if not self.stream.accept(t, d, *((lo, hi) if hi > lo else (-math.inf, math.inf))):
            return
        self.last_receipt_s = self.now_s()
        if not self.ctl.started and not self._start(t, d):
            return
        out = self.ctl.update(t, d)
        note = self.ctl.take_plan_note()
        if note is not None:           # a setpoint's plan finished in this step
            if note[0]:
                self._accept(note[1])
            else:
                self._refuse("setpoint", note[1])
        self.cmd_msg.data = float(out.voltage_V)
        self.voltage_pub.publish(self.cmd_msg)
        if self.stamped_pub is not None:   # latency measurements, bags: the command with its sample's stamp
            stamped = self.stamped_msg
            stamped.header.stamp = msg.header.stamp
            stamped.voltage = self.cmd_msg.data
            self.stamped_pub.publish(stamped)
        if self.ack_pub is not None:
            self.ack_msg.stamp = msg.header.stamp
            self.ack_pub.publish(self.ack_msg)
        self.health.observe(t, d, out)
        self.commands += 1
        self.last_output = out
        self.window.add(out)
        self.max_compute_s = max(self.max_compute_s, time.perf_counter() - t0)

    def _start(self, t: float, d: float) -> bool:
        """(Re)start on a plausible measurement (False, counted, otherwise); the pending or interrupted
        setpoint is planned by the loop from there."""
        if not self.ctl.plausible_start(d):
            self.implausible_starts += 1
            self.get_logger().warning(f"not (re)starting on the implausible measurement {d * 1e6:.1f} um",
                                      throttle_duration_sec=1.0)
            return False
        held = self.ctl.start(t, d)
        self.state = "tracking"
        target = self.pending_setpoint if self.pending_setpoint is not None else self.resume_target
        self.pending_setpoint = self.resume_target = None
        text = f"started at {d * 1e6:.1f} um (holding {held * 1e6:.1f} um)"
        if target is not None:
            try:
                text += "; " + self.ctl.request_setpoint(t, target)
            except UnreachableReferenceError as exc:
                self._refuse("setpoint", exc)
        self._accept(text)
        return True

    def check_sensor(self) -> None:
        if not self.active or self.ctl is None or not self.ctl.started or self.last_receipt_s is None:
            return
        silent = self.now_s() - self.last_receipt_s
        if silent > float(self.p("sensor_timeout_s")):
            self.resume_target = self.ctl.goal_m(self.stream.last_t_s)   # the setpoint survives the dropout
            self.ctl.stop()
            self.sensor_losses += 1
            self.state = "laser lost: not commanding"
            self.get_logger().error(
                f"no laser sample for {silent * 1e3:.0f} ms (sensor_timeout_s {self.p('sensor_timeout_s')}): "
                "stopped commanding; the amplifier watchdog ramps the voltage down. Resuming when samples return.")
            self.publish_diagnostics()

    # ---------------------------------------------------------------- outputs
    def publish_joint_state(self) -> None:
        stream = self.stream
        if not self.active or self.joint_pub is None or stream.last_t_s is None or self.state != "tracking":
            return
        msg = JointState()
        s_to_stamp(stream.last_t_s, msg.header.stamp)
        msg.name = [self.p("joint_name")]
        msg.position = [float(stream.last_m)]
        msg.velocity = [float(stream.velocity_m_per_s)]
        self.joint_pub.publish(msg)

    def publish_diagnostics(self) -> None:
        if not self.active or self.diag_pub is None or self.ctl is None:
            return
        lo, hi = self.ctl.reachable_range_m
        out = self.last_output
        stream, window = self.stream, self.window
        if self.state.startswith("laser lost"):
            level = DiagnosticStatus.ERROR
        elif self.state != "tracking" or self.refused:
            level = DiagnosticStatus.WARN
        else:
            level = DiagnosticStatus.OK
        message = self.state + (f"; last refusal: {self.last_refusal}" if self.last_refusal else "")
        values = [
            ("state", self.state), ("reference_m", f"{out.reference_m:.9f}" if out else "nan"),
            ("measured_m", f"{stream.last_m:.9f}"), ("error_m", f"{out.error_m:.3e}" if out else "nan"),
            ("rms_error_m", f"{window.rms_m:.3e}"), ("max_abs_error_m", f"{window.max_abs_m:.3e}"),
            ("voltage_V", f"{out.voltage_V:.1f}" if out else "nan"),
            ("u2_feedforward_V2", f"{out.u2_feedforward_V2:.4g}" if out else "nan"),
            ("u2_feedback_V2", f"{out.u2_feedback_V2:.4g}" if out else "nan"),
            ("samples", stream.samples), ("commands", self.commands), ("saturated_commands", window.saturations),
            ("stale_samples", stream.stale), ("skipped_samples", stream.skipped),
            ("invalid_samples", stream.invalid), ("implausible_starts", self.implausible_starts),
            ("joint_commands", self.joint_commands), ("joint_commands_shaped", self.joint_stream.shaped),
            ("nan_joint_commands", self.nan_joint_commands),
            ("sensor_losses", self.sensor_losses), ("refused", self.refused), ("last_refusal", self.last_refusal),
            ("last_accepted", self.last_accept), ("reachable_min_m", f"{lo:.9f}"), ("reachable_max_m", f"{hi:.9f}"),
            ("max_voltage_V", f"{self.ctl.max_voltage_V:.1f}"), ("max_compute_ms", f"{self.max_compute_s * 1e3:.3f}"),
            ("feedback_design", self.ctl.gains.describe()),
        ]
        publish_diagnostic(self, self.diag_pub, f"{self.get_name()}: position control", self.ctl.params.name,
                           level, message, values)
        window.clear()
        if self.health is not None and stream.last_t_s is not None:
            h_level, h_message, h_values = self.health.status(stream.last_t_s, out.reference_m if out else None)
            publish_diagnostic(self, self.diag_pub, f"{self.get_name()}: membrane health", self.ctl.params.name,
                               h_level, h_message, h_values)


def _joint_point(k: int, point, joint: int, n_joints: int, start_s: float) -> tuple:
    """A JointTrajectoryPoint of joint ``joint`` as (time s, position m, velocity or None, acceleration or None)."""
    t = start_s + point.time_from_start.sec + point.time_from_start.nanosec * 1e-9
    if len(point.positions) != n_joints:
        raise ValueError(f"point {k}: {len(point.positions)} positions for {n_joints} joints")
    return (t, float(point.positions[joint]),
            float(point.velocities[joint]) if len(point.velocities) == n_joints else None,
            float(point.accelerations[joint]) if len(point.accelerations) == n_joints else None)


def main(args=None) -> None:
    """``ros2 run dea_ros position_controller_node``; ``-p autostart:=true`` configures and activates."""
    def factory():
        node = PositionControllerNode()
        if node.declare_parameter("autostart", False).value:
            node.trigger_configure()
            node.trigger_activate()
        return node

    run_nodes([factory], args=args if args is not None else sys.argv)


if __name__ == "__main__":
    main()
