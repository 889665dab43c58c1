"""The mock amplifier link: voltages as UDP datagrams to the simulated rig.

:class:`MockAmplifierBackend` sends every written voltage as one datagram to
``127.0.0.1:<port>``, where the simulated rig's output stage
(:class:`~dea_ros.sim.amplifier_receiver.MockAmplifierReceiver`) applies it.

UDP datagram format (network byte order, 32 bytes)::

    magic      4s   b"DEAV"
    session    u32  random per sending backend (a restarted sender is recognised)
    sequence   u64  0, 1, 2, ... per session
    voltage_V  f64  high voltage to apply, V
    sent_s     f64  time.monotonic() of the sender at sending, s
"""
from __future__ import annotations

import math
import secrets
import socket
import struct
import time
from dataclasses import dataclass
from typing import Callable

from ...errors import AmplifierBackendError
from .base import AmplifierBackend

__all__ = [
    "DATAGRAM_MAGIC",
    "DATAGRAM_SIZE",
    "DEFAULT_MOCK_PORT",
    "VoltageDatagram",
    "encode_voltage_datagram",
    "decode_voltage_datagram",
    "MockAmplifierBackend",
]

DATAGRAM_MAGIC = b"DEAV"
_DATAGRAM = struct.Struct("!4sIQdd")
DATAGRAM_SIZE = _DATAGRAM.size
#: The mock amplifier's UDP port (amplifier_node ``mock_port``, mock_hardware_node ``amplifier_port``, the
#: launch files' ``amplifier_port``): below every kernel's ephemeral range (Linux 32768-60999) and DDS's
#: ports, so no process's ephemeral socket -- every DDS participant binds some -- can hold it when the mock
#: starts (47650 until session 23 was inside it).
DEFAULT_MOCK_PORT = 5765


@dataclass(frozen=True)
class VoltageDatagram:
    """One decoded datagram of the mock amplifier link."""

    session_id: int
    sequence: int
    voltage_V: float
    sent_monotonic_s: float


def encode_voltage_datagram(
    session_id: int, sequence: int, voltage_V: float, sent_monotonic_s: float
) -> bytes:
    """Pack one datagram (see the module docstring for the layout)."""
    return _DATAGRAM.pack(
        DATAGRAM_MAGIC,
        int(session_id) & 0xFFFFFFFF,
        int(sequence) & 0xFFFFFFFFFFFFFFFF,
        float(voltage_V),
        float(sent_monotonic_s),
    )


def decode_voltage_datagram(data: bytes) -> VoltageDatagram:
    """Unpack one datagram; ValueError for anything that is not a valid one."""
    if len(data) != DATAGRAM_SIZE:
        raise ValueError(f"datagram has {len(data)} bytes, expected {DATAGRAM_SIZE}")
    magic, session_id, sequence, voltage_V, sent_s = _DATAGRAM.unpack(data)
    if magic != DATAGRAM_MAGIC:
        raise ValueError(f"bad magic {magic!r}, expected {DATAGRAM_MAGIC!r}")
    if not math.isfinite(voltage_V) or voltage_V < 0.0:
        raise ValueError(f"voltage {voltage_V} is not a finite value >= 0 V")
    if not math.isfinite(sent_s):
        raise ValueError(f"send time {sent_s} is not finite")
    return VoltageDatagram(session_id, sequence, voltage_V, sent_s)


class MockAmplifierBackend(AmplifierBackend):
    """Sends each written voltage as one UDP datagram to ``host:port``.

    Nothing needs to listen: UDP sends succeed regardless. ``open()`` and
    ``close()`` send 0 V. There is no monitor (``read_monitor_V`` returns None).
    """

    def __init__(
        self,
        port: int,
        host: str = "127.0.0.1",
        max_voltage_V: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(max_voltage_V)
        if isinstance(port, bool) or not isinstance(port, int) or not (1 <= port <= 65535):
            raise AmplifierBackendError(f"field 'port': must be an int in [1, 65535], got {port!r}")
        self._address = (host, port)
        self._clock = clock
        self._session_id = secrets.randbits(32)
        self._sequence = 0
        self._socket: socket.socket | None = None

    @property
    def address(self) -> tuple[str, int]:
        return self._address

    @property
    def session_id(self) -> int:
        return self._session_id

    @property
    def sent_count(self) -> int:
        return self._sequence

    def open(self) -> None:
        if self._is_open:
            return
        try:
            self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        except OSError as exc:
            raise AmplifierBackendError(f"MockAmplifierBackend: cannot create a UDP socket: {exc}") from exc
        self._is_open = True
        try:
            self.write_voltage(0.0)
        except AmplifierBackendError:
            self._close_socket()
            raise

    def _write_validated_V(self, voltage_V: float) -> None:
        assert self._socket is not None
        datagram = encode_voltage_datagram(self._session_id, self._sequence, voltage_V, self._clock())
        try:
            self._socket.sendto(datagram, self._address)
        except OSError as exc:
            raise AmplifierBackendError(
                f"MockAmplifierBackend: sending to {self._address[0]}:{self._address[1]} failed: "
                f"{exc}; check the host and port of the mock hardware node"
            ) from exc
        self._sequence += 1

    def _close_socket(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None
        self._is_open = False

    def close(self) -> None:
        if not self._is_open:
            return
        try:
            self.write_voltage(0.0)
        finally:
            self._close_socket()
