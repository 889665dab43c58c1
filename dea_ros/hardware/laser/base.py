"""Common interface of the laser displacement sensors (real, emulated or mocked).

The DEA rig measures the displacement ``d`` of the mass carried by the membrane
with a laser triangulation sensor. Every backend (the Micro-Epsilon ILD1320 on a
serial port, :class:`~dea_ros.hardware.laser.ild1320_serial.ILD1320Sensor`; the
simulated :class:`~dea_ros.sim.mock_sensor.MockDisplacementSensor`, ...) implements
:class:`DisplacementSensor`, so the ROS node never depends on a particular device.

Units: displacements in metres, times in seconds, rates in hertz.

* :class:`DisplacementReading` -- one sample: ``(acquisition_time_s, value)``
  where ``value`` is a displacement in metres (tare already subtracted) or a
  :class:`MeasurementError` member when the sensor reported an error instead of
  a distance (no target, target out of range, laser off, ...).
* :class:`SensorError` / :class:`SensorDisconnected` -- exceptions raised by the
  backends; ``SensorDisconnected`` means "no usable data stream" (serial port
  error, port vanished, or silence for longer than the backend's timeout) and is
  recoverable with :meth:`DisplacementSensor.reconnect`;
  :class:`SensorConfigurationError` means the connected sensor is not the one the
  configuration describes (model, measuring range, rate): retrying does not help.

This module imports nothing but the standard library.
"""
from __future__ import annotations

import abc
import enum
import math
from typing import NamedTuple

from ...errors import SensorConfigurationError, SensorDisconnected, SensorError

__all__ = [
    "MeasurementError",
    "DisplacementReading",
    "SensorError",
    "SensorDisconnected",
    "SensorConfigurationError",
    "DisplacementSensor",
    "validated_tare_offset_m",
    "validated_measuring_range_m",
    "validated_positive",
]


class MeasurementError(str, enum.Enum):
    """Why a sample carries no displacement (named, never a raw number).

    The names follow the error values of the Micro-Epsilon optoNCDT 1x20 family;
    other backends reuse them with the same meaning.
    """

    #: The configured output data do not fit the baud rate (sensor run-time error).
    DATA_RATE_TOO_HIGH = "data_rate_too_high"
    #: No peak on the detector: no target, too little reflected light.
    NO_PEAK = "no_peak"
    #: Peak before the measuring range: target too close to the sensor.
    TARGET_TOO_CLOSE = "target_too_close"
    #: Peak behind the measuring range: target too far from the sensor.
    TARGET_TOO_FAR = "target_too_far"
    #: The measurement value cannot be calculated.
    CANNOT_CALCULATE = "cannot_calculate"
    #: The peak is too wide (e.g. strongly scattering or tilted target).
    PEAK_TOO_WIDE = "peak_too_wide"
    #: The laser is switched off.
    LASER_OFF = "laser_off"
    #: A raw value that is neither a valid distance nor a documented error code.
    UNKNOWN_CODE = "unknown_code"

    # -- discarded by the backend's plausibility checks (the sensor sent a distance,
    #    but the value cannot be trusted; see :class:`~dea_ros.hardware.laser.plausibility.PlausibilityFilter`)
    #: A distance in the reserve before the start or after the end of the
    #: measuring range (the sensor is not specified there).
    OUTSIDE_MEASURING_RANGE = "outside_measuring_range"
    #: A distance the measured mass cannot have reached from the previous accepted
    #: sample in the time between them (speed limit): a corrupted frame.
    IMPLAUSIBLE_JUMP = "implausible_jump"
    #: A distance off the trend of the previous accepted samples by more than the
    #: mass's largest acceleration allows (acceleration limit): a corrupted frame.
    IMPLAUSIBLE_ACCELERATION = "implausible_acceleration"
    #: The first frame after bytes were lost or corrupted (framing error): it may
    #: be made of random bytes that happen to carry valid flag bits.
    AFTER_FRAMING_ERROR = "after_framing_error"
    #: A distance not yet confirmed by consecutive consistent samples (no trusted
    #: previous value: start of the stream or after a real jump).
    UNCONFIRMED = "unconfirmed"


class _TimedValue(NamedTuple):
    acquisition_time_s: float
    value: float | MeasurementError


class DisplacementReading(_TimedValue):
    """One time-stamped sample, usable as the pair ``(acquisition_time_s, value)``.

    ``acquisition_time_s`` is on the backend's monotonic clock
    (``time.monotonic()`` for the serial and mock backends). ``value`` is the
    displacement in metres with the tare offset subtracted, or a
    :class:`MeasurementError`. ``raw_m`` (an attribute, not part of the pair): for a
    sample the plausibility checks discarded, the displacement it decoded to (tare
    subtracted; NaN otherwise), so that it can be recorded apart without being taken
    for a measurement.
    """

    def __new__(cls, acquisition_time_s: float, value: float | MeasurementError, raw_m: float = math.nan):
        reading = super().__new__(cls, acquisition_time_s, value)
        reading.raw_m = float(raw_m)
        return reading

    @property
    def is_valid(self) -> bool:
        """True when the sample carries a displacement (not an error)."""
        return not isinstance(self.value, MeasurementError)

    @property
    def displacement_m(self) -> float | None:
        """Displacement in metres, or ``None`` for an error sample."""
        return None if isinstance(self.value, MeasurementError) else float(self.value)

    @property
    def error(self) -> MeasurementError | None:
        """The error of an error sample, or ``None`` for a valid one."""
        return self.value if isinstance(self.value, MeasurementError) else None


def validated_positive(name: str, value: float) -> float:
    """``value`` as a positive finite float; ``ValueError`` naming the setting otherwise."""
    number = float(value)
    if not (math.isfinite(number) and number > 0.0):
        raise ValueError(f"{name} must be positive, got {value!r}")
    return number


def validated_measuring_range_m(measuring_range_m: float) -> float:
    """Return ``measuring_range_m`` as a float; raise ``ValueError`` unless it is a positive number of metres."""
    value = float(measuring_range_m)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"measuring range must be a positive number of metres, got {measuring_range_m!r}")
    return value


def validated_tare_offset_m(offset_m: float) -> float:
    """Return ``offset_m`` as a float; raise ``ValueError`` unless it is finite."""
    try:
        value = float(offset_m)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"tare offset must be a number of metres, got {offset_m!r}") from exc
    if not math.isfinite(value):
        raise ValueError(f"tare offset must be finite, got {offset_m!r} m")
    return value


class DisplacementSensor(abc.ABC):
    """Abstract displacement sensor delivering time-stamped batches of samples.

    Lifecycle: ``open()`` -> repeated ``read_batch()`` -> ``close()``; also usable
    as a context manager. ``read_batch`` never blocks for long: it returns what
    has been acquired since the previous call (at most ``max_samples``).
    Readings are displacements minus the software tare offset (see :meth:`tare`).
    """

    @abc.abstractmethod
    def open(self) -> None:
        """Connect to the sensor and start acquisition. Raises :class:`SensorError`."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the sensor; safe to call more than once."""

    @abc.abstractmethod
    def read_batch(self, max_samples: int = 1000) -> list[DisplacementReading]:
        """Return up to ``max_samples`` new readings, oldest first.

        Raises :class:`SensorDisconnected` when the data stream is lost.
        """

    @abc.abstractmethod
    def tare(self) -> float:
        """Software zero: make the current displacement read as 0 m.

        Returns the new tare offset in metres (subtracted from later readings).
        """

    @abc.abstractmethod
    def set_measuring_rate(self, rate_hz: float) -> None:
        """Set the measuring (sampling) rate in Hz; raises ``ValueError`` if unsupported."""

    @abc.abstractmethod
    def measuring_rate(self) -> float:
        """Current measuring rate in Hz."""

    @abc.abstractmethod
    def is_connected(self) -> bool:
        """True while the sensor is open and its data stream is alive."""

    @property
    @abc.abstractmethod
    def tare_offset_m(self) -> float:
        """Current software tare offset in metres (0 when never tared)."""

    @abc.abstractmethod
    def set_tare(self, offset_m: float) -> None:
        """Set the tare offset explicitly (metres); ``0.0`` removes the tare.

        Implementations validate with :func:`validated_tare_offset_m`.
        """

    def diagnostic_counters(self) -> dict[str, int]:
        """Cumulative counters of the backend (bytes and frames discarded, ...), for diagnostics.

        Keys are stable snake_case names; the default backend has none.
        """
        return {}

    def reconnect(self) -> None:
        """Re-establish the connection (default: ``close()`` then ``open()``)."""
        self.close()
        self.open()

    def __enter__(self) -> "DisplacementSensor":
        self.open()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()
