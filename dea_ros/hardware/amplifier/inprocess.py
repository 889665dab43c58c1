"""The in-process amplifier backend: an ideal amplifier in memory (unit tests, single-process demos)."""
from __future__ import annotations

import collections

from ...errors import AmplifierBackendError
from .base import AmplifierBackend

__all__ = ["InProcessAmplifierBackend"]


class InProcessAmplifierBackend(AmplifierBackend):
    """Stores the written voltage; its 'monitor' reads it back (ideal amplifier)."""

    def __init__(self, max_voltage_V: float | None = None, history_length: int = 10_000) -> None:
        super().__init__(max_voltage_V)
        if not isinstance(history_length, int) or history_length < 0:
            raise AmplifierBackendError(
                f"field 'history_length': must be an int >= 0, got {history_length!r}"
            )
        self._voltage_V = 0.0
        self._history: collections.deque[float] = collections.deque(maxlen=history_length)
        self._open_count = 0
        self._close_count = 0

    @property
    def voltage_V(self) -> float:
        """The voltage the ideal amplifier presently outputs, V."""
        return self._voltage_V

    @property
    def history_V(self) -> list[float]:
        """The most recent written voltages, oldest first (includes the 0 V of open/close)."""
        return list(self._history)

    @property
    def open_count(self) -> int:
        return self._open_count

    @property
    def close_count(self) -> int:
        return self._close_count

    def open(self) -> None:
        if self._is_open:
            return
        self._is_open = True
        self._open_count += 1
        self.write_voltage(0.0)

    def _write_validated_V(self, voltage_V: float) -> None:
        self._voltage_V = voltage_V
        self._history.append(voltage_V)

    def read_monitor_V(self) -> float | None:
        return self._voltage_V if self._is_open else None

    @property
    def has_monitor(self) -> bool:
        return True

    def close(self) -> None:
        if not self._is_open:
            return
        try:
            self.write_voltage(0.0)
        finally:
            self._is_open = False
            self._close_count += 1
