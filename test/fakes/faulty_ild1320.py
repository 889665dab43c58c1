"""An ILD1320 emulator that misbehaves on request: the sensor faults the tests play.

:class:`FaultyILD1320Emulator` is the product's :class:`~dea_ros.sim.ild1320_emulator.ILD1320Emulator`
(the pty, the commands, the stream) plus the faults a real line and a real sensor show:

* :meth:`~FaultyILD1320Emulator.inject_garbage` (``raw=True``: truly random bytes that may form
  frames), :meth:`~FaultyILD1320Emulator.corrupt_next`, :meth:`~FaultyILD1320Emulator.pause`
  (silence: no frames, no replies -- a pulled cable);
* :meth:`~FaultyILD1320Emulator.misbehave`: wrong replies (a ``MEASRATE`` query answering 0 or
  7 kHz, ``GETINFO`` with another measuring range or model, any raw reply), commands
  acknowledged but ignored, and random bytes inserted into or dropped from the stream;
* the record of every emitted sample (``record_limit > 0``, :meth:`~FaultyILD1320Emulator.emitted_samples`),
  to judge what a reader decoded against what was sent.

Load it by path (the suite runs with ``--import-mode=importlib``)::

    spec = importlib.util.spec_from_file_location("faulty_ild1320", FAKES / "faulty_ild1320.py")
"""
from __future__ import annotations

import collections
import math
import random
import time
from typing import Any, NamedTuple

from dea_ros.hardware.laser.base import MeasurementError
from dea_ros.hardware.laser.ild1320_protocol.commands import render_reply
from dea_ros.hardware.laser.ild1320_protocol.frames import FLAG_L, FLAG_M, code_to_displacement_m, encode_value
from dea_ros.sim.ild1320_device import DisplacementSource
from dea_ros.sim.ild1320_emulator import ILD1320Emulator

__all__ = ["FaultyILD1320Emulator", "EmittedSample"]

_UNSET = object()


class EmittedSample(NamedTuple):
    """A sample written by the emulator (kept when ``record_limit > 0``)."""

    index: int  #: running number over all emitted samples, from 0
    acquisition_time_s: float  #: ``time.monotonic()`` time of acquisition
    code: int  #: 18-bit value sent (distance or error code)
    value: float | MeasurementError  #: what ``code`` means (metres from the SMR, or error)
    corrupted: bool  #: True when the frame was deliberately corrupted


class FaultyILD1320Emulator(ILD1320Emulator):
    """The ILD1320 emulator with fault injection (see the module docstring).

    ``record_limit``: keep the last ``record_limit`` emitted samples (0: none); ``seed``: of the
    random generator used for garbage and corruption; the rest as :class:`ILD1320Emulator`.
    """

    def __init__(self, displacement_source: DisplacementSource | None = None, *, record_limit: int = 0,
                 seed: int = 0, **kwargs: Any) -> None:
        super().__init__(displacement_source, **kwargs)
        if int(record_limit) < 0:
            raise ValueError(f"record_limit must be >= 0, got {record_limit!r}")
        self._records: collections.deque[EmittedSample] = collections.deque(maxlen=int(record_limit) or 1)
        self._record = int(record_limit) > 0
        self._rng = random.Random(seed)
        self._reported_rate_khz: str | None = None
        self._reported_range_mm: float | None = None
        self._reported_model: str | None = None
        self._ignored_commands: frozenset[str] = frozenset()
        self._reply_overrides: dict[str, bytes] = {}
        self._reply_prefix: bytes | None = None
        self._drop_byte_probability = 0.0
        self._random_byte_probability = 0.0
        self._pause_windows: list[tuple[float, float]] = []
        self._windows_now: list[tuple[float, float]] = []  # the pause windows of the batch being sent
        self._garbage_requests: list[int] = []
        self._corrupt_remaining = 0
        self._tail = bytearray()  # last two bytes queued, for garbage generation
        self.samples_lost_paused = 0
        self.frames_corrupted = 0
        self.garbage_bytes_injected = 0
        self.bytes_dropped_fault = 0
        self.random_bytes_inserted = 0

    # ------------------------------------------------------------------ what the tests call
    def misbehave(self, *, reported_rate_khz=_UNSET, reported_range_mm=_UNSET, reported_model=_UNSET,
                  ignored_commands=_UNSET, reply_overrides=_UNSET, drop_byte_probability=_UNSET,
                  random_byte_probability=_UNSET) -> None:
        """Make the emulator misbehave (arguments left out keep their setting; ``None`` restores).

        * ``reported_rate_khz``: text the ``MEASRATE`` query answers (``"0"``, ``"7"``, ...);
        * ``reported_range_mm``: measuring range in the ``GETINFO`` reply (the
          stream keeps the true range);
        * ``reported_model``: name in the ``GETINFO`` reply;
        * ``ignored_commands``: command names acknowledged but not applied;
        * ``reply_overrides``: ``{command name: raw reply bytes}`` sent instead of
          the real reply (include the ``->`` prompt for a complete reply);
        * ``drop_byte_probability`` / ``random_byte_probability``: each byte of
          the measurement stream is dropped / preceded by a random byte with this
          probability.
        """
        with self._lock:
            if reported_rate_khz is not _UNSET:
                self._reported_rate_khz = None if reported_rate_khz is None else str(reported_rate_khz)
            if reported_range_mm is not _UNSET:
                self._reported_range_mm = None if reported_range_mm is None else float(reported_range_mm)
            if reported_model is not _UNSET:
                self._reported_model = None if reported_model is None else str(reported_model)
            if ignored_commands is not _UNSET:
                self._ignored_commands = frozenset(str(c).upper() for c in (ignored_commands or ()))
            if reply_overrides is not _UNSET:
                self._reply_overrides = {
                    str(k).upper(): v.encode("latin-1") if isinstance(v, str) else bytes(v)
                    for k, v in (reply_overrides or {}).items()
                }
            for name, value in (("drop", drop_byte_probability), ("random", random_byte_probability)):
                if value is _UNSET:
                    continue
                p = 0.0 if value is None else float(value)
                if not 0.0 <= p < 1.0:
                    raise ValueError(f"{name}_byte_probability must be in [0, 1), got {value!r}")
                if name == "drop":
                    self._drop_byte_probability = p
                else:
                    self._random_byte_probability = p

    def inject_garbage(self, n_bytes: int, *, raw: bool = False) -> None:
        """Write ``n_bytes`` random bytes between two frames at the next batch.

        By default the bytes never form a valid frame by accident (no L, M, H run,
        also not across the boundary with the bytes written before), so a decoder
        must drop all of them and lose no real frame. With ``raw=True`` they are
        uniformly random: about one position in 64 starts a frame with valid
        flag bits that decodes to some value (what a noisy line does).
        """
        n = int(n_bytes)
        if n < 0:
            raise ValueError(f"n_bytes must be >= 0, got {n_bytes!r}")
        with self._lock:
            self._garbage_requests.append(-n if raw else n)
        self._wake()

    def stream_unread_for(self, seconds: float) -> None:
        """As if nobody had read the port for ``seconds`` (on the emulator's clock, no sleep).

        The samples of those seconds fall due at the next batch and go through the bounded
        output buffer, which drops the oldest bytes -- mid-frame, 65536 not being a multiple of
        3 -- exactly as when the emulator streams unread in real time.
        """
        duration = float(seconds)
        if not (math.isfinite(duration) and duration >= 0.0):
            raise ValueError(f"seconds must be >= 0, got {seconds!r}")
        with self._lock:
            self._max_catch_up_s = max(self._max_catch_up_s, duration + 1.0)
            self._segment_t0 -= duration
        self._wake()

    def partial_frame_before_replies(self, tail: bytes | None = b"\xbf") -> None:
        """Send ``tail`` (the last bytes of a frame: an orphan H byte by default, what a trimmed
        buffer leaves) just before every reply; ``None`` stops it."""
        with self._lock:
            self._reply_prefix = None if tail is None else bytes(tail)

    def corrupt_next(self, n_frames: int) -> None:
        """Corrupt the next ``n_frames`` frames (a flag bit flipped or a byte lost)."""
        n = int(n_frames)
        if n < 0:
            raise ValueError(f"n_frames must be >= 0, got {n_frames!r}")
        with self._lock:
            self._corrupt_remaining += n

    def pause(self, seconds: float) -> None:
        """Go silent for ``seconds`` from now: samples due then are lost, commands ignored."""
        duration = float(seconds)
        if not (math.isfinite(duration) and duration >= 0.0):
            raise ValueError(f"pause duration must be >= 0 s, got {seconds!r}")
        now = time.monotonic()
        with self._lock:
            self._pause_windows.append((now, now + duration))

    def is_paused(self, t_s: float | None = None) -> bool:
        """True if the emulator is silent at ``t_s`` (default: now)."""
        t = time.monotonic() if t_s is None else t_s
        with self._lock:
            return any(start <= t < end for start, end in self._pause_windows)

    def emitted_samples(self) -> list[EmittedSample]:
        """Copy of the recorded samples (needs ``record_limit > 0``)."""
        if not self._record:
            raise RuntimeError("construct the emulator with record_limit > 0 to record samples")
        with self._lock:
            return list(self._records)

    # ------------------------------------------------------------------ the product's steps, with faults
    def _receive(self, data: bytes, now: float) -> None:
        if self.is_paused(now):
            return  # a disconnected sensor hears nothing
        super()._receive(data, now)

    def _reply(self, name: str, params: list[str], now: float) -> bytes:
        with self._lock:
            override = self._reply_overrides.get(name)
            ignored = name in self._ignored_commands and bool(params)
            rate_text, range_mm, model = self._reported_rate_khz, self._reported_range_mm, self._reported_model
        prefix = self._reply_prefix or b""
        if override is not None:
            return prefix + override
        if ignored:
            return prefix + render_reply()  # acknowledged, not applied
        if name == "MEASRATE" and not params and rate_text is not None:
            return prefix + render_reply([f"MEASRATE {rate_text}"])
        if name == "GETINFO" and not params and (range_mm is not None or model is not None):
            return prefix + render_reply(self._info_lines(
                self._model_name if model is None else model,
                self._range_m * 1e3 if range_mm is None else range_mm))
        return prefix + super()._reply(name, params, now)

    def _send(self, data: bytes) -> None:
        if data:
            self._tail = (self._tail + data)[-2:]
        super()._send(data)

    def _emit_due(self, now: float) -> None:
        with self._lock:
            garbage = self._garbage_requests
            self._garbage_requests = []
            self._windows_now = windows = list(self._pause_windows)
            self._pause_windows = [(s, e) for s, e in self._pause_windows if e > now]  # forget those over
        for request in garbage:
            n_bytes = abs(request)
            if not any(s <= now < e for s, e in windows):
                if request < 0:
                    self._send(bytes(self._rng.randrange(256) for _ in range(n_bytes)))
                else:
                    self._send(self._make_garbage(n_bytes))
                self.garbage_bytes_injected += n_bytes
        super()._emit_due(now)

    def _output_sample(self, t_acq: float, t_out: float, laser_on: bool, streaming: bool) -> None:
        if any(s <= t_out < e for s, e in self._windows_now):
            self.samples_lost_paused += 1
            return
        super()._output_sample(t_acq, t_out, laser_on, streaming)

    def _send_sample(self, t_acq: float, code: int) -> None:
        frame = encode_value(code)
        with self._lock:
            corrupted = self._corrupt_remaining > 0
            if corrupted:
                self._corrupt_remaining -= 1
        if corrupted:
            frame = self._corrupt(frame)
            self.frames_corrupted += 1
        frame += self._additional_frames(code)
        self._send(self._stream_faults(frame))
        self.frames_emitted += 1
        if self._record:
            with self._lock:
                self._records.append(EmittedSample(
                    self._next_index, t_acq, code, code_to_displacement_m(code, self._range_m), corrupted))
        self._next_index += 1

    # ------------------------------------------------------------------ the faults
    def _stream_faults(self, data: bytes) -> bytes:
        with self._lock:
            p_drop, p_random = self._drop_byte_probability, self._random_byte_probability
        if p_drop <= 0.0 and p_random <= 0.0:
            return data
        rng = self._rng
        out = bytearray()
        for byte in data:
            if p_random > 0.0 and rng.random() < p_random:
                out.append(rng.randrange(256))
                self.random_bytes_inserted += 1
            if p_drop > 0.0 and rng.random() < p_drop:
                self.bytes_dropped_fault += 1
                continue
            out.append(byte)
        return bytes(out)

    def _corrupt(self, frame: bytes) -> bytes:
        low, mid, high = frame
        mode = self._rng.randrange(3)
        if mode == 0:  # M byte's flag bit cleared: L, L', H
            return bytes((low, mid & 0x3F, high))
        if mode == 1:  # M byte lost: L, H
            return bytes((low, high))
        return bytes((low, mid, (high & 0x3F) | 0x40))  # H flag turned into M: L, M, M'

    def _make_garbage(self, n_bytes: int) -> bytes:
        buf = bytearray(self._tail[-2:])
        start = len(buf)
        rng = self._rng
        while len(buf) - start < n_bytes:
            byte = rng.randrange(256)
            if (
                byte >> 6 >= 2
                and len(buf) >= 2
                and buf[-2] >> 6 == FLAG_L
                and buf[-1] >> 6 == FLAG_M
            ):
                continue  # would complete an accidental frame
            buf.append(byte)
        return bytes(buf[start:])
