"""ILD1320 ASCII commands and replies: formatting and parsing (pure, no I/O).

The sources of the facts below are in :mod:`dea_ros.hardware.laser.ild1320_protocol`.

*Measuring rate* -- ILD1320 rates 0.25, 0.5, 1 and 2 kHz, set and queried with
``MEASRATE`` in kHz. [1320 manual ch. 6.4: 500 us cycle at 2 kHz, the maximum;
the rate list itself is the 1420's (``0.25|0.5|1|2|4``) without 4 kHz:
**unverified for the 1320**.] A ``MEASRATE`` reply with any other number (0, 7, ...)
is a bad reply (:class:`~dea_ros.errors.SensorError`), never a rate to compute with.

*ASCII commands* [1220 manual A 3.1, 1320 manual A 3.1-A 3.6, 1420 manual A 3.3]:
a command is its name and zero or more parameters separated by blanks, ended by
LF (CR LF is allowed); parameters containing blanks are quoted. A command without
parameters returns the current value. The reply format is ``<Command name>
<Parameter1> [<Parameter2> ...]`` (it can be sent back as a command). "After
processing a command always a return and a prompt (``->``) is returned"; an error
message ``Exxx <text>`` (or a warning ``Wxxx <text>``, the command is executed)
precedes the prompt. Commands used here: ``GETINFO`` (``Name: ILD1320-10``,
``Serial:``, ``Measuring range: 10.00mm``, ... lines), ``MEASRATE``, ``OUTPUT
NONE|RS422|ANALOG`` (1420 manual A 3.5.1), ``OUTADD_RS422 NONE|<values>`` (1320
manual A 3.5.3.2), ``OUTHOLD NONE|0|<count>`` (1320 manual A 3.6 lists it; syntax
of the family), ``MASTERMV NONE|MASTER <MV>`` (1420 manual A 3.4.6.2). **Unverified:** the laser command name
``LASERPOW FULL|OFF`` (1x20 family naming, not found in the searched pages), the
number formatting of the ``MEASRATE`` reply (the parser accepts any number), the
line terminator of replies (CR LF assumed, LF accepted) and whether the sensor
echoes the command (an echo line is tolerated and dropped).
"""
from __future__ import annotations

import math
import re
import shlex
from dataclasses import dataclass, field
from typing import Sequence

from ....errors import CommandError, SensorError

__all__ = [
    "ALLOWED_MEASURING_RATES_HZ",
    "ADDITIONAL_OUTPUTS",
    "PROMPT",
    "COMMAND_TERMINATOR",
    "CommandError",
    "CommandReply",
    "SensorInfo",
    "command_bytes",
    "parse_command_line",
    "validate_measuring_rate_hz",
    "format_rate_khz",
    "getinfo_command",
    "measrate_command",
    "laser_command",
    "output_command",
    "mastermv_command",
    "outadd_rs422_command",
    "outhold_command",
    "find_reply_end",
    "parse_reply",
    "resync_first_line",
    "render_reply",
    "render_error",
    "parse_getinfo_reply",
    "parse_measrate_value_hz",
    "parse_measrate_reply",
    "parse_laser_reply",
    "parse_output_reply",
    "parse_mastermv_reply",
    "parse_outadd_rs422_reply",
    "parse_outhold_reply",
]

#: Measuring rates of the ILD1320 in Hz (0.25, 0.5, 1, 2 kHz).
ALLOWED_MEASURING_RATES_HZ: tuple[float, ...] = (250.0, 500.0, 1000.0, 2000.0)
#: Prompt ending every reply.
PROMPT = b"->"
#: Terminator appended to commands (the sensor requires LF and accepts CR LF).
COMMAND_TERMINATOR = b"\r\n"

_ERROR_LINE = re.compile(r"^E(\d{2,3})\b\s*(.*)$")
_WARNING_LINE = re.compile(r"^W(\d{2,3})\b\s*(.*)$")
_NUMBER = re.compile(r"^[-+]?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?$")


@dataclass(frozen=True)
class CommandReply:
    """A successful reply: body lines without echo, warnings and prompt."""

    command: str
    lines: tuple[str, ...]
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class SensorInfo:
    """Parsed ``GETINFO`` reply."""

    name: str
    serial: str
    measuring_range_m: float | None
    fields: dict[str, str] = field(default_factory=dict)


def command_bytes(command: str) -> bytes:
    """ASCII bytes of ``command`` with the terminator; rejects non-ASCII and line breaks."""
    text = str(command).strip()
    if not text:
        raise ValueError("empty command")
    if "\n" in text or "\r" in text:
        raise ValueError(f"command must be one line, got {command!r}")
    try:
        return text.encode("ascii") + COMMAND_TERMINATOR
    except UnicodeEncodeError:
        raise ValueError(f"command must be ASCII, got {command!r}") from None


def parse_command_line(line: str) -> tuple[str, list[str]]:
    """Split a received command line into (upper-case name, parameters).

    Blanks separate parameters; quoted parameters may contain blanks. Raises
    ``ValueError`` for an empty line or unbalanced quotes.
    """
    tokens = shlex.split(line.strip(), posix=True)
    if not tokens:
        raise ValueError("empty command line")
    return tokens[0].upper(), tokens[1:]


def validate_measuring_rate_hz(rate_hz: float) -> float:
    """Return the allowed ILD1320 rate equal to ``rate_hz``; ``ValueError`` otherwise."""
    try:
        value = float(rate_hz)
    except (TypeError, ValueError):
        raise ValueError(f"measuring rate must be a number of Hz, got {rate_hz!r}") from None
    for allowed in ALLOWED_MEASURING_RATES_HZ:
        if math.isclose(value, allowed, rel_tol=1e-9, abs_tol=1e-9):
            return allowed
    allowed_text = ", ".join(f"{r:g}" for r in ALLOWED_MEASURING_RATES_HZ)
    raise ValueError(f"measuring rate {rate_hz!r} Hz not supported by the ILD1320 (allowed: {allowed_text} Hz)")


def format_rate_khz(rate_hz: float) -> str:
    """The ``MEASRATE`` parameter (kHz) for an allowed rate: 250 Hz -> ``"0.25"``."""
    return f"{validate_measuring_rate_hz(rate_hz) / 1000.0:g}"


def getinfo_command() -> str:
    """``GETINFO``: request sensor information."""
    return "GETINFO"


def measrate_command(rate_hz: float | None = None) -> str:
    """``MEASRATE`` query (``rate_hz=None``) or set (rate in Hz, sent in kHz)."""
    return "MEASRATE" if rate_hz is None else f"MEASRATE {format_rate_khz(rate_hz)}"


def laser_command(on: bool | None = None) -> str:
    """Laser query (``None``), on (``LASERPOW FULL``) or off (``LASERPOW OFF``). Unverified name."""
    if on is None:
        return "LASERPOW"
    return "LASERPOW FULL" if on else "LASERPOW OFF"


def output_command(channel: str | None = "RS422") -> str:
    """``OUTPUT`` set (``NONE``, ``RS422`` or ``ANALOG``) or query (``None``)."""
    if channel is None:
        return "OUTPUT"
    name = str(channel).upper()
    if name not in ("NONE", "RS422", "ANALOG"):
        raise ValueError(f"output channel must be NONE, RS422 or ANALOG, got {channel!r}")
    return f"OUTPUT {name}"


def find_reply_end(buffer: bytes) -> int | None:
    """Index just past the first ``->`` prompt in ``buffer``, or ``None``."""
    index = bytes(buffer).find(PROMPT)
    return None if index < 0 else index + len(PROMPT)


def _normalise(text: str) -> str:
    return " ".join(text.split()).upper()


#: Text that can never be part of a reply: bytes >= 0x80 (decoded as U+FFFD), control characters.
_NOT_REPLY_TEXT = re.compile(r"[^\x20-\x7e\t]")
#: The first body line of a query's reply where it is not ``<COMMAND> <value>``.
_QUERY_REPLY_START = {"GETINFO": "Name:"}


def resync_first_line(line: str, sent_command: str) -> str:
    """The first line of a reply without what a stream left before it.

    A reply read from a sensor that was streaming may start with the remains of a frame (the
    stream does not stop for a reply, and a buffer trimmed while nobody read cuts frames): the
    line is cut after the last character a reply cannot contain, then at the earliest place a
    reply to ``sent_command`` can start (its echo, the query's answer ``<NAME> ...`` or
    ``Name:`` for ``GETINFO``, an error ``Exxx``). A line with none of these is kept as it is
    (the caller's parser then refuses it and the command is repeated).
    """
    bad = [m.end() for m in _NOT_REPLY_TEXT.finditer(line)]
    if bad:
        line = line[bad[-1]:]
    name = str(sent_command).split()[0].upper() if str(sent_command).split() else ""
    starts = [str(sent_command).strip(), name, _QUERY_REPLY_START.get(name, "")]
    positions = [line.upper().find(s.upper()) for s in starts if s]
    error = re.search(r"E\d{2,3}\b", line)
    if error:
        positions.append(error.start())
    found = [p for p in positions if p >= 0]
    return line[min(found):].strip() if found else line.strip()


def parse_reply(raw: bytes, sent_command: str) -> CommandReply:
    """Parse a complete reply (up to and including the prompt) to ``sent_command``.

    Drops an echo of the command if present, collects ``Wxxx`` warnings and
    raises :class:`CommandError` for an ``Exxx`` error line.
    """
    text = bytes(raw).decode("ascii", errors="replace")
    end = text.find(PROMPT.decode())
    if end >= 0:
        text = text[:end]
    lines = [line.strip() for line in re.split(r"\r?\n|\r", text)]
    lines = [line for line in lines if line]
    if lines:
        lines[0] = resync_first_line(lines[0], sent_command)
        lines = [line for line in lines if line]
    if lines and _normalise(lines[0]) == _normalise(sent_command):
        lines = lines[1:]
    body: list[str] = []
    warnings: list[str] = []
    for line in lines:
        error = _ERROR_LINE.match(line)
        if error:
            raise CommandError(sent_command, int(error.group(1)), error.group(2).strip())
        if _WARNING_LINE.match(line):
            warnings.append(line)
        else:
            body.append(line)
    return CommandReply(command=sent_command, lines=tuple(body), warnings=tuple(warnings))


def render_reply(lines: Sequence[str] = ()) -> bytes:
    """Reply bytes as the sensor sends them: body lines, a return, the prompt."""
    if lines:
        body = "".join(f"{line}\r\n" for line in lines)
    else:
        body = "\r\n"
    return body.encode("ascii") + PROMPT


def render_error(code: int, message: str) -> bytes:
    """Error reply bytes: ``Exxx message`` then the prompt."""
    return f"E{int(code):03d} {message}\r\n".encode("ascii") + PROMPT


def _value_of(reply: CommandReply, name: str) -> list[str]:
    """Parameters of the reply line ``<name> <p1> ...`` (or of a bare value line)."""
    upper = name.upper()
    for line in reversed(reply.lines):
        tokens = line.split()
        if tokens and tokens[0].upper() == upper:
            return tokens[1:]
    if len(reply.lines) == 1:
        return reply.lines[0].split()
    raise SensorError(f"reply to {reply.command!r} contains no {name} value: {list(reply.lines)!r}")


def parse_getinfo_reply(reply: CommandReply) -> SensorInfo:
    """``GETINFO`` reply -> :class:`SensorInfo` (measuring range converted to metres)."""
    fields: dict[str, str] = {}
    for line in reply.lines:
        key, sep, value = line.partition(":")
        if sep:
            fields[key.strip()] = value.strip()
    if "Name" not in fields:
        raise SensorError(f"GETINFO reply has no 'Name:' line: {list(reply.lines)!r}")
    measuring_range_m: float | None = None
    text = fields.get("Measuring range", "")
    match = re.match(r"^\s*([0-9]*\.?[0-9]+)\s*mm\s*$", text)
    if match:
        measuring_range_m = float(match.group(1)) * 1e-3
    return SensorInfo(
        name=fields["Name"],
        serial=fields.get("Serial", ""),
        measuring_range_m=measuring_range_m,
        fields=fields,
    )


def parse_measrate_value_hz(reply: CommandReply) -> float:
    """The number in a ``MEASRATE`` query reply (kHz), in Hz, *not* validated.

    Raises :class:`SensorError` when there is no finite number; use
    :func:`parse_measrate_reply` for a rate to work with.
    """
    params = _value_of(reply, "MEASRATE")
    if not params or not _NUMBER.match(params[0]):
        raise SensorError(f"cannot read a rate from the MEASRATE reply {list(reply.lines)!r}")
    value = float(params[0]) * 1000.0
    if not math.isfinite(value):
        raise SensorError(f"cannot read a rate from the MEASRATE reply {list(reply.lines)!r}")
    return value


def parse_measrate_reply(reply: CommandReply) -> float:
    """``MEASRATE`` query reply (kHz) -> measuring rate in Hz, one of the ILD1320 rates.

    A number that is not an ILD1320 rate (``MEASRATE 0``, ``MEASRATE 7``, ...)
    is a bad reply: :class:`SensorError` naming the reply and the allowed rates.
    """
    value = parse_measrate_value_hz(reply)
    try:
        return validate_measuring_rate_hz(value)
    except ValueError:
        allowed = ", ".join(f"{r:g}" for r in ALLOWED_MEASURING_RATES_HZ)
        raise SensorError(
            f"the sensor reports a measuring rate of {value:g} Hz (reply {list(reply.lines)!r}), "
            f"which is not an ILD1320 rate ({allowed} Hz)"
        ) from None


def mastermv_command(reset: bool = True) -> str:
    """``MASTERMV NONE`` (end any mastering) or the query ``MASTERMV`` (``reset=False``)."""
    return "MASTERMV NONE" if reset else "MASTERMV"


#: The additional values ``OUTADD_RS422`` can add after each distance, in output order.
ADDITIONAL_OUTPUTS = ("SHUTTER", "COUNTER", "TIMESTAMP", "INTENSITY", "STATE", "DIST_RAW")


def outadd_rs422_command(values: Sequence[str] | None = ()) -> str:
    """``OUTADD_RS422`` set (``()`` -> ``NONE``, or the additional values) or query (``None``)."""
    if values is None:
        return "OUTADD_RS422"
    names = [str(v).upper() for v in values]
    for name in names:
        if name not in ADDITIONAL_OUTPUTS:
            raise ValueError(f"additional output must be one of {', '.join(ADDITIONAL_OUTPUTS)}, got {name!r}")
    return "OUTADD_RS422 " + (" ".join(names) if names else "NONE")


def outhold_command(mode: str | None = "NONE") -> str:
    """``OUTHOLD NONE`` (errors are output as errors), ``0`` (hold forever), ``<n>`` cycles; ``None`` queries."""
    if mode is None:
        return "OUTHOLD"
    text = str(mode).strip().upper()
    if text != "NONE" and not (text.isdigit() and int(text) <= 2_147_483_645):
        raise ValueError(f"OUTHOLD mode must be NONE, 0 or a number of cycles, got {mode!r}")
    return f"OUTHOLD {text}"


def parse_mastermv_reply(reply: CommandReply) -> str:
    """``MASTERMV`` query reply -> ``"NONE"`` or the mastering as sent (``"MASTER 3.000000"``)."""
    params = _value_of(reply, "MASTERMV")
    if not params:
        raise SensorError(f"cannot read the mastering from the MASTERMV reply {list(reply.lines)!r}")
    return " ".join(p.upper() for p in params)


def parse_outadd_rs422_reply(reply: CommandReply) -> tuple[str, ...]:
    """``OUTADD_RS422`` query reply -> the additional values (``()`` for ``NONE``)."""
    params = [p.upper() for p in _value_of(reply, "OUTADD_RS422")]
    if not params:
        raise SensorError(f"cannot read the additional outputs from {list(reply.lines)!r}")
    if params == ["NONE"]:
        return ()
    return tuple(params)


def parse_outhold_reply(reply: CommandReply) -> str:
    """``OUTHOLD`` query reply -> ``"NONE"``, ``"0"`` or the number of cycles."""
    params = _value_of(reply, "OUTHOLD")
    if not params:
        raise SensorError(f"cannot read the hold mode from the OUTHOLD reply {list(reply.lines)!r}")
    return params[0].upper()


def parse_laser_reply(reply: CommandReply) -> bool:
    """``LASERPOW`` query reply -> True when the laser is on (any power but OFF)."""
    params = _value_of(reply, "LASERPOW")
    if not params:
        raise SensorError(f"cannot read the laser state from {list(reply.lines)!r}")
    return params[0].upper() != "OFF"


def parse_output_reply(reply: CommandReply) -> str:
    """``OUTPUT`` query reply -> channel name (``NONE``, ``RS422`` or ``ANALOG``)."""
    params = _value_of(reply, "OUTPUT")
    if not params:
        raise SensorError(f"cannot read the output channel from {list(reply.lines)!r}")
    return params[0].upper()
