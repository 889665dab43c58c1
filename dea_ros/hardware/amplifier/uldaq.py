"""The uldaq amplifier backend: a Measurement Computing USB DAQ drives the amplifier input.

:class:`UldaqAmplifierBackend` writes the analog output of a USB-1208/1608 series DAQ (via the
``uldaq`` package and the ``libuldaq`` C library) wired to the amplifier input: DAQ volts = high
voltage / amplifier gain (e.g. TREK 10/10B-HS, 1000 V/V). Optionally it reads the amplifier's
voltage monitor on an analog input and drives an enable/interlock line on a digital output.
On open it reads what the board offers and checks it against the configuration
(:func:`~dea_ros.hardware.amplifier.rig_description.describe_amplifier_rig`);
:func:`query_uldaq_board` reads a board without writing anything (``dea-ros rig check``).

``uldaq`` is an optional dependency, imported only when a device is opened or queried (it
loads ``libuldaq.so`` at import).
"""
from __future__ import annotations

import importlib
import math
import numbers
import warnings
from typing import Any

from ...errors import AmplifierBackendError, AmplifierRangeWarning
from .base import AmplifierBackend
from .rig_description import (
    AmplifierRigDescription,
    AmplifierRigExpectation,
    DaqBoardInfo,
    describe_amplifier_rig,
    parse_daq_range,
)

__all__ = [
    "UldaqAmplifierBackend",
    "query_uldaq_board",
    "ULDAQ_INSTALL_HINT",
    "AmplifierBackendError",
    "AmplifierRangeWarning",
]

ULDAQ_INSTALL_HINT = (
    "pip install uldaq and install libuldaq from Measurement Computing "
    "(https://github.com/mccdaq/uldaq: build and 'sudo make install', which also installs the udev rules)"
)


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


def query_uldaq_board(unique_id: str | None = None, interface: str = "USB") -> DaqBoardInfo:
    """Connect to a Measurement Computing DAQ, read what it offers, disconnect (writes nothing).

    For ``dea-ros rig check``: pass the result to :func:`describe_amplifier_rig`.
    Raises :class:`AmplifierBackendError` (no uldaq, no device, no such unique_id).
    """
    probe = UldaqAmplifierBackend(unique_id=unique_id, max_voltage_V=1.0, amplifier_gain_V_per_V=1000.0,
                                  interface=interface)
    return probe.read_board()


class UldaqAmplifierBackend(AmplifierBackend):
    """Amplifier driven by the analog output of a Measurement Computing DAQ (``uldaq``).

    * ``unique_id``: serial number of the DAQ (``DaqDeviceDescriptor.unique_id``); None uses
      the first device found;
    * ``channel``: analog output channel wired to the amplifier input;
    * ``amplifier_gain_V_per_V``: amplifier gain, V out per V in (TREK 10/10B-HS: 1000);
    * ``ao_range``: uldaq ``Range`` name of the analog output, or "auto": on open the smallest
      range the board reports that covers ``0 .. max_voltage_V / gain``
      (:func:`~dea_ros.hardware.amplifier.rig_description.describe_amplifier_rig`; none
      covering it refuses to open, naming the board and its ranges);
    * ``max_voltage_V``: highest high voltage ever written, V (required: the backend cannot
      know it). Writes above it are refused; the DAQ output is clamped to
      ``[0, min(range max, max_voltage_V / gain)]``;
    * ``strict_range_check``: a named ``ao_range`` whose maximum times the gain exceeds
      ``max_voltage_V`` gives an :class:`AmplifierRangeWarning`; with True an
      :class:`AmplifierBackendError` instead;
    * ``interface``: uldaq ``InterfaceType`` name used for discovery ('USB', 'ANY', ...);
    * ``amplifier_max_output_V``, ``amplifier_input_full_scale_V``: the amplifier's rating
      (checked against the gain on open);
    * ``monitor_channel``: analog input wired to the amplifier's voltage monitor (None: no
      monitor); ``monitor_gain_V_per_V``: high volts per monitor volt (required with a
      monitor: no default to the amplifier gain); ``monitor_range``: uldaq ``Range`` name of the monitor input, or
      "auto"; ``monitor_input_mode``: uldaq ``AiInputMode`` name of the monitor input;
    * ``enable_port``: uldaq ``DigitalPortType`` name of the amplifier's enable/interlock line
      (None: none); ``enable_bit`` its bit; ``enable_active_high`` its polarity;
    * ``enable_heartbeat``: while enabled, toggle the line on every write (for a hardware
      watchdog relay / retriggerable monostable that drops the enable when the toggling
      stops: protects against SIGKILL and a hung process too).

    ``uldaq`` is imported only in :meth:`open` (it loads ``libuldaq.so`` at import).
    """

    def __init__(
        self,
        unique_id: str | None = None,
        channel: int = 0,
        amplifier_gain_V_per_V: float = 1000.0,
        ao_range: str = "auto",
        *,
        max_voltage_V: float,
        strict_range_check: bool = False,
        interface: str = "USB",
        amplifier_max_output_V: float = 10000.0,
        amplifier_input_full_scale_V: float = 10.0,
        monitor_channel: int | None = None,
        monitor_gain_V_per_V: float | None = None,
        monitor_range: str = "auto",
        monitor_input_mode: str = "SINGLE_ENDED",
        enable_port: str | None = None,
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
        if monitor_channel is not None and monitor_gain_V_per_V is None:
            raise AmplifierBackendError(
                "field 'monitor_gain_V_per_V': required with a monitor_channel (a separate setting: defaulting it to "
                "the amplifier gain would make a gain slip invisible to the monitor)")
        self._monitor_gain = (
            self._gain
            if monitor_gain_V_per_V is None
            else self._positive("monitor_gain_V_per_V", monitor_gain_V_per_V)
        )
        self._ao_range_request = str(ao_range).strip().upper()
        self._ao_range_name: str | None = None
        if self._ao_range_request != "AUTO":
            self._ao_range_name = self._ao_range_request
            self._set_range_limits(self._ao_range_name, strict_range_check, warn=True)
        self._monitor_range_request = str(monitor_range).strip().upper()
        if self._monitor_range_request != "AUTO":
            parse_daq_range(self._monitor_range_request)
        self._monitor_range_name: str | None = None
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
        self._faulted: str | None = None
        self._last_daq_V: float | None = None
        self._descriptor_text = ""
        self._board: DaqBoardInfo | None = None
        self._description: AmplifierRigDescription | None = None

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
    def ao_range(self) -> str | None:
        """The analog output range in use (chosen on open when "auto"; None before)."""
        return self._ao_range_name

    @property
    def daq_limit_V(self) -> float | None:
        """Largest DAQ output ever written, V (= min(range max, max_voltage_V / gain)); None
        while the range is not chosen yet."""
        return getattr(self, "_daq_limit_V", None)

    @property
    def last_daq_V(self) -> float | None:
        """Last value written to the DAQ analog output, V."""
        return self._last_daq_V

    @property
    def faulted(self) -> str | None:
        """Why the backend stopped working (None while healthy)."""
        return self._faulted

    @property
    def device_description(self) -> str:
        return self._descriptor_text

    @property
    def board(self) -> DaqBoardInfo | None:
        """What the connected board reported on open."""
        return self._board

    @property
    def rig_description(self) -> AmplifierRigDescription | None:
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

    def read_monitor_V(self) -> float | None:
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
        zero_error: BaseException | None = None
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
