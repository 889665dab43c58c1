"""Hardware backends of the high-voltage amplifier.

Every backend takes the *high voltage* the amplifier should produce (V, e.g.
0-3000 V) and does whatever drives the amplifier to it:

* :class:`InProcessAmplifierBackend` -- stores the value (unit tests, single-process demos).
* :class:`MockAmplifierBackend` -- sends it as UDP datagrams to ``127.0.0.1:<port>``,
  where the mock hardware node runs :class:`MockAmplifierReceiver`.
* :class:`UldaqAmplifierBackend` -- a Measurement Computing USB DAQ (USB-1208/1608
  series, via the ``uldaq`` package and the ``libuldaq`` C library) whose analog
  output drives the amplifier input: DAQ volts = high voltage / amplifier gain
  (e.g. TREK 10/10B-HS, 1000 V/V). Optionally it reads the amplifier's voltage
  monitor on an analog input and drives an enable/interlock line on a digital output.

:func:`describe_amplifier_rig` (pure) describes a DAQ board (:class:`DaqBoardInfo`,
read with :func:`query_uldaq_board`) against what the configuration expects
(:class:`AmplifierRigExpectation`): the AO range it chooses, the DAQ output at the
ceiling, and every mismatch.

The backends are the last line of defence, not the first: the slew limiting and
the watchdog live in :mod:`dea_ros.hardware.amplifier_safety`. Still, every
backend refuses NaN, +-inf, negative values and values above its
``max_voltage_V`` (when given) with :class:`AmplifierBackendError`, without
writing anything.

UDP datagram format (network byte order, 32 bytes)::

    magic      4s   b"DEAV"
    session    u32  random per sending backend (a restarted sender is recognised)
    sequence   u64  0, 1, 2, ... per session
    voltage_V  f64  high voltage to apply, V
    sent_s     f64  time.monotonic() of the sender at sending, s
"""
from __future__ import annotations

import abc
import collections
import importlib
import math
import numbers
import re
import secrets
import socket
import struct
import time
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Deque, Dict, List, Mapping, Optional, Tuple
from ..errors import AmplifierBackendError, AmplifierRangeWarning

__all__ = [
    "AmplifierBackendError",
    "AmplifierRangeWarning",
    "AmplifierBackend",
    "InProcessAmplifierBackend",
    "MockAmplifierBackend",
    "MockAmplifierReceiver",
    "ReceivedVoltage",
    "VoltageDatagram",
    "encode_voltage_datagram",
    "decode_voltage_datagram",
    "DATAGRAM_MAGIC",
    "DATAGRAM_SIZE",
    "UldaqAmplifierBackend",
    "parse_daq_range",
    "choose_daq_range",
    "ULDAQ_INSTALL_HINT",
    "DaqBoardInfo",
    "AmplifierRigExpectation",
    "AmplifierRigDescription",
    "describe_amplifier_rig",
    "query_uldaq_board",
    "KNOWN_DAQ_BOARDS",
    "AMPLIFIER_PARAMETERS",
    "AmplifierConfig",
    "amplifier_config_from_parameters",
]

ULDAQ_INSTALL_HINT = (
    "pip install uldaq and install libuldaq from Measurement Computing "
    "(https://github.com/mccdaq/uldaq: build and 'sudo make install', which also installs the udev rules)"
)


# =========================================================================== interface
class AmplifierBackend(abc.ABC):
    """Interface of an amplifier backend.

    ``open()`` before use, ``close()`` at the end (also a context manager).
    ``write_voltage`` validates the value and then calls the subclass's
    :meth:`_write_validated_V`.
    """

    def __init__(self, max_voltage_V: Optional[float] = None) -> None:
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
        self._last_written_V: Optional[float] = None
        self._write_count = 0

    # ---------------------------------------------------------------- properties
    @property
    def max_voltage_V(self) -> Optional[float]:
        return self._max_voltage_V

    @property
    def is_open(self) -> bool:
        return self._is_open

    @property
    def last_written_V(self) -> Optional[float]:
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

    def read_monitor_V(self) -> Optional[float]:
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


# =========================================================================== in-process
class InProcessAmplifierBackend(AmplifierBackend):
    """Stores the written voltage; its 'monitor' reads it back (ideal amplifier)."""

    def __init__(self, max_voltage_V: Optional[float] = None, history_length: int = 10_000) -> None:
        super().__init__(max_voltage_V)
        if not isinstance(history_length, int) or history_length < 0:
            raise AmplifierBackendError(
                f"field 'history_length': must be an int >= 0, got {history_length!r}"
            )
        self._voltage_V = 0.0
        self._history: Deque[float] = collections.deque(maxlen=history_length)
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

    def read_monitor_V(self) -> Optional[float]:
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


# =========================================================================== UDP mock
DATAGRAM_MAGIC = b"DEAV"
_DATAGRAM = struct.Struct("!4sIQdd")
DATAGRAM_SIZE = _DATAGRAM.size


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
        max_voltage_V: Optional[float] = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(max_voltage_V)
        if isinstance(port, bool) or not isinstance(port, int) or not (1 <= port <= 65535):
            raise AmplifierBackendError(f"field 'port': must be an int in [1, 65535], got {port!r}")
        self._address = (host, port)
        self._clock = clock
        self._session_id = secrets.randbits(32)
        self._sequence = 0
        self._socket: Optional[socket.socket] = None

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
        deadman_timeout_s: Optional[float] = None,
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
        self._socket: Optional[socket.socket] = sock
        self._address = sock.getsockname()
        self._latest: Optional[ReceivedVoltage] = None
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
    def latest(self) -> Optional[ReceivedVoltage]:
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
    def deadman_timeout_s(self) -> Optional[float]:
        return self._deadman_timeout_s

    @property
    def deadman_trip_count(self) -> int:
        """How often the dead-man dropped a non-zero output to 0 V."""
        return self._deadman_trip_count

    def deadman_expired(self, now_s: Optional[float] = None) -> bool:
        """True when the dead-man holds the output at 0 V (no datagram for the timeout)."""
        if self._deadman_timeout_s is None or self._latest is None:
            return False
        now_s = self._clock() if now_s is None else now_s
        return now_s - self._latest.received_s > self._deadman_timeout_s

    def applied_voltage_V(self, now_s: Optional[float] = None) -> float:
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

    def poll(self) -> Optional[ReceivedVoltage]:
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

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def __enter__(self) -> "MockAmplifierReceiver":
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.close()


# =========================================================================== uldaq
_RANGE_NAME = re.compile(r"^(UNI|BIP)(\d*)(?:PT(\d+))?VOLTS$")


def parse_daq_range(name: str) -> tuple[float, float]:
    """``(min_V, max_V)`` of a uldaq ``Range`` name, e.g. UNI10VOLTS -> (0, 10),
    BIP2PT5VOLTS -> (-2.5, 2.5), UNIPT625VOLTS -> (0, 0.625)."""
    if not isinstance(name, str):
        raise AmplifierBackendError(f"DAQ range must be a uldaq Range name string, got {name!r}")
    match = _RANGE_NAME.match(name.strip().upper())
    if match is None or (not match.group(2) and not match.group(3)):
        raise AmplifierBackendError(
            f"DAQ range {name!r} is not a uldaq Range name; use e.g. 'UNI10VOLTS', "
            "'BIP10VOLTS', 'UNI5VOLTS'"
        )
    kind, whole, fraction = match.groups()
    magnitude_V = float(f"{whole or '0'}.{fraction or '0'}")
    return (0.0, magnitude_V) if kind == "UNI" else (-magnitude_V, magnitude_V)


# Error codes (uldaq.ULError names) that mean the device went away.
_CONNECTION_LOST_ERRORS = frozenset(
    {"DEV_NOT_CONNECTED", "DEAD_DEV", "NO_CONNECTION_ESTABLISHED", "DEV_UNAVAILABLE", "BAD_DEV_HANDLE"}
)
_ERROR_HINTS = {
    "DEV_NOT_FOUND": "check the USB cable and 'lsusb' for the Measurement Computing device",
    "USB_DEV_NO_PERMISSION": "install the udev rules of libuldaq (or run with USB permissions)",
    "USB_INTERFACE_CLAIMED": "another process uses the DAQ: stop it first",
    "BAD_RANGE": "the device does not support this ao_range",
    "BAD_AO_CHAN": "the device has no such analog output channel",
    "BAD_DA_VAL": "the D/A value is outside the selected range",
}


# =========================================================================== rig description
#: The analog output ranges, analog input (mode -> channels, ranges) and digital ports of the
#: boards this project was checked against (libuldaq sources, src/usb/ao|ai|dio/*.cpp; MCC
#: user's guides): what :func:`query_uldaq_board` reports for them, and what the test fake offers.
KNOWN_DAQ_BOARDS: Dict[str, Dict[str, Any]] = {
    "USB-1208HS-4AO": {
        "ao_channels": 4, "ao_ranges": ("BIP10VOLTS",),
        "ai": (("SINGLE_ENDED", 8, ("BIP10VOLTS", "BIP5VOLTS", "BIP2PT5VOLTS", "UNI10VOLTS")),
               ("DIFFERENTIAL", 4, ("BIP20VOLTS", "BIP10VOLTS", "BIP5VOLTS"))),
        "dio": (("AUXPORT", 16, "BITIO"),),
    },
    "USB-1608GX-2AO": {
        "ao_channels": 2, "ao_ranges": ("BIP10VOLTS",),
        "ai": (("SINGLE_ENDED", 16, ("BIP10VOLTS", "BIP5VOLTS", "BIP2VOLTS", "BIP1VOLTS")),
               ("DIFFERENTIAL", 8, ("BIP10VOLTS", "BIP5VOLTS", "BIP2VOLTS", "BIP1VOLTS"))),
        "dio": (("AUXPORT", 8, "BITIO"),),
    },
    "USB-1208FS-Plus": {
        "ao_channels": 2, "ao_ranges": ("UNI5VOLTS",),
        "ai": (("SINGLE_ENDED", 8, ("BIP10VOLTS",)),
               ("DIFFERENTIAL", 4, ("BIP20VOLTS", "BIP10VOLTS", "BIP5VOLTS", "BIP4VOLTS", "BIP2PT5VOLTS",
                                    "BIP2VOLTS", "BIP1PT25VOLTS", "BIP1VOLTS"))),
        "dio": (("FIRSTPORTA", 8, "IO"), ("FIRSTPORTB", 8, "IO")),
    },
    "USB-202": {
        "ao_channels": 2, "ao_ranges": ("UNI5VOLTS",),
        "ai": (("SINGLE_ENDED", 8, ("BIP10VOLTS",)),),
        "dio": (("AUXPORT", 8, "BITIO"),),
    },
    "USB-205": {
        "ao_channels": 2, "ao_ranges": ("UNI5VOLTS",),
        "ai": (("SINGLE_ENDED", 8, ("BIP10VOLTS",)),),
        "dio": (("AUXPORT", 8, "BITIO"),),
    },
}


@dataclass(frozen=True)
class DaqBoardInfo:
    """What a connected DAQ reports (uldaq ``*Info`` objects), as plain names.

    ``ai`` holds ``(input mode name, channels in that mode, range names)`` per supported
    input mode; ``dio`` holds ``(port type name, number of bits, port I/O type name)``.
    """

    product_name: str
    unique_id: str
    ao_channels: int
    ao_ranges: Tuple[str, ...]
    ai: Tuple[Tuple[str, int, Tuple[str, ...]], ...] = ()
    dio: Tuple[Tuple[str, int, str], ...] = ()

    def __post_init__(self) -> None:  # canonical form: comparable whatever order the library lists
        object.__setattr__(self, "ao_ranges", tuple(self.ao_ranges))
        object.__setattr__(self, "ai", tuple(sorted((str(m), int(n), tuple(r)) for m, n, r in self.ai)))
        object.__setattr__(self, "dio", tuple((str(p), int(n), str(t)) for p, n, t in self.dio))

    @property
    def label(self) -> str:
        return f"{self.product_name} ({self.unique_id})" if self.unique_id else self.product_name

    def ai_mode(self, mode: str) -> Optional[Tuple[int, Tuple[str, ...]]]:
        for name, channels, ranges in self.ai:
            if name == mode:
                return channels, ranges
        return None

    def dio_port(self, port: str) -> Optional[Tuple[int, str]]:
        for name, bits, io_type in self.dio:
            if name == port:
                return bits, io_type
        return None

    @classmethod
    def known(cls, product_name: str, unique_id: str = "") -> "DaqBoardInfo":
        """The description of a board of :data:`KNOWN_DAQ_BOARDS` (tests, documentation)."""
        spec = KNOWN_DAQ_BOARDS[product_name]
        return cls(product_name, unique_id, spec["ao_channels"], tuple(spec["ao_ranges"]),
                   tuple(spec["ai"]), tuple(spec["dio"]))


@dataclass(frozen=True)
class AmplifierRigExpectation:
    """What the configuration of amplifier_node expects of the amplifier and its DAQ.

    Attributes:
        backend: mock, uldaq or inprocess.
        ceiling_V: the highest high voltage ever applied (decided at start-up), V.
        amplifier_gain_V_per_V: amplifier output per input volt (TREK 10/10B-HS: 1000).
        amplifier_max_output_V: rated output of the amplifier, V (TREK 10/10B-HS: 10000).
        amplifier_input_full_scale_V: input giving the rated output, V (TREK: 10);
            gain x full scale must equal the rated output (a gain slip shows here).
        unique_id: the DAQ's serial number (None: the first one found).
        ao_channel: analog output wired to the amplifier input.
        ao_range: uldaq Range name, or "auto" (the smallest the board offers that covers
            0 .. ceiling / gain).
        monitor_channel: analog input wired to the amplifier's voltage monitor (None: none).
        monitor_gain_V_per_V: high volts per monitor volt (None: the amplifier gain).
        monitor_range: uldaq Range name or "auto" (the smallest covering the rated output).
        monitor_input_mode: uldaq AiInputMode name (SINGLE_ENDED, DIFFERENTIAL).
        enable_port: uldaq DigitalPortType name of the enable/interlock line (None: none).
        enable_bit: bit of that port.
    """

    backend: str
    ceiling_V: float
    amplifier_gain_V_per_V: float = 1000.0
    amplifier_max_output_V: float = 10000.0
    amplifier_input_full_scale_V: float = 10.0
    unique_id: Optional[str] = None
    ao_channel: int = 0
    ao_range: str = "auto"
    monitor_channel: Optional[int] = None
    monitor_gain_V_per_V: Optional[float] = None
    monitor_range: str = "auto"
    monitor_input_mode: str = "SINGLE_ENDED"
    enable_port: Optional[str] = None
    enable_bit: int = 0


@dataclass(frozen=True)
class AmplifierRigDescription:
    """Result of :func:`describe_amplifier_rig`: what is there, what was chosen, what is wrong."""

    expected: AmplifierRigExpectation
    board: Optional[DaqBoardInfo]
    ao_range: Optional[str]  #: chosen analog output range (uldaq with a board)
    needed_daq_V: float  #: DAQ output at the ceiling = ceiling / gain, V
    reachable_V: Optional[float]  #: chosen range's maximum x gain, V
    monitor_range: Optional[str]  #: chosen monitor input range
    mismatches: Tuple[str, ...]  #: each a sentence naming the parameter and the fix
    notes: Tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.mismatches

    def lines(self) -> List[str]:
        """A human-readable report (for logs and ``dea-ros rig check``)."""
        e = self.expected
        out = [f"amplifier backend: {e.backend}; ceiling {e.ceiling_V:.1f} V; amplifier gain "
               f"{e.amplifier_gain_V_per_V:g} V/V, rated {e.amplifier_max_output_V:g} V at "
               f"{e.amplifier_input_full_scale_V:g} V input"]
        if self.board is not None:
            b = self.board
            out.append(f"DAQ: {b.label}; AO {b.ao_channels} channel(s), ranges {list(b.ao_ranges)}; "
                       f"AI {[(m, n) for m, n, _ in b.ai]}; DIO {[(p, n) for p, n, _ in b.dio]}")
        elif e.backend == "uldaq":
            out.append("DAQ: not connected / not read")
        if self.ao_range is not None:
            out.append(f"AO channel {e.ao_channel}, range {self.ao_range}: {self.needed_daq_V:.4g} V at the "
                       f"ceiling; the range reaches {self.reachable_V:g} V on the amplifier")
        if e.monitor_channel is not None:
            out.append(f"monitor: AI channel {e.monitor_channel} ({e.monitor_input_mode}), range "
                       f"{self.monitor_range}, {e.monitor_gain_V_per_V or e.amplifier_gain_V_per_V:g} V/V")
        if e.enable_port is not None:
            out.append(f"enable/interlock output: {e.enable_port} bit {e.enable_bit}")
        out += [f"note: {n}" for n in self.notes]
        out += [f"MISMATCH: {m}" for m in self.mismatches]
        out.append("OK: the rig matches the configuration" if self.ok else
                   f"{len(self.mismatches)} mismatch(es): no voltage will be applied")
        return out


def _range_span(name: str) -> Optional[Tuple[float, float]]:
    try:
        return parse_daq_range(name)
    except AmplifierBackendError:
        return None


def choose_daq_range(ranges, needed_V: float) -> Optional[str]:
    """The range (uldaq name) of ``ranges`` that covers ``0 .. needed_V`` with the smallest
    span (best resolution; a unipolar one wins a tie), or None when none covers it."""
    best = None
    for name in ranges:
        span = _range_span(str(name))
        if span is None or span[0] > 0.0 or span[1] < needed_V:
            continue
        key = (span[1], span[0] < 0.0)
        if best is None or key < best[0]:
            best = (key, str(name))
    return None if best is None else best[1]


#: Gain x input full scale may differ from the rated output by this fraction.
GAIN_TOLERANCE = 0.02


def describe_amplifier_rig(
    expected: AmplifierRigExpectation, board: Optional[DaqBoardInfo] = None
) -> AmplifierRigDescription:
    """Describe the amplifier and its DAQ against what the configuration expects (pure).

    Checks, each failure a mismatch naming the parameter and the likely slip:

    * the ceiling is at most the amplifier's rated output (a larger one means the membrane
      limit is implausible: a thickness or breakdown-field slip);
    * gain x input full scale = rated output within 2 % (a gain slip, e.g. 100 for 1000);
    * with a board (uldaq): the AO channel exists; an AO range of the board covers
      0 .. ceiling / gain ("auto" chooses the smallest, :func:`choose_daq_range`; a named
      one must be offered and cover it); the monitor input mode, channel and range exist
      and the range covers the amplifier's rated output / monitor gain; the enable port
      and bit exist and can output;
    * monitor and enable are refused for backends that have neither (mock, inprocess).
    """
    e = expected
    mismatches: List[str] = []
    notes: List[str] = []
    gain = float(e.amplifier_gain_V_per_V)
    needed_daq_V = float(e.ceiling_V) / gain if gain > 0 else math.inf
    if not (gain > 0 and math.isfinite(gain)):
        mismatches.append(f"amplifier_gain_V_per_V = {gain!r} must be a finite gain > 0 V/V")
    if e.ceiling_V > e.amplifier_max_output_V:
        mismatches.append(
            f"the voltage ceiling {e.ceiling_V:.1f} V (membrane: margin x breakdown field x thickness, or "
            f"max_voltage_V) is above the amplifier's rated output amplifier_max_output_V = "
            f"{e.amplifier_max_output_V:g} V: a thickness or breakdown-field slip in the membrane file (x10?); "
            f"if the membrane really holds more, set max_voltage_V to at most {e.amplifier_max_output_V:g} V")
    full_scale_V = gain * e.amplifier_input_full_scale_V
    if e.amplifier_max_output_V > 0 and abs(full_scale_V / e.amplifier_max_output_V - 1.0) > GAIN_TOLERANCE:
        mismatches.append(
            f"amplifier_gain_V_per_V = {gain:g} V/V x amplifier_input_full_scale_V = "
            f"{e.amplifier_input_full_scale_V:g} V = {full_scale_V:g} V, but amplifier_max_output_V = "
            f"{e.amplifier_max_output_V:g} V: one of the three is wrong (a gain slip would scale every output; "
            f"TREK 10/10B-HS: 1000 V/V, 10 V, 10000 V)")
    ao_range = monitor_range = None
    reachable_V = None
    if e.backend != "uldaq":
        if e.monitor_channel is not None:
            mismatches.append(f"monitor_channel = {e.monitor_channel}: the {e.backend} backend has no monitor "
                              "input (uldaq only); set monitor_channel to -1")
        if e.enable_port is not None:
            mismatches.append(f"enable_port = {e.enable_port!r}: the {e.backend} backend has no enable output "
                              "(uldaq only); set enable_port to ''")
    elif board is not None:
        label = board.label
        if board.ao_channels <= 0:
            mismatches.append(f"{label} has no analog output; use a DAQ with AO (USB-1208HS-4AO, USB-1608GX-2AO)")
        elif not (0 <= e.ao_channel < board.ao_channels):
            mismatches.append(f"uldaq_channel = {e.ao_channel}, but {label} has analog output channels "
                              f"0..{board.ao_channels - 1}")
        wanted = str(e.ao_range).strip().upper()
        if wanted == "AUTO":
            ao_range = choose_daq_range(board.ao_ranges, needed_daq_V)
            if ao_range is None:
                mismatches.append(
                    f"no analog output range of {label} (ranges {list(board.ao_ranges)}) covers the needed "
                    f"0..{needed_daq_V:.4g} V (ceiling {e.ceiling_V:.1f} V / gain {gain:g} V/V); a gain slip, "
                    "or a board with a larger output range")
        elif wanted not in board.ao_ranges:
            mismatches.append(f"uldaq_range = {wanted} is not offered by {label}; it offers {list(board.ao_ranges)} "
                              "(use 'auto')")
        else:
            span = _range_span(wanted)
            if span is None or span[0] > 0.0 or span[1] < needed_daq_V:
                mismatches.append(f"uldaq_range = {wanted} does not cover the needed 0..{needed_daq_V:.4g} V "
                                  f"(ceiling {e.ceiling_V:.1f} V / gain {gain:g} V/V)")
            else:
                ao_range = wanted
        if ao_range is not None:
            span = _range_span(ao_range)
            reachable_V = span[1] * gain
            if span[1] > e.amplifier_input_full_scale_V * (1.0 + GAIN_TOLERANCE):
                notes.append(f"the range {ao_range} can exceed the amplifier's {e.amplifier_input_full_scale_V:g} V "
                             "input full scale; only the software clamp prevents it")
            if reachable_V > e.ceiling_V:
                notes.append(f"the range reaches {reachable_V:g} V on the amplifier, above the ceiling "
                             f"{e.ceiling_V:.1f} V: the DAQ output is clamped at {needed_daq_V:.4g} V in software; "
                             "a hardware limit on the amplifier is the real protection")
        if e.monitor_channel is not None:
            mode = str(e.monitor_input_mode).strip().upper()
            found = board.ai_mode(mode)
            monitor_gain = e.monitor_gain_V_per_V or gain
            needed_monitor_V = e.amplifier_max_output_V / monitor_gain
            if found is None:
                mismatches.append(f"monitor_input_mode = {mode}: {label} has analog input modes "
                                  f"{[m for m, _, _ in board.ai]}")
            else:
                channels, ai_ranges = found
                if not (0 <= e.monitor_channel < channels):
                    mismatches.append(f"monitor_channel = {e.monitor_channel}, but {label} has {mode} analog "
                                      f"inputs 0..{channels - 1}")
                wanted_monitor = str(e.monitor_range).strip().upper()
                if wanted_monitor == "AUTO":  # a bipolar range first: it shows a polarity error too
                    bipolar = [r for r in ai_ranges if (_range_span(r) or (0.0, 0.0))[0] < 0.0]
                    monitor_range = (choose_daq_range(bipolar, needed_monitor_V)
                                     or choose_daq_range(ai_ranges, needed_monitor_V))
                    if monitor_range is None:
                        mismatches.append(
                            f"no {mode} analog input range of {label} ({list(ai_ranges)}) covers the monitor "
                            f"signal 0..{needed_monitor_V:.4g} V (rated output {e.amplifier_max_output_V:g} V / "
                            f"monitor gain {monitor_gain:g} V/V)")
                elif wanted_monitor not in ai_ranges:
                    mismatches.append(f"monitor_range = {wanted_monitor} is not a {mode} range of {label}: "
                                      f"{list(ai_ranges)}")
                else:
                    monitor_range = wanted_monitor
        if e.enable_port is not None:
            port = str(e.enable_port).strip().upper()
            found_port = board.dio_port(port)
            if found_port is None:
                mismatches.append(f"enable_port = {port}: {label} has digital ports "
                                  f"{[p for p, _, _ in board.dio]}")
            else:
                bits, io_type = found_port
                if not (0 <= e.enable_bit < bits):
                    mismatches.append(f"enable_bit = {e.enable_bit}, but {port} of {label} has bits 0..{bits - 1}")
                if io_type == "IN":
                    mismatches.append(f"enable_port = {port} of {label} is input-only")
    return AmplifierRigDescription(e, board, ao_range, needed_daq_V, reachable_V, monitor_range,
                                   tuple(mismatches), tuple(notes))


def _enum_name(value: Any) -> str:
    return str(getattr(value, "name", value))


def _read_board_info(ul: Any, device: Any, descriptor: Any) -> DaqBoardInfo:
    """Read a connected uldaq ``DaqDevice`` into a :class:`DaqBoardInfo`."""
    name = getattr(descriptor, "product_name", "?")
    uid = getattr(descriptor, "unique_id", "")
    if isinstance(uid, bytes):
        uid = uid.decode("utf-8", "replace")
    ao_channels, ao_ranges = 0, ()
    ao = device.get_ao_device()
    if ao is not None:
        info = ao.get_info()
        ao_channels = int(info.get_num_chans())
        ao_ranges = tuple(_enum_name(r) for r in info.get_ranges())
    ai_modes = []
    ai = device.get_ai_device()
    if ai is not None:
        info = ai.get_info()
        for mode in ul.AiInputMode:
            try:
                channels = int(info.get_num_chans_by_mode(mode))
            except Exception:  # noqa: BLE001 - a mode the device does not know
                continue
            if channels > 0:
                ai_modes.append((_enum_name(mode), channels, tuple(_enum_name(r) for r in info.get_ranges(mode))))
    dio_ports = []
    dio = device.get_dio_device()
    if dio is not None:
        info = dio.get_info()
        for port in info.get_port_types():
            port_info = info.get_port_info(port)
            dio_ports.append((_enum_name(port), int(port_info.number_of_bits), _enum_name(port_info.port_io_type)))
    return DaqBoardInfo(str(name), str(uid), ao_channels, ao_ranges, tuple(ai_modes), tuple(dio_ports))


def query_uldaq_board(unique_id: Optional[str] = None, interface: str = "USB") -> DaqBoardInfo:
    """Connect to a Measurement Computing DAQ, read what it offers, disconnect (writes nothing).

    For ``dea-ros rig check``: pass the result to :func:`describe_amplifier_rig`.
    Raises :class:`AmplifierBackendError` (no uldaq, no device, no such unique_id).
    """
    probe = UldaqAmplifierBackend(unique_id=unique_id, max_voltage_V=1.0, amplifier_gain_V_per_V=1000.0,
                                  interface=interface)
    return probe.read_board()


class UldaqAmplifierBackend(AmplifierBackend):
    """Amplifier driven by the analog output of a Measurement Computing DAQ (``uldaq``).

    Args:
        unique_id: serial number of the DAQ (``DaqDeviceDescriptor.unique_id``);
            None uses the first device found.
        channel: analog output channel wired to the amplifier input.
        amplifier_gain_V_per_V: amplifier gain, V out per V in (TREK 10/10B-HS: 1000).
        ao_range: uldaq ``Range`` name of the analog output, or "auto": on open the
            smallest range the board reports that covers ``0 .. max_voltage_V / gain``
            (:func:`describe_amplifier_rig`; none covering it refuses to open, naming
            the board and its ranges).
        max_voltage_V: highest high voltage ever written, V (required: the backend
            cannot know it). Writes above it are refused; the DAQ output is clamped
            to ``[0, min(range max, max_voltage_V / gain)]``.
        strict_range_check: a named ``ao_range`` whose maximum times the gain exceeds
            ``max_voltage_V`` gives an :class:`AmplifierRangeWarning`; with True an
            :class:`AmplifierBackendError` instead.
        interface: uldaq ``InterfaceType`` name used for discovery ('USB', 'ANY', ...).
        amplifier_max_output_V, amplifier_input_full_scale_V: the amplifier's rating
            (checked against the gain on open).
        monitor_channel: analog input wired to the amplifier's voltage monitor
            (None: no monitor).
        monitor_gain_V_per_V: high volts per monitor volt (defaults to the amplifier gain).
        monitor_range: uldaq ``Range`` name of the monitor input, or "auto".
        monitor_input_mode: uldaq ``AiInputMode`` name of the monitor input.
        enable_port: uldaq ``DigitalPortType`` name of the amplifier's enable/interlock
            line (None: none); ``enable_bit`` its bit; ``enable_active_high`` its polarity.
        enable_heartbeat: while enabled, toggle the line on every write (for a hardware
            watchdog relay / retriggerable monostable that drops the enable when the
            toggling stops: protects against SIGKILL and a hung process too).

    ``uldaq`` is imported only in :meth:`open` (it loads ``libuldaq.so`` at import).
    """

    def __init__(
        self,
        unique_id: Optional[str] = None,
        channel: int = 0,
        amplifier_gain_V_per_V: float = 1000.0,
        ao_range: str = "auto",
        *,
        max_voltage_V: float,
        strict_range_check: bool = False,
        interface: str = "USB",
        amplifier_max_output_V: float = 10000.0,
        amplifier_input_full_scale_V: float = 10.0,
        monitor_channel: Optional[int] = None,
        monitor_gain_V_per_V: Optional[float] = None,
        monitor_range: str = "auto",
        monitor_input_mode: str = "SINGLE_ENDED",
        enable_port: Optional[str] = None,
        enable_bit: int = 0,
        enable_active_high: bool = True,
        enable_heartbeat: bool = False,
    ) -> None:
        if max_voltage_V is None:
            raise AmplifierBackendError(
                "field 'max_voltage_V': required for the uldaq backend (the highest high "
                "voltage the amplifier may output, V)"
            )
        super().__init__(max_voltage_V)
        assert self._max_voltage_V is not None
        for name, value, low in (("channel", channel, 0), ("enable_bit", enable_bit, 0)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise AmplifierBackendError(f"field '{name}': must be an int >= {low}, got {value!r}")
        if monitor_channel is not None and (
            isinstance(monitor_channel, bool) or not isinstance(monitor_channel, int) or monitor_channel < 0
        ):
            raise AmplifierBackendError(
                f"field 'monitor_channel': must be None or an int >= 0, got {monitor_channel!r}"
            )
        self._gain = self._positive("amplifier_gain_V_per_V", amplifier_gain_V_per_V)
        self._amp_max_V = self._positive("amplifier_max_output_V", amplifier_max_output_V)
        self._amp_full_scale_V = self._positive("amplifier_input_full_scale_V", amplifier_input_full_scale_V)
        self._monitor_gain = (
            self._gain
            if monitor_gain_V_per_V is None
            else self._positive("monitor_gain_V_per_V", monitor_gain_V_per_V)
        )
        self._ao_range_request = str(ao_range).strip().upper()
        self._ao_range_name: Optional[str] = None
        if self._ao_range_request != "AUTO":
            self._ao_range_name = self._ao_range_request
            self._set_range_limits(self._ao_range_name, strict_range_check, warn=True)
        self._monitor_range_request = str(monitor_range).strip().upper()
        if self._monitor_range_request != "AUTO":
            parse_daq_range(self._monitor_range_request)
        self._monitor_range_name: Optional[str] = None
        self._monitor_input_mode_name = str(monitor_input_mode).strip().upper()
        self._interface_name = str(interface).strip().upper()
        self._unique_id = None if unique_id is None else str(unique_id)
        self._channel = channel
        self._monitor_channel = monitor_channel
        self._enable_port_name = None if not enable_port else str(enable_port).strip().upper()
        self._enable_bit = enable_bit
        self._enable_active_high = bool(enable_active_high)
        self._enable_heartbeat = bool(enable_heartbeat)
        self._enabled = False
        self._heartbeat_level = False

        self._uldaq: Any = None
        self._device: Any = None
        self._ao_device: Any = None
        self._ai_device: Any = None
        self._dio_device: Any = None
        self._faulted: Optional[str] = None
        self._last_daq_V: Optional[float] = None
        self._descriptor_text = ""
        self._board: Optional[DaqBoardInfo] = None
        self._description: Optional[AmplifierRigDescription] = None

    def _set_range_limits(self, range_name: str, strict: bool = False, warn: bool = False) -> None:
        self._ao_min_V, self._ao_max_V = parse_daq_range(range_name)
        assert self._max_voltage_V is not None
        reachable_V = max(abs(self._ao_min_V), abs(self._ao_max_V)) * self._gain
        if warn and reachable_V > self._max_voltage_V:
            message = (
                f"UldaqAmplifierBackend: ao_range {range_name} x gain {self._gain:g} V/V "
                f"can drive the amplifier to {reachable_V:g} V, above max_voltage_V = "
                f"{self._max_voltage_V:g} V; only the software clamp at "
                f"{self._max_voltage_V / self._gain:g} V DAQ output prevents it. Prefer a smaller "
                "AO range or a hardware limit on the amplifier"
            )
            if strict:
                raise AmplifierBackendError(message + " (strict_range_check=True refuses this)")
            warnings.warn(message, AmplifierRangeWarning, stacklevel=3)
        if warn and self._ao_max_V * self._gain < self._max_voltage_V:
            warnings.warn(
                f"UldaqAmplifierBackend: max_voltage_V = {self._max_voltage_V:g} V is unreachable "
                f"with ao_range {range_name} x gain {self._gain:g} V/V "
                f"(at most {self._ao_max_V * self._gain:g} V); commands above are clamped",
                AmplifierRangeWarning,
                stacklevel=3,
            )
        self._daq_limit_V = min(self._ao_max_V, self._max_voltage_V / self._gain)

    @staticmethod
    def _positive(name: str, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise AmplifierBackendError(f"field '{name}': must be a number, got {value!r}")
        value = float(value)
        if not (math.isfinite(value) and value > 0.0):
            raise AmplifierBackendError(f"field '{name}': must be finite and > 0, got {value}")
        return value

    # ---------------------------------------------------------------- properties
    @property
    def amplifier_gain_V_per_V(self) -> float:
        return self._gain

    @property
    def ao_range(self) -> Optional[str]:
        """The analog output range in use (chosen on open when "auto"; None before)."""
        return self._ao_range_name

    @property
    def daq_limit_V(self) -> Optional[float]:
        """Largest DAQ output ever written, V (= min(range max, max_voltage_V / gain)); None
        while the range is not chosen yet."""
        return getattr(self, "_daq_limit_V", None)

    @property
    def last_daq_V(self) -> Optional[float]:
        """Last value written to the DAQ analog output, V."""
        return self._last_daq_V

    @property
    def faulted(self) -> Optional[str]:
        """Why the backend stopped working (None while healthy)."""
        return self._faulted

    @property
    def device_description(self) -> str:
        return self._descriptor_text

    @property
    def board(self) -> Optional[DaqBoardInfo]:
        """What the connected board reported on open."""
        return self._board

    @property
    def rig_description(self) -> Optional[AmplifierRigDescription]:
        """:func:`describe_amplifier_rig` of the board found on open."""
        return self._description

    @property
    def has_monitor(self) -> bool:
        return self._monitor_channel is not None

    @property
    def has_enable_output(self) -> bool:
        return self._enable_port_name is not None

    def expectation(self) -> AmplifierRigExpectation:
        """What this backend's configuration expects of the board."""
        assert self._max_voltage_V is not None
        return AmplifierRigExpectation(
            backend="uldaq", ceiling_V=self._max_voltage_V, amplifier_gain_V_per_V=self._gain,
            amplifier_max_output_V=self._amp_max_V, amplifier_input_full_scale_V=self._amp_full_scale_V,
            unique_id=self._unique_id, ao_channel=self._channel,
            ao_range=self._ao_range_request if self._ao_range_request != "AUTO" else "auto",
            monitor_channel=self._monitor_channel, monitor_gain_V_per_V=self._monitor_gain,
            monitor_range=self._monitor_range_request if self._monitor_range_request != "AUTO" else "auto",
            monitor_input_mode=self._monitor_input_mode_name, enable_port=self._enable_port_name,
            enable_bit=self._enable_bit,
        )

    def high_voltage_to_daq_V(self, voltage_V: float) -> float:
        """DAQ analog output for a high voltage: ``V / gain`` clamped to ``[0, daq_limit_V]``."""
        if self.daq_limit_V is None:
            raise AmplifierBackendError("UldaqAmplifierBackend: the AO range is chosen on open(); open first")
        daq_V = float(voltage_V) / self._gain
        return min(max(daq_V, max(self._ao_min_V, 0.0)), self._daq_limit_V) + 0.0

    # ---------------------------------------------------------------- uldaq plumbing
    @staticmethod
    def _import_uldaq() -> Any:
        try:
            return importlib.import_module("uldaq")
        except ImportError as exc:
            raise AmplifierBackendError(
                f"UldaqAmplifierBackend: the Python package 'uldaq' is not installed ({exc}); "
                + ULDAQ_INSTALL_HINT
            ) from exc
        except OSError as exc:  # uldaq loads libuldaq.so with ctypes at import
            raise AmplifierBackendError(
                f"UldaqAmplifierBackend: the C library libuldaq could not be loaded ({exc}); "
                + ULDAQ_INSTALL_HINT
            ) from exc

    def _ul_errors(self) -> tuple[type, ...]:
        ul_exception = getattr(self._uldaq, "ULException", None)
        if isinstance(ul_exception, type) and issubclass(ul_exception, BaseException):
            return (ul_exception, OSError)
        return (OSError,)

    def _describe(self, action: str, exc: BaseException) -> AmplifierBackendError:
        code = getattr(exc, "error_code", None)
        code_name = getattr(code, "name", None) or (str(code) if code is not None else None)
        detail = str(exc) or type(exc).__name__
        hint = _ERROR_HINTS.get(code_name or "", "")
        if code_name in _CONNECTION_LOST_ERRORS:
            hint = (
                "the DAQ connection was lost (USB unplugged, hub power?); the amplifier input "
                "state is unknown: switch the amplifier off, reconnect and restart"
            )
        text = f"UldaqAmplifierBackend: {action} failed: {detail}"
        if hint:
            text += f"; {hint}"
        return AmplifierBackendError(text)

    def _enum(self, enum_name: str, member: str) -> Any:
        enum_type = getattr(self._uldaq, enum_name)
        try:
            return enum_type[member]
        except KeyError:
            raise AmplifierBackendError(
                f"UldaqAmplifierBackend: {member!r} is not a uldaq {enum_name} "
                f"(uldaq.{enum_name} has {[m.name for m in enum_type]})"
            ) from None

    def _select_descriptor(self, descriptors: list) -> Any:
        if not descriptors:
            raise AmplifierBackendError(
                f"UldaqAmplifierBackend: no Measurement Computing DAQ found on interface "
                f"{self._interface_name}; check the USB cable, 'lsusb' and the libuldaq udev rules"
            )
        if self._unique_id is None:
            return descriptors[0]
        found = []
        for descriptor in descriptors:
            uid = getattr(descriptor, "unique_id", "")
            if isinstance(uid, bytes):
                uid = uid.decode("utf-8", "replace")
            found.append(str(uid))
            if str(uid) == self._unique_id:
                return descriptor
        raise AmplifierBackendError(
            f"UldaqAmplifierBackend: no DAQ with unique_id {self._unique_id!r} found; "
            f"connected devices have unique_id {found}; fix the unique_id parameter"
        )

    def _connect(self) -> Any:
        """Import uldaq, find and connect the device; return its descriptor."""
        self._uldaq = self._import_uldaq()
        ul = self._uldaq
        errors = self._ul_errors()
        interface = self._enum("InterfaceType", self._interface_name)
        try:
            descriptors = list(ul.get_daq_device_inventory(interface))
        except errors as exc:
            raise self._describe("device discovery (get_daq_device_inventory)", exc) from exc
        descriptor = self._select_descriptor(descriptors)
        try:
            self._device = ul.DaqDevice(descriptor)
        except errors as exc:
            raise self._describe("creating the DaqDevice", exc) from exc
        self._descriptor_text = "{} ({})".format(
            getattr(descriptor, "product_name", "?"), getattr(descriptor, "unique_id", "?")
        )
        try:
            self._device.connect()
        except errors as exc:
            self._release_device()
            raise self._describe(f"connecting to {self._descriptor_text}", exc) from exc
        return descriptor

    def read_board(self) -> DaqBoardInfo:
        """Connect, read what the board offers, release it (writes nothing)."""
        if self._is_open:
            assert self._board is not None
            return self._board
        descriptor = self._connect()
        try:
            return _read_board_info(self._uldaq, self._device, descriptor)
        except self._ul_errors() as exc:
            raise self._describe(f"reading the capabilities of {self._descriptor_text}", exc) from exc
        finally:
            self._release_device()

    # ---------------------------------------------------------------- lifecycle
    def open(self) -> None:
        """Find and connect the DAQ, check it against the configuration, choose the AO range,
        drive the enable line inactive and write 0 V (and check the monitor reads ~0 V)."""
        if self._is_open:
            return
        self._faulted = None
        descriptor = self._connect()
        errors = self._ul_errors()
        try:
            try:
                board = _read_board_info(self._uldaq, self._device, descriptor)
            except errors as exc:
                raise self._describe(f"reading the capabilities of {self._descriptor_text}", exc) from exc
            self._board = board
            self._description = description = describe_amplifier_rig(self.expectation(), board)
            if not description.ok:
                raise AmplifierBackendError(
                    f"UldaqAmplifierBackend: {board.label} does not match the configuration: "
                    + "; ".join(description.mismatches)
                )
            assert description.ao_range is not None
            self._ao_range_name = description.ao_range
            self._set_range_limits(self._ao_range_name)
            self._monitor_range_name = description.monitor_range
            self._ao_device = self._device.get_ao_device()
            if self._monitor_channel is not None:
                self._ai_device = self._device.get_ai_device()
            if self._enable_port_name is not None:
                self._dio_device = self._device.get_dio_device()
                self._configure_enable_output()
            self._is_open = True
            self.set_output_enabled(False)
            self.write_voltage(0.0)
        except BaseException:
            self._is_open = False
            self._release_device()
            raise

    def _configure_enable_output(self) -> None:
        ul = self._uldaq
        port = self._enum("DigitalPortType", self._enable_port_name)
        assert self._board is not None
        found = self._board.dio_port(self._enable_port_name)
        io_type = found[1] if found else "BITIO"
        try:
            if io_type == "BITIO":
                self._dio_device.d_config_bit(port, self._enable_bit, ul.DigitalDirection.OUTPUT)
            elif io_type == "IO":  # port-configurable only: the whole port becomes an output
                self._dio_device.d_config_port(port, ul.DigitalDirection.OUTPUT)
        except self._ul_errors() as exc:
            raise self._describe(f"configuring {self._enable_port_name} bit {self._enable_bit} as output",
                                 exc) from exc

    def _write_enable_level(self, level: bool) -> None:
        bit_value = 1 if (level == self._enable_active_high) else 0
        self._dio_device.d_bit_out(self._enum("DigitalPortType", self._enable_port_name), self._enable_bit,
                                   bit_value)

    def set_output_enabled(self, enabled: bool) -> None:
        """Drive the enable/interlock line (active level while enabled; with heartbeat the
        line toggles on every write while enabled and rests inactive otherwise)."""
        if self._enable_port_name is None or self._dio_device is None:
            return
        enabled = bool(enabled)
        try:
            self._write_enable_level(enabled)
        except self._ul_errors() as exc:
            error = self._describe(f"driving the enable line {self._enable_port_name} bit {self._enable_bit}", exc)
            self._faulted = str(error)
            raise error from exc
        self._enabled = enabled
        self._heartbeat_level = enabled

    def _a_out(self, daq_V: float) -> None:
        ul = self._uldaq
        self._ao_device.a_out(
            self._channel, ul.Range[self._ao_range_name], ul.AOutFlag.DEFAULT, daq_V
        )

    def _write_validated_V(self, voltage_V: float) -> None:
        if self._faulted is not None:
            raise AmplifierBackendError(
                f"UldaqAmplifierBackend: not writing, the backend is faulted ({self._faulted}); "
                "close() and open() again"
            )
        daq_V = self.high_voltage_to_daq_V(voltage_V)
        try:
            self._a_out(daq_V)
            if self._enable_heartbeat and self._enabled and self._dio_device is not None:
                self._heartbeat_level = not self._heartbeat_level
                self._write_enable_level(self._heartbeat_level)
        except self._ul_errors() as exc:
            error = self._describe(f"writing {daq_V:.6g} V to AO channel {self._channel}", exc)
            self._faulted = str(error)
            raise error from exc
        self._last_daq_V = daq_V

    def read_monitor_V(self) -> Optional[float]:
        """Amplifier voltage monitor in high volts, or None without a monitor channel."""
        if self._monitor_channel is None or not self._is_open or self._ai_device is None:
            return None
        ul = self._uldaq
        try:
            monitor_V = self._ai_device.a_in(
                self._monitor_channel,
                self._enum("AiInputMode", self._monitor_input_mode_name),
                self._enum("Range", self._monitor_range_name or self._monitor_range_request),
                ul.AInFlag.DEFAULT,
            )
        except self._ul_errors() as exc:
            error = self._describe(f"reading the monitor on AI channel {self._monitor_channel}", exc)
            self._faulted = str(error)
            raise error from exc
        return float(monitor_V) * self._monitor_gain

    def _release_device(self) -> list[str]:
        problems: list[str] = []
        device, self._device = self._device, None
        self._ao_device = None
        self._ai_device = None
        self._dio_device = None
        if device is None:
            return problems
        errors = self._ul_errors()
        try:
            if bool(device.is_connected()):
                device.disconnect()
        except errors as exc:
            problems.append(f"disconnect: {exc}")
        try:
            device.release()
        except errors as exc:
            problems.append(f"release: {exc}")
        return problems

    def close(self) -> None:
        """Drive the enable line inactive, write 0 V, disconnect and release the DAQ.

        Everything is released even when a step fails; if 0 V could not be
        written an :class:`AmplifierBackendError` is raised afterwards, because
        the amplifier input state is then unknown.
        """
        if not self._is_open:
            return
        zero_error: Optional[BaseException] = None
        try:
            # Bypass the fault latch: try to reach 0 V even after an error.
            self._faulted = None
            try:
                self.set_output_enabled(False)
            except AmplifierBackendError as exc:
                zero_error = exc
                self._faulted = None
            self.write_voltage(0.0)
        except AmplifierBackendError as exc:
            zero_error = exc
        finally:
            self._is_open = False
            problems = self._release_device()
        if zero_error is not None:
            raise AmplifierBackendError(
                f"UldaqAmplifierBackend: could not write 0 V on close ({zero_error}); the "
                "amplifier may still be driven: switch it off by hand"
                + (f"; also {problems}" if problems else "")
            ) from zero_error


# =========================================================================== amplifier_node configuration
BACKENDS = ("mock", "uldaq", "inprocess")

#: amplifier_node's parameters, name -> (default, description); all fixed at start-up (read-only).
AMPLIFIER_PARAMETERS: Dict[str, Tuple[Any, str]] = {
    "backend": ("mock", "mock (UDP to mock_hardware_node), uldaq (MCC DAQ) or inprocess"),
    "params_file": ("A2", "membrane (preset or YAML, with breakdown_field_V_per_m) whose breakdown limit "
                          "bounds the output; read once at start-up"),
    "margin": (0.9, "fraction of the breakdown voltage allowed, in (0, 1)"),
    "max_voltage_V": (0.0, "maximum output, V (0: the membrane limit; above it is refused)"),
    "slew_rate_V_per_s": (100000.0, "largest rate of change of the output, V/s (1 .. 1e7)"),
    "ramp_down_rate_V_per_s": (10000.0, "rate of every ramp to 0 V, V/s (<= slew; 0 V within 10 s after "
                                        "the watchdog)"),
    "watchdog_timeout_s": (0.5, "ramp to 0 V after this long without a command, s"),
    "update_rate_hz": (1000.0, "output update and publication rate, Hz (1 .. 20000)"),
    "mock_port": (47650, "UDP port of mock_hardware_node (backend mock)"),
    "uldaq_unique_id": ("", "DAQ unique id (empty: the first USB device)"),
    "uldaq_channel": (0, "analog output channel wired to the amplifier input"),
    "uldaq_range": ("auto", "analog output range: auto (the smallest the board offers that covers "
                            "0 .. ceiling / gain) or a uldaq Range name"),
    "amplifier_gain_V_per_V": (1000.0, "amplifier gain, V/V (TREK 10/10B-HS: 1000)"),
    "amplifier_max_output_V": (10000.0, "rated output of the amplifier, V (TREK 10/10B-HS: 10000); the ceiling "
                                        "may not exceed it"),
    "amplifier_input_full_scale_V": (10.0, "amplifier input for the rated output, V (TREK: 10); gain x full "
                                           "scale must equal the rated output"),
    "monitor_channel": (-1, "uldaq analog input wired to the amplifier's voltage monitor (-1: none)"),
    "monitor_gain_V_per_V": (0.0, "high volts per monitor volt (0: the amplifier gain)"),
    "monitor_range": ("auto", "monitor input range: auto or a uldaq Range name"),
    "monitor_input_mode": ("SINGLE_ENDED", "monitor input mode: SINGLE_ENDED or DIFFERENTIAL"),
    "monitor_tolerance_V": (50.0, "monitor vs command: allowed difference, V (plus the fraction below)"),
    "monitor_tolerance_fraction": (0.05, "monitor vs command: allowed difference as a fraction of the command"),
    "enable_port": ("", "uldaq digital port of the amplifier's enable/interlock input ('': none), e.g. AUXPORT"),
    "enable_bit": (0, "bit of enable_port"),
    "enable_active_high": (True, "enable_port level that enables the amplifier"),
    "enable_heartbeat": (False, "toggle the enable line on every update while enabled (for a hardware "
                                "watchdog relay that drops the enable when the toggling stops)"),
}


@dataclass(frozen=True)
class AmplifierConfig:
    """amplifier_node's configuration, validated: the limits and what it expects of the hardware."""

    values: Dict[str, Any]  #: every parameter (defaults filled in)
    limits: Any  #: :class:`dea_ros.hardware.amplifier_safety.SafetyLimits` (ceiling = ``limits.max_voltage_V``)
    expected: AmplifierRigExpectation

    @property
    def ceiling_V(self) -> float:
        return self.limits.max_voltage_V


def amplifier_config_from_parameters(values: Mapping[str, Any], use_sim_time: bool = False) -> AmplifierConfig:
    """Validate amplifier_node's parameters (e.g. the ``ros__parameters`` of config/amplifier.yaml;
    missing ones take their defaults) and derive the limits and the hardware expectation, without ROS
    or hardware. Raises ``ValueError`` (:class:`~dea_ros.hardware.amplifier_safety.SafetyConfigError`,
    :class:`~dea_ros.model.parameters.ParameterError`) naming the parameter and the likely slip.

    The board itself is checked by :func:`describe_amplifier_rig` with ``result.expected``.
    """
    from ..model.parameters import load_parameters
    from .amplifier_safety import SafetyLimits

    unknown = sorted(set(values) - set(AMPLIFIER_PARAMETERS) - {"autostart", "use_sim_time"})
    if unknown:
        raise ValueError(f"unknown amplifier_node parameter(s) {unknown}; known: {sorted(AMPLIFIER_PARAMETERS)}")
    c = {name: values.get(name, default) for name, (default, _) in AMPLIFIER_PARAMETERS.items()}
    use_sim_time = bool(values.get("use_sim_time", use_sim_time))
    backend = str(c["backend"]).strip()
    if backend not in BACKENDS:
        raise ValueError(f"parameter 'backend': one of {BACKENDS}, got {backend!r}")
    if use_sim_time and backend != "mock":
        raise ValueError(
            f"parameter 'use_sim_time': simulated time is accepted only with the mock backend (a simulated "
            f"clock must never pace real high voltage); backend is {backend!r}: set use_sim_time:=false")

    def check(name: str, low: float, high: float, hint: str = "") -> float:
        try:
            value = float(c[name])
        except (TypeError, ValueError):
            raise ValueError(f"parameter '{name}': must be a number, got {c[name]!r}") from None
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"parameter '{name}': {value:g} is outside [{low:g}, {high:g}]" +
                             (f"; {hint}" if hint else ""))
        return value

    check("update_rate_hz", 1.0, 20000.0, "Hz")
    check("slew_rate_V_per_s", 1.0, 1e7, "V/s (2.2 kV in 22 ms = 1e5 V/s; a value in V/ms?)")
    check("mock_port", 1, 65535)
    check("uldaq_channel", 0, 255)
    check("enable_bit", 0, 63)
    check("monitor_channel", -1, 255, "-1 for no monitor")
    check("monitor_tolerance_V", 1.0, 1e4, "V")
    check("monitor_tolerance_fraction", 0.0, 0.5)
    check("monitor_gain_V_per_V", 0.0, 1e6, "0 for the amplifier gain")
    check("amplifier_max_output_V", 1.0, 30000.0, "V (TREK 10/10B-HS: 10000; a value in kV?)")
    check("amplifier_input_full_scale_V", 0.1, 20.0, "V (TREK: 10)")
    check("amplifier_gain_V_per_V", 1.0, 1e5, "V/V (TREK 10/10B-HS: 1000)")
    configured_max = check("max_voltage_V", 0.0, 30000.0, "V, 0 for the membrane limit (a value in kV?)")
    try:
        membrane = load_parameters(str(c["params_file"]), require=("breakdown_field_V_per_m",))
    except FileNotFoundError as exc:
        raise ValueError(f"parameter 'params_file': {exc}") from None
    limits = SafetyLimits.from_membrane(
        membrane.thickness_m, membrane.breakdown_field_V_per_m, float(c["margin"]),
        slew_rate_V_per_s=float(c["slew_rate_V_per_s"]),
        watchdog_timeout_s=float(c["watchdog_timeout_s"]),
        ramp_down_rate_V_per_s=float(c["ramp_down_rate_V_per_s"]),
        max_voltage_V=configured_max if configured_max > 0 else None,
    )
    monitor_channel = int(c["monitor_channel"])
    expected = AmplifierRigExpectation(
        backend=backend, ceiling_V=limits.max_voltage_V,
        amplifier_gain_V_per_V=float(c["amplifier_gain_V_per_V"]),
        amplifier_max_output_V=float(c["amplifier_max_output_V"]),
        amplifier_input_full_scale_V=float(c["amplifier_input_full_scale_V"]),
        unique_id=str(c["uldaq_unique_id"]) or None, ao_channel=int(c["uldaq_channel"]),
        ao_range=str(c["uldaq_range"]),
        monitor_channel=monitor_channel if monitor_channel >= 0 else None,
        monitor_gain_V_per_V=float(c["monitor_gain_V_per_V"]) or None,
        monitor_range=str(c["monitor_range"]), monitor_input_mode=str(c["monitor_input_mode"]),
        enable_port=str(c["enable_port"]).strip() or None, enable_bit=int(c["enable_bit"]),
    )
    description = describe_amplifier_rig(expected, None)  # the board is checked when connected
    if not description.ok:
        raise ValueError("; ".join(description.mismatches))
    return AmplifierConfig(dict(c), limits, expected)
