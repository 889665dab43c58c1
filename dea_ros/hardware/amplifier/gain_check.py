"""The amplifier's gain verified on activation: a low-voltage loop check of command, output and monitor.

A slip in ``amplifier_gain_V_per_V`` (100 configured on a 1000 V/V amplifier: every command x10
on the membrane) cannot be seen from the command side. With the amplifier's voltage monitor wired
(and its gain a separate, required setting: a monitor gain defaulting to the amplifier gain would
scale with the same slip and agree), amplifier_node runs :class:`GainLoopCheck` on every
activation before it follows any command: it ramps its command to ``check_V`` (a few tens of
volts) at ``ramp_V_per_s`` (through the safety controller, so the ceiling and the slew limit apply;
slowly, so that the node's continuous monitor comparison stops a x10 slip at a few volts written),
waits until the output has been there for ``settle_s`` and compares the monitor with it. A ratio outside
[1 - tolerance, 1 + tolerance] (x0.1 and x10 slips are far outside) fails with the numbers; the
node then faults to 0 V. A monitor that agrees proves the DAQ volts x the real gain = the volts
the controller meant (up to the monitor's own calibration, checked once with a meter: README,
commissioning). Without a monitor nothing on the rig can see the gain: :func:`unverified_gain_note`.

No ROS, no clock: times are the node's control times, s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["GainCheckResult", "GainLoopCheck", "unverified_gain_note"]


@dataclass(frozen=True)
class GainCheckResult:
    """The outcome of one loop check (V; ``ratio`` = monitor / output)."""

    ok: bool
    commanded_V: float
    output_V: float
    monitor_V: float
    ratio: float
    message: str


class GainLoopCheck:
    """Drive ``check_V``, hold it ``settle_s``, compare the monitor with command and output.

    Call :meth:`observe` once per amplifier update with the output written and the monitor read;
    it returns None while the check runs and a :class:`GainCheckResult` when it is decided (also a
    failure when the output has not settled at ``check_V`` within ``timeout_s``).
    """

    def __init__(self, check_V: float, tolerance_fraction: float, settle_s: float, timeout_s: float,
                 amplifier_gain_V_per_V: float, monitor_gain_V_per_V: float, ramp_V_per_s: float = 1000.0):
        for name, value in (("check_V", check_V), ("settle_s", settle_s), ("timeout_s", timeout_s),
                            ("amplifier_gain_V_per_V", amplifier_gain_V_per_V),
                            ("monitor_gain_V_per_V", monitor_gain_V_per_V), ("ramp_V_per_s", ramp_V_per_s)):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name}: must be a positive number, got {value!r}")
        if not 0.0 < tolerance_fraction < 1.0:
            raise ValueError(f"tolerance_fraction: must be in (0, 1), got {tolerance_fraction!r}")
        self.check_V = float(check_V)
        self.tolerance_fraction = float(tolerance_fraction)
        self.settle_s = float(settle_s)
        self.timeout_s = float(timeout_s)
        self.gains = (float(amplifier_gain_V_per_V), float(monitor_gain_V_per_V))
        self.ramp_V_per_s = float(ramp_V_per_s)
        self.started_s: float | None = None
        self.reached_s: float | None = None
        self.result: GainCheckResult | None = None

    def command_at(self, t_s: float) -> float:
        """What the node commands at time t while the check runs (V): the ramp to ``check_V``."""
        if self.started_s is None:
            self.started_s = float(t_s)
        return min(self.check_V, self.ramp_V_per_s * (t_s - self.started_s))

    def observe(self, t_s: float, output_V: float, monitor_V: float | None) -> GainCheckResult | None:
        """One update: the output written (V) and the monitor read (V, None: none) at time t (s)."""
        if self.result is not None:
            return self.result
        if self.started_s is None:
            self.started_s = float(t_s)
        if self.reached_s is None and output_V >= self.check_V * (1.0 - 1e-9):
            self.reached_s = float(t_s)
        if self.reached_s is not None and t_s - self.reached_s >= self.settle_s:
            self.result = self.judge(output_V, monitor_V)
        elif t_s - self.started_s > self.timeout_s:
            self.result = self._result(False, output_V, monitor_V,
                                       f"the output did not reach {self.check_V:.1f} V within {self.timeout_s:g} s "
                                       f"(output {output_V:.1f} V)")
        return self.result

    def judge(self, output_V: float, monitor_V: float | None) -> GainCheckResult:
        """Compare the monitor with the output now (also used when the monitor disagrees before the hold)."""
        m = math.nan if monitor_V is None else float(monitor_V)
        ratio = m / output_V if output_V > 0.0 else math.nan
        tol = self.tolerance_fraction
        if math.isfinite(ratio) and abs(ratio - 1.0) <= tol and abs(output_V - self.check_V) <= tol * self.check_V:
            return self._result(True, output_V, m, f"gain verified: monitor {m:.1f} V for {output_V:.1f} V "
                                                   f"(ratio {ratio:.3f}, tolerance {tol:g})")
        amp_gain, mon_gain = self.gains
        return self._result(False, output_V, m, (
            f"gain loop check failed: commanded {self.check_V:.1f} V, output {output_V:.1f} V (DAQ "
            f"{output_V / amp_gain:.4g} V at amplifier_gain_V_per_V {amp_gain:g}), monitor reads {m:.1f} V (at "
            f"monitor_gain_V_per_V {mon_gain:g}): ratio {ratio:.3g}, allowed 1 +- {tol:g}. The amplifier's real "
            f"gain is about {amp_gain * ratio:.4g} V/V if the monitor gain is right (or the monitor gain is "
            f"{mon_gain / ratio:.4g} V/V if the amplifier gain is): check both against the amplifier's "
            "data sheet and a meter (README, commissioning)"))

    def _result(self, ok: bool, output_V: float, monitor_V: float, message: str) -> GainCheckResult:
        ratio = monitor_V / output_V if output_V > 0.0 and math.isfinite(monitor_V) else math.nan
        return GainCheckResult(ok, self.check_V, float(output_V), float(monitor_V), ratio, message)


def unverified_gain_note(amplifier_gain_V_per_V: float) -> str:
    """What the node says when no monitor is wired (the gain cannot be checked on the rig)."""
    return (f"amplifier gain {amplifier_gain_V_per_V:g} V/V NOT verified: no monitor input (monitor_channel -1); "
            "measure the output with a high-voltage meter before the first run (README, commissioning)")
