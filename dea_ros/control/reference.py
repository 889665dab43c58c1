"""Smooth references d_r(t) with their derivatives, and the check that the actuator can follow them.

The dynamic feedforward (:meth:`ModelInverse.dynamic_u2`) needs d_r, d_r' and d_r'' (the model
has relative degree 2 from u^2 to d), so every reference here is at least C^2:

* :class:`Hold` -- a constant displacement;
* :class:`QuinticMove` -- point to point from any (d, v, a) to rest at a target in a given time
  (the minimum-jerk polynomial when starting at rest), used to shape setpoint changes;
* :class:`PiecewiseQuintic` -- a trajectory through timed points (trajectory_msgs/JointTrajectory):
  quintic Hermite segments through the given positions, velocities and accelerations; where
  velocities or accelerations are not given, those of the C^2 cubic spline through the positions
  (a positions-only trajectory is that spline between its second and second-to-last points), with
  zero velocity and acceleration at the ends unless given; :func:`trajectory_from_points` builds
  one that continues the current reference;
* :class:`SineReference` -- c + A sin(2 pi f t) faded in over whole periods by a C^2 envelope.

:func:`check_trajectory` integrates the viscoelastic strain along a reference, evaluates the
feedforward u^2 and refuses references that need u^2 < 0 (the membrane would have to push the
mass up), u above the voltage limit, or a voltage slew above the allowed rate, with a message
naming the time and the fix. :func:`plan_move` shapes a setpoint change into the fastest
feasible :class:`QuinticMove` (its duration grows until the check passes).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from .inverse import ModelInverse, StrainIntegrator, UnreachableReferenceError

__all__ = [
    "Trajectory", "Hold", "QuinticMove", "PiecewiseQuintic", "SineReference",
    "Feasibility", "check_trajectory", "plan_move", "plan_move_steps", "plan_checks", "trajectory_from_points",
    "PLAN_MAX_POINTS",
]

#: Points due within this time of now (s) are in the past for :func:`trajectory_from_points`.
PAST_TOLERANCE_S = 1e-4
#: Grid points of one feasibility check in :func:`plan_move` (bounds the planner's cost).
PLAN_MAX_POINTS = 400


class Trajectory:
    """A C^2 reference: ``sample(t) -> (d, v, a)`` (m, m/s, m/s^2) for any time t (s).

    Before ``start_s`` ``sample`` returns the initial state; after ``end_s`` the reference holds
    its final position at rest.
    """

    start_s: float = 0.0
    end_s: float = 0.0

    def sample(self, t_s: float) -> tuple[float, float, float]:  # pragma: no cover - interface
        raise NotImplementedError

    @property
    def check_until_s(self) -> float:
        """End of the span :func:`check_trajectory` evaluates (periodic references: a few periods)."""
        return self.end_s

    @property
    def final_m(self) -> float:
        return self.sample(self.end_s)[0]

    def sample_many(self, t_s) -> np.ndarray:
        """(3, K) array of d, v, a at the times t_s."""
        return np.array([self.sample(float(t)) for t in np.asarray(t_s, float)]).T


@dataclass
class Hold(Trajectory):
    displacement_m: float
    start_s: float = 0.0

    def __post_init__(self):
        self.end_s = self.start_s

    def sample(self, t_s):
        return float(self.displacement_m), 0.0, 0.0


def _quintic_coefficients(p0, v0, a0, p1, v1, a1, T):
    """Coefficients c0..c5 of p(tau) = sum c_i tau^i, tau in [0, T], matching both ends."""
    c0, c1, c2 = p0, v0, 0.5 * a0
    T2, T3 = T * T, T * T * T
    h = p1 - (c0 + c1 * T + c2 * T2)
    hv = v1 - (c1 + 2 * c2 * T)
    ha = a1 - 2 * c2
    c3 = (10 * h - 4 * hv * T + 0.5 * ha * T2) / T3
    c4 = (-15 * h + 7 * hv * T - ha * T2) / (T3 * T)
    c5 = (6 * h - 3 * hv * T + 0.5 * ha * T2) / (T3 * T2)
    return c0, c1, c2, c3, c4, c5


def _eval_quintic(c, tau):
    c0, c1, c2, c3, c4, c5 = c
    p = c0 + tau * (c1 + tau * (c2 + tau * (c3 + tau * (c4 + tau * c5))))
    v = c1 + tau * (2 * c2 + tau * (3 * c3 + tau * (4 * c4 + tau * 5 * c5)))
    a = 2 * c2 + tau * (6 * c3 + tau * (12 * c4 + tau * 20 * c5))
    return p, v, a


class QuinticMove(Trajectory):
    """From (d0, v0, a0) at ``start_s`` to rest at ``target_m`` at ``start_s + duration_s``."""

    def __init__(self, start_s: float, d0_m: float, target_m: float, duration_s: float,
                 v0_m_per_s: float = 0.0, a0_m_per_s2: float = 0.0):
        if not (duration_s > 0.0 and math.isfinite(duration_s)):
            raise ValueError(f"duration_s: must be > 0, got {duration_s}")
        self.start_s = float(start_s)
        self.duration_s = float(duration_s)
        self.end_s = self.start_s + self.duration_s
        self.target_m = float(target_m)
        self.initial = (float(d0_m), float(v0_m_per_s), float(a0_m_per_s2))
        self._c = _quintic_coefficients(d0_m, v0_m_per_s, a0_m_per_s2, target_m, 0.0, 0.0, duration_s)

    def sample(self, t_s):
        tau = t_s - self.start_s
        if tau >= self.duration_s:
            return self.target_m, 0.0, 0.0
        if tau <= 0.0:
            return self.initial
        return _eval_quintic(self._c, tau)

    def sample_many(self, t_s) -> np.ndarray:
        """(3, K) array of d, v, a at the times t_s (vectorised: the planner's cost is bounded by it)."""
        tau = np.clip(np.asarray(t_s, float) - self.start_s, 0.0, self.duration_s)
        out = np.array(_eval_quintic(self._c, tau))
        out[:, tau >= self.duration_s] = np.array([[self.target_m], [0.0], [0.0]])
        out[:, tau <= 0.0] = np.array(self.initial)[:, None]
        return out


class PiecewiseQuintic(Trajectory):
    """Quintic Hermite segments through timed knots (absolute times, s).

    ``velocities`` / ``accelerations`` may be None (or contain None entries): missing values
    come from the C^2 cubic spline through the positions whose end velocities are the given
    (or zero) first and last velocities; missing end accelerations are zero.
    """

    def __init__(self, times_s, positions_m, velocities=None, accelerations=None):
        t = np.asarray(times_s, dtype=float)
        p = np.asarray(positions_m, dtype=float)
        if t.ndim != 1 or t.size < 2 or p.shape != t.shape:
            raise ValueError("a trajectory needs at least 2 points with one time and one position each")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))):
            raise ValueError("trajectory times and positions must be finite")
        if np.any(np.diff(t) <= 0.0):
            k = int(np.argmax(np.diff(t) <= 0.0)) + 1
            raise ValueError(
                f"trajectory point {k}: time_from_start {t[k] - t[0]:.6g} s does not increase; "
                "points must be strictly increasing in time"
            )
        v_given = self._optional(velocities, t.size, "velocities")
        a_given = self._optional(accelerations, t.size, "accelerations")
        v0 = v_given[0] if np.isfinite(v_given[0]) else 0.0
        v1 = v_given[-1] if np.isfinite(v_given[-1]) else 0.0
        spline = CubicSpline(t, p, bc_type=((1, v0), (1, v1)))
        v = np.where(np.isfinite(v_given), v_given, spline(t, 1))
        a = np.where(np.isfinite(a_given), a_given, spline(t, 2))
        # the ends are at rest in acceleration unless given (no jump of u^2 when the hold begins)
        for i in (0, -1):
            if not np.isfinite(a_given[i]):
                a[i] = 0.0
        self.times = t
        self.positions = p
        self.velocities = v
        self.accelerations = a
        self.start_s = float(t[0])
        self.end_s = float(t[-1])
        self._coef = [
            _quintic_coefficients(p[i], v[i], a[i], p[i + 1], v[i + 1], a[i + 1], t[i + 1] - t[i])
            for i in range(t.size - 1)
        ]

    @staticmethod
    def _optional(values, n, name):
        if values is None:
            return np.full(n, np.nan)
        out = np.array([np.nan if x is None else float(x) for x in values], dtype=float)
        if out.size == 0:
            return np.full(n, np.nan)
        if out.size != n:
            raise ValueError(f"trajectory {name}: {out.size} values for {n} points; give one per point or none")
        return out

    def sample(self, t_s):
        t = self.times
        if t_s >= t[-1]:
            return float(self.positions[-1]), 0.0, 0.0
        if t_s <= t[0]:
            return float(self.positions[0]), float(self.velocities[0]), float(self.accelerations[0])
        i = int(np.searchsorted(t, t_s, side="right")) - 1
        return _eval_quintic(self._coef[i], t_s - t[i])

    def sample_many(self, t_s) -> np.ndarray:
        """(3, K) array of d, v, a at the times t_s (vectorised over the segments)."""
        t = self.times
        ts = np.clip(np.asarray(t_s, float), t[0], t[-1])
        i = np.clip(np.searchsorted(t, ts, side="right") - 1, 0, t.size - 2)
        coef = np.array(self._coef)[i].T                      # (6, K): each time's segment
        out = np.array(_eval_quintic(tuple(coef), ts - t[i]))
        out[:, ts >= t[-1]] = np.array([[self.positions[-1]], [0.0], [0.0]])
        return out


def trajectory_from_points(now_s: float, state, points) -> PiecewiseQuintic:
    """A trajectory that continues the current reference through timed points.

    ``state``: (d, v, a) of the current reference at ``now_s`` (m, m/s, m/s^2), the first knot;
    ``points``: (time s, position m, velocity m/s or None, acceleration m/s^2 or None) in time order,
    times absolute (a JointTrajectory's stamp + time_from_start). Points due at or before now (within
    :data:`PAST_TOLERANCE_S`) are left out: the current reference stands for them. The last
    velocity defaults to rest. ValueError when no point is left (or from :class:`PiecewiseQuintic`).
    """
    d0, v0, a0 = state
    times, pos, vel, acc = [now_s], [d0], [v0], [a0]
    for t, position, velocity, acceleration in points:
        if t <= now_s + PAST_TOLERANCE_S:
            continue            # in the past (or now): the current reference stands for it
        times.append(t)
        pos.append(float(position))
        vel.append(None if velocity is None else float(velocity))
        acc.append(None if acceleration is None else float(acceleration))
    if len(times) < 2:
        raise ValueError("every point is in the past (header.stamp + time_from_start <= now)")
    if vel[-1] is None:
        vel[-1] = 0.0
    return PiecewiseQuintic(times, pos, vel, acc)


class SineReference(Trajectory):
    """center + A E(t) sin(2 pi f (t - start)), E a C^2 fade-in over ``fade_periods`` periods."""

    def __init__(self, center_m: float, amplitude_m: float, frequency_Hz: float, start_s: float = 0.0,
                 duration_s: float = math.inf, fade_periods: float = 2.0):
        if not (frequency_Hz > 0.0):
            raise ValueError(f"frequency_Hz: must be > 0, got {frequency_Hz}")
        self.center_m, self.amplitude_m, self.frequency_Hz = float(center_m), float(amplitude_m), float(frequency_Hz)
        self.start_s = float(start_s)
        self.end_s = self.start_s + float(duration_s)
        self.fade_s = max(float(fade_periods), 0.0) / self.frequency_Hz

    @property
    def check_until_s(self) -> float:
        """Fade-in plus 3 periods: afterwards the feedforward repeats (eps1 settles with the creep)."""
        return min(self.end_s, self.start_s + self.fade_s + 3.0 / self.frequency_Hz)

    def _envelope(self, tau):
        if self.fade_s <= 0.0 or tau >= self.fade_s:
            return 1.0, 0.0, 0.0
        x = tau / self.fade_s
        T = self.fade_s
        return (x ** 3 * (10 - 15 * x + 6 * x * x), 30 * x * x * (1 - x) ** 2 / T,
                60 * x * (1 - x) * (1 - 2 * x) / (T * T))

    def sample(self, t_s):
        tau = min(max(t_s - self.start_s, 0.0), self.end_s - self.start_s)
        if t_s <= self.start_s:
            return self.center_m, 0.0, 0.0
        w = 2 * math.pi * self.frequency_Hz
        e, e1, e2 = self._envelope(tau)
        s, c = math.sin(w * tau), math.cos(w * tau)
        A = self.amplitude_m
        d = self.center_m + A * e * s
        if t_s >= self.end_s:
            return d, 0.0, 0.0
        return d, A * (e1 * s + e * w * c), A * (e2 * s + 2 * e1 * w * c - e * w * w * s)


@dataclass(frozen=True)
class Feasibility:
    """Result of :func:`check_trajectory`: ``ok``, a message, and the feedforward along the grid."""

    ok: bool
    message: str
    times_s: np.ndarray
    u2_V2: np.ndarray
    voltage_V: np.ndarray
    worst_slew_V_per_s: float
    eps1_end: float

    def __bool__(self) -> bool:
        return self.ok


def check_trajectory(trajectory: Trajectory, inverse: ModelInverse, max_voltage_V: float,
                     slew_rate_V_per_s: float, t_from_s: float | None = None, eps1: float | None = None,
                     dt_s: float = 1e-3, what: str = "trajectory", max_points: int | None = None) -> Feasibility:
    """Can the actuator follow ``trajectory`` from ``t_from_s`` to its end? (model feedforward).

    Checks every position against the reachable range, then integrates eps1 along the
    reference (from ``eps1``, default relaxed at the first position) and evaluates the
    feedforward u^2 (eq. 5 inverted) on a ``dt_s`` grid: u^2 must stay >= 0 (the membrane can
    only pull the mass down), u <= ``max_voltage_V`` and |du/dt| <= ``slew_rate_V_per_s``.
    ``max_points`` caps the grid (the step grows beyond ``dt_s`` on long spans): the cost of a check is
    then bounded, which suits references smooth over their whole span (a :class:`QuinticMove`).
    Vectorised: eps1 by :meth:`StrainIntegrator.run`, u^2 by :meth:`ModelInverse.dynamic_u2` on arrays.
    """
    t0 = trajectory.start_s if t_from_s is None else float(t_from_s)
    t1 = max(trajectory.check_until_s, t0)
    n = max(int(math.ceil((t1 - t0) / dt_s)), 1) + 1
    if max_points is not None:
        n = min(n, max(int(max_points), 2))
    times = np.linspace(t0, t1, n) if t1 > t0 else np.array([t0, t0 + dt_s])
    ref = trajectory.sample_many(times)
    lo, hi = inverse.reachable_range_m
    bad = np.nonzero((ref[0] < lo - 1e-12) | (ref[0] > hi + 1e-12))[0]
    if bad.size:
        k = int(bad[0])
        try:
            inverse.check_reachable(float(ref[0, k]), f"{what} at t = {times[k] - t0:.4f} s: position")
        except UnreachableReferenceError as exc:
            return Feasibility(False, str(exc), times, np.full(n, np.nan), np.full(n, np.nan), math.nan, math.nan)
    strain = StrainIntegrator(inverse, float(ref[0, 0]), eps1)
    eps = strain.run(ref[0], float(times[1] - times[0]))
    u2 = inverse.dynamic_u2(ref[0], ref[1], ref[2], eps)
    u = np.sqrt(np.maximum(u2, 0.0))
    slew = np.abs(np.diff(u)) / np.diff(times)
    worst = float(slew.max()) if slew.size else 0.0
    tol = 1e-9 * max_voltage_V ** 2
    neg = np.nonzero(u2 < -tol)[0]
    high = np.nonzero(u > max_voltage_V * (1 + 1e-9))[0]
    fast = np.nonzero(slew > slew_rate_V_per_s)[0]
    first = [(int(x[0]), kind) for x, kind in ((neg, "neg"), (high, "high"), (fast, "slew")) if x.size]
    if not first:
        return Feasibility(True, "ok", times, u2, u, worst, strain.eps1)
    k, kind = min(first)
    at = f"{what} at t = {times[k] - t0:.4f} s"
    if kind == "neg":
        message = (f"{at} needs u^2 = {u2[k]:.4g} V^2 < 0: the mass would have to be pushed up faster than the "
                   f"membrane's restoring force lifts it (acceleration {ref[2, k]:.3g} m/s^2 at "
                   f"{ref[0, k] * 1e6:.1f} um); slow it down (longer time_from_start)")
    elif kind == "high":
        message = (f"{at} needs {u[k]:.0f} V, above the {max_voltage_V:.0f} V limit (acceleration "
                   f"{ref[2, k]:.3g} m/s^2 at {ref[0, k] * 1e6:.1f} um); slow it down (longer time_from_start)")
    else:
        message = (f"{at} needs a voltage slew of {slew[k]:.4g} V/s, above the {slew_rate_V_per_s:.4g} V/s "
                   f"allowed; slow it down (longer time_from_start)")
    return Feasibility(False, message, times, u2, u, worst, strain.eps1)


def plan_move(inverse: ModelInverse, start_s: float, state, target_m: float, max_voltage_V: float,
              slew_rate_V_per_s: float, min_duration_s: float, eps1: float | None = None,
              growth: float = 1.02, max_duration_s: float = 30.0,
              max_points: int = PLAN_MAX_POINTS) -> tuple[QuinticMove, Feasibility]:
    """The fastest feasible :class:`QuinticMove` to ``target_m`` no shorter than ``min_duration_s``.

    ``state`` is the reference (d, v, a) at ``start_s``. Runs :func:`plan_move_steps` to the end (its
    bounded number of checks); raises :class:`UnreachableReferenceError` for a target outside the
    reachable range or when no duration up to ``max_duration_s`` is feasible.
    """
    steps = plan_move_steps(inverse, start_s, state, target_m, max_voltage_V, slew_rate_V_per_s, min_duration_s,
                            eps1, growth, max_duration_s, max_points)
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def plan_move_steps(inverse: ModelInverse, start_s: float, state, target_m: float, max_voltage_V: float,
                    slew_rate_V_per_s: float, min_duration_s: float, eps1: float | None = None,
                    growth: float = 1.02, max_duration_s: float = 30.0, max_points: int = PLAN_MAX_POINTS):
    """:func:`plan_move` one feasibility check at a time: a generator that yields after each check
    and returns ``(move, feasibility)`` (``StopIteration.value``) or raises UnreachableReferenceError.

    Bounded cost (issue 20): the duration doubles from ``min_duration_s`` until a check passes
    (none up to ``max_duration_s``: refused), then is bisected on a log scale between the last
    failing and the first passing duration until they are within a factor ``growth`` -- at most
    :func:`plan_checks` checks (18 for the defaults), each on at most ``max_points`` grid points (a
    quintic is smooth over its span). Doubling, rather than trying the longest duration first,
    keeps a move that starts in motion from overshooting the range on a needlessly slow quintic.
    The control loop runs one check per sample, so no sample waits for a whole plan.
    """
    inverse.check_reachable(target_m, "setpoint")
    d0, v0, a0 = (float(x) for x in state)
    if not growth > 1.0:
        raise ValueError(f"growth: must be > 1, got {growth!r}")

    def check(duration):
        move = QuinticMove(start_s, d0, target_m, duration, v0, a0)
        return move, check_trajectory(move, inverse, max_voltage_V, slew_rate_V_per_s, eps1=eps1, what="move",
                                      max_points=max_points)

    duration = max(float(min_duration_s), 1e-3)
    longest = max(float(max_duration_s), duration)
    move, feas = check(duration)
    if feas.ok:
        return move, feas
    failed, why = duration, feas
    while True:
        yield
        duration = min(2.0 * failed, longest)
        move, feas = check(duration)
        if feas.ok:
            break
        if duration >= longest:
            raise UnreachableReferenceError(
                f"setpoint {target_m * 1e6:.1f} um: no move up to {max_duration_s:g} s is feasible "
                f"({feas.message}); reachable range [{inverse.d_min_m * 1e6:.1f}, {inverse.d_max_m * 1e6:.1f}] um")
        failed, why = duration, feas
    while duration > failed * growth:
        yield
        mid = math.sqrt(failed * duration)
        m_move, m_feas = check(mid)
        if m_feas.ok:
            duration, move, feas = mid, m_move, m_feas
        else:
            failed, why = mid, m_feas
    return move, dataclasses.replace(feas, message=f"lengthened: {failed * 1e3:.1f} ms fails: {why.message}")


def plan_checks(min_duration_s: float, growth: float = 1.02, max_duration_s: float = 30.0) -> int:
    """The largest number of feasibility checks :func:`plan_move_steps` makes."""
    short = max(float(min_duration_s), 1e-3)
    doublings = int(math.ceil(math.log2(max(float(max_duration_s), short) / short)))
    return 1 + doublings + int(math.ceil(math.log2(math.log(2.0) / math.log(growth))))
