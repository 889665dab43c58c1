"""Hardware backends of the high-voltage amplifier.

Every backend takes the *high voltage* the amplifier should produce (V, e.g.
0-3000 V) and does whatever drives the amplifier to it:

* :class:`InProcessAmplifierBackend` -- stores the value (unit tests, single-process demos).
* :class:`MockAmplifierBackend` -- sends it as UDP datagrams to ``127.0.0.1:<port>``,
  where the mock hardware node runs :class:`MockAmplifierReceiver`.
* :class:`UldaqAmplifierBackend` -- a Measurement Computing USB DAQ (USB-1208/1608
  series, via the ``uldaq`` package and the ``libuldaq`` C library) whose analog
  output drives the amplifier input: DAQ volts = high voltage / amplifier gain
  (e.g. TREK 10/10B-HS, 1000 V/V).

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
from typing import Any, Callable, Deque, Optional

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
    "ULDAQ_INSTALL_HINT",
]

ULDAQ_INSTALL_HINT = (
    "pip install uldaq and install libuldaq from Measurement Computing "
    "(https://github.com/mccdaq/uldaq: build and 'sudo make install', which also installs the udev rules)"
)


class AmplifierBackendError(RuntimeError):
    """An amplifier backend failed or refused a value. The message says what to do."""


class AmplifierRangeWarning(UserWarning):
    """The DAQ range times the amplifier gain does not match the configured maximum voltage."""


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
    ) -> None:
        if isinstance(port, bool) or not isinstance(port, int) or not (0 <= port <= 65535):
            raise AmplifierBackendError(f"field 'port': must be an int in [0, 65535], got {port!r}")
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


class UldaqAmplifierBackend(AmplifierBackend):
    """Amplifier driven by the analog output of a Measurement Computing DAQ (``uldaq``).

    Args:
        unique_id: serial number of the DAQ (``DaqDeviceDescriptor.unique_id``);
            None uses the first device found.
        channel: analog output channel wired to the amplifier input.
        amplifier_gain_V_per_V: amplifier gain, V out per V in (TREK 10/10B-HS: 1000).
        ao_range: uldaq ``Range`` name of the analog output ('UNI10VOLTS', 'BIP10VOLTS', ...);
            checked against ``AoInfo.get_ranges()`` of the device on open.
        max_voltage_V: highest high voltage ever written, V (required: the backend
            cannot know it). Writes above it are refused; the DAQ output is clamped
            to ``[0, min(range max, max_voltage_V / gain)]``.
        strict_range_check: when the AO range times the gain could exceed
            ``max_voltage_V`` an :class:`AmplifierRangeWarning` is issued; with
            True an :class:`AmplifierBackendError` is raised instead.
        interface: uldaq ``InterfaceType`` name used for discovery ('USB', 'ANY', ...).
        monitor_channel: analog input wired to the amplifier's voltage monitor
            (None: no monitor).
        monitor_gain_V_per_V: high volts per monitor volt (defaults to the amplifier gain).
        monitor_range: uldaq ``Range`` name of the monitor input.
        monitor_input_mode: uldaq ``AiInputMode`` name of the monitor input.

    ``uldaq`` is imported only in :meth:`open` (it loads ``libuldaq.so`` at import).
    """

    def __init__(
        self,
        unique_id: Optional[str] = None,
        channel: int = 0,
        amplifier_gain_V_per_V: float = 1000.0,
        ao_range: str = "UNI10VOLTS",
        *,
        max_voltage_V: float,
        strict_range_check: bool = False,
        interface: str = "USB",
        monitor_channel: Optional[int] = None,
        monitor_gain_V_per_V: Optional[float] = None,
        monitor_range: str = "BIP10VOLTS",
        monitor_input_mode: str = "SINGLE_ENDED",
    ) -> None:
        if max_voltage_V is None:
            raise AmplifierBackendError(
                "field 'max_voltage_V': required for the uldaq backend (the highest high "
                "voltage the amplifier may output, V)"
            )
        super().__init__(max_voltage_V)
        assert self._max_voltage_V is not None
        if isinstance(channel, bool) or not isinstance(channel, int) or channel < 0:
            raise AmplifierBackendError(f"field 'channel': must be an int >= 0, got {channel!r}")
        if monitor_channel is not None and (
            isinstance(monitor_channel, bool) or not isinstance(monitor_channel, int) or monitor_channel < 0
        ):
            raise AmplifierBackendError(
                f"field 'monitor_channel': must be None or an int >= 0, got {monitor_channel!r}"
            )
        self._gain = self._positive("amplifier_gain_V_per_V", amplifier_gain_V_per_V)
        self._monitor_gain = (
            self._gain
            if monitor_gain_V_per_V is None
            else self._positive("monitor_gain_V_per_V", monitor_gain_V_per_V)
        )
        self._ao_range_name = str(ao_range).strip().upper()
        self._ao_min_V, self._ao_max_V = parse_daq_range(self._ao_range_name)
        self._monitor_range_name = str(monitor_range).strip().upper()
        parse_daq_range(self._monitor_range_name)
        self._monitor_input_mode_name = str(monitor_input_mode).strip().upper()
        self._interface_name = str(interface).strip().upper()
        self._unique_id = None if unique_id is None else str(unique_id)
        self._channel = channel
        self._monitor_channel = monitor_channel

        # Range x gain vs the configured maximum.
        reachable_V = max(abs(self._ao_min_V), abs(self._ao_max_V)) * self._gain
        if reachable_V > self._max_voltage_V:
            message = (
                f"UldaqAmplifierBackend: ao_range {self._ao_range_name} x gain {self._gain:g} V/V "
                f"can drive the amplifier to {reachable_V:g} V, above max_voltage_V = "
                f"{self._max_voltage_V:g} V; only the software clamp at "
                f"{self._max_voltage_V / self._gain:g} V DAQ output prevents it. Prefer a smaller "
                "AO range or a hardware limit on the amplifier"
            )
            if strict_range_check:
                raise AmplifierBackendError(message + " (strict_range_check=True refuses this)")
            warnings.warn(message, AmplifierRangeWarning, stacklevel=2)
        if self._ao_max_V * self._gain < self._max_voltage_V:
            warnings.warn(
                f"UldaqAmplifierBackend: max_voltage_V = {self._max_voltage_V:g} V is unreachable "
                f"with ao_range {self._ao_range_name} x gain {self._gain:g} V/V "
                f"(at most {self._ao_max_V * self._gain:g} V); commands above are clamped",
                AmplifierRangeWarning,
                stacklevel=2,
            )
        self._daq_limit_V = min(self._ao_max_V, self._max_voltage_V / self._gain)

        self._uldaq: Any = None
        self._device: Any = None
        self._ao_device: Any = None
        self._ai_device: Any = None
        self._faulted: Optional[str] = None
        self._last_daq_V: Optional[float] = None
        self._descriptor_text = ""

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
    def daq_limit_V(self) -> float:
        """Largest DAQ output ever written, V (= min(range max, max_voltage_V / gain))."""
        return self._daq_limit_V

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

    def high_voltage_to_daq_V(self, voltage_V: float) -> float:
        """DAQ analog output for a high voltage: ``V / gain`` clamped to ``[0, daq_limit_V]``."""
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

    # ---------------------------------------------------------------- lifecycle
    def open(self) -> None:
        """Find and connect the DAQ, check channel and range, write 0 V."""
        if self._is_open:
            return
        self._uldaq = self._import_uldaq()
        ul = self._uldaq
        errors = self._ul_errors()
        self._faulted = None
        ao_range = self._enum("Range", self._ao_range_name)
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
            try:
                self._device.connect()
            except errors as exc:
                raise self._describe(f"connecting to {self._descriptor_text}", exc) from exc
            self._ao_device = self._device.get_ao_device()
            if self._ao_device is None:
                raise AmplifierBackendError(
                    f"UldaqAmplifierBackend: {self._descriptor_text} has no analog output; "
                    "use a DAQ with AO (e.g. USB-1208HS-4AO, USB-1608GX-2AO)"
                )
            try:
                ao_info = self._ao_device.get_info()
                num_channels = int(ao_info.get_num_chans())
                ranges = list(ao_info.get_ranges())
            except errors as exc:
                raise self._describe("reading the analog output info", exc) from exc
            if self._channel >= num_channels:
                raise AmplifierBackendError(
                    f"UldaqAmplifierBackend: field 'channel' = {self._channel} but "
                    f"{self._descriptor_text} has {num_channels} analog output channel(s) "
                    f"(0..{num_channels - 1})"
                )
            if ao_range not in ranges:
                names = [getattr(r, "name", str(r)) for r in ranges]
                raise AmplifierBackendError(
                    f"UldaqAmplifierBackend: field 'ao_range' = {self._ao_range_name} is not "
                    f"supported by {self._descriptor_text}; supported: {names}"
                )
            if self._monitor_channel is not None:
                self._ai_device = self._device.get_ai_device()
                if self._ai_device is None:
                    raise AmplifierBackendError(
                        f"UldaqAmplifierBackend: monitor_channel set but {self._descriptor_text} "
                        "has no analog input; set monitor_channel to None"
                    )
            self._is_open = True
            self.write_voltage(0.0)
        except BaseException:
            self._is_open = False
            self._release_device()
            raise

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
                self._enum("Range", self._monitor_range_name),
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
        """Write 0 V, disconnect and release the DAQ.

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
