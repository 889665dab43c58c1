"""Micro-Epsilon optoNCDT 1320 (ILD1320) RS422 protocol -- pure, no I/O.

Encoding and decoding of the binary measurement stream, an incremental
:class:`FrameDecoder` that resynchronises on corrupted streams, conversion of the
digital values to metres (with software tare), and formatting / parsing of the
ASCII commands. Nothing here touches a port or a clock.

Protocol facts and where they come from
---------------------------------------
Sources: the optoNCDT 1320 operating instructions (ILD1320 manual) and, where the
1320 pages could not be found, the optoNCDT 1420 / 1220 manuals of the same
sensor family, which share the interface chapter and the ASCII appendix.

*Serial interface* -- RS422, factory baud rate 921.6 kBaud (921600), maximum
1 MBaud, 8 data bits, no parity, one stop bit (8N1). Measurement values are sent
in binary, commands and replies as ASCII. [1420 manual ch. 8.1; **not seen in a
1320 page**, the family shares it.]

*Measurement frame* -- each output value is three bytes, sent L, M, H; the two
most significant bits of each byte are flag bits that identify it::

    L-byte  0 0 D5  D4  D3  D2  D1  D0
    M-byte  0 1 D11 D10 D9  D8  D7  D6
    H-byte  1 0 D17 D16 D15 D14 D13 D12

The flags are deleted and the remaining bits compiled into an 18-bit word
D17..D0; D16/D17 are needed for the error codes. [1320 manual ch. 8.3 for the
flag-bit identification and the 18-bit word; 1420 manual ch. 8.2 for the byte
layout.] The 1420 manual also says the H-byte of *additional* output values
(OUTADD_RS422: exposure, counter, ...) differs from that of the first value,
which "represents the identifier of a new block"; its wording is ambiguous about
the bit. **Unverified assumption:** additional values carry H flags ``11``. The
decoder emits only first values (H flags ``10``) and counts and skips ``11``
frames; with no additional values configured (the default) only ``10`` occurs.
The sensor keeps streaming values while it answers commands, so ASCII replies
arrive interleaved with frames [1320 manual ch. 8.3]. ASCII never contains a
byte >= 0x80, so text can never complete a frame; :class:`FrameDecoder` can
keep the non-frame bytes for the reply parser.

*Distance conversion* -- a distance is a 16-bit value ``x`` [1420 manual
ch. 7.5.2.1, not mastered]:

    d [mm] = (x * 1.02 / 65520 - 0.01) * MR [mm],    x in [0, 65520]

i.e. ``x`` in [0, 643) is the reserve before the start of the measuring range
(SMR), [643, 64877] the measuring range, (64877, 65520] the reserve after its end
(EMR); ``d`` spans [-0.01 MR, 1.01 MR] from the SMR. For the ILD1320-10,
``MR = 10 mm`` (default :data:`DEFAULT_MEASURING_RANGE_M`), so one digit is
``10 mm * 1.02 / 65520 = 0.1557 um`` (:func:`quantum_m`).

*Mastering* -- a sensor mastered with ``MASTERMV MASTER <MV>`` (a setting a
previous user may have left) sends 18-bit values shifted by the master value
[1420 manual ch. 7.5.2.1]: ``d_out [mm] = (x * 1.02 / 65520 - 0.51) * MR`` with
``d_out = d - MP + MV`` (MP: the distance at the time of mastering, MV: the
master value). Decoded with the formula above such values are off by
``MV - MP + 0.5 MR`` (and may exceed 65520). The backend therefore never reads a
mastered stream: on every connect it sends ``MASTERMV NONE`` and checks the
read-back (:func:`mastered_displacement_to_code` exists for the emulator only);
zeroing is the software tare.

*Error values* (18 bit, sent instead of a distance) [1420 manual ch. 7.5.2.1;
**not seen in a 1320 page**]:

======  ============================================  ==============================
code    manual                                        :class:`MeasurementError`
======  ============================================  ==============================
262075  data amount too big for selected baud rate   ``DATA_RATE_TOO_HIGH``
262076  no peak available                             ``NO_PEAK``
262077  peak before the measuring range              ``TARGET_TOO_CLOSE``
262078  peak behind the measuring range              ``TARGET_TOO_FAR``
262080  measurement value cannot be calculated       ``CANNOT_CALCULATE``
262081  peak is too large (wide)                     ``PEAK_TOO_WIDE``
262082  laser is off                                 ``LASER_OFF``
======  ============================================  ==============================

Any other value above 65520 decodes to ``MeasurementError.UNKNOWN_CODE``.

*Measuring rate* -- ILD1320 rates 0.25, 0.5, 1 and 2 kHz, set and queried with
``MEASRATE`` in kHz. [1320 manual ch. 6.4: 500 us cycle at 2 kHz, the maximum;
the rate list itself is the 1420's (``0.25|0.5|1|2|4``) without 4 kHz:
**unverified for the 1320**.] Timing [1320 manual ch. 6.4]: a value is output
three cycles after its acquisition (1.5 ms at 2 kHz), one value per cycle. A
``MEASRATE`` reply with any other number (0, 7, ...) is a bad reply
(:class:`~dea_ros.hardware.laser.SensorError`), never a rate to compute with.

*Known state on connect* [1320 manual A 3.5.3.2, A 3.6; 1420 manual A 3.4.6.2,
A 3.5.1]: ``OUTPUT RS422`` (values on the serial line), ``OUTADD_RS422 NONE``
(no additional values: exposure, counter, ... would interleave with the
distances), ``OUTHOLD NONE`` (an error value is sent as an error, never replaced
by the last valid value: a held value would look like a fresh, valid sample),
``MASTERMV NONE`` (no mastering), ``MEASRATE`` as configured; each read back.
The query replies are assumed to follow the general reply format ``<Command>
<Parameter> ...`` (``OUTHOLD NONE``, ``MASTERMV NONE``, ``OUTADD_RS422 NONE``):
**unverified** on a real ILD1320. :func:`check_laser_sensor` compares what the
sensor reports with the configuration (:class:`LaserSensorReport`).

*Plausibility* -- the binary stream has no checksum: a corrupted or random byte
sequence with the right flag bits decodes to a "valid" distance. Every distance
therefore passes :class:`PlausibilityFilter` (inside the measuring range, not
the first frame after a framing error, within the distance the mass can travel
since the previous accepted value, confirmed by consecutive samples when there
is no trusted previous value).

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
from typing import Iterable, NamedTuple, Optional, Sequence, Union

from dea_ros.hardware.laser import MeasurementError, SensorError
from ..errors import CommandError, FrameFormatError

__all__ = [
    # serial settings
    "DEFAULT_BAUDRATE",
    "SERIAL_BYTESIZE",
    "SERIAL_PARITY",
    "SERIAL_STOPBITS",
    # frame format
    "BYTES_PER_VALUE",
    "FLAG_L",
    "FLAG_M",
    "FLAG_H",
    "FLAG_H_ADDITIONAL",
    "MAX_RAW_CODE",
    "DISTANCE_CODE_MAX",
    "SMR_CODE",
    "EMR_CODE",
    "DEFAULT_MEASURING_RANGE_M",
    "ERROR_CODES",
    "OUTPUT_DELAY_CYCLES",
    "ALLOWED_MEASURING_RATES_HZ",
    "FrameFormatError",
    "Sample",
    "encode_value",
    "decode_frame",
    "quantum_m",
    "code_to_displacement_m",
    "displacement_to_code",
    "error_to_code",
    "encode_displacement",
    "apply_tare",
    "FrameDecoder",
    # ASCII commands
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
    "find_reply_end",
    "parse_reply",
    "render_reply",
    "render_error",
    "parse_getinfo_reply",
    "parse_measrate_reply",
    "parse_laser_reply",
    "parse_output_reply",
    "mastermv_command",
    "outadd_rs422_command",
    "outhold_command",
    "parse_mastermv_reply",
    "parse_outadd_rs422_reply",
    "parse_outhold_reply",
    "parse_measrate_value_hz",
    "mastered_displacement_to_code",
    # connected sensor vs configuration
    "MODEL_PREFIX",
    "KNOWN_STATE",
    "LaserSensorSettings",
    "LaserSensorExpectation",
    "LaserSensorReport",
    "check_laser_sensor",
    # plausibility of samples
    "DEFAULT_MAX_SPEED_M_PER_S",
    "DEFAULT_JUMP_TOLERANCE_M",
    "DEFAULT_CONFIRM_SAMPLES",
    "PlausibilityFilter",
]

# --------------------------------------------------------------------------- serial
#: Factory-set baud rate of the RS422 interface (921.6 kBaud).
DEFAULT_BAUDRATE = 921_600
#: 8N1 framing: 8 data bits, no parity, 1 stop bit.
SERIAL_BYTESIZE = 8
SERIAL_PARITY = "N"
SERIAL_STOPBITS = 1

# --------------------------------------------------------------------------- frames
#: Bytes per output value (L, M, H).
BYTES_PER_VALUE = 3
#: Flag bits (two most significant bits) of the L, M and H bytes.
FLAG_L = 0b00
FLAG_M = 0b01
FLAG_H = 0b10
#: H flags of an additional output value (assumption, see module docstring).
FLAG_H_ADDITIONAL = 0b11
_PAYLOAD_MASK = 0x3F
#: Largest 18-bit value.
MAX_RAW_CODE = (1 << 18) - 1
#: Largest distance code (16-bit range, end of the EMR reserve).
DISTANCE_CODE_MAX = 65_520
#: First code of the measuring range proper (start of measuring range, SMR).
SMR_CODE = 643
#: Last code of the measuring range proper (end of measuring range, EMR).
EMR_CODE = 64_877
_CODE_SCALE = 1.02 / DISTANCE_CODE_MAX  # fraction of MR per digit
_CODE_OFFSET = 0.01  # the reserve before the SMR, fraction of MR
#: Measuring range of the ILD1320-10 (10 mm).
DEFAULT_MEASURING_RANGE_M = 0.010

#: Error values sent in place of a distance.
ERROR_CODES: dict[int, MeasurementError] = {
    262_075: MeasurementError.DATA_RATE_TOO_HIGH,
    262_076: MeasurementError.NO_PEAK,
    262_077: MeasurementError.TARGET_TOO_CLOSE,
    262_078: MeasurementError.TARGET_TOO_FAR,
    262_080: MeasurementError.CANNOT_CALCULATE,
    262_081: MeasurementError.PEAK_TOO_WIDE,
    262_082: MeasurementError.LASER_OFF,
}
_ERROR_TO_CODE: dict[MeasurementError, int] = {v: k for k, v in ERROR_CODES.items()}

#: A value is output this many measuring cycles after its acquisition.
OUTPUT_DELAY_CYCLES = 3
#: Measuring rates of the ILD1320 in Hz (0.25, 0.5, 1, 2 kHz).
ALLOWED_MEASURING_RATES_HZ: tuple[float, ...] = (250.0, 500.0, 1000.0, 2000.0)


class Sample(NamedTuple):
    """One decoded output value: the 18-bit ``code`` and its meaning.

    ``value`` is the displacement in metres from the start of the measuring range
    (no tare applied) or a :class:`MeasurementError`.
    """

    code: int
    value: Union[float, MeasurementError]
    #: Bytes the decoder dropped between the previous frame and this one (> 0
    #: means frames may have been lost just before this sample).
    discarded_before: int = 0

    @property
    def is_valid(self) -> bool:
        return not isinstance(self.value, MeasurementError)


def _check_code(code: int) -> int:
    if isinstance(code, bool) or not isinstance(code, int):
        raise TypeError(f"raw code must be an int, got {code!r}")
    if not 0 <= code <= MAX_RAW_CODE:
        raise ValueError(f"raw code {code} outside the 18-bit range [0, {MAX_RAW_CODE}]")
    return code


def _check_range_m(measuring_range_m: float) -> float:
    value = float(measuring_range_m)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"measuring range must be a positive number of metres, got {measuring_range_m!r}")
    return value


def encode_value(code: int, *, additional: bool = False) -> bytes:
    """Encode an 18-bit value as the three bytes L, M, H (with flag bits)."""
    _check_code(code)
    low = (FLAG_L << 6) | (code & _PAYLOAD_MASK)
    mid = (FLAG_M << 6) | ((code >> 6) & _PAYLOAD_MASK)
    high_flag = FLAG_H_ADDITIONAL if additional else FLAG_H
    high = (high_flag << 6) | ((code >> 12) & _PAYLOAD_MASK)
    return bytes((low, mid, high))


def decode_frame(frame: bytes) -> int:
    """Decode exactly one first-value frame (L, M, H) into its 18-bit code.

    Raises :class:`FrameFormatError` if the length or any flag bits are wrong.
    """
    if len(frame) != BYTES_PER_VALUE:
        raise FrameFormatError(f"a frame has {BYTES_PER_VALUE} bytes, got {len(frame)}")
    low, mid, high = frame[0], frame[1], frame[2]
    flags = (low >> 6, mid >> 6, high >> 6)
    if flags != (FLAG_L, FLAG_M, FLAG_H):
        raise FrameFormatError(
            f"bad flag bits {flags} in frame {bytes(frame).hex()} (expected L=0b00, M=0b01, H=0b10)"
        )
    return (low & _PAYLOAD_MASK) | ((mid & _PAYLOAD_MASK) << 6) | ((high & _PAYLOAD_MASK) << 12)


def quantum_m(measuring_range_m: float = DEFAULT_MEASURING_RANGE_M) -> float:
    """Digital resolution in metres: one code step (0.1557 um for 10 mm)."""
    return _check_range_m(measuring_range_m) * _CODE_SCALE


def code_to_displacement_m(
    code: int, measuring_range_m: float = DEFAULT_MEASURING_RANGE_M
) -> Union[float, MeasurementError]:
    """Convert an 18-bit code to metres from the SMR, or to a named error."""
    _check_code(code)
    if code <= DISTANCE_CODE_MAX:
        return (code * _CODE_SCALE - _CODE_OFFSET) * _check_range_m(measuring_range_m)
    return ERROR_CODES.get(code, MeasurementError.UNKNOWN_CODE)


def error_to_code(error: MeasurementError) -> int:
    """The code the sensor sends for ``error`` (``UNKNOWN_CODE`` has none)."""
    try:
        return _ERROR_TO_CODE[MeasurementError(error)]
    except (KeyError, ValueError):
        raise ValueError(f"{error!r} has no ILD1320 error code") from None


def displacement_to_code(
    value: Union[float, MeasurementError], measuring_range_m: float = DEFAULT_MEASURING_RANGE_M
) -> int:
    """What the sensor would send for a displacement (metres from the SMR).

    Quantises to the nearest code. Beyond the reserves, i.e. outside
    [-0.01 MR, 1.01 MR] after rounding, gives ``TARGET_TOO_CLOSE`` /
    ``TARGET_TOO_FAR``; NaN gives ``NO_PEAK``; a :class:`MeasurementError` gives
    its own code.
    """
    if isinstance(value, MeasurementError):
        return error_to_code(value)
    d = float(value)
    if math.isnan(d):
        return _ERROR_TO_CODE[MeasurementError.NO_PEAK]
    scaled = (d / _check_range_m(measuring_range_m) + _CODE_OFFSET) / _CODE_SCALE
    if scaled < -0.5:
        return _ERROR_TO_CODE[MeasurementError.TARGET_TOO_CLOSE]
    if scaled >= DISTANCE_CODE_MAX + 0.5:
        return _ERROR_TO_CODE[MeasurementError.TARGET_TOO_FAR]
    return min(max(int(round(scaled)), 0), DISTANCE_CODE_MAX)


def encode_displacement(
    value: Union[float, MeasurementError], measuring_range_m: float = DEFAULT_MEASURING_RANGE_M
) -> bytes:
    """Frame bytes the sensor would send for a displacement (see :func:`displacement_to_code`)."""
    return encode_value(displacement_to_code(value, measuring_range_m))


#: Offset of the mastered (18-bit) output code, fraction of MR [1420 manual ch. 7.5.2.1].
_MASTERED_CODE_OFFSET = 0.51
#: Largest mastered code the emulator sends (just below the error codes).
_MASTERED_CODE_MAX = min(ERROR_CODES) - 1


def mastered_displacement_to_code(
    value: Union[float, MeasurementError],
    master_position_m: float,
    master_value_m: float,
    measuring_range_m: float = DEFAULT_MEASURING_RANGE_M,
) -> int:
    """What a *mastered* sensor sends for a distance ``value`` (metres from the SMR).

    ``d_out = value - master_position_m + master_value_m`` coded as
    ``x = (d_out / MR + 0.51) * 65520 / 1.02`` (18 bit, see the module docstring).
    Only the emulator uses it: the backend resets mastering instead of decoding it.
    Values outside the sensor's range still give the range error codes.
    """
    if isinstance(value, MeasurementError) or math.isnan(float(value)):
        return displacement_to_code(value, measuring_range_m)
    range_m = _check_range_m(measuring_range_m)
    if displacement_to_code(value, range_m) in ERROR_CODES:  # beyond the reserves
        return displacement_to_code(value, range_m)
    d_out = float(value) - float(master_position_m) + float(master_value_m)
    scaled = (d_out / range_m + _MASTERED_CODE_OFFSET) / _CODE_SCALE
    if scaled < -0.5:
        return _ERROR_TO_CODE[MeasurementError.TARGET_TOO_CLOSE]
    return min(max(int(round(scaled)), 0), _MASTERED_CODE_MAX)


def apply_tare(
    value: Union[float, MeasurementError], tare_offset_m: float
) -> Union[float, MeasurementError]:
    """Subtract the software zero offset (metres); errors pass through unchanged."""
    if isinstance(value, MeasurementError):
        return value
    return float(value) - float(tare_offset_m)


class FrameDecoder:
    """Incremental decoder of the binary stream; resynchronises on the flag bits.

    ``feed(data)`` accepts any chunking of the stream (frames may be split
    between calls) and returns the complete first-value frames as
    :class:`Sample`. Bytes that cannot belong to a valid L, M, H sequence are
    dropped and counted; the decoder never raises on content. A frame is
    recognised only as three consecutive bytes with flags L, M, H, so one
    corrupted or missing byte loses at most the frame it belongs to.

    Counters (all cumulative): ``frames_decoded``, ``additional_values_skipped``
    (H flags ``11``), ``bytes_discarded`` (bytes outside any valid frame,
    including interleaved ASCII replies) and ``partial_frames_dropped``
    (incomplete L or L, M prefixes abandoned). Each :class:`Sample` carries the
    number of bytes discarded since the previous frame, and
    :attr:`discarded_since_last_frame` those after the newest frame, so a
    consumer can tell where in the stream frames may have been lost.

    With ``keep_non_frame_bytes=True`` the discarded bytes are retained in order
    (at most ``max_non_frame_bytes``, oldest dropped first) so that ASCII command
    replies interleaved with the stream can be recovered, see
    :meth:`non_frame_bytes` and :meth:`consume_non_frame_bytes`.
    """

    def __init__(
        self,
        measuring_range_m: float = DEFAULT_MEASURING_RANGE_M,
        *,
        keep_non_frame_bytes: bool = False,
        max_non_frame_bytes: int = 8192,
    ) -> None:
        self.measuring_range_m = _check_range_m(measuring_range_m)
        if int(max_non_frame_bytes) <= 0:
            raise ValueError(f"max_non_frame_bytes must be positive, got {max_non_frame_bytes!r}")
        self._keep = bool(keep_non_frame_bytes)
        self._max_non_frame = int(max_non_frame_bytes)
        self._pending = bytearray()  # b"" or L or L, M
        self._non_frame = bytearray()
        self.frames_decoded = 0
        self.additional_values_skipped = 0
        self.bytes_discarded = 0
        self.partial_frames_dropped = 0
        self.non_frame_bytes_overflowed = 0
        self._discarded_since_frame = 0

    def reset(self) -> None:
        """Forget any partial frame and retained bytes (counters are kept)."""
        self._pending.clear()
        self._non_frame.clear()
        self._discarded_since_frame = 0

    @property
    def discarded_since_last_frame(self) -> int:
        """Bytes discarded after the most recent complete frame."""
        return self._discarded_since_frame

    @property
    def pending_bytes(self) -> int:
        """Number of bytes of an incomplete frame held back (0, 1 or 2)."""
        return len(self._pending)

    def _discard(self, data: Iterable[int]) -> None:
        chunk = bytes(data)
        self.bytes_discarded += len(chunk)
        self._discarded_since_frame += len(chunk)
        if self._keep and chunk:
            self._non_frame += chunk
            excess = len(self._non_frame) - self._max_non_frame
            if excess > 0:
                del self._non_frame[:excess]
                self.non_frame_bytes_overflowed += excess

    def _abandon_pending(self) -> None:
        if self._pending:
            self.partial_frames_dropped += 1
            self._discard(self._pending)
            self._pending.clear()

    def feed(self, data: bytes) -> list[Sample]:
        """Decode ``data`` (any length, any split point) and return the new samples."""
        samples: list[Sample] = []
        pending = self._pending
        range_m = self.measuring_range_m
        for byte in bytes(data):
            flag = byte >> 6
            if flag == FLAG_L:
                self._abandon_pending()
                pending.append(byte)
            elif flag == FLAG_M:
                if len(pending) == 1:
                    pending.append(byte)
                else:
                    self._abandon_pending()
                    self._discard((byte,))
            else:  # FLAG_H or FLAG_H_ADDITIONAL
                if len(pending) == 2:
                    code = (
                        (pending[0] & _PAYLOAD_MASK)
                        | ((pending[1] & _PAYLOAD_MASK) << 6)
                        | ((byte & _PAYLOAD_MASK) << 12)
                    )
                    pending.clear()
                    if flag == FLAG_H:
                        self.frames_decoded += 1
                        samples.append(
                            Sample(code, code_to_displacement_m(code, range_m), self._discarded_since_frame)
                        )
                    else:
                        self.additional_values_skipped += 1
                    self._discarded_since_frame = 0
                else:
                    self._abandon_pending()
                    self._discard((byte,))
        return samples

    # -- retained non-frame bytes (ASCII replies) ---------------------------------
    def non_frame_bytes(self) -> bytes:
        """Retained non-frame bytes followed by the held-back partial frame bytes.

        The partial frame is included because a reply's final characters (the
        ``->`` prompt is two L-type bytes) stay pending until the next byte.
        """
        return bytes(self._non_frame) + bytes(self._pending)

    def consume_non_frame_bytes(self, count: int) -> None:
        """Remove the first ``count`` bytes of :meth:`non_frame_bytes`."""
        count = int(count)
        available = len(self._non_frame) + len(self._pending)
        if not 0 <= count <= available:
            raise ValueError(f"cannot consume {count} of {available} non-frame bytes")
        if count <= len(self._non_frame):
            del self._non_frame[:count]
            return
        from_pending = count - len(self._non_frame)
        self._non_frame.clear()
        self.bytes_discarded += from_pending
        self._discarded_since_frame += from_pending
        rest = bytes(self._pending[from_pending:])
        self._pending.clear()
        if rest:
            if rest[0] >> 6 == FLAG_L:
                self._pending += rest
            else:  # an orphan M byte cannot start a frame
                self._discard(rest)

    def clear_non_frame_bytes(self) -> None:
        """Drop the retained non-frame bytes (the pending partial frame is kept)."""
        self._non_frame.clear()


# --------------------------------------------------------------------------- ASCII
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
    measuring_range_m: Optional[float]
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


def measrate_command(rate_hz: Optional[float] = None) -> str:
    """``MEASRATE`` query (``rate_hz=None``) or set (rate in Hz, sent in kHz)."""
    return "MEASRATE" if rate_hz is None else f"MEASRATE {format_rate_khz(rate_hz)}"


def laser_command(on: Optional[bool] = None) -> str:
    """Laser query (``None``), on (``LASERPOW FULL``) or off (``LASERPOW OFF``). Unverified name."""
    if on is None:
        return "LASERPOW"
    return "LASERPOW FULL" if on else "LASERPOW OFF"


def output_command(channel: Optional[str] = "RS422") -> str:
    """``OUTPUT`` set (``NONE``, ``RS422`` or ``ANALOG``) or query (``None``)."""
    if channel is None:
        return "OUTPUT"
    name = str(channel).upper()
    if name not in ("NONE", "RS422", "ANALOG"):
        raise ValueError(f"output channel must be NONE, RS422 or ANALOG, got {channel!r}")
    return f"OUTPUT {name}"


def find_reply_end(buffer: bytes) -> Optional[int]:
    """Index just past the first ``->`` prompt in ``buffer``, or ``None``."""
    index = bytes(buffer).find(PROMPT)
    return None if index < 0 else index + len(PROMPT)


def _normalise(text: str) -> str:
    return " ".join(text.split()).upper()


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
    measuring_range_m: Optional[float] = None
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


_OUTADD_VALUES = ("SHUTTER", "COUNTER", "TIMESTAMP", "INTENSITY", "STATE", "DIST_RAW")


def outadd_rs422_command(values: Optional[Sequence[str]] = ()) -> str:
    """``OUTADD_RS422`` set (``()`` -> ``NONE``, or the additional values) or query (``None``)."""
    if values is None:
        return "OUTADD_RS422"
    names = [str(v).upper() for v in values]
    for name in names:
        if name not in _OUTADD_VALUES:
            raise ValueError(f"additional output must be one of {', '.join(_OUTADD_VALUES)}, got {name!r}")
    return "OUTADD_RS422 " + (" ".join(names) if names else "NONE")


def outhold_command(mode: Optional[str] = "NONE") -> str:
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


# --------------------------------------------------------------------------- connected sensor
#: Model name prefix of the sensors this backend drives (``GETINFO`` ``Name:`` line).
MODEL_PREFIX = "ILD1320"

#: The state the backend puts the sensor into on every connect (query reply values).
KNOWN_STATE: dict[str, object] = {
    "output": "RS422",
    "additional_outputs": (),
    "output_hold": "NONE",
    "mastering": "NONE",
}

_RANGE_ABS_TOL_M = 5e-6  # GETINFO prints the range in mm with 2 decimals


@dataclass(frozen=True)
class LaserSensorSettings:
    """What a connected ILD1320 reports about itself (``None``: not read / unreadable).

    ``measuring_rate_hz`` is the number the sensor sent, not validated (it may be
    0 or 7000 on a misbehaving sensor). ``unreadable`` has one sentence per reply
    that could not be read.
    """

    model: str = ""
    serial_number: str = ""
    measuring_range_m: Optional[float] = None
    measuring_rate_hz: Optional[float] = None
    output: Optional[str] = None
    additional_outputs: Optional[tuple[str, ...]] = None
    output_hold: Optional[str] = None
    mastering: Optional[str] = None
    unreadable: tuple[str, ...] = ()


@dataclass(frozen=True)
class LaserSensorExpectation:
    """What the configuration expects of the sensor.

    ``measuring_range_m``: the head's measuring range (laser_sensor_node parameter
    ``measuring_range_m``); ``None`` accepts any range the sensor reports.
    ``measuring_rate_hz``: the rate the node sets on connect (``None``: keep).
    """

    measuring_range_m: Optional[float] = DEFAULT_MEASURING_RANGE_M
    measuring_rate_hz: Optional[float] = None


@dataclass(frozen=True)
class LaserSensorReport:
    """The connected sensor, the configuration's expectation and their differences.

    ``mismatches``: differences that make the sensor unusable with this
    configuration (another model or measuring range, a rate that is not an
    ILD1320 rate, an unreadable identity): the node refuses to stream.
    ``to_reset``: settings that differ from :data:`KNOWN_STATE` or the configured
    rate; the backend sets them on connect (and reads them back).
    """

    settings: LaserSensorSettings
    expected: LaserSensorExpectation
    mismatches: tuple[str, ...] = ()
    to_reset: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return not self.mismatches

    def lines(self) -> list[str]:
        """Human-readable report, one fact per line."""
        s, e = self.settings, self.expected

        def mm(value: Optional[float]) -> str:
            return "unknown" if value is None else f"{value * 1e3:g} mm"

        def hz(value: Optional[float]) -> str:
            return "unknown" if value is None else f"{value:g} Hz"

        extra = "unknown" if s.additional_outputs is None else (" ".join(s.additional_outputs) or "NONE")
        out = [
            f"laser sensor: {s.model or 'unknown model'}, serial {s.serial_number or 'unknown'}",
            f"  measuring range: {mm(s.measuring_range_m)} (configuration: "
            f"{'any' if e.measuring_range_m is None else mm(e.measuring_range_m)})",
            f"  measuring rate: {hz(s.measuring_rate_hz)} (configuration: "
            f"{'keep' if e.measuring_rate_hz is None else hz(e.measuring_rate_hz)})",
            f"  output {s.output or 'unknown'}, additional outputs {extra}, "
            f"hold {s.output_hold or 'unknown'}, mastering {s.mastering or 'unknown'}",
        ]
        out += [f"  unreadable: {text}" for text in s.unreadable]
        out += [f"  reset on connect: {text}" for text in self.to_reset]
        out += [f"  MISMATCH: {text}" for text in self.mismatches]
        return out


def _range_from_model_m(model: str) -> Optional[float]:
    match = re.match(r"^ILD\s*1320\s*-\s*(\d+(?:\.\d+)?)\b", model.strip(), re.IGNORECASE)
    return None if match is None else float(match.group(1)) * 1e-3


def check_laser_sensor(settings: LaserSensorSettings, expected: LaserSensorExpectation) -> LaserSensorReport:
    """Compare what the sensor reports with the configuration (pure, no I/O).

    Returns a :class:`LaserSensorReport` whose ``mismatches`` name the setting,
    the sensor's value, the configuration's value and the fix.
    """
    mismatches: list[str] = []
    to_reset: list[str] = []
    model = settings.model.strip()
    if not model:
        mismatches.append("model: GETINFO reported no 'Name:'; cannot identify the sensor")
    elif not model.replace(" ", "").upper().startswith(MODEL_PREFIX):
        mismatches.append(f"model: the sensor is a {model!r}; this backend drives an {MODEL_PREFIX} "
                          f"(other models use other rates and codes)")
    reported_range = settings.measuring_range_m
    if reported_range is None:
        mismatches.append("measuring range: GETINFO reported no 'Measuring range: <n>mm'; distances "
                          "cannot be converted without it")
    elif not (math.isfinite(reported_range) and reported_range > 0.0):
        mismatches.append(f"measuring range: GETINFO reported {reported_range!r} m, not a positive range")
    else:
        model_range = _range_from_model_m(model)
        if model_range is not None and abs(model_range - reported_range) > _RANGE_ABS_TOL_M:
            mismatches.append(f"measuring range: GETINFO is inconsistent, name {model!r} but measuring range "
                              f"{reported_range * 1e3:g} mm")
        if expected.measuring_range_m is not None \
                and abs(reported_range - expected.measuring_range_m) > _RANGE_ABS_TOL_M:
            mismatches.append(f"measuring range: the sensor reports {reported_range * 1e3:g} mm but parameter "
                              f"measuring_range_m is {expected.measuring_range_m * 1e3:g} mm; set "
                              f"measuring_range_m to the head's range or connect the right head")
    if expected.measuring_rate_hz is not None:
        try:
            validate_measuring_rate_hz(expected.measuring_rate_hz)
        except ValueError as exc:
            mismatches.append(f"measuring rate: parameter measuring_rate_hz: {exc}")
    rate = settings.measuring_rate_hz
    if rate is not None:
        try:
            rate = validate_measuring_rate_hz(rate)
        except ValueError:
            mismatches.append(f"measuring rate: the sensor reports {rate:g} Hz, which is not an ILD1320 rate "
                              f"({', '.join(f'{r:g}' for r in ALLOWED_MEASURING_RATES_HZ)} Hz)")
        else:
            if expected.measuring_rate_hz is not None and not math.isclose(rate, expected.measuring_rate_hz):
                to_reset.append(f"measuring rate {rate:g} Hz -> {expected.measuring_rate_hz:g} Hz")
    if settings.output is not None and settings.output != KNOWN_STATE["output"]:
        to_reset.append(f"output {settings.output} -> {KNOWN_STATE['output']}")
    if settings.additional_outputs:
        to_reset.append(f"additional outputs {' '.join(settings.additional_outputs)} -> NONE")
    if settings.output_hold is not None and settings.output_hold != KNOWN_STATE["output_hold"]:
        to_reset.append(f"hold mode OUTHOLD {settings.output_hold} -> NONE (errors reported as errors)")
    if settings.mastering is not None and settings.mastering != KNOWN_STATE["mastering"]:
        to_reset.append(f"mastering MASTERMV {settings.mastering} (shifts every distance) -> NONE")
    return LaserSensorReport(settings, expected, tuple(mismatches), tuple(to_reset))


# --------------------------------------------------------------------------- plausibility
#: Default speed limit of the measured target (m/s). The mass on the membrane is
#: driven by the membrane stress and gravity only: forward integration of the
#: model (eq. 17) for steps between 0 V and the breakdown voltage of the A1, A2
#: and LP1 presets gives at most 0.07 m/s (accelerations below 9 m/s^2); a mass
#: falling freely through the whole 10 mm range (a torn membrane) reaches
#: sqrt(2 g 10 mm) = 0.44 m/s. 0.5 m/s covers both.
DEFAULT_MAX_SPEED_M_PER_S = 0.5
#: Default allowance for sensor noise and quantisation on top of the speed limit (m).
DEFAULT_JUMP_TOLERANCE_M = 20e-6
#: Consecutive consistent samples needed to accept a value without a trusted previous one.
DEFAULT_CONFIRM_SAMPLES = 3


class PlausibilityFilter:
    """Per-sample plausibility checks of decoded distances (the stream has no checksum).

    :meth:`check` returns the value when it is accepted, otherwise the reason as
    a :class:`MeasurementError` (sensor error codes pass through unchanged):

    1. ``OUTSIDE_MEASURING_RANGE``: the distance lies in the reserves before the
       SMR or after the EMR (outside ``[0, MR]``).
    2. ``AFTER_FRAMING_ERROR``: bytes were dropped just before the frame; random
       bytes carry valid flag bits once every ~64 positions, so a frame right
       after corrupt bytes is not trusted (the decoder resynchronises on the
       flag bits, the filter on the next clean frame). Also restarts the
       confirmation chain.
    3. ``IMPLAUSIBLE_JUMP``: farther from the last accepted sample than the mass
       can travel in the time between them,
       ``|d - d_ref| > max_speed_m_per_s * (t - t_ref) + jump_tolerance_m``.
    4. ``UNCONFIRMED``: without a trusted reference (start of the stream, after
       :meth:`reset`) a value is accepted only as the ``confirm_samples``-th of
       consecutive samples each consistent with its predecessor; the same chain
       re-anchors the reference after a real jump (a target moved by hand):
       the samples of the chain before the last are discarded.

    Counters: ``accepted``, ``discarded`` (per :class:`MeasurementError`, sensor
    error codes included) and ``reanchors``. Never raises on values.
    """

    def __init__(
        self,
        measuring_range_m: float = DEFAULT_MEASURING_RANGE_M,
        *,
        max_speed_m_per_s: float = DEFAULT_MAX_SPEED_M_PER_S,
        jump_tolerance_m: float = DEFAULT_JUMP_TOLERANCE_M,
        confirm_samples: int = DEFAULT_CONFIRM_SAMPLES,
    ) -> None:
        self.measuring_range_m = _check_range_m(measuring_range_m)
        self.max_speed_m_per_s = float(max_speed_m_per_s)
        if not (math.isfinite(self.max_speed_m_per_s) and self.max_speed_m_per_s > 0.0):
            raise ValueError(f"max_speed_m_per_s must be a positive speed, got {max_speed_m_per_s!r}")
        self.jump_tolerance_m = float(jump_tolerance_m)
        if not (math.isfinite(self.jump_tolerance_m) and self.jump_tolerance_m >= 0.0):
            raise ValueError(f"jump_tolerance_m must be >= 0 m, got {jump_tolerance_m!r}")
        if isinstance(confirm_samples, bool) or int(confirm_samples) != confirm_samples \
                or not 1 <= confirm_samples <= 100:
            raise ValueError(f"confirm_samples must be an integer in [1, 100], got {confirm_samples!r}")
        self.confirm_samples = int(confirm_samples)
        self.accepted = 0
        self.discarded: dict[MeasurementError, int] = {}
        self.reanchors = 0
        self._ref: Optional[tuple[float, float]] = None
        self._chain: list[tuple[float, float]] = []

    def reset(self) -> None:
        """Forget the reference and the chain (a new connection); counters are kept."""
        self._ref = None
        self._chain = []

    @property
    def reference(self) -> Optional[tuple[float, float]]:
        """(time s, distance m) of the last accepted sample, or ``None``."""
        return self._ref

    def allowed_jump_m(self, dt_s: float) -> float:
        """Largest plausible change of the distance in ``dt_s`` seconds."""
        return self.max_speed_m_per_s * max(float(dt_s), 0.0) + self.jump_tolerance_m

    def _consistent(self, a: tuple[float, float], t_s: float, d_m: float) -> bool:
        return abs(d_m - a[1]) <= self.allowed_jump_m(t_s - a[0])

    def _reject(self, reason: MeasurementError) -> MeasurementError:
        self.discarded[reason] = self.discarded.get(reason, 0) + 1
        return reason

    def check(
        self, t_s: float, value: Union[float, MeasurementError], framing_error_before: bool = False
    ) -> Union[float, MeasurementError]:
        """The value if plausible, else the reason it is discarded (see the class docstring)."""
        if isinstance(value, MeasurementError):
            return self._reject(value)
        try:
            d = float(value)
            t = float(t_s)
        except (TypeError, ValueError):
            return self._reject(MeasurementError.UNKNOWN_CODE)
        if not (math.isfinite(d) and math.isfinite(t)):
            return self._reject(MeasurementError.UNKNOWN_CODE)
        if framing_error_before:
            self._chain = []
            return self._reject(MeasurementError.AFTER_FRAMING_ERROR)
        if not 0.0 <= d <= self.measuring_range_m:
            return self._reject(MeasurementError.OUTSIDE_MEASURING_RANGE)
        if self._ref is not None and self._consistent(self._ref, t, d):
            self._chain = []
            self._ref = (t, d)
            self.accepted += 1
            return d
        if self._chain and self._consistent(self._chain[-1], t, d):
            self._chain.append((t, d))
        else:
            self._chain = [(t, d)]
        if len(self._chain) >= self.confirm_samples:
            if self._ref is not None:
                self.reanchors += 1
            self._chain = []
            self._ref = (t, d)
            self.accepted += 1
            return d
        return self._reject(
            MeasurementError.UNCONFIRMED if self._ref is None else MeasurementError.IMPLAUSIBLE_JUMP
        )
