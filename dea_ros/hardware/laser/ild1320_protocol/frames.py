"""ILD1320 binary measurement stream: frames, codes, distances (pure, no I/O).

Encoding and decoding of the binary measurement stream, an incremental
:class:`FrameDecoder` that resynchronises on corrupted streams, and conversion of the
digital values to metres (with software tare). The sources of the facts below are in
:mod:`dea_ros.hardware.laser.ild1320_protocol`.

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

*Timing* [1320 manual ch. 6.4]: a value is output three cycles after its acquisition
(:data:`OUTPUT_DELAY_CYCLES`; 1.5 ms at 2 kHz), one value per cycle.
"""
from __future__ import annotations

import math
from typing import Iterable, NamedTuple

from ....errors import FrameFormatError
from ..base import MeasurementError, validated_measuring_range_m

__all__ = [
    "DEFAULT_BAUDRATE",
    "SERIAL_BYTESIZE",
    "SERIAL_PARITY",
    "SERIAL_STOPBITS",
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
    "FrameFormatError",
    "Sample",
    "encode_value",
    "decode_frame",
    "quantum_m",
    "code_to_displacement_m",
    "displacement_to_code",
    "error_to_code",
    "encode_displacement",
    "mastered_displacement_to_code",
    "apply_tare",
    "FrameDecoder",
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

#: A value is output this many measuring cycles after its acquisition.


class Sample(NamedTuple):
    """One decoded output value: the 18-bit ``code`` and its meaning.

    ``value`` is the displacement in metres from the start of the measuring range
    (no tare applied) or a :class:`MeasurementError`.
    """

    code: int
    value: float | MeasurementError
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
    return validated_measuring_range_m(measuring_range_m) * _CODE_SCALE


def code_to_displacement_m(
    code: int, measuring_range_m: float = DEFAULT_MEASURING_RANGE_M
) -> float | MeasurementError:
    """Convert an 18-bit code to metres from the SMR, or to a named error."""
    _check_code(code)
    if code <= DISTANCE_CODE_MAX:
        return (code * _CODE_SCALE - _CODE_OFFSET) * validated_measuring_range_m(measuring_range_m)
    return ERROR_CODES.get(code, MeasurementError.UNKNOWN_CODE)


def error_to_code(error: MeasurementError) -> int:
    """The code the sensor sends for ``error`` (``UNKNOWN_CODE`` has none)."""
    try:
        return _ERROR_TO_CODE[MeasurementError(error)]
    except (KeyError, ValueError):
        raise ValueError(f"{error!r} has no ILD1320 error code") from None


def displacement_to_code(
    value: float | MeasurementError, measuring_range_m: float = DEFAULT_MEASURING_RANGE_M
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
    scaled = (d / validated_measuring_range_m(measuring_range_m) + _CODE_OFFSET) / _CODE_SCALE
    if scaled < -0.5:
        return _ERROR_TO_CODE[MeasurementError.TARGET_TOO_CLOSE]
    if scaled >= DISTANCE_CODE_MAX + 0.5:
        return _ERROR_TO_CODE[MeasurementError.TARGET_TOO_FAR]
    return min(max(int(round(scaled)), 0), DISTANCE_CODE_MAX)


def encode_displacement(
    value: float | MeasurementError, measuring_range_m: float = DEFAULT_MEASURING_RANGE_M
) -> bytes:
    """Frame bytes the sensor would send for a displacement (see :func:`displacement_to_code`)."""
    return encode_value(displacement_to_code(value, measuring_range_m))


#: Offset of the mastered (18-bit) output code, fraction of MR [1420 manual ch. 7.5.2.1].
_MASTERED_CODE_OFFSET = 0.51
#: Largest mastered code the emulator sends (just below the error codes).
_MASTERED_CODE_MAX = min(ERROR_CODES) - 1


def mastered_displacement_to_code(
    value: float | MeasurementError,
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
    range_m = validated_measuring_range_m(measuring_range_m)
    if displacement_to_code(value, range_m) in ERROR_CODES:  # beyond the reserves
        return displacement_to_code(value, range_m)
    d_out = float(value) - float(master_position_m) + float(master_value_m)
    scaled = (d_out / range_m + _MASTERED_CODE_OFFSET) / _CODE_SCALE
    if scaled < -0.5:
        return _ERROR_TO_CODE[MeasurementError.TARGET_TOO_CLOSE]
    return min(max(int(round(scaled)), 0), _MASTERED_CODE_MAX)


def apply_tare(
    value: float | MeasurementError, tare_offset_m: float
) -> float | MeasurementError:
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
        self.measuring_range_m = validated_measuring_range_m(measuring_range_m)
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
