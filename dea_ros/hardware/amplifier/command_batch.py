"""Batched voltage commands: an open-loop sequence that amplifier_node applies one sample per update.

An identification protocol is open loop: the identifier knows the voltages of the next K updates
before they happen. In simulated time (the mock rig's lockstep) it may send them as one batch; the
amplifier queues them in a :class:`CommandQueue` and at each of its updates hands exactly one sample
to the unchanged :class:`~dea_ros.hardware.amplifier.safety.SafeVoltageController` as if that sample
had arrived as a single command just before the update. Every sample therefore passes every check at
its own update (NaN/inf/negative/above the ceiling rejected, slew limited, the watchdog fed exactly
as by K single commands arriving one per update).

What the queue itself enforces (a batch that fails any of these is rejected whole, and the queue is
emptied):

* at most ``max_length`` samples, and the batch may not span more than ``max_span_s`` (amplifier_node:
  its watchdog timeout), so a sender that dies right after a batch keeps the output alive at most
  that much longer than a sender of single commands;
* exactly one sample per update: sample i is for ``first_s + i x period_s`` (the offsets checked to a
  quarter period);
* fresh: the first sample is for the next update after the last one (``last_update_s + period_s``,
  to half a period); a batch for an update already done (stale, replayed, delayed) or for a later one
  is rejected;
* only while the controller is activated (checked by the caller: ``offer(..., activated=...)``).

At each update :meth:`CommandQueue.take` returns the sample for that update; samples for updates the
clock skipped are dropped (counted). The caller empties the queue (:meth:`clear`) on a single command
(it supersedes the sequence), on deactivate, cleanup, a fault, and whenever the controller rejects a
sample. A new batch replaces what is queued.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Sequence

__all__ = ["BatchVerdict", "CommandQueue"]


@dataclass(frozen=True)
class BatchVerdict:
    """The queue's answer to a batch: accepted or the reason, and the last queued sample's time, s."""

    accepted: bool
    reason: str                  #: "accepted" or why the batch was rejected
    last_sample_s: float | None  #: update time of the batch's last sample (None when rejected)

    def __bool__(self) -> bool:
        return self.accepted


class CommandQueue:
    """The samples of the latest accepted batch, each tagged with the update time it is for (s)."""

    def __init__(self, max_length: int, period_s: float, max_span_s: float) -> None:
        if max_length < 1 or not period_s > 0.0 or not max_span_s > 0.0:
            raise ValueError(f"CommandQueue: max_length >= 1, period_s > 0 and max_span_s > 0 "
                             f"(got {max_length}, {period_s}, {max_span_s})")
        self.max_length = int(max_length)
        self.period_s = float(period_s)
        self.max_span_s = float(max_span_s)
        self._samples: deque[tuple[float, float]] = deque()
        self.accepted_batches = 0
        self.rejected: dict[str, int] = {}
        self.skipped_samples = 0   #: samples whose update the clock skipped
        self.cleared_samples = 0   #: samples dropped by clear()

    def __len__(self) -> int:
        return len(self._samples)

    def _reject(self, reason: str) -> BatchVerdict:
        self.clear()
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        return BatchVerdict(False, reason, None)

    def offer(self, first_s: float, offsets_s: Sequence[float], values_V: Sequence[float],
              last_update_s: float | None, activated: bool) -> BatchVerdict:
        """A batch: ``values_V[i]`` for the update at ``first_s + offsets_s[i]`` (s). ``last_update_s``:
        the time of the amplifier's last update. Replaces the queue when accepted."""
        n, period = len(values_V), self.period_s
        if not activated:
            return self._reject("inactive")
        if n == 0 or len(offsets_s) != n:
            return self._reject("malformed")
        if n > self.max_length:
            return self._reject("oversized")
        if n * period > self.max_span_s * (1.0 + 1e-9):
            return self._reject("longer than the watchdog")
        if not math.isfinite(first_s) or last_update_s is None:
            return self._reject("stale")
        for i, offset in enumerate(offsets_s):
            if not (math.isfinite(offset) and abs(offset - i * period) <= 0.25 * period):
                return self._reject("not one sample per update")
        expected_s = last_update_s + period
        if first_s < expected_s - 0.5 * period:
            return self._reject("stale")
        if first_s > expected_s + 0.5 * period:
            return self._reject("not for the next update")
        self._samples.clear()
        # the samples' times on the amplifier's update grid (offsets were checked to a quarter period)
        self._samples.extend((expected_s + i * period, values_V[i]) for i in range(n))
        self.accepted_batches += 1
        return BatchVerdict(True, "accepted", expected_s + (n - 1) * period)

    def take(self, t_s: float):
        """The sample for the update at ``t_s`` (s), or None (queue empty, or no sample for this update).
        Samples for earlier updates (the clock skipped them) are dropped and counted."""
        half = 0.5 * self.period_s
        while self._samples and self._samples[0][0] < t_s - half:
            self._samples.popleft()
            self.skipped_samples += 1
        if self._samples and self._samples[0][0] <= t_s + half:
            return self._samples.popleft()[1]
        return None

    def clear(self) -> None:
        self.cleared_samples += len(self._samples)
        self._samples.clear()

    def counts(self) -> dict[str, int]:
        """Accepted and rejected batches (per reason), skipped and cleared samples."""
        return {"accepted": self.accepted_batches, **{f"rejected {k}": v for k, v in self.rejected.items()},
                "skipped": self.skipped_samples, "cleared": self.cleared_samples}
