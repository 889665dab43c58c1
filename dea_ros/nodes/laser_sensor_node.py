"""laser_sensor_node: the Micro-Epsilon optoNCDT ILD1320 laser head on its RS422/USB serial port.

Reads the binary measurement stream in batches (``poll_period_s``), stamps every sample with its
acquisition time (reconstructed from the measuring rate, see
:class:`dea_ros.hardware.laser.sample_clock.SampleClock`) and publishes it on ``displacement``
(sensor_msgs/Range, m, sensor-data QoS).

On every connect the sensor is checked against the parameters and put into a known state
(:meth:`dea_ros.hardware.laser.ild1320_serial.ILD1320Sensor.open`): another model, a measuring range
other than ``measuring_range_m`` or a rate that is not an ILD1320 rate is refused with the
mismatch in the log and in the diagnostics (nothing is published; the node retries slowly in case
the right head is plugged in); mastering, additional outputs and the hold mode a previous user may
have left are reset and read back. A bad reply never ends the node: it is an error, logged, and
the node reconnects with a back-off.

Every sample passes the plausibility checks of
:class:`dea_ros.hardware.laser.plausibility.PlausibilityFilter` (inside the measuring range, not
right after a framing error, within the speed and acceleration the mass can have: with
``params_file`` set, the limits are derived from the membrane model up to ``max_voltage_V``
(:func:`~dea_ros.hardware.laser.plausibility.motion_limits`, margin ``motion_margin``), otherwise
``max_speed_m_per_s`` alone). A sample the checks discard is published on ``displacement`` with
``range = NaN`` (REP 117: invalid; consumers skip non-finite ranges) and its decoded value on
``displacement_implausible`` (Range, same stamp), so nothing recorded is lost and nothing
fabricated is measured. The sensor's own error values (no target, too close, ...) are not
published. ``/diagnostics`` counts both per reason (``errors_<reason>``, ``implausible``) next to
the backend's byte/frame counters (``bytes_discarded``, ``partial_frames_dropped``, ...).

Parameters (all read-only: what a parameter read reports is what runs): ``port`` (e.g.
/dev/ttyUSB0, or the mock's /tmp/dea_ros_mock_laser), ``baudrate``, ``measuring_rate_hz`` (250,
500, 1000, 2000), ``measuring_range_m`` (of the head: 0.01 for the ILD1320-10), ``zero_offset_m``
(the distance reading of the flat membrane: displacement = reading - zero_offset, applied at the
first connect; -1 keeps the backend's tare; a later ``~/tare`` survives reconnects),
``max_speed_m_per_s``, ``jump_tolerance_m``, ``params_file``, ``max_voltage_V``, ``motion_margin``
(plausibility), ``poll_period_s``, ``backend`` (``ild1320``
or ``mock``), ``frame_id``. Service ``~/tare``
(std_srvs/Trigger): zero on the current position (averaging).
"""
from __future__ import annotations

import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import Range
from std_srvs.srv import Trigger

from ..sim.mock_sensor import MockDisplacementSensor
from ..hardware.laser.ild1320_protocol import ALLOWED_MEASURING_RATES_HZ, validate_measuring_rate_hz
from ..errors import ParameterError
from ..hardware.laser.plausibility import (DEFAULT_JUMP_TOLERANCE_M, DEFAULT_MAX_SPEED_M_PER_S, DEFAULT_MOTION_MARGIN,
                                           motion_limits)
from ..model import load_parameters
from ..hardware.laser.ild1320_serial import ILD1320Sensor
from ..hardware.laser import SensorConfigurationError, SensorDisconnected, SensorError
from .common import (
    SENSOR_QOS,
    TOPIC_DISPLACEMENT,
    TOPIC_DISPLACEMENT_IMPLAUSIBLE,
    declare_float,
    declare_int,
    declare_str,
    make_range,
    publish_diagnostic,
)
from .runner import run_node

__all__ = ["LaserSensorNode", "main"]

#: Back-off between connection attempts, s (doubles up to the maximum).
_BACKOFF_INITIAL_S = 0.5
_BACKOFF_MAX_S = 5.0
#: A sensor that does not match the configuration is retried this slowly.
_MISMATCH_RETRY_S = 10.0
#: Mapping of acquisition times (time.monotonic) to ROS time: a measurement of the offset counts
#: only when the two clock reads were at most this far apart (no preemption between them) ...
_OFFSET_BRACKET_S = 200e-6
#: ... and moves the offset by at most this much per batch (stamps stay increasing: samples are
#: >= 250 us apart), unless it differs by more than _OFFSET_JUMP_S (the ROS clock was set).
_OFFSET_SLEW_S = 20e-6
_OFFSET_JUMP_S = 0.1


class LaserSensorNode(Node):
    def __init__(self, sensor=None, **kwargs):
        super().__init__("laser_sensor_node", **kwargs)
        ro = {"read_only": True}
        self.port = declare_str(self, "port", "/dev/ttyUSB0", "serial device of the sensor (RS422/USB adapter)", **ro)
        self.baudrate = declare_int(self, "baudrate", 921600, "serial baud rate (factory: 921600)", 9600, 4000000,
                                    **ro)
        self.rate_hz = declare_float(self, "measuring_rate_hz", 2000.0, "measuring rate: 250, 500, 1000 or 2000 Hz",
                                     250.0, 2000.0, **ro)
        self.zero_offset_m = declare_float(self, "zero_offset_m", -1.0,
                                           "reading of the flat membrane, m (-1: keep the current tare)", -1.0, 0.05,
                                           **ro)
        poll = declare_float(self, "poll_period_s", 0.005, "period of batch reads, s", 0.0005, 0.1, **ro)
        backend = declare_str(self, "backend", "ild1320", "ild1320 (serial) or mock (no hardware)", **ro)
        self.frame_id = declare_str(self, "frame_id", "dea_laser", "frame_id of the measurements", **ro)
        self.range_m = declare_float(self, "measuring_range_m", 10e-3,
                                     "measuring range of the head, m (ILD1320-10: 0.01); the sensor must report it",
                                     1e-3, 1.0, **ro)
        self.max_speed_m_per_s = declare_float(
            self, "max_speed_m_per_s", DEFAULT_MAX_SPEED_M_PER_S,
            "plausibility: fastest the measured mass can move, m/s (faster jumps are corrupt frames)",
            0.01, 100.0, **ro)
        self.jump_tolerance_m = declare_float(
            self, "jump_tolerance_m", DEFAULT_JUMP_TOLERANCE_M,
            "plausibility: noise allowance added to the speed limit, m", 0.0, 1e-3, **ro)
        self.max_acceleration_m_per_s2 = self._motion_limits(
            declare_str(self, "params_file", "", "plausibility: membrane preset or YAML the speed and acceleration "
                        "limits are derived from ('': max_speed_m_per_s alone)", **ro),
            declare_float(self, "max_voltage_V", 0.0, "plausibility: largest voltage of the rig, V (0: the "
                          "membrane's breakdown voltage, above any amplifier limit)", 0.0, 20000.0, **ro),
            declare_float(self, "motion_margin", DEFAULT_MOTION_MARGIN, "plausibility: factor on the model's limits",
                          1.0, 100.0, **ro))
        try:
            self.rate_hz = validate_measuring_rate_hz(self.rate_hz)
        except ValueError:
            allowed = ", ".join(f"{r:g}" for r in ALLOWED_MEASURING_RATES_HZ)
            raise SystemExit(f"laser_sensor_node: parameter 'measuring_rate_hz' = {self.rate_hz:g} Hz is not an "
                             f"ILD1320 rate; use one of {allowed}") from None
        if sensor is None:
            sensor = self._make_sensor(backend)
        self.sensor = sensor
        self.pub = self.create_publisher(Range, TOPIC_DISPLACEMENT, SENSOR_QOS)
        self.implausible_pub = self.create_publisher(Range, TOPIC_DISPLACEMENT_IMPLAUSIBLE, SENSOR_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_service(Trigger, "~/tare", self.on_tare)
        self.published = 0
        self.implausible = 0
        self.error_counts: dict[str, int] = {}
        self.disconnects = 0
        self.connect_failures = 0
        self.reconnect_at = 0.0
        self.backoff_s = _BACKOFF_INITIAL_S
        self.connected = False
        self.mismatch = False  # the connected sensor does not match the parameters
        self.last_error = ""
        self.time_offset_s = None  # ROS time - time.monotonic(), s
        self.zero_applied = False
        self.connect()
        self.create_timer(poll, self.on_poll)
        self.create_timer(1.0, self.publish_diagnostics)

    def _motion_limits(self, params_file: str, max_voltage_V: float, margin: float):
        """Speed limit from the membrane model (overrides ``max_speed_m_per_s``) and the acceleration limit."""
        if not params_file:
            return None
        try:
            params = load_parameters(params_file)
            max_voltage_V = max_voltage_V or params.breakdown_voltage_V()
            limits = motion_limits(params, max_voltage_V, margin)
        except (ParameterError, FileNotFoundError, ValueError) as exc:
            raise SystemExit(f"laser_sensor_node: parameters 'params_file'/'max_voltage_V': {exc}") from None
        self.max_speed_m_per_s = limits.max_speed_m_per_s
        self.get_logger().info(
            f"plausibility limits from {params_file} up to {max_voltage_V:g} V (margin {margin:g}): "
            f"{limits.max_speed_m_per_s:.3g} m/s, {limits.max_acceleration_m_per_s2:.3g} m/s^2")
        return limits.max_acceleration_m_per_s2

    def _make_sensor(self, backend: str):
        if backend == "ild1320":
            return ILD1320Sensor(self.port, baudrate=self.baudrate, measuring_rate_hz=self.rate_hz,
                                 measuring_range_m=self.range_m, max_speed_m_per_s=self.max_speed_m_per_s,
                                 jump_tolerance_m=self.jump_tolerance_m,
                                 max_acceleration_m_per_s2=self.max_acceleration_m_per_s2)
        if backend == "mock":
            return MockDisplacementSensor(measuring_rate_hz=self.rate_hz, measuring_range_m=self.range_m)
        raise SystemExit(f"laser_sensor_node: parameter 'backend': ild1320 or mock, got {backend!r}")

    def _close_quietly(self) -> None:
        try:
            self.sensor.close()
        except Exception:  # noqa: BLE001 - closing a broken port must not end the node
            pass

    def connect(self) -> bool:
        """Open and check the sensor; on any failure log it, stay alive and retry later."""
        try:
            self.sensor.open()
            if self.zero_offset_m >= 0.0 and not self.zero_applied:
                # once: a tare made later (service ~/tare) survives reconnects
                self.sensor.set_tare(self.zero_offset_m)
                self.zero_applied = True
        except SensorConfigurationError as exc:
            self._connect_failed(exc, "the sensor does not match the parameters", _MISMATCH_RETRY_S)
            self.mismatch = True
            return False
        except Exception as exc:  # noqa: BLE001 - a bad reply (or anything else) must not end the node
            self.mismatch = False
            self._connect_failed(exc, "cannot open the sensor", self.backoff_s)
            self.backoff_s = min(self.backoff_s * 2.0, _BACKOFF_MAX_S)
            return False
        self.connected = True
        self.mismatch = False
        self.backoff_s = _BACKOFF_INITIAL_S
        report = getattr(self.sensor, "connect_report", None)
        for line in (report.lines() if report is not None else []):
            self.get_logger().info(line)
        self.get_logger().info(f"sensor open on {self.port}, {self.sensor.measuring_rate():g} Hz")
        return True

    def _connect_failed(self, exc: Exception, what: str, retry_s: float) -> None:
        self._close_quietly()
        self.connected = False
        self.connect_failures += 1
        kind = "" if isinstance(exc, SensorError) else f"{type(exc).__name__}: "
        self.last_error = f"{what}: {kind}{exc}"
        self.get_logger().error(f"{self.last_error} (port {self.port}); retrying in {retry_s:g} s",
                                throttle_duration_sec=5.0)
        self.reconnect_at = time.monotonic() + retry_s

    def on_poll(self) -> None:
        if not self.connected:
            if time.monotonic() >= self.reconnect_at:
                self._close_quietly()
                self.connect()
            return
        try:
            batch = self.sensor.read_batch(4096)
        except Exception as exc:  # noqa: BLE001 - disconnects, and anything unexpected, end in a reconnect
            self.connected = False
            self.disconnects += 1
            kind = "" if isinstance(exc, SensorDisconnected) else f"{type(exc).__name__}: "
            self.last_error = f"sensor disconnected: {kind}{exc}"
            self.reconnect_at = time.monotonic() + self.backoff_s
            self.get_logger().error(f"{self.last_error}; reconnecting")
            return
        if not batch:
            return
        offset_s = self.update_time_offset()
        for reading in batch:
            t_ns = int(round((reading.acquisition_time_s + offset_s) * 1e9))
            if reading.is_valid:
                self.pub.publish(make_range(reading.value, t_ns, self.frame_id, -self.range_m, self.range_m))
                self.published += 1
                continue
            key = reading.error.value
            self.error_counts[key] = self.error_counts.get(key, 0) + 1
            if math.isfinite(reading.raw_m):  # decoded, then flagged: invalid here, the value kept apart
                self.pub.publish(make_range(math.nan, t_ns, self.frame_id, -self.range_m, self.range_m))
                self.implausible_pub.publish(make_range(reading.raw_m, t_ns, self.frame_id, -self.range_m,
                                                        self.range_m))
                self.implausible += 1

    def update_time_offset(self) -> float:
        """ROS time minus time.monotonic() (s), measured once per batch, filtered.

        Acquisition times are on time.monotonic(). A measurement interrupted between its two clock
        reads (a loaded machine) is ignored, and the offset slews slowly, so the published stamps
        keep the spacing of the acquisition times instead of the jitter of the scheduler.
        """
        bracket, measured = float("inf"), 0.0
        for _ in range(3):  # the tightest of three measurements
            before = time.monotonic()
            ros_s = self.get_clock().now().nanoseconds * 1e-9
            after = time.monotonic()
            if after - before < bracket:
                bracket, measured = after - before, ros_s - 0.5 * (before + after)
        if self.time_offset_s is None:
            self.time_offset_s = measured
        elif bracket <= _OFFSET_BRACKET_S:  # a preempted measurement says nothing
            step = measured - self.time_offset_s
            if abs(step) > _OFFSET_JUMP_S:
                self.time_offset_s = measured
            else:
                self.time_offset_s += max(-_OFFSET_SLEW_S, min(_OFFSET_SLEW_S, step))
        return self.time_offset_s

    def on_tare(self, _req, resp):
        if not self.connected:
            resp.success = False
            resp.message = f"tare failed: sensor not connected ({self.last_error})"
            return resp
        try:
            offset = self.sensor.tare()
        except (SensorError, OSError, ValueError) as exc:
            resp.success = False
            resp.message = f"tare failed: {exc}"
            return resp
        resp.success = True
        resp.message = f"zero set at reading {offset * 1e3:.6f} mm"
        self.get_logger().info(resp.message)
        return resp

    def diagnostic_values(self) -> list[tuple[str, object]]:
        """(key, value) pairs published on /diagnostics: the sensor found at the last connect, node
        counts, discards per reason (``errors_<reason>``) and the backend's byte/frame counters."""
        values: list[tuple[str, object]] = []
        report = getattr(self.sensor, "connect_report", None)
        if report is not None:
            found = report.settings
            values += [("sensor_model", found.model), ("sensor_serial", found.serial_number),
                       ("sensor_measuring_range_mm", "unknown" if found.measuring_range_m is None
                        else f"{found.measuring_range_m * 1e3:g}"),
                       ("reset_on_connect", "; ".join(report.to_reset) or "nothing")]
            values += [(f"mismatch_{i}", text) for i, text in enumerate(report.mismatches)]
        values += [("published", self.published), ("implausible", self.implausible),
                   ("max_speed_m_per_s", f"{self.max_speed_m_per_s:.4g}"),
                   ("max_acceleration_m_per_s2", "none" if self.max_acceleration_m_per_s2 is None
                    else f"{self.max_acceleration_m_per_s2:.4g}"), ("disconnects", self.disconnects),
                   ("connect_failures", self.connect_failures)]
        values += [(f"errors_{k}", v) for k, v in sorted(self.error_counts.items())]
        try:
            counters = self.sensor.diagnostic_counters()
        except Exception:  # noqa: BLE001 - diagnostics must not end the node
            counters = {}
        values += sorted(counters.items())
        return values

    def publish_diagnostics(self) -> None:
        if self.connected:
            level, message = DiagnosticStatus.OK, "streaming"
        elif self.mismatch:
            level, message = DiagnosticStatus.ERROR, f"refused: {self.last_error}"
        else:
            level, message = DiagnosticStatus.ERROR, f"disconnected: {self.last_error}"
        publish_diagnostic(self, self.diag_pub, f"{self.get_name()}: ILD1320", self.port, level, message,
                           self.diagnostic_values())

    def shutdown_safely(self) -> None:
        self._close_quietly()


def main(args=None) -> None:
    """``ros2 run dea_ros laser_sensor_node``."""
    run_node(LaserSensorNode, args)


if __name__ == "__main__":
    main()
