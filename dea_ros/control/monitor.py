"""What the control loop watches besides the control step: the laser stream and the tracking error.

* :class:`SampleStream` -- each laser sample (acquisition time, displacement) is accepted or
  counted as invalid (not finite) or stale (not newer than the last); gaps in the stamps count
  the samples never seen; a first-order filtered finite difference (5 ms) gives the velocity
  published on ``joint_states``.
* :class:`TrackingWindow` -- RMS and largest tracking error and saturated commands since the last
  report (position_controller_node's diagnostics).

No ROS, no clock: times are the samples' acquisition times, s.
"""
from __future__ import annotations

import math

from .controller import ControlOutput

__all__ = ["SampleStream", "TrackingWindow", "VELOCITY_TIME_CONSTANT_S", "VELOCITY_MAX_GAP_S"]

#: Time constant of the velocity filter, s.
VELOCITY_TIME_CONSTANT_S = 0.005
#: A sample this long after the previous one (s) restarts the velocity from the last estimate (no update).
VELOCITY_MAX_GAP_S = 0.1


class SampleStream:
    """The laser samples as the controller sees them (SI units; counts since construction)."""

    def __init__(self, sample_period_s: float):
        self.sample_period_s = float(sample_period_s)
        self.last_t_s: float | None = None      # stamp of the latest accepted sample
        self.last_m = math.nan                  # its displacement
        self.velocity_m_per_s = 0.0
        self.samples = 0
        self.stale = 0                          # not newer than the latest (out of order, repeated)
        self.skipped = 0                        # never seen (gaps in the stamps: dropped or overtaken)
        self.invalid = 0                        # not finite or outside the sensor's range

    def accept(self, t_s: float, displacement_m: float, min_m: float = -math.inf, max_m: float = math.inf) -> bool:
        """Take a sample acquired at ``t_s``; False (counted) when it is invalid or stale.

        Invalid: not finite (a sample the laser node flagged implausible arrives as NaN) or outside
        [``min_m``, ``max_m``] (the sensor's measuring range, sensor_msgs/Range min_range/max_range).
        """
        d = float(displacement_m)
        t = float(t_s)
        if not (math.isfinite(d) and min_m <= d <= max_m):
            self.invalid += 1
            return False
        last = self.last_t_s
        if last is not None and t <= last:
            self.stale += 1
            return False
        period = self.sample_period_s
        if last is not None and t - last > 1.5 * period:
            self.skipped += int(round((t - last) / period)) - 1
        if last is not None and t - last < VELOCITY_MAX_GAP_S and math.isfinite(self.last_m):
            dt = t - last
            a = dt / (dt + VELOCITY_TIME_CONSTANT_S)
            self.velocity_m_per_s += a * ((d - self.last_m) / dt - self.velocity_m_per_s)
        self.last_t_s = t
        self.last_m = d
        self.samples += 1
        return True


class TrackingWindow:
    """Tracking error and saturations over a reporting window (:meth:`clear` starts the next one)."""

    def __init__(self):
        self.saturations = 0                    # saturated commands since construction
        self.clear()

    def clear(self) -> None:
        """Start a new window (the saturation count runs on)."""
        self.sum_sq_m2 = 0.0
        self.n = 0
        self.max_abs_m = 0.0

    def add(self, out: ControlOutput) -> None:
        """Count one control step's output."""
        if out.saturated:
            self.saturations += 1
        self.sum_sq_m2 += out.error_m * out.error_m
        self.n += 1
        self.max_abs_m = max(self.max_abs_m, abs(out.error_m))

    @property
    def rms_m(self) -> float:
        """RMS tracking error over the window, m (NaN when empty)."""
        return math.sqrt(self.sum_sq_m2 / self.n) if self.n else math.nan
