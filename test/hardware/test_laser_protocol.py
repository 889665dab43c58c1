"""Tests of the pure ILD1320 protocol layer and of the sample clock (no I/O)."""
from __future__ import annotations

import math
import random

import pytest

from dea_ros.hardware.laser import ild1320_protocol as proto
from dea_ros.hardware.laser.ild1320_protocol import (
    ALLOWED_MEASURING_RATES_HZ,
    DEFAULT_MEASURING_RANGE_M,
    DISTANCE_CODE_MAX,
    EMR_CODE,
    ERROR_CODES,
    MAX_RAW_CODE,
    SMR_CODE,
    CommandError,
    CommandReply,
    FrameDecoder,
    FrameFormatError,
    apply_tare,
    code_to_displacement_m,
    command_bytes,
    decode_frame,
    displacement_to_code,
    encode_displacement,
    encode_value,
    error_to_code,
    find_reply_end,
    format_rate_khz,
    laser_command,
    measrate_command,
    output_command,
    parse_command_line,
    parse_getinfo_reply,
    parse_laser_reply,
    parse_measrate_reply,
    parse_output_reply,
    parse_reply,
    quantum_m,
    render_error,
    render_reply,
    validate_measuring_rate_hz,
)
from dea_ros.hardware.laser.sample_clock import SampleClock
from dea_ros.hardware.laser import DisplacementReading, MeasurementError, SensorError

MR = DEFAULT_MEASURING_RANGE_M
Q = quantum_m(MR)


# --------------------------------------------------------------------- frames
def test_frame_layout_matches_manual():
    # 18-bit word D17..D0 = 0b10_110011_010101 split in 6-bit groups, L first.
    code = (0b101100 << 12) | (0b110011 << 6) | 0b010101
    assert encode_value(code) == bytes((0b00_010101, 0b01_110011, 0b10_101100))
    assert encode_value(code, additional=True)[2] == 0b11_101100


def test_encode_decode_round_trip_all_18_bit_values():
    for code in range(MAX_RAW_CODE + 1):
        frame = encode_value(code)
        assert [b >> 6 for b in frame] == [0, 1, 2]
        assert decode_frame(frame) == code


def test_decoder_decodes_every_18_bit_value_in_one_stream():
    stream = b"".join(encode_value(code) for code in range(MAX_RAW_CODE + 1))
    decoder = FrameDecoder()
    samples = decoder.feed(stream)
    assert [s.code for s in samples] == list(range(MAX_RAW_CODE + 1))
    assert decoder.frames_decoded == MAX_RAW_CODE + 1
    assert decoder.bytes_discarded == 0 and decoder.pending_bytes == 0


@pytest.mark.parametrize("bad", [-1, MAX_RAW_CODE + 1, 1 << 20])
def test_encode_rejects_codes_outside_18_bits(bad):
    with pytest.raises(ValueError):
        encode_value(bad)


@pytest.mark.parametrize("bad", [1.0, True, "3", None])
def test_encode_rejects_non_int(bad):
    with pytest.raises(TypeError):
        encode_value(bad)


@pytest.mark.parametrize(
    "frame",
    [b"", b"\x00\x40", b"\x00\x40\x80\x00", bytes((0x40, 0x40, 0x80)), bytes((0x00, 0x00, 0x80)),
     bytes((0x00, 0x40, 0x40)), bytes((0x00, 0x40, 0xC0))],
)
def test_decode_frame_rejects_wrong_length_or_flags(frame):
    with pytest.raises(FrameFormatError):
        decode_frame(frame)


# --------------------------------------------------------------------- conversion
def test_code_to_metres_formula_and_range_markers():
    assert Q == pytest.approx(10e-3 * 1.02 / 65520)
    assert code_to_displacement_m(0) == pytest.approx(-0.01 * MR)
    assert code_to_displacement_m(DISTANCE_CODE_MAX) == pytest.approx(1.01 * MR)
    assert abs(code_to_displacement_m(SMR_CODE)) < Q  # start of measuring range ~ 0 mm
    assert abs(code_to_displacement_m(EMR_CODE) - MR) < Q  # end of measuring range ~ 10 mm
    assert code_to_displacement_m(32760) == pytest.approx((32760 * 1.02 / 65520 - 0.01) * MR)
    # other measuring ranges scale linearly
    assert code_to_displacement_m(40000, 0.025) == pytest.approx(2.5 * code_to_displacement_m(40000, 0.010))


def test_displacement_code_round_trip_over_whole_range():
    for code in range(DISTANCE_CODE_MAX + 1):
        assert displacement_to_code(code_to_displacement_m(code)) == code
    rng = random.Random(1)
    for _ in range(20000):
        d = rng.uniform(-0.01 * MR, 1.01 * MR)
        back = code_to_displacement_m(displacement_to_code(d))
        assert abs(back - d) <= 0.5 * Q * (1 + 1e-9)


def test_out_of_range_and_nan_become_named_errors():
    assert code_to_displacement_m(displacement_to_code(-0.02 * MR)) is MeasurementError.TARGET_TOO_CLOSE
    assert code_to_displacement_m(displacement_to_code(1.02 * MR)) is MeasurementError.TARGET_TOO_FAR
    assert code_to_displacement_m(displacement_to_code(math.nan)) is MeasurementError.NO_PEAK
    assert code_to_displacement_m(displacement_to_code(-math.inf)) is MeasurementError.TARGET_TOO_CLOSE
    assert code_to_displacement_m(displacement_to_code(math.inf)) is MeasurementError.TARGET_TOO_FAR
    # just inside the reserves is still a value
    assert displacement_to_code(-0.01 * MR) == 0
    assert displacement_to_code(1.01 * MR) == DISTANCE_CODE_MAX


def test_error_codes_decode_to_named_errors_not_numbers():
    expected = {
        262075: MeasurementError.DATA_RATE_TOO_HIGH,
        262076: MeasurementError.NO_PEAK,
        262077: MeasurementError.TARGET_TOO_CLOSE,
        262078: MeasurementError.TARGET_TOO_FAR,
        262080: MeasurementError.CANNOT_CALCULATE,
        262081: MeasurementError.PEAK_TOO_WIDE,
        262082: MeasurementError.LASER_OFF,
    }
    assert ERROR_CODES == expected
    for code, error in expected.items():
        assert code_to_displacement_m(code) is error
        assert error_to_code(error) == code
        assert displacement_to_code(error) == code
        samples = FrameDecoder().feed(encode_value(code))
        assert samples[0].value is error and not samples[0].is_valid


@pytest.mark.parametrize("code", [DISTANCE_CODE_MAX + 1, 100000, 262074, 262079, 262083, MAX_RAW_CODE])
def test_undocumented_codes_are_unknown(code):
    assert code_to_displacement_m(code) is MeasurementError.UNKNOWN_CODE


def test_unknown_code_has_no_wire_code():
    with pytest.raises(ValueError):
        error_to_code(MeasurementError.UNKNOWN_CODE)


def test_encode_displacement_and_tare():
    frame = encode_displacement(0.004)
    value = code_to_displacement_m(decode_frame(frame))
    assert abs(value - 0.004) <= 0.5 * Q
    assert apply_tare(value, 0.004) == pytest.approx(value - 0.004)
    assert apply_tare(MeasurementError.NO_PEAK, 0.004) is MeasurementError.NO_PEAK
    with pytest.raises(ValueError):
        quantum_m(0.0)


# --------------------------------------------------------------------- decoder fuzzing
def _reference_counts(stream: bytes) -> tuple[int, int]:
    """Number of (L, M, H) and (L, M, H-additional) runs; runs cannot overlap."""
    flags = [b >> 6 for b in stream]
    first = sum(1 for i in range(len(flags) - 2) if flags[i : i + 3] == [0, 1, 2])
    additional = sum(1 for i in range(len(flags) - 2) if flags[i : i + 3] == [0, 1, 3])
    return first, additional


def _reference_codes(stream: bytes) -> list[int]:
    codes = []
    for i in range(len(stream) - 2):
        if [b >> 6 for b in stream[i : i + 3]] == [0, 1, 2]:
            codes.append(decode_frame(stream[i : i + 3]))
    return codes


def _random_split(data: bytes, rng: random.Random) -> list[bytes]:
    cuts = sorted(rng.sample(range(len(data) + 1), k=min(len(data) + 1, rng.randrange(0, 12))))
    pieces, last = [], 0
    for cut in cuts + [len(data)]:
        pieces.append(data[last:cut])
        last = cut
    return pieces


def _feed_all(decoder: FrameDecoder, pieces) -> list:
    out = []
    for piece in pieces:
        out.extend(decoder.feed(piece))
    return out


def test_fuzz_random_bytes_never_raise_and_match_reference():
    rng = random.Random(20240601)
    for _ in range(3000):
        stream = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 120)))
        decoder = FrameDecoder()
        samples = _feed_all(decoder, _random_split(stream, rng))
        first, additional = _reference_counts(stream)
        assert decoder.frames_decoded == len(samples) == first
        assert decoder.additional_values_skipped == additional
        assert [s.code for s in samples] == _reference_codes(stream)
        assert decoder.bytes_discarded + decoder.pending_bytes + 3 * (first + additional) == len(stream)


def test_fuzz_clean_streams_split_anywhere_decode_exactly():
    rng = random.Random(7)
    for _ in range(3000):
        codes = [rng.randrange(MAX_RAW_CODE + 1) for _ in range(rng.randrange(0, 40))]
        stream = b"".join(encode_value(c) for c in codes)
        decoder = FrameDecoder()
        samples = _feed_all(decoder, _random_split(stream, rng))
        assert [s.code for s in samples] == codes
        assert decoder.frames_decoded == len(codes)
        assert decoder.bytes_discarded == 0 and decoder.partial_frames_dropped == 0
    # byte by byte
    codes = list(range(0, MAX_RAW_CODE, 997))
    decoder = FrameDecoder()
    stream = b"".join(encode_value(c) for c in codes)
    samples = _feed_all(decoder, [stream[i : i + 1] for i in range(len(stream))])
    assert [s.code for s in samples] == codes


def _is_subsequence(needle: list, haystack: list) -> bool:
    iterator = iter(haystack)
    return all(any(item == other for other in iterator) for item in needle)


def test_fuzz_truncated_streams_lose_only_the_damaged_frames():
    rng = random.Random(11)
    spliced_total = 0
    for _ in range(3000):
        codes = [rng.randrange(MAX_RAW_CODE + 1) for _ in range(rng.randrange(1, 40))]
        stream = b"".join(encode_value(c) for c in codes)
        removed = set(rng.sample(range(len(stream)), k=rng.randrange(0, min(6, len(stream)) + 1)))
        if rng.random() < 0.3:  # also cut off the end of the stream
            removed |= set(range(rng.randrange(len(stream) + 1), len(stream)))
        damaged_frames = {i // 3 for i in removed}
        truncated = bytes(b for i, b in enumerate(stream) if i not in removed)
        intact = [c for i, c in enumerate(codes) if i not in damaged_frames]
        decoder = FrameDecoder()
        decoded = [s.code for s in _feed_all(decoder, _random_split(truncated, rng))]
        # every intact frame survives, in order; the decoder finds exactly the L, M, H runs
        assert _is_subsequence(intact, decoded)
        assert decoded == _reference_codes(truncated)
        # a removed run of bytes can splice L of one frame to M, H of a later one
        # (the protocol has no checksum); that needs at least two removed bytes
        spliced = len(decoded) - len(intact)
        assert 0 <= spliced <= len(removed) // 2
        if len(removed) <= 1:
            assert decoded == intact
        spliced_total += spliced
    assert spliced_total < 300


def _garbage_without_frames(n: int, rng: random.Random, before: bytes = b"") -> bytes:
    """Random bytes forming no L, M, H run, also not together with ``before``."""
    out = bytearray(before[-2:])
    start = len(out)
    while len(out) - start < n:
        b = rng.randrange(256)
        if b >> 6 >= 2 and len(out) >= 2 and out[-2] >> 6 == 0 and out[-1] >> 6 == 1:
            continue
        out.append(b)
    return bytes(out[start:])


def test_fuzz_recovers_all_frames_after_garbage():
    rng = random.Random(3)
    for _ in range(2000):
        blocks = []
        expected = []
        for _ in range(rng.randrange(1, 6)):
            blocks.append(_garbage_without_frames(rng.randrange(0, 30), rng, b"".join(blocks)))
            codes = [rng.randrange(MAX_RAW_CODE + 1) for _ in range(rng.randrange(0, 8))]
            expected.extend(codes)
            blocks.append(b"".join(encode_value(c) for c in codes))
        stream = b"".join(blocks)
        decoder = FrameDecoder()
        samples = _feed_all(decoder, _random_split(stream, rng))
        assert [s.code for s in samples] == expected


def test_random_garbage_between_frames_keeps_real_frames_in_order():
    rng = random.Random(5)
    for _ in range(1000):
        codes = [rng.randrange(DISTANCE_CODE_MAX + 1) for _ in range(20)]
        stream = b""
        for c in codes:
            stream += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 10))) + encode_value(c)
        samples = _feed_all(FrameDecoder(), _random_split(stream, rng))
        decoded = [s.code for s in samples]
        assert decoded == _reference_codes(stream)
        assert _is_subsequence(codes, decoded)  # real frames survive, in order


def test_additional_values_are_skipped_and_counted():
    stream = encode_value(100) + encode_value(5, additional=True) + encode_value(200)
    decoder = FrameDecoder()
    assert [s.code for s in decoder.feed(stream)] == [100, 200]
    assert decoder.additional_values_skipped == 1


def test_interleaved_reply_is_recovered_from_non_frame_bytes():
    reply = render_reply(["MEASRATE 2"])
    stream = encode_value(1000) + encode_value(2000) + reply + encode_value(3000)
    for split in range(len(stream) + 1):
        decoder = FrameDecoder(keep_non_frame_bytes=True)
        samples = decoder.feed(stream[:split]) + decoder.feed(stream[split:])
        assert [s.code for s in samples] == [1000, 2000, 3000]
        buffer = decoder.non_frame_bytes()
        end = find_reply_end(buffer)
        assert end is not None and buffer[:end] == reply
        decoder.consume_non_frame_bytes(end)
        assert decoder.non_frame_bytes() == b""


def test_prompt_held_as_pending_bytes_is_visible_and_consumable():
    decoder = FrameDecoder(keep_non_frame_bytes=True)
    assert decoder.feed(encode_value(7) + b"\r\n->") == [proto.Sample(7, code_to_displacement_m(7))]
    assert decoder.pending_bytes == 1  # '>' is an L-type byte
    buffer = decoder.non_frame_bytes()
    assert find_reply_end(buffer) == len(buffer)
    decoder.consume_non_frame_bytes(len(buffer))
    assert decoder.non_frame_bytes() == b"" and decoder.pending_bytes == 0
    assert [s.code for s in decoder.feed(encode_value(8))] == [8]
    with pytest.raises(ValueError):
        decoder.consume_non_frame_bytes(1)


def test_non_frame_buffer_is_bounded():
    decoder = FrameDecoder(keep_non_frame_bytes=True, max_non_frame_bytes=16)
    decoder.feed(b"A" * 100)
    assert len(decoder.non_frame_bytes()) == 16
    assert decoder.non_frame_bytes_overflowed == 84


# --------------------------------------------------------------------- ASCII commands
def test_command_formatting():
    assert command_bytes("GETINFO") == b"GETINFO\r\n"
    assert measrate_command() == "MEASRATE"
    assert [measrate_command(r) for r in ALLOWED_MEASURING_RATES_HZ] == [
        "MEASRATE 0.25", "MEASRATE 0.5", "MEASRATE 1", "MEASRATE 2",
    ]
    assert format_rate_khz(500) == "0.5"
    assert laser_command(True) == "LASERPOW FULL" and laser_command(False) == "LASERPOW OFF"
    assert laser_command() == "LASERPOW"
    assert output_command() == "OUTPUT RS422" and output_command(None) == "OUTPUT"
    with pytest.raises(ValueError):
        output_command("USB")
    for bad in ("", "GET\nINFO", "MEASRATE 2 µ"):
        with pytest.raises(ValueError):
            command_bytes(bad)


@pytest.mark.parametrize("rate", [0, 100, 1500, 4000, -2000, float("nan"), "fast", None])
def test_invalid_measuring_rates_are_rejected(rate):
    with pytest.raises(ValueError, match="measuring rate"):
        validate_measuring_rate_hz(rate)


def test_parse_command_line():
    assert parse_command_line("measrate 2\r") == ("MEASRATE", ["2"])
    assert parse_command_line('PASSWD "a b" c') == ("PASSWD", ["a b", "c"])
    for bad in ("", "   ", 'X "unbalanced'):
        with pytest.raises(ValueError):
            parse_command_line(bad)


def test_parse_reply_body_echo_warning_and_error():
    reply = parse_reply(b"MEASRATE\r\nMEASRATE 0.5\r\n->", "MEASRATE")  # with echo
    assert reply.lines == ("MEASRATE 0.5",)
    assert parse_measrate_reply(reply) == pytest.approx(500.0)
    assert parse_reply(b"\r\n->", "MEASRATE 2").lines == ()
    warned = parse_reply(b"W100 value rounded\r\n->", "MEASRATE 2")
    assert warned.warnings == ("W100 value rounded",) and warned.lines == ()
    with pytest.raises(CommandError) as info:
        parse_reply(b"E232 Invalid parameter value\r\n->", "MEASRATE 3")
    assert info.value.code == 232 and "Invalid parameter" in info.value.message
    assert isinstance(info.value, SensorError)
    with pytest.raises(CommandError):
        parse_reply(render_error(210, "Unknown command"), "FOO")


def test_parse_value_replies():
    assert parse_measrate_reply(CommandReply("MEASRATE", ("MEASRATE 2.000",))) == pytest.approx(2000.0)
    assert parse_measrate_reply(CommandReply("MEASRATE", ("0.25",))) == pytest.approx(250.0)
    with pytest.raises(SensorError):
        parse_measrate_reply(CommandReply("MEASRATE", ("MEASRATE fast",)))
    assert parse_laser_reply(CommandReply("LASERPOW", ("LASERPOW OFF",))) is False
    assert parse_laser_reply(CommandReply("LASERPOW", ("LASERPOW FULL",))) is True
    assert parse_output_reply(CommandReply("OUTPUT", ("OUTPUT rs422",))) == "RS422"


def test_parse_getinfo_reply():
    raw = render_reply(
        ["Name:            ILD1320-10", "Serial:          20110036", "Measuring range: 10.00mm", "Version: 001.062"]
    )
    info = parse_getinfo_reply(parse_reply(raw, "GETINFO"))
    assert info.name == "ILD1320-10" and info.serial == "20110036"
    assert info.measuring_range_m == pytest.approx(0.010)
    assert info.fields["Version"] == "001.062"
    with pytest.raises(SensorError):
        parse_getinfo_reply(CommandReply("GETINFO", ("nothing useful",)))


def test_render_reply_format():
    assert render_reply() == b"\r\n->"
    assert render_reply(["A 1", "B"]) == b"A 1\r\nB\r\n->"
    assert render_error(7, "x") == b"E007 x\r\n->"
    assert find_reply_end(b"abc") is None and find_reply_end(b"x\r\n->yz") == 5


def test_displacement_reading_accessors():
    ok = DisplacementReading(1.0, 0.002)
    bad = DisplacementReading(2.0, MeasurementError.LASER_OFF)
    t, value = ok
    assert (t, value) == (1.0, 0.002) and ok.is_valid and ok.displacement_m == 0.002 and ok.error is None
    assert not bad.is_valid and bad.displacement_m is None and bad.error is MeasurementError.LASER_OFF


# --------------------------------------------------------------------- sample clock
def _simulate_clock(rate, n_samples, rng, *, drift_ppm=0.0, lost=(), latency=0.0015, jitter_mean=0.0008):
    """Feed a SampleClock with chunks as a streaming sensor would produce them."""
    period = 1.0 / rate
    clock = SampleClock(rate, latency)
    true_times = [k * period * (1 + drift_ppm * 1e-6) for k in range(n_samples)]
    stamped, truth = [], []
    k = 0
    lost_since_delivered = False
    while k < n_samples:
        chunk = list(range(k, min(k + rng.randrange(1, 12), n_samples)))
        k = chunk[-1] + 1
        delivered, loss_before = [], []
        for i in chunk:
            if i in lost:
                lost_since_delivered = True
            else:
                delivered.append(i)
                loss_before.append(lost_since_delivered)
                lost_since_delivered = False
        if not delivered:
            continue
        arrival = true_times[chunk[-1]] + latency + rng.expovariate(1.0 / jitter_mean)
        times = clock.stamp(len(delivered), arrival, loss_before=loss_before, loss_after=lost_since_delivered)
        stamped.extend(times)
        truth.extend(true_times[i] for i in delivered)
    return stamped, truth, clock


@pytest.mark.parametrize("drift_ppm", [0.0, 200.0, -200.0])
def test_sample_clock_is_monotonic_and_tracks_true_times(drift_ppm):
    rng = random.Random(42)
    rate = 2000.0
    stamped, truth, _ = _simulate_clock(rate, 8000, rng, drift_ppm=drift_ppm)
    diffs = [b - a for a, b in zip(stamped, stamped[1:])]
    assert min(diffs) >= 0.5 / rate - 1e-12
    errors = [s - t for s, t in zip(stamped, truth)]
    settled = errors[len(errors) // 10 :]
    assert max(abs(e) for e in settled) < 0.6e-3
    assert abs(sorted(settled)[len(settled) // 2]) < 0.2e-3


def test_sample_clock_skips_lost_samples_and_pauses():
    rng = random.Random(9)
    lost = set(range(3000, 3010)) | set(range(5000, 5600))  # 10 corrupted frames, 0.3 s pause
    stamped, truth, clock = _simulate_clock(2000.0, 8000, rng, lost=lost)
    assert all(b > a for a, b in zip(stamped, stamped[1:]))
    errors = [s - t for s, t in zip(stamped, truth)]
    assert max(abs(e) for e in errors[len(errors) // 10 :]) < 1.0e-3
    assert clock.periods_skipped >= 600


def test_sample_clock_validation_and_reset():
    with pytest.raises(ValueError):
        SampleClock(0.0)
    with pytest.raises(ValueError):
        SampleClock(1000.0, -1.0)
    clock = SampleClock(1000.0, 0.0)
    assert clock.stamp(0, 1.0) == []
    assert clock.stamp(3, 1.0) == pytest.approx([0.998, 0.999, 1.0])
    # 0.1 ms later than predicted: jitter, the prediction is kept
    assert clock.stamp(1, 1.0011) == pytest.approx([1.001], abs=1e-12)
    # earlier than predicted: moved down by at most half a period
    assert clock.stamp(1, 0.9) == pytest.approx([1.002 - 0.0005], abs=1e-12)
    clock.reset(rate_hz=500.0)
    assert clock.stamp(2, 5.0) == pytest.approx([4.998, 5.0])


def test_sample_clock_follows_drift_once_per_window():
    clock = SampleClock(500.0, 0.0, drift_window_s=0.5)
    t = 5.0
    clock.stamp(1, t)
    stamps = []
    for k in range(1, 301):  # every chunk arrives >= 0.3 ms late for 0.6 s
        t += 0.002
        stamps += clock.stamp(1, t + (0.0003 if k % 2 else 0.0009))
    spacings = [b - a for a, b in zip(stamps, stamps[1:])]
    assert sum(abs(s - 0.002) > 1e-12 for s in spacings) == 1  # one correction ...
    assert stamps[-1] == pytest.approx(t + 0.0003, abs=1e-9)  # ... by the smallest delay


def test_a_flagged_reading_keeps_its_raw_value_and_is_still_a_pair():
    flagged = DisplacementReading(3.0, MeasurementError.IMPLAUSIBLE_JUMP, raw_m=0.004)
    t, value = flagged
    assert (t, value) == (3.0, MeasurementError.IMPLAUSIBLE_JUMP) and flagged.raw_m == 0.004
    assert math.isnan(DisplacementReading(1.0, 0.002).raw_m)
