"""Interface of the high-voltage amplifier's backends.

Every backend takes the *high voltage* the amplifier should produce (V, e.g. 0-3000 V) and does
whatever drives the amplifier to it:

* :class:`~dea_ros.hardware.amplifier.inprocess.InProcessAmplifierBackend` -- stores the value
  (unit tests, single-process demos);
* :class:`~dea_ros.hardware.amplifier.udp.MockAmplifierBackend` -- sends it as UDP datagrams to
  the simulated rig (:class:`~dea_ros.sim.amplifier_receiver.MockAmplifierReceiver`);
* :class:`~dea_ros.hardware.amplifier.uldaq.UldaqAmplifierBackend` -- a Measurement Computing
  USB DAQ whose analog output drives the amplifier input.

The backends are the last line of defence, not the first: the slew limiting and the watchdog
live in :mod:`dea_ros.hardware.amplifier.safety`. Still, every backend refuses NaN, +-inf,
negative values and values above its ``max_voltage_V`` (when given) with
:class:`AmplifierBackendError`, without writing anything.
"""
from __future__ import annotations

import abc
import math
import numbers
from typing import Any

from ...errors import AmplifierBackendError

__all__ = ["AmplifierBackend", "AmplifierBackendError"]


class AmplifierBackend(abc.ABC):
    """Interface of an amplifier backend.

    ``open()`` before use, ``close()`` at the end (also a context manager).
    ``write_voltage`` validates the value and then calls the subclass's
    :meth:`_write_validated_V`.
    """

    def __init__(self, max_voltage_V: float | None = None) -> None:
        if max_voltage_V is not None:
            if isinstance(max_voltage_V, bool) or not isinstance(max_voltage_V, numbers.Real):
                raise AmplifierBackendError(
                    f"field 'max_voltage_V': must be a number of volts, got {max_voltage_V!r}"
                )
            max_voltage_V = float(max_voltage_V)
            if not (math.isfinite(max_voltage_V) and max_voltage_V > 0.0):
                raise AmplifierBackendError(
                    f"field 'max_voltage_V': must be a finite voltage > 0 V, got {max_voltage_V}"
                )
        self._max_voltage_V = max_voltage_V
        self._is_open = False
        self._last_written_V: float | None = None
        self._write_count = 0

    # ---------------------------------------------------------------- properties
    @property
    def max_voltage_V(self) -> float | None:
        return self._max_voltage_V

    @property
    def is_open(self) -> bool:
        return self._is_open

    @property
    def last_written_V(self) -> float | None:
        """The last high voltage successfully written (None before the first write)."""
        return self._last_written_V

    @property
    def write_count(self) -> int:
        return self._write_count

    # ---------------------------------------------------------------- interface
    @abc.abstractmethod
    def open(self) -> None:
        """Acquire the hardware/socket and set the output to 0 V."""

    @abc.abstractmethod
    def close(self) -> None:
        """Set the output to 0 V and release everything. Safe to call twice."""

    @abc.abstractmethod
    def _write_validated_V(self, voltage_V: float) -> None:
        """Drive the amplifier to ``voltage_V`` (already validated, 0 <= V <= max)."""

    def read_monitor_V(self) -> float | None:
        """The amplifier's voltage monitor, V, or None when this backend has none."""
        return None

    @property
    def has_monitor(self) -> bool:
        """True when :meth:`read_monitor_V` reads a real (or simulated) monitor."""
        return False

    @property
    def has_enable_output(self) -> bool:
        """True when :meth:`set_output_enabled` drives a hardware enable/interlock line."""
        return False

    def set_output_enabled(self, enabled: bool) -> None:
        """Drive the amplifier's enable/interlock line (no-op without one)."""

    def write_voltage(self, voltage_V: float) -> None:
        """Make the amplifier output ``voltage_V`` (high voltage, V)."""
        if not self._is_open:
            raise AmplifierBackendError(
                f"{type(self).__name__}: write_voltage() before open(); call open() first"
            )
        value_V = self._validate_V(voltage_V)
        self._write_validated_V(value_V)
        self._last_written_V = value_V
        self._write_count += 1

    def _validate_V(self, voltage_V: Any) -> float:
        name = type(self).__name__
        if isinstance(voltage_V, bool) or not isinstance(voltage_V, numbers.Real):
            raise AmplifierBackendError(f"{name}: voltage must be a number of volts, got {voltage_V!r}")
        value_V = float(voltage_V)
        if not math.isfinite(value_V):
            raise AmplifierBackendError(
                f"{name}: refusing non-finite voltage {value_V}; nothing was written"
            )
        if value_V < 0.0:
            raise AmplifierBackendError(
                f"{name}: refusing negative voltage {value_V} V; nothing was written"
            )
        if self._max_voltage_V is not None and value_V > self._max_voltage_V:
            raise AmplifierBackendError(
                f"{name}: refusing {value_V} V above max_voltage_V = {self._max_voltage_V} V; "
                "nothing was written (limit the command with SafeVoltageController)"
            )
        return value_V + 0.0

    def __enter__(self) -> "AmplifierBackend":
        self.open()
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.close()
