"""amplifier_node: the high-voltage amplifier, a lifecycle node that is safe by construction.

Lifecycle (``ros2 lifecycle set /amplifier_node configure|activate|deactivate|cleanup``):

* unconfigured -> ``configure``: opens the backend (which writes 0 V) with the limits decided
  at start-up; refuses (stays unconfigured, 0 V) on any configuration or hardware mismatch;
* inactive: output 0 V (after a ramp-down); commands are rejected (counted);
* ``activate``: commands on ``voltage_cmd`` (std_msgs/Float64, V) are followed within the limits;
  with a monitor wired, only after the gain loop check
  (:class:`~dea_ros.hardware.amplifier.gain_check.GainLoopCheck`: ``gain_check_V``, a few tens of
  volts, through the same limits; until it passes commands are rejected and counted; a monitor
  that disagrees is a latched fault at 0 V with the numbers); without a monitor the diagnostics
  say the gain is unverified (README, commissioning: check it with a meter);
* ``deactivate`` / ``cleanup`` / ``shutdown`` / SIGINT / SIGTERM / SIGHUP / SIGQUIT / an
  exception in a callback / executor shutdown: ramp to 0 V.

Start-up, not run time, decides every limit. All parameters are read-only; a set-parameters
callback refuses any change (``use_sim_time`` included) with the reason. The membrane file is
read once, at construction; the voltage ceiling derived then (``enforced_max_voltage_V``, a
read-only parameter reporting what is enforced) is the only one a later configure uses.

Every output goes through :class:`dea_ros.hardware.amplifier.safety.SafeVoltageController`:
never above the ceiling (margin x breakdown field x thickness of the membrane, or the lower
``max_voltage_V``), never faster than ``slew_rate_V_per_s``, a watchdog ramps to 0 V when
commands stop for ``watchdog_timeout_s``, and NaN, inf, negative and out-of-range commands are
rejected, logged (throttled) and counted without moving the output.

Time: slew, ramp and watchdog run on ``time.monotonic`` (the update timer is a steady timer):
no ROS time change can stall or jump them. Simulated time (``use_sim_time``, set at start-up)
is accepted only with the ``mock`` backend; then the update follows the simulated clock (the
mock rig runs lockstep with it), each update advancing the controller by at most one update
period (:class:`~dea_ros.hardware.amplifier.safety.ControlClock`); a clock that advanced 2 to
:data:`MAX_CATCH_UP_UPDATES` periods since the last update (the mock rig's ticks of one batch per
``/clock``) is that many updates, one per period, and a wall-clock backstop
ramps to 0 V when the simulated clock stalls for ``SIM_CLOCK_STALL_S``. In simulated time the node
also acknowledges every ``voltage_cmd`` it receives on ``~/command_received`` (std_msgs/Header
stamped with the simulated time of receipt; nothing else): with that topic in the mock rig's
``lockstep_topics`` the simulated clock does not advance before a command has reached the
amplifier, so a controller's sample -> applied voltage delay is a fixed number of updates.

Batches (simulated time only, ``max_command_batch`` > 0): an open-loop sender (identifier_node's
``command_batch``) may send the voltages of its next K updates as one ``voltage_cmd_batch``
(trajectory_msgs/JointTrajectory: ``header.stamp`` = the simulated time of the next update, point i
at ``time_from_start`` = i update periods, ``positions[0]`` in V). The batch is queued
(:class:`~dea_ros.hardware.amplifier.command_batch.CommandQueue`: at most ``max_command_batch``
samples spanning at most ``watchdog_timeout_s``, for the very next update, only while active) and
each update hands exactly one sample to the same SafeVoltageController as a command (every sample
checked: ceiling, NaN/inf/negative, slew, watchdog). A rejected sample, a single ``voltage_cmd``,
deactivate, cleanup and a fault empty the queue. The batch is acknowledged once on
``~/command_received``, stamped with the update before its last sample's: the mock rig then steps K
ticks per acknowledgement (its lockstep accepts any stamp at or after the tick).

Backends (parameter ``backend``): ``mock`` (UDP to mock_hardware_node), ``uldaq``
(Measurement Computing DAQ analog output into the amplifier input, ``amplifier_gain_V_per_V``;
optionally the amplifier's monitor on an analog input and an enable/interlock digital output),
``inprocess`` (tests). The applied voltage is published on ``voltage``
(sensor_msgs/BatteryState, ``voltage`` in V, stamped when applied, ``present`` = output enabled).
"""
from __future__ import annotations

import functools
import json
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.time import Time
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64, Header
from trajectory_msgs.msg import JointTrajectory

from ..errors import AmplifierBackendError
from ..hardware.amplifier.command_batch import CommandQueue
from ..hardware.amplifier.config import AMPLIFIER_PARAMETERS, amplifier_config_from_parameters
from ..hardware.amplifier.gain_check import GainLoopCheck, unverified_gain_note
from ..hardware.amplifier.inprocess import InProcessAmplifierBackend
from ..hardware.amplifier.rig_description import AmplifierRigExpectation, describe_amplifier_rig
from ..hardware.amplifier.udp import MockAmplifierBackend
from ..hardware.amplifier.uldaq import UldaqAmplifierBackend
from ..errors import SafetyConfigError
from ..hardware.amplifier.limits import SafetyLimits
from ..hardware.amplifier.safety import ControlClock, SafeVoltageController, drive_to_zero
from ..model import ParameterError
from .command_batch_msg import parse_batch
from .common import (
    COMMAND_QOS,
    SENSOR_QOS,
    TOPIC_VOLTAGE,
    TOPIC_VOLTAGE_CMD,
    TOPIC_VOLTAGE_CMD_BATCH,
    make_voltage_state,
    publish_diagnostic,
)
from .runner import run_nodes

__all__ = ["AmplifierNode", "main", "PARAMETERS", "SIM_CLOCK_STALL_S", "MAX_CATCH_UP_UPDATES"]

#: Simulated time: when the simulated clock has not advanced an update for this long on the
#: wall clock, the output is ramped to 0 V on the wall clock (latched until deactivate/activate).
SIM_CLOCK_STALL_S = 2.0

#: Simulated time: a /clock advance of 2 to this many update periods is that many updates (the mock rig's
#: ticks of one batch per /clock, ``max_ticks_per_clock``); a larger jump is one update.
MAX_CATCH_UP_UPDATES = 64

#: name -> (default, description). Every one is read-only: fixed at start-up.
PARAMETERS = AMPLIFIER_PARAMETERS


def _descriptor(description: str) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, read_only=True)


class AmplifierNode(LifecycleNode):
    def __init__(self, **kwargs):
        super().__init__("amplifier_node", **kwargs)
        for name, (default, description) in PARAMETERS.items():
            self.declare_parameter(name, default, _descriptor(description))
        #: the start-up values: the only ones this node ever uses
        self.config = {name: self.get_parameter(name).value for name in PARAMETERS}
        self.sim_time = bool(self.get_parameter("use_sim_time").value)
        self.add_on_set_parameters_callback(self._refuse_parameter_changes)
        self.startup_error: str | None = None
        self.limits: SafetyLimits | None = None
        self.expected: AmplifierRigExpectation | None = None
        try:
            self.limits, self.expected = self._derive_startup_limits()
        except (SafetyConfigError, ParameterError, ValueError, FileNotFoundError) as exc:
            self.startup_error = str(exc)
            self.get_logger().error(f"configuration refused (the node stays at 0 V; fix and restart): {exc}")
        #: the hardware ceiling decided at start-up: nothing at run time raises it
        self.ceiling_V = self.limits.max_voltage_V if self.limits is not None else 0.0
        self.declare_parameter("enforced_max_voltage_V", float(self.ceiling_V), _descriptor(
            "the voltage ceiling enforced, V (decided at start-up; 0: configuration refused)"), ignore_override=True)
        self.declare_parameter("membrane_limit_V", float(self.limits.membrane_limit_V if self.limits else 0.0),
                               _descriptor("margin x breakdown field x thickness of params_file, V"),
                               ignore_override=True)
        self.update_period_s = 1.0 / float(self.config["update_rate_hz"]) if self.limits else 0.001

        self.controller: SafeVoltageController | None = None
        self.control_clock: ControlClock | None = None
        self.backend = None
        self.timer = None
        self.backstop_timer = None
        self.voltage_pub = None
        self.received_pub = None   # simulated time: ~/command_received, for the mock rig's lockstep
        self.cmd_sub = None
        self.batch_sub = None      # simulated time: voltage_cmd_batch
        self.batch_queue: CommandQueue | None = None
        self.fault_reason: str | None = None
        self.backend_fault: str | None = None
        self.last_rejection_log = 0.0
        self.last_update_wall_s = time.monotonic()
        self.stamp_s = 0.0  # time carried by the next datagram (monotonic, or simulated time)
        self.stamp_ros_s: float | int = 0.0  # s (simulated time) or ns (an int: real time)
        self.mono_to_ros_ns = 0
        self.last_sim_s: float | None = None
        self.last_sim_ns: int | None = None   # simulated time of the last update, ns
        self.previous_output_V = 0.0
        self.monitor_V: float | None = None
        self.gain_check: GainLoopCheck | None = None   # running on activation (monitor wired)
        self.gain_status = "not checked"
        self.gain_check_rejections = 0
        self.output_enabled = False
        self.sim_stalls = 0
        self._shutting_down = False
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0, self._guarded(self.publish_diagnostics), clock=self.steady)

    # ------------------------------------------------------------------ start-up
    def _refuse_parameter_changes(self, parameters) -> SetParametersResult:
        for parameter in parameters:
            if not self.has_parameter(parameter.name):
                continue  # a declaration (start-up), not a change
            current = self.get_parameter(parameter.name).value
            return SetParametersResult(successful=False, reason=(
                f"amplifier_node: '{parameter.name}' is fixed at start-up for safety (it stays {current!r}); "
                f"restart the node with --ros-args -p {parameter.name}:=<value> to change it"))
        return SetParametersResult(successful=True)

    def _derive_startup_limits(self) -> tuple[SafetyLimits, AmplifierRigExpectation]:
        config = amplifier_config_from_parameters(self.config, use_sim_time=self.sim_time)
        return config.limits, config.expected

    # ------------------------------------------------------------------ helpers
    def now_s(self) -> float:
        """ROS time, s (stamps only: the safety logic never reads it outside simulated time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def p(self, name):
        return self.config[name] if name in self.config else self.get_parameter(name).value

    def _guarded(self, callback):
        """Any exception in a callback is a fault: ramp to 0 V, disable, close (never a silent death)."""
        @functools.wraps(callback)
        def run(*args):
            try:
                return callback(*args)
            except Exception as exc:  # noqa: BLE001 - every exception must end at 0 V
                self.enter_fault(f"{callback.__name__} raised {type(exc).__name__}: {exc}")
        return run

    def _control_time(self, source: str, sim_ns: int | None = None) -> float:
        """Advance and return the controller's time, s. ``source``: "update" (the update timer) or
        "wall" (shutdown ramps, the stall backstop); ``sim_ns``: the update's simulated time, ns (default:
        the node's clock). Sets the stamp of the next datagram."""
        mono = time.monotonic()
        if self.sim_time and source == "update":
            self.last_sim_ns = self.get_clock().now().nanoseconds if sim_ns is None else int(sim_ns)
            sim = self.last_sim_ns * 1e-9
            self.last_sim_s = self.stamp_ros_s = self.stamp_s = sim
            return self.control_clock.advance(sim, "sim")
        if not self.sim_time:
            self.stamp_s = mono
            # the stamp on `voltage`: ROS time of this very instant (an offset fixed at configure, so
            # the stamped stream keeps the controller's exact time differences, like the mock rig's)
            self.stamp_ros_s = int(round(mono * 1e9)) + self.mono_to_ros_ns  # integer ns: exact differences
        elif self.last_sim_s is not None:
            self.stamp_s = self.last_sim_s
        return self.control_clock.advance(mono, "wall")

    def _datagram_stamp(self) -> float:
        return self.stamp_s

    def make_backend(self):
        c = self.config
        kind = self.expected.backend
        if kind == "mock":
            return MockAmplifierBackend(int(c["mock_port"]), max_voltage_V=self.ceiling_V, clock=self._datagram_stamp)
        if kind == "inprocess":
            return InProcessAmplifierBackend(max_voltage_V=self.ceiling_V)
        e = self.expected
        return UldaqAmplifierBackend(
            unique_id=e.unique_id, channel=e.ao_channel, amplifier_gain_V_per_V=e.amplifier_gain_V_per_V,
            ao_range=e.ao_range, max_voltage_V=self.ceiling_V, amplifier_max_output_V=e.amplifier_max_output_V,
            amplifier_input_full_scale_V=e.amplifier_input_full_scale_V, monitor_channel=e.monitor_channel,
            monitor_gain_V_per_V=e.monitor_gain_V_per_V, monitor_range=e.monitor_range,
            monitor_input_mode=e.monitor_input_mode, enable_port=e.enable_port, enable_bit=e.enable_bit,
            enable_active_high=bool(c["enable_active_high"]), enable_heartbeat=bool(c["enable_heartbeat"]),
        )

    def write(self, voltage_V: float) -> bool:
        """Write to the backend; a failure is a fault (returns False)."""
        try:
            self.backend.write_voltage(voltage_V)
            return True
        except Exception as exc:  # noqa: BLE001 - AmplifierBackendError or anything the driver raises
            self.backend_fault = str(exc)
            self.get_logger().error(f"backend failed: {exc}", throttle_duration_sec=2.0)
            return False

    def _set_enabled(self, enabled: bool) -> None:
        if self.backend is None or not self.backend.is_open or enabled == self.output_enabled:
            return
        self.backend.set_output_enabled(enabled)
        self.output_enabled = enabled

    # --------------------------------------------------------------- lifecycle
    def on_configure(self, state) -> TransitionCallbackReturn:
        if self.startup_error is not None:
            self.get_logger().error(f"configure refused: {self.startup_error} (fix the parameters and restart)")
            return TransitionCallbackReturn.FAILURE
        self.mono_to_ros_ns = self.get_clock().now().nanoseconds - int(round(time.monotonic() * 1e9))
        self.stamp_s = self.now_s() if self.sim_time else time.monotonic()  # of the 0 V written on open
        try:
            backend = self.make_backend()
            backend.open()  # writes 0 V (uldaq: after checking the board against the configuration)
        except (AmplifierBackendError, ValueError, OSError) as exc:
            self.get_logger().error(f"configure failed: {exc}")
            return TransitionCallbackReturn.FAILURE
        description = getattr(backend, "rig_description", None) or describe_amplifier_rig(self.expected, None)
        for line in description.lines():
            self.get_logger().info(line)
        self.backend = backend
        self.fault_reason = self.backend_fault = None
        self.output_enabled = False
        self.previous_output_V = 0.0
        self.monitor_V = None
        if self.expected.monitor_channel is not None:
            problem = self._monitor_problem(0.0, 0.0)
            if problem is not None:
                self.get_logger().error(f"configure failed: with 0 V commanded {problem}")
                self._close_backend()
                return TransitionCallbackReturn.FAILURE
        self.controller = SafeVoltageController(self.limits)
        self.control_clock = ControlClock(max_step_s=self.update_period_s if self.sim_time else None)
        self._control_time("update")
        self._control_time("wall")
        self.voltage_pub = self.create_publisher(BatteryState, TOPIC_VOLTAGE, SENSOR_QOS)
        if self.sim_time:
            self.received_pub = self.create_publisher(Header, "~/command_received", 10)
        self.cmd_sub = self.create_subscription(Float64, TOPIC_VOLTAGE_CMD, self._guarded(self.on_command),
                                                COMMAND_QOS)
        if self.sim_time and int(self.config["max_command_batch"]) > 0:
            self.batch_queue = CommandQueue(int(self.config["max_command_batch"]), self.update_period_s,
                                            self.limits.watchdog_timeout_s)
            self.batch_sub = self.create_subscription(JointTrajectory, TOPIC_VOLTAGE_CMD_BATCH,
                                                      self._guarded(self.on_command_batch), COMMAND_QOS)
        self.last_update_wall_s = time.monotonic()
        if self.sim_time:  # lockstep with the simulated rig; a wall-clock backstop for a stalled clock
            self.timer = self.create_timer(self.update_period_s, self._guarded(self.on_update))
            self.backstop_timer = self.create_timer(0.1, self._guarded(self.on_backstop), clock=self.steady)
        else:
            self.timer = self.create_timer(self.update_period_s, self._guarded(self.on_update), clock=self.steady)
        lim = self.limits
        self.get_logger().info(
            f"configured: backend {self.expected.backend}, ceiling {lim.max_voltage_V:.0f} V (membrane limit "
            f"{lim.membrane_limit_V:.0f} V), slew {lim.slew_rate_V_per_s:g} V/s, watchdog "
            f"{lim.watchdog_timeout_s:g} s, ramp {lim.ramp_down_rate_V_per_s:g} V/s, "
            f"{'simulated' if self.sim_time else 'monotonic'} time")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        if self.fault_reason is not None or self.controller is None or self.backend is None \
                or not self.backend.is_open:
            self.get_logger().error(f"activate refused: faulted ({self.fault_reason}); cleanup and configure")
            return TransitionCallbackReturn.FAILURE
        self.controller.activate(self.control_clock.now_s)
        try:
            self._set_enabled(True)
        except AmplifierBackendError as exc:
            self.enter_fault(f"enable output failed: {exc}")
            return TransitionCallbackReturn.FAILURE
        if self.expected.monitor_channel is not None:
            self.gain_check = self._new_gain_check()
            self.gain_status = f"loop check at {self.gain_check.check_V:.1f} V running"
            self.get_logger().info(f"active: gain loop check at {self.gain_check.check_V:.1f} V before following "
                                   "voltage_cmd")
            return super().on_activate(state)
        if self.expected.backend == "uldaq":
            self.gain_status = unverified_gain_note(self.expected.amplifier_gain_V_per_V)
            self.get_logger().warning(self.gain_status)
        else:
            self.gain_status = f"no gain stage (backend {self.expected.backend}: volts are sent as volts)"
        self.get_logger().info("active: following voltage_cmd")
        return super().on_activate(state)

    def _new_gain_check(self) -> GainLoopCheck:
        c, lim = self.config, self.limits
        check_V = min(float(c["gain_check_V"]), lim.max_voltage_V)
        settle_s = max(float(c["gain_check_settle_s"]), 3.0 * self.update_period_s)
        return GainLoopCheck(check_V, float(c["gain_check_tolerance_fraction"]), settle_s,
                             timeout_s=check_V / min(lim.slew_rate_V_per_s, 1000.0) + settle_s + 1.0,
                             amplifier_gain_V_per_V=self.expected.amplifier_gain_V_per_V,
                             monitor_gain_V_per_V=float(self.expected.monitor_gain_V_per_V))

    def _step_gain_check(self, t: float, u: float) -> bool:
        """One update of the loop check; False when it failed (the node has faulted)."""
        result = self.gain_check.observe(t, u, self.monitor_V)
        if result is None:
            return True
        self.gain_check = None
        self.gain_status = result.message
        if not result.ok:
            self.enter_fault(result.message)
            return False
        self.controller.command(0.0, t)     # leave the check voltage; follow voltage_cmd from here
        self.get_logger().info(f"{result.message}; following voltage_cmd")
        return True

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.gain_check = None
        self._drop_queue()
        if self.controller is not None:
            self.controller.deactivate(self.control_clock.now_s)  # the update timer ramps to 0 V
        self.get_logger().info("inactive: ramping to 0 V")
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self.shutdown_safely()
        for timer in (self.timer, self.backstop_timer):
            if timer is not None:
                self.destroy_timer(timer)
        self.timer = self.backstop_timer = None
        for sub in (self.cmd_sub, self.batch_sub):
            if sub is not None:
                self.destroy_subscription(sub)
        self.cmd_sub = self.batch_sub = self.batch_queue = None
        for pub in (self.voltage_pub, self.received_pub):
            if pub is not None:
                self.destroy_publisher(pub)
        self.voltage_pub = self.received_pub = None
        self.controller = None
        self.backend = None
        self.fault_reason = None  # the next configure checks everything again
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self.shutdown_safely()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state) -> TransitionCallbackReturn:
        self.shutdown_safely()
        return TransitionCallbackReturn.SUCCESS

    # ----------------------------------------------------------- ramps and faults
    def _ramp_to_zero(self) -> float:
        """Blocking ramp to 0 V at the ramp-down rate on the wall clock (controller time)."""
        period = min(0.002, self.update_period_s)
        return drive_to_zero(self.controller, self.write, lambda: self._control_time("wall"), time.sleep,
                             period_s=period)

    def _close_backend(self) -> None:
        backend = self.backend
        if backend is None or not backend.is_open:
            return
        try:
            backend.set_output_enabled(False)
        except Exception as exc:  # noqa: BLE001
            self.get_logger().error(f"disabling the amplifier failed: {exc}")
        self.output_enabled = False
        try:
            backend.close()  # writes 0 V again
        except Exception as exc:  # noqa: BLE001
            self.get_logger().error(f"closing the backend failed: {exc}")

    def shutdown_safely(self) -> None:
        """Ramp to 0 V on the wall clock, disable the amplifier, close the backend (idempotent).

        Called on cleanup, shutdown, errors, every caught signal and executor shutdown.
        """
        self._drop_queue()
        if self._shutting_down or self.controller is None or self.backend is None or not self.backend.is_open:
            return
        self._shutting_down = True
        try:
            last = self._ramp_to_zero()
            if last != 0.0:
                self.get_logger().error(f"ramp to 0 V did not finish (last output {last:.1f} V)")
            self._close_backend()
            self.get_logger().info("output at 0 V, amplifier disabled, backend closed")
        finally:
            self._shutting_down = False

    def enter_fault(self, reason: str) -> None:
        """Latched fault: the enable line drops at once, the output ramps to 0 V, the backend closes.
        Leaves only through cleanup + configure (which checks everything again)."""
        self._drop_queue()
        if self.fault_reason is None:
            self.fault_reason = reason
            self.get_logger().error(f"FAULT: {reason}; ramping to 0 V and disabling the amplifier")
        if self.backend is not None and self.backend.is_open:
            try:
                self.backend.set_output_enabled(False)
                self.output_enabled = False
            except Exception as exc:  # noqa: BLE001
                self.get_logger().error(f"disabling the amplifier failed: {exc}")
        self.shutdown_safely()

    def _monitor_problem(self, commanded_V: float, previous_V: float) -> str | None:
        """Compare the monitor with the command; None when they agree."""
        try:
            monitor_V = self.backend.read_monitor_V()
        except Exception as exc:  # noqa: BLE001
            return f"the amplifier monitor was lost ({exc})"
        if monitor_V is None or not math.isfinite(monitor_V):
            return f"the amplifier monitor was lost (read {monitor_V!r})"
        self.monitor_V = monitor_V
        low, high = min(commanded_V, previous_V), max(commanded_V, previous_V)  # the output moves between them
        tolerance = float(self.config["monitor_tolerance_V"]) + float(self.config["monitor_tolerance_fraction"]) * high
        if low - tolerance <= monitor_V <= high + tolerance:
            return None
        return (f"the amplifier monitor reads {monitor_V:.1f} V while {commanded_V:.1f} V is commanded (tolerance "
                f"{tolerance:.1f} V): amplifier gain slip, wiring or amplifier fault")

    # ---------------------------------------------------------------- callbacks
    def on_command(self, msg: Float64) -> None:
        if self.controller is None:
            return
        if self.gain_check is not None:     # no command is followed before the gain is verified
            self.gain_check_rejections += 1
            return
        self._drop_queue()   # a single command supersedes a queued sequence
        result = self.controller.command(msg.data, self.control_clock.now_s)
        if self.received_pub is not None:  # simulated time: the mock rig's lockstep waits for it
            self.received_pub.publish(Header(stamp=self.get_clock().now().to_msg(), frame_id=self.get_name()))
        if not result:
            self._log_rejection(f"voltage_cmd {msg.data!r}", result.reason)

    def _log_rejection(self, what: str, reason: str) -> None:
        now = time.monotonic()
        if now - self.last_rejection_log > 1.0:
            self.last_rejection_log = now
            self.get_logger().warning(f"rejected {what}: {reason}; counts {self.controller.rejected_counts}, "
                                      f"batches {self.batch_queue.counts() if self.batch_queue else '-'}")

    def _drop_queue(self) -> None:
        if self.batch_queue is not None:
            self.batch_queue.clear()

    def on_command_batch(self, msg: JointTrajectory) -> None:
        """Simulated time: queue the voltages of the next updates (one per update); acknowledge once."""
        if self.controller is None or self.batch_queue is None:
            return
        first_s, offsets, values = parse_batch(msg)   # (malformed: refused whole by the queue)
        verdict = self.batch_queue.offer(first_s, offsets, values, self.last_sim_s,
                                         self.controller.is_activated and self.gain_check is None)
        if self.received_pub is not None:
            self.received_pub.publish(Header(stamp=Time(nanoseconds=self._batch_ack_ns(first_s, len(msg.points)))
                                             .to_msg(), frame_id=self.get_name()))
        if not verdict:
            self._log_rejection(f"voltage_cmd_batch of {len(msg.points)} samples for t = {first_s:.6f} s "
                                f"(last update {self.last_sim_s:.6f} s)", verdict.reason)

    def _batch_ack_ns(self, first_s: float, n_points: int) -> int:
        """The acknowledgement of a batch, ns: the update before its last sample's, counted from the update
        it was sent for (at most the next one), whether it was accepted or not. A refused batch counts as
        that many refused single commands, each of which is acknowledged too: the lockstep goes on (nothing
        of it is applied) and a sender one update late (a race at start-up) is back in step with its next
        batch. The acknowledgement paces the simulation only; it never moves the output."""
        n_updates = min(max(n_points, 1), self.batch_queue.max_length)
        next_s = self.last_sim_s + self.update_period_s
        base_s = min(first_s, next_s) if math.isfinite(first_s) else next_s
        return max(0, int(round((base_s + (n_updates - 2) * self.update_period_s) * 1e9)))

    def on_update(self) -> None:
        """The update timer: one update (real time), or in simulated time one per update period the clock
        advanced since the last (:meth:`_update_times_ns`)."""
        for sim_ns in self._update_times_ns() if self.sim_time else [None]:
            if not self._update_once(sim_ns):
                return

    def _update_times_ns(self) -> list[int]:
        """Simulated time: the updates due since the last one, ns. The mock rig advances ``/clock`` by several
        ticks at once while a batch of commands covers them (its ``max_ticks_per_clock``): each of those ticks
        is an update here, on the update grid, so each batched sample is applied at its own update and passes
        the limits there, and each output goes out stamped with its own time. A jump of more than
        :data:`MAX_CATCH_UP_UPDATES` periods (or backwards) is one update, as any clock jump: the controller's
        time then advances one period at most (ControlClock). None is due when the clock has not moved since
        the last update (rcl calls a timer once more at the instant a jump ends on its grid)."""
        now_ns = self.get_clock().now().nanoseconds
        last_ns = self.last_sim_ns
        period_ns = int(round(self.update_period_s * 1e9))
        n = int(round((now_ns - last_ns) / period_ns)) if last_ns is not None else 1
        if last_ns is not None and 0 <= now_ns - last_ns < period_ns // 2:
            return []
        if not 2 <= n <= MAX_CATCH_UP_UPDATES:
            return [now_ns]
        return [now_ns - (n - 1 - i) * period_ns for i in range(n)]

    def _update_once(self, sim_ns: int | None = None) -> bool:
        """One update of the output (``sim_ns``: its simulated time, ns); False when the node faulted or is
        not running."""
        if self.controller is None or self.backend is None or not self.backend.is_open or self._shutting_down:
            return False
        t = self._control_time("update", sim_ns)
        if self.gain_check is not None:
            self.controller.command(self.gain_check.command_at(t), t)   # through the limits (ceiling, slew)
        elif self.batch_queue is not None and len(self.batch_queue):
            sample_V = self.batch_queue.take(self.last_sim_s)   # this update's sample, as a command
            if sample_V is not None:
                result = self.controller.command(sample_V, t)
                if not result:
                    self._drop_queue()
                    self._log_rejection(f"batched sample {sample_V!r}", result.reason)
        u = self.controller.update(t)
        if not self.write(u):
            self.enter_fault(f"backend write failed: {self.backend_fault}")
            return False
        if self.expected.monitor_channel is not None:
            problem = self._monitor_problem(u, self.previous_output_V)
            if problem is not None:
                if self.gain_check is not None and u > 0.0 and self.monitor_V is not None:   # during the check
                    problem = f"{problem}; {self.gain_check.judge(u, self.monitor_V).message}"
                self.enter_fault(problem)
                return False
            if self.gain_check is not None and not self._step_gain_check(t, u):
                return False
        self.previous_output_V = u
        self._set_enabled(self.controller.is_activated or u > 0.0)
        self.last_update_wall_s = time.monotonic()
        if self.voltage_pub is not None:
            self.voltage_pub.publish(make_voltage_state(u, self.stamp_ros_s, self.controller.is_activated))
        return True

    def on_backstop(self) -> None:
        """Simulated time only: when the simulated clock stalls, ramp to 0 V on the wall clock."""
        if self.controller is None or self.backend is None or not self.backend.is_open:
            return
        stalled_s = time.monotonic() - self.last_update_wall_s
        if stalled_s < SIM_CLOCK_STALL_S or self.controller.output_V == 0.0:
            return  # (at 0 V nothing can rise without an update, i.e. without the simulated clock)
        self.sim_stalls += 1
        self.get_logger().error(
            f"simulated clock stalled for {stalled_s:.1f} s (wall): ramping to 0 V on the wall clock; "
            "deactivate and activate to resume")
        self._ramp_to_zero()
        self.last_update_wall_s = time.monotonic()

    def publish_diagnostics(self) -> None:
        if self.controller is None:
            level = DiagnosticStatus.ERROR if (self.startup_error or self.fault_reason) else DiagnosticStatus.OK
            message = self.startup_error or self.fault_reason or "unconfigured (0 V)"
            values = [("enforced_max_voltage_V", f"{self.ceiling_V:.1f}")]
        else:
            values = self.controller.diagnostics(self.control_clock.now_s).key_values()
            values += [("enforced_max_voltage_V", f"{self.ceiling_V:.1f}"),
                       ("monitor_V", "none" if self.monitor_V is None else f"{self.monitor_V:.1f}"),
                       ("gain", self.gain_status), ("rejected_during_gain_check", str(self.gain_check_rejections)),
                       ("output_enabled", str(self.output_enabled)),
                       ("clock_clamped_steps", str(self.control_clock.clamped_steps)),
                       ("sim_clock_stalls", str(self.sim_stalls))]
            if self.batch_queue is not None:
                values += [("command_batches", json.dumps(self.batch_queue.counts()))]
            rejected = sum(self.controller.rejected_counts.values())
            fault = self.fault_reason or self.backend_fault
            level = DiagnosticStatus.ERROR if fault else (
                DiagnosticStatus.WARN if rejected or self.controller.watchdog_trip_count else DiagnosticStatus.OK)
            message = fault or f"{self.controller.state.value}, {rejected} rejected commands"
        publish_diagnostic(self, self.diag_pub, f"{self.get_name()}: high voltage", str(self.config["backend"]),
                           level, message, values)


def main(args=None) -> None:
    """``ros2 run dea_ros amplifier_node``: configures and, with ``-p autostart:=true``, activates.

    Exits with code 2 (and a message naming the parameter) when the parameters are refused.
    """
    def factory():
        try:
            node = AmplifierNode()
        except (ParameterException, TypeError, ValueError) as exc:
            print(f"amplifier_node: parameter error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        autostart = node.declare_parameter(
            "autostart", False, _descriptor("configure and activate at start (no lifecycle manager)")).value
        if autostart:
            if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                print(f"amplifier_node: configure failed ({node.startup_error or 'see the log'}); nothing was "
                      "applied", file=sys.stderr)
                node.destroy_node()
                raise SystemExit(2)
            node.trigger_activate()
        return node

    run_nodes([factory], args=args if args is not None else sys.argv)


if __name__ == "__main__":
    main()
