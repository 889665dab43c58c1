"""Laser samples paired with the applied voltage in effect at their stamps (model_node's drift tracking, no ROS).

The amplifier publishes every output it applies, stamped when applied, and holds it until the next
(zero-order hold: an output stamped t holds from t on, as the bag extraction reads a record and as the
core's simulated rig samples ``ClosedLoopResult.applied_V``). A laser sample stamped t_k is paired with
the voltage in effect at t_k: the last output stamped at or before t_k. That is the voltage acting on the
membrane at the sample (the force balance at t_k holds with u(t_k)), so a tracker fed these pairs has
``TrackerConfig(voltage_delay_samples=0)`` (:data:`APPLIED_VOLTAGE_DELAY_SAMPLES`); the controller's
tracker, fed its *command*, has 1 (the command acts one sample later). What remains, the amplifier's
phase within a sample (at most half a sample either way), is the window fit's extra loop delay.

The two topics arrive in any order: a sample waits (at most ``max_pending`` samples) until an output
stamped at or after it has arrived, then the voltage at its stamp is known; beyond that the oldest waiting
sample is paired with the latest output (the amplifier holds it). A sample older than every buffered
output gets NaN (the tracker skips it). Stamps are integer nanoseconds (exact comparisons).
"""
from __future__ import annotations

import math
from bisect import bisect_right
from collections import deque

__all__ = ["APPLIED_VOLTAGE_DELAY_SAMPLES", "StampedVoltagePairing"]

#: ``TrackerConfig.voltage_delay_samples`` for a tracker fed the applied voltage at the sample stamp
APPLIED_VOLTAGE_DELAY_SAMPLES = 0


class StampedVoltagePairing:
    """(measured d m, applied voltage V at the sample's stamp) pairs from two stamped streams (module docstring)."""

    def __init__(self, max_pending: int = 8, history: int = 64):
        self.max_pending = int(max_pending)
        self.history = int(history)
        self.stamps_ns: list = []        # applied outputs, increasing stamps
        self.voltages_V: list = []
        self.pending: deque = deque()    # (stamp ns, measured m), waiting for the voltage at their stamp
        self.stale_voltages = 0          # outputs older than the latest one (ignored)
        self.stale_samples = 0           # samples not newer than the previous one (ignored)
        self.released_ns: int | None = None   # stamp of the latest sample handed out

    def voltage_at(self, t_ns: int) -> float:
        """The buffered output in effect at t_ns (the last stamped at or before it), V; NaN before them all."""
        i = bisect_right(self.stamps_ns, t_ns) - 1
        return self.voltages_V[i] if i >= 0 else math.nan

    def add_voltage(self, t_ns: int, voltage_V: float) -> list:
        """An applied output stamped t_ns; returns the samples it completes as [(measured m, voltage V)]."""
        stamps = self.stamps_ns
        if stamps and t_ns < stamps[-1]:
            self.stale_voltages += 1
            return []
        if stamps and t_ns == stamps[-1]:
            self.voltages_V[-1] = float(voltage_V)
        else:
            stamps.append(int(t_ns))
            self.voltages_V.append(float(voltage_V))
        if len(stamps) > 2 * self.history:
            del stamps[:-self.history], self.voltages_V[:-self.history]
        return self._release()

    def add_sample(self, t_ns: int, measured_m: float) -> list:
        """A laser sample stamped t_ns; returns the samples now paired as [(measured m, voltage V)], oldest first."""
        last = self.pending[-1][0] if self.pending else self.released_ns
        if last is not None and t_ns <= last:
            self.stale_samples += 1
            return []
        self.pending.append((int(t_ns), float(measured_m)))
        return self._release()

    def _release(self) -> list:
        pending, out = self.pending, []
        latest = self.stamps_ns[-1] if self.stamps_ns else None
        while pending and ((latest is not None and pending[0][0] <= latest) or len(pending) > self.max_pending):
            t_ns, d = pending.popleft()
            out.append((d, self.voltage_at(t_ns)))
            self.released_ns = t_ns
        return out

    def clear(self) -> None:
        """Forget everything (the clock jumped back, the model was replaced)."""
        self.stamps_ns.clear()
        self.voltages_V.clear()
        self.pending.clear()
        self.released_ns = None
