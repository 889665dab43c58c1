"""The simulated amplifier's output stage: receives the mock backend's UDP datagrams.

:class:`MockAmplifierReceiver` binds a UDP port and returns the voltages
:class:`~dea_ros.hardware.amplifier.udp.MockAmplifierBackend` sends (datagram format in
:mod:`dea_ros.hardware.amplifier.udp`), with the dead-man interlock of a real rig: the output
drops to 0 V when the datagrams stop.
"""
from __future__ import annotations

import math
import numbers
import random
import select
import socket
import time
from dataclasses import dataclass
from typing import Any, Callable

from ..errors import AmplifierBackendError
from ..hardware.amplifier.udp import DATAGRAM_SIZE, decode_voltage_datagram

__all__ = ["ReceivedVoltage", "MockAmplifierReceiver", "free_udp_port"]

#: Where :func:`free_udp_port` looks: below DDS's ports (7400 + 250 x domain id and up; Fast DDS's
#: participants also take 7000 + n) and below every kernel's ephemeral range (Linux: 32768-60999), so
#: that no process's ``bind(0)`` -- every DDS participant binds two or three -- can take the port
#: between the check and the receiver's bind.
FREE_PORT_RANGE = (4000, 6900)


def free_udp_port(host: str = "127.0.0.1", attempts: int = 200) -> int:
    """A UDP port on ``host`` free now, for a receiver another process will bind a moment later (the
    amplifier's port of ``dea-ros rig``: both the mock and amplifier_node must know it before either
    starts). Drawn at random from :data:`FREE_PORT_RANGE`, where no ephemeral bind lands: a port from
    ``bind(0)``, closed again, is anybody's next ephemeral port until the receiver binds it."""
    rng = random.SystemRandom()
    for _ in range(attempts):
        port = rng.randrange(*FREE_PORT_RANGE)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind((host, port))
            except OSError:
                continue
            return port
    raise AmplifierBackendError(f"free_udp_port: no free UDP port on {host} in {FREE_PORT_RANGE} after "
                                f"{attempts} tries; pass amplifier_port explicitly")


@dataclass(frozen=True)
class ReceivedVoltage:
    """Latest voltage received by :class:`MockAmplifierReceiver`."""

    voltage_V: float
    received_s: float  #: receiver clock (time.monotonic by default) when drained
    sent_s: float  #: sender's time.monotonic() at sending
    sequence: int
    session_id: int


class MockAmplifierReceiver:
    """Binds a UDP port and returns the latest voltage sent by :class:`MockAmplifierBackend`.

    ``port=0`` binds an ephemeral port (read it back from :attr:`port`).
    :meth:`poll` never blocks. Datagrams that are not valid (wrong size, magic,
    non-finite or negative voltage) are counted in :attr:`garbage_count` and
    ignored; a datagram older than the latest of the same sender session
    (reordering) is counted in :attr:`stale_count` and ignored.

    Dead-man: with ``deadman_timeout_s`` the simulated amplifier output
    (:meth:`applied_voltage_V`) drops to 0 V by itself when no valid datagram
    arrived for that long on the receiver's clock, as a real rig's interlock would
    when its controller dies (SIGKILL, power loss, a hung process). A new datagram
    re-arms it.
    """

    #: At most this many datagrams are drained per poll() (a flood cannot stall the caller).
    MAX_DATAGRAMS_PER_POLL = 4096
    #: Requested socket receive buffer, bytes.
    RECEIVE_BUFFER_BYTES = 1 << 20

    def __init__(
        self,
        port: int = 0,
        host: str = "127.0.0.1",
        clock: Callable[[], float] = time.monotonic,
        deadman_timeout_s: float | None = None,
    ) -> None:
        if isinstance(port, bool) or not isinstance(port, int) or not (0 <= port <= 65535):
            raise AmplifierBackendError(f"field 'port': must be an int in [0, 65535], got {port!r}")
        if deadman_timeout_s is not None:
            if isinstance(deadman_timeout_s, bool) or not isinstance(deadman_timeout_s, numbers.Real) or not (
                math.isfinite(deadman_timeout_s) and deadman_timeout_s > 0.0
            ):
                raise AmplifierBackendError(
                    f"field 'deadman_timeout_s': must be None or a time > 0 s, got {deadman_timeout_s!r}"
                )
            deadman_timeout_s = float(deadman_timeout_s)
        self._deadman_timeout_s = deadman_timeout_s
        self._deadman_tripped = False
        self._deadman_trip_count = 0
        self._clock = clock
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            # Room for a burst while the caller is busy (the kernel caps it at rmem_max).
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.RECEIVE_BUFFER_BYTES)
            sock.bind((host, port))
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise AmplifierBackendError(
                f"MockAmplifierReceiver: cannot bind UDP {host}:{port}: {exc}; "
                "choose a free port (or 0 for an ephemeral one)"
            ) from exc
        self._socket: socket.socket | None = sock
        self._address = sock.getsockname()
        self._latest: ReceivedVoltage | None = None
        self._received_count = 0
        self._garbage_count = 0
        self._stale_count = 0

    @property
    def port(self) -> int:
        return int(self._address[1])

    @property
    def host(self) -> str:
        return str(self._address[0])

    @property
    def latest(self) -> ReceivedVoltage | None:
        return self._latest

    @property
    def received_count(self) -> int:
        """Valid datagrams accepted."""
        return self._received_count

    @property
    def garbage_count(self) -> int:
        return self._garbage_count

    @property
    def stale_count(self) -> int:
        return self._stale_count

    @property
    def is_open(self) -> bool:
        return self._socket is not None

    @property
    def deadman_timeout_s(self) -> float | None:
        return self._deadman_timeout_s

    @property
    def deadman_trip_count(self) -> int:
        """How often the dead-man dropped a non-zero output to 0 V."""
        return self._deadman_trip_count

    def deadman_expired(self, now_s: float | None = None) -> bool:
        """True when the dead-man holds the output at 0 V (no datagram for the timeout)."""
        if self._deadman_timeout_s is None or self._latest is None:
            return False
        now_s = self._clock() if now_s is None else now_s
        return now_s - self._latest.received_s > self._deadman_timeout_s

    def applied_voltage_V(self, now_s: float | None = None) -> float:
        """The simulated amplifier's output, V: the latest voltage received, or 0 V before
        the first datagram and while the dead-man has expired. Does not poll."""
        latest = self._latest
        if latest is None:
            return 0.0
        if self.deadman_expired(now_s):
            if not self._deadman_tripped and latest.voltage_V > 0.0:
                self._deadman_trip_count += 1
            self._deadman_tripped = True
            return 0.0
        self._deadman_tripped = False
        return latest.voltage_V

    def poll(self) -> ReceivedVoltage | None:
        """Drain pending datagrams; return the latest valid voltage (None if none yet)."""
        self.poll_all()
        return self._latest

    def poll_all(self) -> list[ReceivedVoltage]:
        """Drain pending datagrams; return every new valid one, oldest first.

        A simulator that applies each voltage at its send time needs them all: a
        slew-limited ramp arrives as several datagrams between two polls.
        """
        if self._socket is None:
            raise AmplifierBackendError("MockAmplifierReceiver: poll() after close()")
        fresh: list[ReceivedVoltage] = []
        for _ in range(self.MAX_DATAGRAMS_PER_POLL):
            try:
                data = self._socket.recv(DATAGRAM_SIZE + 1)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                # e.g. ECONNREFUSED surfacing from an ICMP error: not data, keep draining.
                self._garbage_count += 1
                continue
            try:
                datagram = decode_voltage_datagram(data)
            except ValueError:
                self._garbage_count += 1
                continue
            latest = self._latest
            if (
                latest is not None
                and datagram.session_id == latest.session_id
                and datagram.sequence <= latest.sequence
            ):
                self._stale_count += 1
                continue
            self._received_count += 1
            self._latest = ReceivedVoltage(
                voltage_V=datagram.voltage_V,
                received_s=self._clock(),
                sent_s=datagram.sent_monotonic_s,
                sequence=datagram.sequence,
                session_id=datagram.session_id,
            )
            fresh.append(self._latest)
        return fresh

    def wait_readable(self, timeout_s: float) -> bool:
        """Block up to ``timeout_s`` until a datagram is pending (True) or not (False; also once closed).

        For a simulator that sleeps until the amplifier sends instead of polling on a timer."""
        sock = self._socket
        if sock is None:
            return False
        try:
            readable, _, _ = select.select([sock], [], [], timeout_s)
        except (OSError, ValueError):  # closed meanwhile
            return False
        return bool(readable)

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def __enter__(self) -> "MockAmplifierReceiver":
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.close()
