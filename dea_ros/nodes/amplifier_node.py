"""amplifier_node: the high-voltage amplifier, a lifecycle node that is safe by construction.

Lifecycle (``ros2 lifecycle set /amplifier_node configure|activate|deactivate|cleanup``):

* unconfigured -> ``configure``: derives the safety limits, opens the backend (which writes 0 V);
* inactive: output 0 V (after a ramp-down); commands are rejected (counted);
* ``activate``: commands on ``voltage_cmd`` (std_msgs/Float64, V) are followed within the limits;
* ``deactivate`` / ``cleanup`` / ``shutdown`` / SIGINT / SIGTERM: ramp to 0 V.

Every output goes through :class:`dea_ros.hardware.amplifier_safety.SafeVoltageController`:
never above ``max_voltage_V`` (derived from the membrane: margin x breakdown field x
thickness; a configured value above that is refused), never faster than
``slew_rate_V_per_s``, a watchdog ramps to 0 V when commands stop for
``watchdog_timeout_s``, and NaN, inf, negative and out-of-range commands are rejected,
logged (throttled) and counted without moving the output.

Backends (parameter ``backend``): ``mock`` (UDP to mock_hardware_node), ``uldaq``
(Measurement Computing DAQ analog output into the amplifier input, ``amplifier_gain_V_per_V``),
``inprocess`` (tests). The applied voltage is published on ``voltage``
(sensor_msgs/BatteryState, ``voltage`` in V, stamped when applied, ``present`` = output enabled).
"""
from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64

from ..hardware.amplifier_backends import (
    AmplifierBackendError,
    InProcessAmplifierBackend,
    MockAmplifierBackend,
    UldaqAmplifierBackend,
)
from ..hardware.amplifier_safety import SafeVoltageController, SafetyConfigError, SafetyLimits, drive_to_zero
from ..model import ParameterError, load_parameters
from .common import (
    COMMAND_QOS,
    SENSOR_QOS,
    TOPIC_VOLTAGE,
    TOPIC_VOLTAGE_CMD,
    declare_float,
    declare_int,
    declare_str,
    make_voltage_state,
    publish_diagnostic,
)

__all__ = ["AmplifierNode", "main"]


class AmplifierNode(LifecycleNode):
    def __init__(self, **kwargs):
        super().__init__("amplifier_node", **kwargs)
        declare_str(self, "backend", "mock", "mock (UDP to mock_hardware_node), uldaq (MCC DAQ) or inprocess")
        declare_str(self, "params_file", "A2", "membrane (preset or YAML) whose breakdown limit bounds the output")
        declare_float(self, "margin", 0.9, "fraction of the breakdown voltage allowed", 0.05, 1.0)
        declare_float(self, "max_voltage_V", 0.0,
                      "maximum output, V (0: the membrane limit; above it is refused)", 0.0, 30000.0)
        declare_float(self, "slew_rate_V_per_s", 100000.0, "largest rate of change of the output, V/s", 1.0, 1e7)
        declare_float(self, "ramp_down_rate_V_per_s", 10000.0, "rate of every ramp to 0 V, V/s", 1.0, 1e7)
        declare_float(self, "watchdog_timeout_s", 0.5, "ramp to 0 V after this long without a command, s",
                      0.001, 60.0)
        declare_float(self, "update_rate_hz", 1000.0, "output update and publication rate, Hz", 1.0, 20000.0)
        declare_int(self, "mock_port", 47650, "UDP port of mock_hardware_node (backend mock)", 1, 65535)
        declare_str(self, "uldaq_unique_id", "", "DAQ unique id (empty: the first USB device)")
        declare_int(self, "uldaq_channel", 0, "analog output channel", 0, 15)
        declare_float(self, "amplifier_gain_V_per_V", 1000.0, "amplifier gain (TREK 10/10B-HS: 1000)", 1.0, 1e5)
        declare_str(self, "uldaq_range", "UNI10VOLTS", "analog output range (uldaq Range name)")
        self.controller: SafeVoltageController | None = None
        self.backend = None
        self.timer = None
        self.voltage_pub = None
        self.cmd_sub = None
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0, self.publish_diagnostics)
        self.last_rejection_log = 0.0
        self.backend_fault: str | None = None

    # ------------------------------------------------------------------ helpers
    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def p(self, name):
        return self.get_parameter(name).value

    def make_limits(self) -> SafetyLimits:
        membrane = load_parameters(self.p("params_file"))
        configured = float(self.p("max_voltage_V"))
        return SafetyLimits.from_membrane(
            membrane.thickness_m, membrane.breakdown_field_V_per_m, float(self.p("margin")),
            slew_rate_V_per_s=float(self.p("slew_rate_V_per_s")),
            watchdog_timeout_s=float(self.p("watchdog_timeout_s")),
            ramp_down_rate_V_per_s=float(self.p("ramp_down_rate_V_per_s")),
            max_voltage_V=configured if configured > 0 else None,
        )

    def make_backend(self, max_voltage_V: float):
        kind = self.p("backend")
        if kind == "mock":
            if self.get_parameter("use_sim_time").value:
                # simulated time: stamp the datagrams with the ROS (simulated) clock so that the mock
                # applies each voltage at the simulated instant it was applied (lockstep)
                return MockAmplifierBackend(int(self.p("mock_port")), max_voltage_V=max_voltage_V, clock=self.now_s)
            return MockAmplifierBackend(int(self.p("mock_port")), max_voltage_V=max_voltage_V)
        if kind == "inprocess":
            return InProcessAmplifierBackend(max_voltage_V=max_voltage_V)
        if kind == "uldaq":
            return UldaqAmplifierBackend(
                unique_id=self.p("uldaq_unique_id") or None, channel=int(self.p("uldaq_channel")),
                amplifier_gain_V_per_V=float(self.p("amplifier_gain_V_per_V")),
                ao_range=self.p("uldaq_range"), max_voltage_V=max_voltage_V,
            )
        raise ValueError(f"parameter 'backend': mock, uldaq or inprocess, got {kind!r}")

    def write(self, voltage_V: float) -> None:
        try:
            self.backend.write_voltage(voltage_V)
        except AmplifierBackendError as exc:
            self.backend_fault = str(exc)
            self.get_logger().error(f"backend failed: {exc}", throttle_duration_sec=2.0)

    # --------------------------------------------------------------- lifecycle
    def on_configure(self, state) -> TransitionCallbackReturn:
        try:
            limits = self.make_limits()
            self.backend = self.make_backend(limits.max_voltage_V)
            self.backend.open()  # writes 0 V
        except (SafetyConfigError, ParameterError, AmplifierBackendError, ValueError, FileNotFoundError) as exc:
            self.get_logger().error(f"configure failed: {exc}")
            self.backend = None
            return TransitionCallbackReturn.FAILURE
        self.controller = SafeVoltageController(limits)
        self.voltage_pub = self.create_publisher(BatteryState, TOPIC_VOLTAGE, SENSOR_QOS)
        self.cmd_sub = self.create_subscription(Float64, TOPIC_VOLTAGE_CMD, self.on_command, COMMAND_QOS)
        self.timer = self.create_timer(1.0 / float(self.p("update_rate_hz")), self.on_update)
        self.get_logger().info(
            f"configured: backend {self.p('backend')}, max {limits.max_voltage_V:.0f} V "
            f"(membrane limit {limits.membrane_limit_V:.0f} V), slew {limits.slew_rate_V_per_s:g} V/s, "
            f"watchdog {limits.watchdog_timeout_s:g} s"
        )
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.controller.activate(self.now_s())
        self.get_logger().info("active: following voltage_cmd")
        return super().on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.controller.deactivate(self.now_s())  # the update timer ramps the output to 0 V
        self.get_logger().info("inactive: ramping to 0 V")
        return super().on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self.shutdown_safely()
        for attr in ("timer",):
            if getattr(self, attr) is not None:
                self.destroy_timer(self.timer)
                self.timer = None
        if self.cmd_sub is not None:
            self.destroy_subscription(self.cmd_sub)
            self.cmd_sub = None
        if self.voltage_pub is not None:
            self.destroy_publisher(self.voltage_pub)
            self.voltage_pub = None
        self.controller = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self.shutdown_safely()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state) -> TransitionCallbackReturn:
        self.shutdown_safely()
        return TransitionCallbackReturn.SUCCESS

    def shutdown_safely(self) -> None:
        """Blocking ramp to 0 V on the wall clock, then close the backend (SIGINT/SIGTERM/cleanup)."""
        if self.controller is None or self.backend is None or not self.backend.is_open:
            return
        last = drive_to_zero(self.controller, self.write, time.monotonic, time.sleep, period_s=0.002)
        if last != 0.0:
            self.get_logger().error(f"ramp to 0 V did not finish (last output {last:.1f} V)")
        try:
            self.backend.close()  # writes 0 V again
        except AmplifierBackendError as exc:
            self.get_logger().error(f"closing the backend failed: {exc}")
        self.get_logger().info("output at 0 V, backend closed")

    # ---------------------------------------------------------------- callbacks
    def on_command(self, msg: Float64) -> None:
        if self.controller is None:
            return
        result = self.controller.command(msg.data, self.now_s())
        if not result:
            now = time.monotonic()
            if now - self.last_rejection_log > 1.0:
                self.last_rejection_log = now
                self.get_logger().warning(
                    f"rejected voltage_cmd {msg.data!r}: {result.reason}; counts {self.controller.rejected_counts}"
                )

    def on_update(self) -> None:
        if self.controller is None or self.backend is None:
            return
        t = self.now_s()
        u = self.controller.update(t)
        self.write(u)
        if self.voltage_pub is not None:
            self.voltage_pub.publish(make_voltage_state(u, t, self.controller.is_activated))

    def publish_diagnostics(self) -> None:
        if self.controller is None:
            level, message, values = DiagnosticStatus.OK, "unconfigured (0 V)", []
        else:
            values = self.controller.diagnostics(self.now_s()).key_values()
            rejected = sum(self.controller.rejected_counts.values())
            level = DiagnosticStatus.ERROR if self.backend_fault else (
                DiagnosticStatus.WARN if rejected or self.controller.watchdog_trip_count else DiagnosticStatus.OK)
            message = self.backend_fault or f"{self.controller.state.value}, {rejected} rejected commands"
        publish_diagnostic(self, self.diag_pub, f"{self.get_name()}: high voltage", str(self.p("backend")),
                           level, message, values)


def main(args=None) -> None:
    """``ros2 run dea_ros amplifier_node``: configures and, with ``-p autostart:=true``, activates."""
    import sys

    import rclpy

    from .runner import run_nodes

    def factory():
        node = AmplifierNode()
        autostart = node.declare_parameter("autostart", False).value
        if autostart:
            node.trigger_configure()
            node.trigger_activate()
        return node

    run_nodes([factory], args=args if args is not None else sys.argv)
    del rclpy


if __name__ == "__main__":
    main()
