"""The serial-free mock sensor with a lost connection on request (:meth:`PausableMockSensor.pause`).

Load it by path (the suite runs with ``--import-mode=importlib``).
"""
from __future__ import annotations

import math

from dea_ros.errors import SensorDisconnected
from dea_ros.hardware.laser.base import DisplacementReading
from dea_ros.sim.mock_sensor import MockDisplacementSensor

__all__ = ["PausableMockSensor"]


class PausableMockSensor(MockDisplacementSensor):
    """:class:`~dea_ros.sim.mock_sensor.MockDisplacementSensor` whose data stream can go silent."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._paused_until = -math.inf
        self.samples_lost_paused = 0

    def pause(self, seconds: float) -> None:
        """No data for ``seconds``: ``read_batch`` raises :class:`SensorDisconnected`."""
        duration = float(seconds)
        if not (math.isfinite(duration) and duration >= 0.0):
            raise ValueError(f"pause duration must be >= 0 s, got {seconds!r}")
        self._paused_until = self._clock() + duration

    def is_connected(self) -> bool:
        return super().is_connected() and self._clock() >= self._paused_until

    def read_batch(self, max_samples: int = 1000) -> list[DisplacementReading]:
        self._require_open()
        now = self._clock()
        if now < self._paused_until:
            end = self._due_end(now)
            self.samples_lost_paused += max(0, end - self._next)
            self._next = max(self._next, end)
            raise SensorDisconnected(f"mock sensor silent for another {self._paused_until - now:.3f} s")
        return super().read_batch(max_samples)

    def reconnect(self) -> None:
        if self._clock() < self._paused_until:
            raise SensorDisconnected("mock sensor still silent; reconnect failed")
        super().reconnect()
