"""Acquisition times of a fixed-rate sample stream that carries no time stamps (pure, no I/O).

The ILD1320 sends no time stamps, so :class:`SampleClock` reconstructs the time of each sample
from the measuring rate ``f`` and the arrival time of the chunk of bytes that
contained it:

1. The sensor streams continuously, one value per cycle, so the *newest* value
   of a chunk read right after it arrived left the sensor at most about one
   adapter/OS latency before the arrival time ``t_arr`` (``time.monotonic()``
   just after the read). It was acquired
   :data:`~dea_ros.hardware.laser.ild1320_protocol.frames.OUTPUT_DELAY_CYCLES` cycles
   before it was output (manual ch. 6.4: 1.5 ms at 2 kHz) plus the 3-byte
   transmission time, so ``t_arr - latency`` is an *upper bound* of its
   acquisition time. The ``n`` values of a chunk are one cycle apart:
   ``t_i = t_first + i / f``.
2. A sample clock ``t_first(k) = t_next`` is predicted from the previous chunk
   and compared with the bound ``c = t_arr - latency - (n - 1) / f``:

   * ``c < t_next`` -- the prediction is too late (it can never be later than a
     bound): move it down, by at most half a period per chunk so time stamps
     stay strictly increasing (spacing >= 0.5/f at chunk boundaries);
   * ``0 <= c - t_next <= gap_threshold_s`` -- ordinary transport jitter: no
     change, but if *every* chunk within ``drift_window_s`` (0.5 s) arrived
     late, the smallest of these deviations is clock drift: move up by it;
   * ``c - t_next > 0.75 / f`` and the decoder dropped bytes in front of a
     sample of the chunk (corrupted frames): the missing whole periods are
     skipped just before that sample;
   * ``c - t_next > gap_threshold_s`` (50 ms) without dropped bytes: the sensor
     was silent (samples were never sent): skip the missing periods. Shorter
     unexplained delays are taken for transport delay, not for lost samples.

The result is the lower envelope of the arrival times -- the least-delayed
chunks define the clock -- tracking crystal drift, independent of how often
the reader polls, with an error of about the minimum transport latency
(sub-millisecond on a pty, the USB latency timer on a real adapter).
"""
from __future__ import annotations

import math
from typing import Sequence

__all__ = ["SampleClock"]


class SampleClock:
    """Reconstructs acquisition times of a fixed-rate stream from chunk arrival times.

    See the module docstring for the method. ``latency_s`` is the nominal delay
    from acquisition to arrival of a sample (output delay plus transmission).
    Between corrections the stamps are exactly ``1 / rate_hz`` apart.
    """

    def __init__(
        self,
        rate_hz: float,
        latency_s: float = 0.0,
        *,
        gap_threshold_s: float = 0.05,
        drift_window_s: float = 0.5,
    ) -> None:
        self._rate_hz = self._positive("rate_hz", rate_hz)
        self._latency_s = self._non_negative("latency_s", latency_s)
        self._gap_threshold_s = self._positive("gap_threshold_s", gap_threshold_s)
        self._drift_window_s = self._positive("drift_window_s", drift_window_s)
        self._t_next: float | None = None
        self._last_stamp = -math.inf  # stamps stay increasing across resets
        self._window_start = 0.0
        self._window_min_residual = math.inf
        self.periods_skipped = 0

    @staticmethod
    def _positive(name: str, value: float) -> float:
        result = float(value)
        if not (math.isfinite(result) and result > 0.0):
            raise ValueError(f"{name} must be positive, got {value!r}")
        return result

    @staticmethod
    def _non_negative(name: str, value: float) -> float:
        result = float(value)
        if not (math.isfinite(result) and result >= 0.0):
            raise ValueError(f"{name} must be >= 0, got {value!r}")
        return result

    @property
    def rate_hz(self) -> float:
        return self._rate_hz

    @property
    def latency_s(self) -> float:
        return self._latency_s

    def reset(self, rate_hz: float | None = None, latency_s: float | None = None) -> None:
        """Forget the anchor (next chunk re-anchors); optionally change rate/latency.

        Stamps stay strictly increasing across a reset: the new anchor is at
        least half a period after the last stamp given out.
        """
        if rate_hz is not None:
            self._rate_hz = self._positive("rate_hz", rate_hz)
        if latency_s is not None:
            self._latency_s = self._non_negative("latency_s", latency_s)
        self._t_next = None

    def stamp(
        self,
        n_samples: int,
        arrival_time_s: float,
        *,
        loss_before: Sequence[bool] | None = None,
        loss_after: bool = False,
    ) -> list[float]:
        """Acquisition times (s) of ``n_samples`` samples that arrived at ``arrival_time_s``.

        ``loss_before[i]`` is True when frames may have been lost just before
        sample ``i`` (the decoder dropped bytes there, possibly in an earlier
        chunk); ``loss_after`` when bytes were dropped after the last sample.
        A detected gap is inserted before the last flagged sample (or before
        the first one when unflagged); with ``loss_after`` a positive deviation
        is ambiguous and does not count for the drift correction.
        """
        n = int(n_samples)
        if n <= 0:
            return []
        flags = [False] * n if loss_before is None else [bool(f) for f in loss_before]
        if len(flags) != n:
            raise ValueError(f"loss_before has {len(flags)} flags for {n} samples")
        arrival = float(arrival_time_s)
        period = 1.0 / self._rate_hz
        bound_first = arrival - self._latency_s - (n - 1) * period
        if self._t_next is None:
            t_first = max(bound_first, self._last_stamp + 0.5 * period)
            times = [t_first + i * period for i in range(n)]
            self._t_next = times[-1] + period
            self._last_stamp = times[-1]
            self._window_start = arrival
            self._window_min_residual = math.inf
            return times
        last_loss = max((i for i, flag in enumerate(flags) if flag), default=None)
        error = bound_first - self._t_next
        shift = 0.0
        skip, skip_at = 0, n
        if error < 0.0:
            shift = max(error, -0.5 * period)  # prediction too late: move down, bounded
        elif last_loss is not None and error > 0.75 * period:
            skip, skip_at = int(round(error / period)), last_loss  # lost frames
        elif error > max(self._gap_threshold_s, 0.75 * period):
            skip, skip_at = int(round(error / period)), 0  # silence / undetected loss
        if not (loss_after and error > 0.0):
            residual = error - shift - skip * period
            self._window_min_residual = min(self._window_min_residual, residual)
        if arrival - self._window_start >= self._drift_window_s:
            # every chunk of the window arrived later than predicted: the sensor
            # clock is slower than nominal (or the anchor was late) -> move up
            if math.isfinite(self._window_min_residual) and self._window_min_residual > 0.0:
                shift += self._window_min_residual
            self._window_start = arrival
            self._window_min_residual = math.inf
        self.periods_skipped += skip
        t_first = self._t_next + shift
        times = [t_first + (i + (skip if i >= skip_at else 0)) * period for i in range(n)]
        self._t_next = times[-1] + period
        self._last_stamp = times[-1]
        return times
