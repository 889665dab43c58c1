"""The laser displacement sensor: its interface and the Micro-Epsilon ILD1320 (no ROS).

* :mod:`.base`: :class:`DisplacementSensor`, the interface every backend implements, and its
  samples (:class:`DisplacementReading`, :class:`MeasurementError`);
* :mod:`.ild1320_protocol`: the ILD1320's RS422 protocol, pure and unit-tested (frames,
  ASCII commands, the connected sensor against the configuration);
* :mod:`.plausibility`: the checks every decoded distance passes (the stream has no checksum);
* :mod:`.sample_clock`: acquisition times reconstructed from the measuring rate and the
  arrival times (the sensor sends no time stamps);
* :mod:`.ild1320_serial`: the ILD1320 over a serial port (imports pyserial: import it where a
  serial sensor is used).

The simulated sensors (the ILD1320 emulator on a pseudo-terminal, the serial-free mock
sensor) are in :mod:`dea_ros.sim`.
"""
from .base import (
    DisplacementReading,
    DisplacementSensor,
    MeasurementError,
    SensorConfigurationError,
    SensorDisconnected,
    SensorError,
    validated_measuring_range_m,
    validated_tare_offset_m,
)

__all__ = [
    "MeasurementError", "DisplacementReading", "SensorError", "SensorDisconnected", "SensorConfigurationError",
    "DisplacementSensor", "validated_tare_offset_m", "validated_measuring_range_m",
]
