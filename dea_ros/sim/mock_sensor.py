"""A serial-free displacement sensor: the ILD1320's samples without a port (laser_sensor_node's ``mock`` backend).

:class:`MockDisplacementSensor` implements :class:`~dea_ros.hardware.laser.base.DisplacementSensor`
by evaluating a displacement source at the exact sample times, with the ILD1320's quantisation
and error codes (:func:`~dea_ros.hardware.laser.ild1320_protocol.frames.displacement_to_code`).
"""
from __future__ import annotations

import math
import time
from typing import Callable

from ..errors import SensorError
from ..hardware.laser.base import DisplacementReading, DisplacementSensor, MeasurementError, validated_tare_offset_m
from ..hardware.laser.ild1320_protocol.commands import ALLOWED_MEASURING_RATES_HZ
from ..hardware.laser.ild1320_protocol.frames import (
    DEFAULT_MEASURING_RANGE_M,
    code_to_displacement_m,
    displacement_to_code,
)
from .ild1320_device import DisplacementSource, mid_range_source, positive_finite

__all__ = ["MockDisplacementSensor"]


class MockDisplacementSensor(DisplacementSensor):
    """Serial-free sensor: evaluates ``displacement_source`` at the sample times.

    Sample ``k`` is acquired at ``t_0 + k / rate`` on ``clock`` (default
    ``time.monotonic``), where ``t_0`` is the time of :meth:`open` (or of the
    last rate change). :meth:`read_batch` returns the samples acquired since the
    previous call (at most ``max_samples``; at most ``max_backlog_s`` of backlog
    is kept), quantised like the ILD1320 and minus the tare offset.
    """

    def __init__(
        self,
        displacement_source: DisplacementSource | None = None,
        *,
        measuring_rate_hz: float = 2000.0,
        measuring_range_m: float = DEFAULT_MEASURING_RANGE_M,
        allowed_rates_hz: tuple[float, ...] = ALLOWED_MEASURING_RATES_HZ,
        clock: Callable[[], float] = time.monotonic,
        max_backlog_s: float = 1.0,
    ) -> None:
        self._range_m = positive_finite("measuring_range_m", measuring_range_m)
        self._source = displacement_source or mid_range_source(self._range_m)
        if not callable(self._source):
            raise TypeError(f"displacement_source must be callable, got {displacement_source!r}")
        self._allowed = tuple(float(r) for r in allowed_rates_hz)
        self._rate_hz = self._validate_rate(measuring_rate_hz)
        self._clock = clock
        self._max_backlog_s = positive_finite("max_backlog_s", max_backlog_s)
        self._open = False
        self._t0 = 0.0
        self._next = 0
        self._tare_m = 0.0
        self.samples_skipped_backlog = 0

    def _validate_rate(self, rate_hz: float) -> float:
        value = float(rate_hz)
        for allowed in self._allowed:
            if math.isclose(value, allowed, rel_tol=1e-9):
                return allowed
        raise ValueError(f"measuring rate {rate_hz!r} Hz not supported (allowed: {list(self._allowed)} Hz)")

    def _due_end(self, now: float) -> int:
        return max(0, math.floor((now - self._t0) * self._rate_hz) + 1)

    def _value(self, t_s: float) -> float | MeasurementError:
        return code_to_displacement_m(displacement_to_code(self._source(t_s), self._range_m), self._range_m)

    def open(self) -> None:
        self._open = True
        self._t0 = self._clock()
        self._next = 0

    def close(self) -> None:
        self._open = False

    def _require_open(self) -> None:
        if not self._open:
            raise SensorError("mock displacement sensor is not open")

    def is_connected(self) -> bool:
        return self._open

    def read_batch(self, max_samples: int = 1000) -> list[DisplacementReading]:
        if int(max_samples) < 1:
            raise ValueError(f"max_samples must be >= 1, got {max_samples!r}")
        self._require_open()
        now = self._clock()
        end = self._due_end(now)
        backlog_limit = int(self._max_backlog_s * self._rate_hz)
        if end - self._next > backlog_limit:
            skipped = end - self._next - backlog_limit
            self.samples_skipped_backlog += skipped
            self._next += skipped
        stop = min(end, self._next + int(max_samples))
        readings = []
        for k in range(self._next, stop):
            t_s = self._t0 + k / self._rate_hz
            value = self._value(t_s)
            if not isinstance(value, MeasurementError):
                value -= self._tare_m
            readings.append(DisplacementReading(t_s, value))
        self._next = stop
        return readings

    def tare(self, averaging_samples: int = 1) -> float:
        """Zero on the mean of the last ``averaging_samples`` sample values (valid ones)."""
        self._require_open()
        n = int(averaging_samples)
        if n < 1:
            raise ValueError(f"averaging_samples must be >= 1, got {averaging_samples!r}")
        end = self._due_end(self._clock())
        values = [self._value(self._t0 + k / self._rate_hz) for k in range(max(0, end - n), end)]
        valid = [v for v in values if not isinstance(v, MeasurementError)]
        if not valid:
            raise SensorError(f"tare failed: none of the last {n} samples is a valid displacement")
        self._tare_m = math.fsum(valid) / len(valid)
        return self._tare_m

    @property
    def tare_offset_m(self) -> float:
        return self._tare_m

    def set_tare(self, offset_m: float) -> None:
        self._tare_m = validated_tare_offset_m(offset_m)

    def set_measuring_rate(self, rate_hz: float) -> None:
        """Change the rate; samples due but not yet read at the old rate are dropped."""
        rate = self._validate_rate(rate_hz)
        if self._open:
            last_t = self._t0 + (self._next - 1) / self._rate_hz
            self._t0 = max(self._clock(), last_t) + 1.0 / rate
            self._next = 0
        self._rate_hz = rate

    def measuring_rate(self) -> float:
        return self._rate_hz
