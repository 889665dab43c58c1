"""laser_sensor_node: the Micro-Epsilon optoNCDT ILD1320 laser head on its RS422/USB serial port.

Reads the binary measurement stream in batches (``poll_period_s``), stamps every sample with its
acquisition time (reconstructed from the measuring rate, see
:class:`dea_ros.hardware.ild1320_sensor.SampleClock`) and publishes it on ``displacement``
(sensor_msgs/Range, m, sensor-data QoS). Error values of the sensor (no target, too close,
too far, ...) are counted per kind and not published. A disconnect (serial error or silence)
is reported and the node reconnects with a back-off; the byte stream resynchronises on its
own after corrupted bytes.

Parameters: ``port`` (e.g. /dev/ttyUSB0, or the mock's /tmp/dea_ros_mock_laser), ``baudrate``,
``measuring_rate_hz`` (250, 500, 1000, 2000), ``zero_offset_m`` (the distance reading of the
flat membrane: displacement = reading - zero_offset; -1 keeps the sensor's current tare),
``poll_period_s``, ``backend`` (``ild1320`` or ``mock``). Service ``~/tare``
(std_srvs/Trigger): zero on the current position (averaging).
"""
from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import Range
from std_srvs.srv import Trigger

from ..hardware.laser import SensorDisconnected, SensorError
from .common import (
    SENSOR_QOS,
    TOPIC_DISPLACEMENT,
    declare_float,
    declare_int,
    declare_str,
    make_range,
    publish_diagnostic,
)

__all__ = ["LaserSensorNode", "main"]


class LaserSensorNode(Node):
    def __init__(self, sensor=None, **kwargs):
        super().__init__("laser_sensor_node", **kwargs)
        self.port = declare_str(self, "port", "/dev/ttyUSB0", "serial device of the sensor (RS422/USB adapter)")
        self.baudrate = declare_int(self, "baudrate", 921600, "serial baud rate (factory: 921600)", 9600, 4000000)
        self.rate_hz = declare_float(self, "measuring_rate_hz", 2000.0, "measuring rate: 250, 500, 1000 or 2000 Hz",
                                     250.0, 2000.0)
        self.zero_offset_m = declare_float(self, "zero_offset_m", -1.0,
                                           "reading of the flat membrane, m (-1: keep the current tare)", -1.0, 0.05)
        poll = declare_float(self, "poll_period_s", 0.005, "period of batch reads, s", 0.0005, 0.1)
        backend = declare_str(self, "backend", "ild1320", "ild1320 (serial) or mock (no hardware)")
        self.frame_id = declare_str(self, "frame_id", "dea_laser", "frame_id of the measurements")
        self.range_m = declare_float(self, "measuring_range_m", 10e-3, "measuring range of the head, m", 1e-3, 1.0)
        if sensor is None:
            sensor = self._make_sensor(backend)
        self.sensor = sensor
        self.pub = self.create_publisher(Range, TOPIC_DISPLACEMENT, SENSOR_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_service(Trigger, "~/tare", self.on_tare)
        self.published = 0
        self.error_counts: dict[str, int] = {}
        self.disconnects = 0
        self.reconnect_at = 0.0
        self.backoff_s = 0.5
        self.connected = False
        self.last_error = ""
        self.connect()
        self.create_timer(poll, self.on_poll)
        self.create_timer(1.0, self.publish_diagnostics)

    def _make_sensor(self, backend: str):
        if backend == "ild1320":
            from ..hardware.ild1320_sensor import ILD1320Sensor

            return ILD1320Sensor(self.port, baudrate=self.baudrate, measuring_rate_hz=self.rate_hz)
        if backend == "mock":
            from ..hardware.ild1320_emulator import MockDisplacementSensor

            return MockDisplacementSensor(measuring_rate_hz=self.rate_hz)
        raise SystemExit(f"laser_sensor_node: parameter 'backend': ild1320 or mock, got {backend!r}")

    def connect(self) -> bool:
        try:
            self.sensor.open()
            if self.zero_offset_m >= 0.0:
                self.sensor.set_tare(self.zero_offset_m)
        except (SensorError, OSError, ValueError) as exc:
            self.connected = False
            self.last_error = str(exc)
            self.get_logger().error(f"cannot open the sensor on {self.port}: {exc}; retrying",
                                    throttle_duration_sec=5.0)
            self.reconnect_at = time.monotonic() + self.backoff_s
            self.backoff_s = min(self.backoff_s * 2.0, 5.0)
            return False
        self.connected = True
        self.backoff_s = 0.5
        self.get_logger().info(f"sensor open on {self.port}, {self.sensor.measuring_rate():g} Hz")
        return True

    def on_poll(self) -> None:
        if not self.connected:
            if time.monotonic() >= self.reconnect_at:
                try:
                    self.sensor.close()
                except (SensorError, OSError):
                    pass
                self.connect()
            return
        try:
            batch = self.sensor.read_batch(4096)
        except SensorDisconnected as exc:
            self.connected = False
            self.disconnects += 1
            self.last_error = str(exc)
            self.reconnect_at = time.monotonic() + self.backoff_s
            self.get_logger().error(f"sensor disconnected: {exc}; reconnecting")
            return
        if not batch:
            return
        # acquisition times are on time.monotonic(): map to ROS time once per batch
        offset_s = self.get_clock().now().nanoseconds * 1e-9 - time.monotonic()
        for reading in batch:
            if reading.is_valid:
                t_ns = int(round((reading.acquisition_time_s + offset_s) * 1e9))
                self.pub.publish(make_range(reading.value, t_ns, self.frame_id, -self.range_m, self.range_m))
                self.published += 1
            else:
                key = reading.error.value
                self.error_counts[key] = self.error_counts.get(key, 0) + 1

    def on_tare(self, _req, resp):
        try:
            offset = self.sensor.tare()
        except (SensorError, OSError) as exc:
            resp.success = False
            resp.message = f"tare failed: {exc}"
            return resp
        resp.success = True
        resp.message = f"zero set at reading {offset * 1e3:.6f} mm"
        self.get_logger().info(resp.message)
        return resp

    def publish_diagnostics(self) -> None:
        values = [("published", self.published), ("disconnects", self.disconnects)]
        values += [(f"errors_{k}", v) for k, v in sorted(self.error_counts.items())]
        decoder = getattr(self.sensor, "decoder", None)
        if decoder is not None:
            values += [(attr, getattr(decoder, attr)) for attr in ("invalid_bytes", "frames_dropped", "resyncs")
                       if hasattr(decoder, attr)]
        publish_diagnostic(
            self, self.diag_pub, f"{self.get_name()}: ILD1320", self.port,
            DiagnosticStatus.OK if self.connected else DiagnosticStatus.ERROR,
            "streaming" if self.connected else f"disconnected: {self.last_error}", values,
        )

    def shutdown_safely(self) -> None:
        try:
            self.sensor.close()
        except (SensorError, OSError):
            pass


def main(args=None) -> None:
    from .runner import run_node

    run_node(LaserSensorNode, args)


if __name__ == "__main__":
    main()
