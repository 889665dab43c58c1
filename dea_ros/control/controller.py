"""The position controller: reference shaping + model feedforward + feedback on u^2 + limits.

One call per laser sample::

    ctl = PositionController(params, ControllerConfig(max_voltage_V=3150, slew_rate_V_per_s=1e5))
    ctl.start(t, d_measured)                       # holds the measured position
    ctl.set_setpoint(t, 0.80e-3)                   # shaped into a feasible move (or refused)
    out = ctl.update(t_k, d_k)                     # -> out.voltage_V for the amplifier

Per sample (t_k the acquisition time of the measurement d_k):

1. the reference (d_r, v_r, a_r) at t_k + ``feedforward_lead_s`` (the command acts after the loop
   delay) gives the feedforward u^2 by eq. 5 inverted, eps1 integrated along the reference (eq. 11);
2. the error e = d_r(t_k) - d_k drives the PID on u^2 (:mod:`.feedback`): du^2 = a_fb / b(d_r);
3. u^2 is clamped to [0, u_max^2], u = sqrt(u^2) to the slew limit; saturation freezes the integrator.

Setpoints are shaped by :func:`plan_move` (fastest feasible quintic from the current reference
state, never shorter than ``min_move_time_s``); trajectories are checked by
:func:`check_trajectory` and refused with the reason when the actuator cannot follow them.

The ends of the range (issue 20): a setpoint more than ``end_tolerance_m`` beyond the reachable
range [d(0 V), d(u_max)] is refused at once with the range in the message; one inside that band is
clamped to the *usable* range, where the static u^2 keeps ``end_margin_fraction`` of u_max^2 from
0 and from u_max^2 (the feedback's headroom: at d(0 V) it could only pull, at d(u_max) only
release). :meth:`PositionController.request_setpoint` plans without blocking: the setpoint is
answered at once (clamped or refused) and :meth:`update` runs one feasibility check of the
planner per sample (:func:`plan_move_steps`, at most :func:`plan_checks`), the current reference
held meanwhile; the move starts when that many samples have passed.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import SafetyConfigError
from ..hardware.amplifier.limits import membrane_voltage_limit_V
from ..model import MembraneParameters
from .feedback import FeedbackGains, PIDOnU2, design_gains
from .inverse import ModelInverse, StrainIntegrator, UnreachableReferenceError
from .reference import Hold, QuinticMove, Trajectory, check_trajectory, plan_checks, plan_move, plan_move_steps

__all__ = ["ControllerConfig", "ControlOutput", "PositionController"]


@dataclass(frozen=True)
class ControllerConfig:
    """Settings of :class:`PositionController` (SI units)."""

    max_voltage_V: float                      # highest command (<= the amplifier's limit)
    slew_rate_V_per_s: float                  # the amplifier's slew limit
    sample_period_s: float = 1e-3             # laser sample period (the control period)
    loop_delay_s: float = 1.0e-3              # acquisition -> voltage applied (latency, amplifier update)
    feedforward: bool = True
    feedback: bool = True
    max_sensitivity: float = 1.6              # robustness of the feedback design (Ms)
    max_noise_gain: float = 0.2               # RMS position error per RMS laser noise the feedback may add
    min_move_time_s: float = 0.02             # shortest shaped setpoint move
    feedforward_slew_fraction: float = 0.9    # share of the slew limit a reference may use
    operating_point_m: float | None = None    # gain design point (default: mid-range)
    feedforward_lead_s: float | None = None   # default: loop_delay_s + sample_period_s / 2
    end_margin_fraction: float = 0.05         # u^2 headroom kept at each end of the range (share of u_max^2)
    end_tolerance_m: float = 2e-6             # setpoints this far beyond the reachable range are clamped
    start_tolerance_fraction: float = 0.25    # a (re)start needs a measurement within this share of the range

    def __post_init__(self):
        for name in ("max_voltage_V", "slew_rate_V_per_s", "sample_period_s", "min_move_time_s",
                     "feedforward_slew_fraction"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be a positive number, got {v!r}")
        if not (math.isfinite(self.loop_delay_s) and self.loop_delay_s >= 0):
            raise ValueError(f"loop_delay_s: must be >= 0 s, got {self.loop_delay_s!r}")
        if self.feedforward_slew_fraction > 1.0:
            raise ValueError("feedforward_slew_fraction: must be in (0, 1]")
        if not (0.0 <= self.end_margin_fraction < 0.5):
            raise ValueError(f"end_margin_fraction: must be in [0, 0.5), got {self.end_margin_fraction!r}")
        for name in ("end_tolerance_m", "start_tolerance_fraction"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: must be >= 0, got {v!r}")

    @classmethod
    def for_membrane(cls, params: MembraneParameters, margin: float, max_voltage_V: float = 0.0,
                     **settings) -> "ControllerConfig":
        """The settings for a membrane: the highest command is ``max_voltage_V`` or, when 0, the membrane's
        limit margin x breakdown field x thickness (as amplifier_node's); a ``max_voltage_V`` above that limit
        is refused (:class:`~dea_ros.errors.SafetyConfigError`). ``settings``: the other fields."""
        limit = membrane_voltage_limit_V(params.thickness_m, params.breakdown_field_V_per_m, float(margin))
        configured = float(max_voltage_V)
        if configured > limit:
            raise SafetyConfigError(
                f"parameter 'max_voltage_V': {configured} V exceeds the membrane limit {limit:.6g} V (margin x "
                "breakdown field x thickness); lower it or set 0 to use the limit")
        return cls(max_voltage_V=configured if configured > 0 else limit, **settings)

    @property
    def lead_s(self) -> float:
        return self.loop_delay_s + 0.5 * self.sample_period_s if self.feedforward_lead_s is None \
            else float(self.feedforward_lead_s)

    @property
    def design_delay_s(self) -> float:
        """Delay of the loop for the gain design: latency plus half a sample (zero-order hold)."""
        return self.loop_delay_s + 0.5 * self.sample_period_s


@dataclass
class ControlOutput:
    """What one :meth:`PositionController.update` decided (SI units)."""

    voltage_V: float
    reference_m: float
    error_m: float
    u2_feedforward_V2: float
    u2_feedback_V2: float
    saturated: int          # -1 at u^2 = 0 / slew down, +1 at the voltage limit / slew up, 0 free
    slew_limited: bool = False


@dataclass
class _Plan:
    """A setpoint being planned: one check per sample, the move starting at ``start_s``."""

    target_m: float
    start_s: float
    eps1: float                       # the reference's eps1 at start_s
    steps: object                     # the plan_move_steps generator
    retry: bool = False               # refused: plan again from the end of the running move


@dataclass
class _State:
    trajectory: Trajectory
    t_ff: float                       # time of the strain integrator (reference time, s)
    last_t: float | None = None
    last_u: float = 0.0
    messages: list = field(default_factory=list)


class PositionController:
    """Feedforward (eq. 5 inverted) + PID on u^2 for one identified membrane; no ROS, no clock."""

    def __init__(self, params: MembraneParameters, config: ControllerConfig):
        self.params = params
        self.config = config
        self.inverse = ModelInverse(params, config.max_voltage_V)
        self.max_voltage_V = min(config.max_voltage_V, self.inverse.top_voltage_V)
        lo, hi = self.inverse.reachable_range_m
        d_op = 0.5 * (lo + hi) if config.operating_point_m is None else float(config.operating_point_m)
        self.gains: FeedbackGains = design_gains(self.inverse, d_op, config.design_delay_s,
                                                 config.sample_period_s, config.max_sensitivity,
                                                 config.max_noise_gain)
        self.pid = PIDOnU2(self.gains)
        self.strain: StrainIntegrator | None = None
        self.state: _State | None = None
        self.usable_range_m = self.usable_range()
        self.plan: _Plan | None = None
        self.plan_checks = plan_checks(config.min_move_time_s)
        self.plan_note: tuple[bool, str] | None = None   # (accepted?, text) of the last finished plan

    # ---------------------------------------------------------------- setup
    def usable_range(self) -> tuple[float, float]:
        """The usable range of the model in use (m): the static u^2 keeps ``end_margin_fraction`` of u_max^2
        from 0 and from u_max^2 (recomputed when a retune changes the model: :func:`.adaptive.apply_retune`)."""
        umax2 = self.max_voltage_V ** 2
        frac = self.config.end_margin_fraction
        return (self.inverse.static_displacement(frac * umax2), self.inverse.static_displacement((1.0 - frac) * umax2))

    @property
    def reachable_range_m(self) -> tuple[float, float]:
        return self.inverse.reachable_range_m

    @property
    def reference_slew_V_per_s(self) -> float:
        return self.config.slew_rate_V_per_s * self.config.feedforward_slew_fraction

    @property
    def started(self) -> bool:
        return self.state is not None

    def plausible_start(self, displacement_m: float) -> bool:
        """Can the controller (re)start on this measurement? Finite and within the reachable range
        widened by ``start_tolerance_fraction`` of its width (a reading far outside is a sensor fault)."""
        d = float(displacement_m)
        lo, hi = self.reachable_range_m
        pad = self.config.start_tolerance_fraction * (hi - lo)
        return math.isfinite(d) and lo - pad <= d <= hi + pad

    def start(self, t_s: float, displacement_m: float, voltage_V: float | None = None) -> float:
        """Begin at time t holding the measured displacement (clamped into the reachable range).

        The membrane is assumed at rest (eps1 relaxed); ``voltage_V`` is the voltage applied now
        (default: the static inverse of the held position). Returns the held position, m.
        Raises ValueError for a measurement that is not :meth:`plausible_start`.
        """
        if not self.plausible_start(displacement_m):
            raise ValueError(f"start: implausible measurement {float(displacement_m) * 1e6:.1f} um (reachable range "
                             f"{self.reachable_range_m[0] * 1e6:.1f}-{self.reachable_range_m[1] * 1e6:.1f} um)")
        lo, hi = self.reachable_range_m
        d = min(max(float(displacement_m), lo), hi)
        self.strain = StrainIntegrator(self.inverse, d)
        u0 = self.inverse.static_voltage(d, check=False) if voltage_V is None else float(voltage_V)
        self.state = _State(trajectory=Hold(d, t_s), t_ff=float(t_s), last_u=u0)
        self.pid.reset()
        return d

    def stop(self) -> None:
        self.state = None
        self.strain = None
        self.plan = None

    def goal_m(self, t_s: float) -> float:
        """Where the reference is heading: the setpoint being planned, the end of a move or hold, or
        (a trajectory: aborted on a stop) the reference position at t (m)."""
        if self.plan is not None:
            return self.plan.target_m
        traj = self.state.trajectory
        if isinstance(traj, (QuinticMove, Hold)):
            return traj.final_m
        return self.reference_at(t_s)[0]

    def reference_at(self, t_s: float) -> tuple[float, float, float]:
        return self.state.trajectory.sample(t_s)

    # ------------------------------------------------------------ references
    def clamp_setpoint(self, target_m: float) -> tuple[float, str]:
        """(the setpoint to plan, a note): within ``end_tolerance_m`` of the reachable range, clamped to the
        usable range; beyond it, :class:`UnreachableReferenceError` naming both ranges."""
        lo, hi = self.reachable_range_m
        tol = self.config.end_tolerance_m
        d = float(target_m)
        u_lo, u_hi = self.usable_range_m
        if not (math.isfinite(d) and lo - tol <= d <= hi + tol):
            try:
                self.inverse.check_reachable(d, "setpoint")
            except UnreachableReferenceError as exc:
                within = "" if "reachable range" in str(exc) else \
                    f" (reachable range [{lo * 1e6:.1f} um, {hi * 1e6:.1f} um])"
                raise UnreachableReferenceError(
                    f"{exc}{within}; setpoints within {tol * 1e6:g} um of the reachable range are clamped to the "
                    f"usable range [{u_lo * 1e6:.1f}, {u_hi * 1e6:.1f}] um") from None
        clamped = min(max(d, u_lo), u_hi)
        if clamped == d:
            return d, ""
        return clamped, (f"setpoint {d * 1e6:.1f} um clamped to {clamped * 1e6:.1f} um, the end of the usable range "
                         f"[{u_lo * 1e6:.1f}, {u_hi * 1e6:.1f}] um (u^2 headroom "
                         f"{self.config.end_margin_fraction:g} x u_max^2 for the feedback)")

    def request_setpoint(self, t_s: float, target_m: float) -> str:
        """Answer a setpoint at once without planning it here: clamped (the note says so) or refused
        (:class:`UnreachableReferenceError`); :meth:`update` plans it one check per sample, holding the
        current reference meanwhile, and the move starts at t_s + lead + :attr:`plan_checks` periods.
        The outcome is left in :attr:`plan_note`. A newer request replaces a pending one.
        """
        self._require_started()
        target, note = self.clamp_setpoint(target_m)
        self._begin_plan(t_s + self.config.lead_s + self.plan_checks * self.config.sample_period_s, target)
        return f"planning a move to {target * 1e6:.1f} um" + (f" ({note})" if note else "")

    def _begin_plan(self, start_s: float, target_m: float, retry: bool = True) -> None:
        state = self.reference_at(start_s)
        eps = self._strain_ahead(start_s)
        steps = plan_move_steps(self.inverse, start_s, state, target_m, self.max_voltage_V,
                                self.reference_slew_V_per_s, self.config.min_move_time_s, eps1=eps)
        self.plan = _Plan(target_m, start_s, eps, steps, retry=retry and abs(state[1]) > 0.0)

    def _step_plan(self) -> None:
        """One check of the pending plan (at most one per sample)."""
        plan = self.plan
        try:
            next(plan.steps)
            return
        except StopIteration as done:
            move, feas = done.value
            self.plan = None
            self._set_trajectory(move, plan.start_s, plan.eps1)
            self.plan_note = (True, f"move to {plan.target_m * 1e6:.1f} um in {move.duration_s * 1e3:.1f} ms"
                              + (f" ({feas.message})" if feas.message != "ok" else ""))
        except UnreachableReferenceError as exc:
            self.plan = None
            traj = self.state.trajectory
            if plan.retry and isinstance(traj, QuinticMove) and traj.end_s > plan.start_s:
                # from a moving reference every quintic may overshoot the range: plan again from the end
                # of the running move (at rest there), the same bounded number of checks
                self._begin_plan(traj.end_s, plan.target_m, retry=False)
                return
            self.plan_note = (False, str(exc))

    def take_plan_note(self) -> tuple[bool, str] | None:
        """The outcome of the last finished plan, once."""
        note, self.plan_note = self.plan_note, None
        return note

    def _strain_ahead(self, t_s: float) -> float:
        """eps1 of the current reference at a time t that may lie ahead of the integrator (not advancing it)."""
        st = self.state
        if t_s <= st.t_ff:
            return self._strain_at(t_s)
        n = int(math.ceil((t_s - st.t_ff) / 5e-3)) + 1      # steps of at most 5 ms, as _advance_strain
        times = np.linspace(st.t_ff, t_s, max(n, 2))
        ahead = copy.copy(self.strain)
        return float(ahead.run(st.trajectory.sample_many(times)[0], float(times[1] - times[0]))[-1])

    def set_setpoint(self, t_s: float, target_m: float) -> str:
        """Shape a move from the current reference to ``target_m`` (planned here, a bounded number of
        checks), starting ``lead_s`` after t_s; returns a description. Clamped at the ends as
        :meth:`clamp_setpoint`.

        Why the move starts a lead later: the command computed at t_s acts only after the loop delay,
        so the feedforward of a move starting at t_s would skip its first ``lead_s`` (the mass lags
        the reference, the feedback corrects it with a ringing of the lightly damped mode: with a 2.25
        ms lead, noise-free 40 um steps settled in 35-42 ms with 2-4 % overshoot instead of 25-28 ms
        with 0.2 %); :meth:`request_setpoint` starts its moves after the lead as well.
        Raises :class:`UnreachableReferenceError` (the reference is unchanged) for a target outside
        the reachable range.
        """
        self._require_started()
        target_m, note = self.clamp_setpoint(target_m)
        self.plan = None
        start = t_s + self.config.lead_s
        state = self.reference_at(start)
        eps = self._strain_ahead(start)
        move, feas = plan_move(self.inverse, start, state, target_m, self.max_voltage_V,
                               self.reference_slew_V_per_s, self.config.min_move_time_s, eps1=eps)
        self._set_trajectory(move, start, eps)
        return (f"move to {target_m * 1e6:.1f} um in {move.duration_s * 1e3:.1f} ms"
                + (f" ({feas.message})" if feas.message != "ok" else "") + (f"; {note}" if note else ""))

    def set_trajectory(self, t_s: float, trajectory: Trajectory) -> str:
        """Follow ``trajectory`` (absolute times) from now on; refused with the reason when infeasible.

        The trajectory should continue the current reference (start at or before t_s at the
        current reference position, as :func:`trajectory_from_points` builds it): the reference
        jumps to ``trajectory.sample(t_s)`` otherwise. Raises :class:`UnreachableReferenceError`
        (the reference is unchanged) when the actuator cannot follow it.
        """
        self._require_started()
        eps = self._strain_at(t_s)
        feas = check_trajectory(trajectory, self.inverse, self.max_voltage_V, self.reference_slew_V_per_s,
                                t_from_s=t_s, eps1=eps)
        if not feas.ok:
            raise UnreachableReferenceError(feas.message)
        self.plan = None
        self._set_trajectory(trajectory, t_s, eps)
        return (f"trajectory of {trajectory.end_s - trajectory.start_s:.3f} s accepted (peak feedforward "
                f"{float(feas.voltage_V.max()):.0f} V, slew {feas.worst_slew_V_per_s:.3g} V/s)")

    def _set_trajectory(self, trajectory: Trajectory, t_s: float, eps1: float) -> None:
        st = self.state
        st.trajectory = trajectory
        self.strain.reset(trajectory.sample(t_s)[0], eps1)
        st.t_ff = t_s

    def _strain_at(self, t_s: float) -> float:
        """eps1 of the reference at t (advancing the integrator if t is ahead of it)."""
        st = self.state
        if t_s > st.t_ff:
            self._advance_strain(t_s)
        return self.strain.eps1

    def _advance_strain(self, t_s: float) -> None:
        st = self.state
        # sub-steps of at most 5 ms keep the piecewise-linear forcing accurate through moves
        while st.t_ff < t_s:
            h = min(t_s - st.t_ff, 5e-3)
            st.t_ff += h
            self.strain.step(st.trajectory.sample(st.t_ff)[0], h)

    def _require_started(self) -> None:
        if self.state is None:
            raise RuntimeError("PositionController: call start() with the first measurement first")

    # ----------------------------------------------------------------- loop
    def update(self, t_s: float, measured_m: float) -> ControlOutput:
        """One control step for a measurement acquired at t_s; returns the voltage to command."""
        self._require_started()
        cfg = self.config
        st = self.state
        dt = cfg.sample_period_s if st.last_t is None else max(t_s - st.last_t, 0.0)
        st.last_t = t_s
        if self.plan is not None:
            self._step_plan()
        d_ref = st.trajectory.sample(t_s)[0]
        # 1. feedforward at the time the command will act
        t_ff = t_s + cfg.lead_s
        self._advance_strain(t_ff)
        d, v, a = st.trajectory.sample(t_ff)
        u2_ff = self.inverse.dynamic_u2(d, v, a, self.strain.eps1) if cfg.feedforward \
            else self.inverse.static_u2(d)
        # 2. feedback on u^2
        error = d_ref - float(measured_m)
        u2_fb = 0.0
        if cfg.feedback:
            u2_fb = self.pid.update(error, dt) / float(self.inverse.input_gain(d_ref))
        # 3. limits
        u2 = u2_ff + u2_fb
        sat = 0
        umax2 = self.max_voltage_V ** 2
        if u2 < 0.0:
            u2, sat = 0.0, -1
        elif u2 > umax2:
            u2, sat = umax2, 1
        u = math.sqrt(u2)
        step = cfg.slew_rate_V_per_s * (dt if dt > 0 else cfg.sample_period_s)
        slew_limited = False
        if u > st.last_u + step:
            u, sat, slew_limited = st.last_u + step, 1, True
        elif u < st.last_u - step:
            u, sat, slew_limited = max(st.last_u - step, 0.0), -1, True
        self.pid.saturated(sat)
        st.last_u = u
        return ControlOutput(u, d_ref, error, u2_ff, u2_fb, sat, slew_limited)
