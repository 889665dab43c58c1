"""A reference streamed as timed samples: ros2_control's joint commands (no ROS).

The topic-based hardware interfaces of ros2_control (``joint_state_topic_hardware_interface/
JointStateTopicSystem``, ``topic_based_ros2_control/TopicBasedSystem``) publish, in every ``write()``
of the controller manager (its ``update_rate``), the command interfaces' values: for this actuator
the position d (m) a joint_trajectory_controller wants now and, with a velocity command interface,
its velocity (m/s). The samples arrive at the update rate, may pause (``trigger_joint_command_threshold``:
nothing is sent while the state is within the threshold of the command) and may be NaN (command
interfaces start at NaN before a controller claims the joint).

:class:`StreamedReference` turns each sample into the controller's reference: a quintic segment
from the current reference state to where the stream will be ``horizon_periods`` command periods
later (the position extrapolated with the commanded velocity, or with the finite difference of the
last two samples when none is given), checked like a trajectory (:func:`~.reference.check_trajectory`
through :meth:`PositionController.set_trajectory`); a sample the actuator cannot follow that way (a
jump) is shaped like a setpoint (:meth:`PositionController.set_setpoint`: the fastest feasible move),
and one outside the reachable range is refused (:class:`UnreachableReferenceError`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .controller import PositionController
from .inverse import UnreachableReferenceError
from .reference import trajectory_from_points

__all__ = ["StreamedReference", "StreamDecision"]


@dataclass(frozen=True)
class StreamDecision:
    """What :meth:`StreamedReference.command` did with one sample."""

    kind: str              # "followed" (a segment to the extrapolated sample) or "shaped" (a setpoint move)
    target_m: float        # where the reference goes, m
    at_s: float            # when it gets there (followed) or when the move started (shaped), s
    text: str


class StreamedReference:
    """Joint commands (position, optional velocity) at a controller manager's rate -> reference.

    ``horizon_periods``: the segment of each sample ends this many command periods ahead (> 1, so
    that one late or suppressed sample does not make the reference stop); the command period is
    measured on the arrival times (median-free running mean of the intervals, clamped to
    [``min_period_s``, ``max_period_s``]); a pause longer than ``max_period_s`` restarts the estimate
    (the stream stopped under the threshold: the next sample starts from rest).
    """

    def __init__(self, horizon_periods: float = 2.0, min_period_s: float = 1e-3, max_period_s: float = 0.1):
        if not horizon_periods >= 1.0:
            raise ValueError(f"horizon_periods: must be >= 1, got {horizon_periods!r}")
        self.horizon_periods = float(horizon_periods)
        self.min_period_s = float(min_period_s)
        self.max_period_s = float(max_period_s)
        self.period_s = math.nan
        self.last_t_s: float | None = None
        self.last_m: float | None = None
        self.followed = 0
        self.shaped = 0

    def reset(self) -> None:
        self.period_s = math.nan
        self.last_t_s = self.last_m = None

    def _update_period(self, t_s: float) -> float:
        if self.last_t_s is not None:
            dt = t_s - self.last_t_s
            if 0.0 < dt <= self.max_period_s:
                dt = max(dt, self.min_period_s)
                self.period_s = dt if math.isnan(self.period_s) else 0.8 * self.period_s + 0.2 * dt
            elif dt > self.max_period_s:
                self.period_s = math.nan        # the stream paused: start again
        return self.period_s

    def command(self, ctl: PositionController, t_s: float, position_m: float,
                velocity_m_per_s: float | None = None) -> StreamDecision:
        """Make the sample (position m, velocity m/s or None) at t_s the controller's reference.

        Raises :class:`UnreachableReferenceError` (reference unchanged) for a non-finite position or
        one outside the reachable range.
        """
        d = float(position_m)
        ctl.inverse.check_reachable(d, "joint command position")
        paused = self.last_t_s is None or t_s - self.last_t_s > self.max_period_s
        period = self._update_period(t_s)
        v = velocity_m_per_s if velocity_m_per_s is not None and math.isfinite(velocity_m_per_s) else None
        if v is None:
            v = 0.0 if paused or math.isnan(period) else (d - self.last_m) / max(t_s - self.last_t_s, 1e-9)
        self.last_t_s, self.last_m = t_s, d
        if math.isnan(period):
            period = self.max_period_s if paused else self.min_period_s
            v = 0.0
        horizon = self.horizon_periods * period
        lo, hi = ctl.reachable_range_m
        target = min(max(d + v * horizon, lo), hi)
        if target != d + v * horizon:
            v = 0.0
        try:
            traj = trajectory_from_points(t_s, ctl.reference_at(t_s), [(t_s + horizon, target, v, 0.0)])
            ctl.set_trajectory(t_s, traj)
            self.followed += 1
            return StreamDecision("followed", target, t_s + horizon, "following the joint command stream")
        except (ValueError, UnreachableReferenceError):
            text = ctl.set_setpoint(t_s, d)     # raises UnreachableReferenceError when no move is feasible
            self.shaped += 1
            return StreamDecision("shaped", d, t_s, f"joint command shaped as a setpoint: {text}")
