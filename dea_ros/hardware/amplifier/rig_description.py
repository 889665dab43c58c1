"""The amplifier and its DAQ described against what the configuration expects (pure: no I/O).

:func:`describe_amplifier_rig` compares a DAQ board (:class:`DaqBoardInfo`, read from the device
by :func:`~dea_ros.hardware.amplifier.uldaq.query_uldaq_board`, or :meth:`DaqBoardInfo.known`
for the boards of :data:`KNOWN_DAQ_BOARDS`) with what amplifier_node's configuration expects
(:class:`AmplifierRigExpectation`): the analog output range it chooses, the DAQ output at the
ceiling, and every mismatch, each a sentence naming the parameter and the likely slip
(:class:`AmplifierRigDescription`). uldaq ``Range`` names are parsed by :func:`parse_daq_range`.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from ...errors import AmplifierBackendError

__all__ = [
    "KNOWN_DAQ_BOARDS",
    "GAIN_TOLERANCE",
    "DaqBoardInfo",
    "AmplifierRigExpectation",
    "AmplifierRigDescription",
    "describe_amplifier_rig",
    "parse_daq_range",
    "choose_daq_range",
]

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


#: The analog output ranges, analog input (mode -> channels, ranges) and digital ports of the
#: boards this project was checked against (libuldaq sources, src/usb/ao|ai|dio/*.cpp; MCC
#: user's guides): what :func:`~dea_ros.hardware.amplifier.uldaq.query_uldaq_board` reports for them,
#: and what the test fake offers.
KNOWN_DAQ_BOARDS: dict[str, dict[str, Any]] = {
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
    ao_ranges: tuple[str, ...]
    ai: tuple[tuple[str, int, tuple[str, ...]], ...] = ()
    dio: tuple[tuple[str, int, str], ...] = ()

    def __post_init__(self) -> None:  # canonical form: comparable whatever order the library lists
        object.__setattr__(self, "ao_ranges", tuple(self.ao_ranges))
        object.__setattr__(self, "ai", tuple(sorted((str(m), int(n), tuple(r)) for m, n, r in self.ai)))
        object.__setattr__(self, "dio", tuple((str(p), int(n), str(t)) for p, n, t in self.dio))

    @property
    def label(self) -> str:
        return f"{self.product_name} ({self.unique_id})" if self.unique_id else self.product_name

    def ai_mode(self, mode: str) -> tuple[int, tuple[str, ...]] | None:
        for name, channels, ranges in self.ai:
            if name == mode:
                return channels, ranges
        return None

    def dio_port(self, port: str) -> tuple[int, str] | None:
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
    """What the configuration of amplifier_node expects of the amplifier and its DAQ (SI units).

    ``amplifier_gain_V_per_V`` x ``amplifier_input_full_scale_V`` must equal
    ``amplifier_max_output_V`` (a gain slip shows here).
    """

    backend: str  #: mock, uldaq or inprocess
    ceiling_V: float  #: the highest high voltage ever applied (decided at start-up), V
    amplifier_gain_V_per_V: float = 1000.0  #: amplifier output per input volt (TREK 10/10B-HS: 1000)
    amplifier_max_output_V: float = 10000.0  #: rated output of the amplifier, V (TREK 10/10B-HS: 10000)
    amplifier_input_full_scale_V: float = 10.0  #: input giving the rated output, V (TREK: 10)
    unique_id: str | None = None  #: the DAQ's serial number (None: the first one found)
    ao_channel: int = 0  #: analog output wired to the amplifier input
    #: uldaq Range name, or "auto" (the smallest the board offers that covers 0 .. ceiling / gain)
    ao_range: str = "auto"
    monitor_channel: int | None = None  #: analog input wired to the amplifier's voltage monitor (None: none)
    monitor_gain_V_per_V: float | None = None  #: high volts per monitor volt (None: the amplifier gain)
    monitor_range: str = "auto"  #: uldaq Range name or "auto" (the smallest covering the rated output)
    monitor_input_mode: str = "SINGLE_ENDED"  #: uldaq AiInputMode name (SINGLE_ENDED, DIFFERENTIAL)
    enable_port: str | None = None  #: uldaq DigitalPortType name of the enable/interlock line (None: none)
    enable_bit: int = 0  #: bit of that port


@dataclass(frozen=True)
class AmplifierRigDescription:
    """Result of :func:`describe_amplifier_rig`: what is there, what was chosen, what is wrong."""

    expected: AmplifierRigExpectation
    board: DaqBoardInfo | None
    ao_range: str | None  #: chosen analog output range (uldaq with a board)
    needed_daq_V: float  #: DAQ output at the ceiling = ceiling / gain, V
    reachable_V: float | None  #: chosen range's maximum x gain, V
    monitor_range: str | None  #: chosen monitor input range
    mismatches: tuple[str, ...]  #: each a sentence naming the parameter and the fix
    notes: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.mismatches

    def lines(self) -> list[str]:
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


def _range_span(name: str) -> tuple[float, float] | None:
    try:
        return parse_daq_range(name)
    except AmplifierBackendError:
        return None


def choose_daq_range(ranges, needed_V: float) -> str | None:
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
    expected: AmplifierRigExpectation, board: DaqBoardInfo | None = None
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
    gain = float(e.amplifier_gain_V_per_V)
    needed_daq_V = float(e.ceiling_V) / gain if gain > 0 else math.inf
    mismatches = _amplifier_mismatches(e, gain)
    notes: list[str] = []
    ao_range = monitor_range = None
    reachable_V = None
    if e.backend != "uldaq":
        mismatches += _without_daq_mismatches(e)
    elif board is not None:
        mismatches += _ao_channel_mismatches(e, board)
        ao_range, found = _ao_range(e, board, gain, needed_daq_V)
        mismatches += found
        if ao_range is not None:
            reachable_V, range_notes = _ao_range_notes(e, ao_range, gain, needed_daq_V)
            notes += range_notes
        if e.monitor_channel is not None:
            monitor_range, found = _monitor_range(e, board, gain)
            mismatches += found
        if e.enable_port is not None:
            mismatches += _enable_mismatches(e, board)
    return AmplifierRigDescription(e, board, ao_range, needed_daq_V, reachable_V, monitor_range,
                                   tuple(mismatches), tuple(notes))


def _amplifier_mismatches(e: AmplifierRigExpectation, gain: float) -> list[str]:
    """The amplifier's own checks: gain, ceiling vs rated output, gain x full scale vs rated output."""
    mismatches = []
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
    return mismatches


def _without_daq_mismatches(e: AmplifierRigExpectation) -> list[str]:
    """Monitor and enable line asked of a backend without a DAQ (mock, inprocess)."""
    mismatches = []
    if e.monitor_channel is not None:
        mismatches.append(f"monitor_channel = {e.monitor_channel}: the {e.backend} backend has no monitor "
                          "input (uldaq only); set monitor_channel to -1")
    if e.enable_port is not None:
        mismatches.append(f"enable_port = {e.enable_port!r}: the {e.backend} backend has no enable output "
                          "(uldaq only); set enable_port to ''")
    return mismatches


def _ao_channel_mismatches(e: AmplifierRigExpectation, board: DaqBoardInfo) -> list[str]:
    """The board has an analog output, and the configured channel."""
    if board.ao_channels <= 0:
        return [f"{board.label} has no analog output; use a DAQ with AO (USB-1208HS-4AO, USB-1608GX-2AO)"]
    if not (0 <= e.ao_channel < board.ao_channels):
        return [f"uldaq_channel = {e.ao_channel}, but {board.label} has analog output channels "
                f"0..{board.ao_channels - 1}"]
    return []


def _ao_range(e: AmplifierRigExpectation, board: DaqBoardInfo, gain: float,
              needed_daq_V: float) -> tuple[str | None, list[str]]:
    """The analog output range (chosen for "auto", checked when named) and the mismatches."""
    label = board.label
    wanted = str(e.ao_range).strip().upper()
    if wanted == "AUTO":
        ao_range = choose_daq_range(board.ao_ranges, needed_daq_V)
        if ao_range is None:
            return None, [
                f"no analog output range of {label} (ranges {list(board.ao_ranges)}) covers the needed "
                f"0..{needed_daq_V:.4g} V (ceiling {e.ceiling_V:.1f} V / gain {gain:g} V/V); a gain slip, "
                "or a board with a larger output range"]
        return ao_range, []
    if wanted not in board.ao_ranges:
        return None, [f"uldaq_range = {wanted} is not offered by {label}; it offers {list(board.ao_ranges)} "
                      "(use 'auto')"]
    span = _range_span(wanted)
    if span is None or span[0] > 0.0 or span[1] < needed_daq_V:
        return None, [f"uldaq_range = {wanted} does not cover the needed 0..{needed_daq_V:.4g} V "
                      f"(ceiling {e.ceiling_V:.1f} V / gain {gain:g} V/V)"]
    return wanted, []


def _ao_range_notes(e: AmplifierRigExpectation, ao_range: str, gain: float,
                    needed_daq_V: float) -> tuple[float, list[str]]:
    """What the chosen range reaches on the amplifier, V, and the notes on it (only software clamps)."""
    span = _range_span(ao_range)
    reachable_V = span[1] * gain
    notes = []
    if span[1] > e.amplifier_input_full_scale_V * (1.0 + GAIN_TOLERANCE):
        notes.append(f"the range {ao_range} can exceed the amplifier's {e.amplifier_input_full_scale_V:g} V "
                     "input full scale; only the software clamp prevents it")
    if reachable_V > e.ceiling_V:
        notes.append(f"the range reaches {reachable_V:g} V on the amplifier, above the ceiling "
                     f"{e.ceiling_V:.1f} V: the DAQ output is clamped at {needed_daq_V:.4g} V in software; "
                     "a hardware limit on the amplifier is the real protection")
    return reachable_V, notes


def _monitor_range(e: AmplifierRigExpectation, board: DaqBoardInfo, gain: float) -> tuple[str | None, list[str]]:
    """The monitor input's range (chosen for "auto", bipolar first) and the mismatches of mode, channel, range."""
    label = board.label
    mode = str(e.monitor_input_mode).strip().upper()
    found = board.ai_mode(mode)
    monitor_gain = e.monitor_gain_V_per_V or gain
    needed_monitor_V = e.amplifier_max_output_V / monitor_gain
    if found is None:
        return None, [f"monitor_input_mode = {mode}: {label} has analog input modes {[m for m, _, _ in board.ai]}"]
    channels, ai_ranges = found
    mismatches = []
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
        return monitor_range, mismatches
    if wanted_monitor not in ai_ranges:
        mismatches.append(f"monitor_range = {wanted_monitor} is not a {mode} range of {label}: {list(ai_ranges)}")
        return None, mismatches
    return wanted_monitor, mismatches


def _enable_mismatches(e: AmplifierRigExpectation, board: DaqBoardInfo) -> list[str]:
    """The enable/interlock port exists, has the bit and can output."""
    label = board.label
    port = str(e.enable_port).strip().upper()
    found_port = board.dio_port(port)
    if found_port is None:
        return [f"enable_port = {port}: {label} has digital ports {[p for p, _, _ in board.dio]}"]
    bits, io_type = found_port
    mismatches = []
    if not (0 <= e.enable_bit < bits):
        mismatches.append(f"enable_bit = {e.enable_bit}, but {port} of {label} has bits 0..{bits - 1}")
    if io_type == "IN":
        mismatches.append(f"enable_port = {port} of {label} is input-only")
    return mismatches
