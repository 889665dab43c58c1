"""A corrupted ILD1320 stream with the truth of every byte: how many fabricated values reach a consumer.

:func:`fuzz_stream` encodes a true displacement series as frames, corrupts the bytes (dropped,
random bytes inserted, bits flipped), decodes them with the product's
:class:`~dea_ros.hardware.laser.ild1320_protocol.frames.FrameDecoder`, judges every decoded value
with a :class:`~dea_ros.hardware.laser.plausibility.PlausibilityFilter` and compares what the
filter accepts -- what laser_sensor_node publishes as a finite range, what a consumer acts on --
with the true value of the sample whose H byte closed the frame. Used by
test/hardware/test_laser_plausibility.py and bench/bench_laser_edges.py.
"""
from __future__ import annotations

import random
from typing import NamedTuple

import numpy as np

from dea_ros.hardware.laser.base import MeasurementError
from dea_ros.hardware.laser.ild1320_protocol.frames import (
    FrameDecoder,
    code_to_displacement_m,
    displacement_to_code,
    encode_value,
    quantum_m,
)
from dea_ros.hardware.laser.plausibility import PlausibilityFilter

__all__ = ["FuzzResult", "corrupt", "fuzz_stream"]


class FuzzResult(NamedTuple):
    frames: int                 # true frames sent
    decoded: int                # values the decoder produced (valid-looking or error codes)
    decoded_fabricated: int     # decoded distances off their truth by more than 1 quantum
    decoded_max_jump_m: float   # largest step between consecutive decoded distances
    accepted: int               # values the filter passed (what a consumer sees)
    fabricated: int             # accepted values off their truth by more than 1 quantum
    fabricated_jumps: int       # accepted values off their truth by more than the filter's jump allowance
    max_error_m: float          # largest |accepted - truth|
    flagged: int                # values the filter flagged (published as NaN)


def corrupt(stream: bytes, origin: list[int], rng: random.Random, p_drop: float, p_insert: float,
            p_flip: float) -> tuple[bytes, list[int]]:
    """The corrupted bytes and, for each, the index of the true frame it came from (or sits in)."""
    out, where = bytearray(), []
    for byte, index in zip(stream, origin):
        if rng.random() < p_insert:
            out.append(rng.randrange(256))
            where.append(index)
        if rng.random() < p_drop:
            continue
        if rng.random() < p_flip:
            byte ^= 1 << rng.randrange(8)
        out.append(byte)
        where.append(index)
    return bytes(out), where


def fuzz_stream(truth_m: np.ndarray, rate_hz: float, seed: int, *, p_drop=0.01, p_insert=0.01, p_flip=0.01,
                measuring_range_m=0.010, **filter_kwargs) -> FuzzResult:
    """Corrupt, decode and filter ``truth_m`` (metres from the SMR, one per sample at ``rate_hz``)."""
    codes = [displacement_to_code(float(d), measuring_range_m) for d in truth_m]
    true_m = [code_to_displacement_m(c, measuring_range_m) for c in codes]
    stream = b"".join(encode_value(c) for c in codes)
    origin = [i // 3 for i in range(len(stream))]
    data, where = corrupt(stream, origin, random.Random(seed), p_drop, p_insert, p_flip)
    decoder = FrameDecoder(measuring_range_m)
    filt = PlausibilityFilter(measuring_range_m, **filter_kwargs)
    q = quantum_m(measuring_range_m)
    decoded = decoded_fab = accepted = fabricated = jumps = flagged = 0
    max_err = max_jump = 0.0
    previous = None
    feed = decoder.feed
    for pos in range(len(data)):
        samples = feed(data[pos:pos + 1])  # byte by byte: the sample index is the origin of its H byte
        if not samples:
            continue
        sample, index = samples[0], where[pos]
        decoded += 1
        if not isinstance(sample.value, MeasurementError):
            if abs(sample.value - true_m[index]) > q:
                decoded_fab += 1
            if previous is not None:
                max_jump = max(max_jump, abs(sample.value - previous))
            previous = sample.value
        value = filt.check(index / rate_hz, sample.value, sample.discarded_before > 0)
        if isinstance(value, MeasurementError):
            flagged += not isinstance(sample.value, MeasurementError)
            continue
        accepted += 1
        error = abs(value - true_m[index])
        max_err = max(max_err, error)
        fabricated += error > q
        jumps += error > filt.allowed_jump_m(1.0 / rate_hz)
    return FuzzResult(len(codes), decoded, decoded_fab, max_jump, accepted, fabricated, jumps, max_err, flagged)
