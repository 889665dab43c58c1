"""References and the feedforward: exact tracking on the model, refusal of what the actuator cannot do."""
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from dea_ros.control import (
    ModelInverse,
    PiecewiseQuintic,
    QuinticMove,
    SineReference,
    UnreachableReferenceError,
    check_trajectory,
    plan_move,
)


def _integrate_with_feedforward(p, traj, t_end):
    """The model (eq. 18) driven by the feedforward u^2(t) of ``traj``; eps1 of the feedforward
    integrated alongside (eq. 11) as a 4th state. Returns t, d(t), d_r(t)."""
    inv = ModelInverse(p, 1e4)
    model = inv.model
    r = model.relax_rate

    def rhs(t, y):
        d, e, v, e_ff = y
        dr, vr, ar = traj.sample(t)
        u2 = inv.dynamic_u2(dr, vr, ar, e_ff)
        f = model.rhs_u2(d, e, v, u2)
        return [f[0], f[1], f[2], r * (inv.relaxed_strain(dr) - e_ff)]

    d0, v0, _ = traj.sample(0.0)
    e0 = inv.relaxed_strain(d0)
    t = np.linspace(0.0, t_end, 2001)
    sol = solve_ivp(rhs, (0.0, t_end), [d0, e0, v0, e0], method="DOP853", t_eval=t, rtol=1e-11,
                    atol=[1e-14, 1e-14, 1e-12, 1e-14], max_step=2e-3)
    assert sol.success
    return t, sol.y[0], traj.sample_many(t)[0], inv


@pytest.mark.parametrize("name", ["unlike", "rig"])
def test_feedforward_reproduces_a_trajectory_exactly_on_the_model(name, unlike, rig_truth):
    p = unlike if name == "unlike" else rig_truth
    inv = ModelInverse(p, 1e4)
    lo, hi = inv.reachable_range_m
    span = min(hi - lo, 200e-6)
    # timed points (a robot's JointTrajectory), positions only: the C^2 spline through them
    times = [0.0, 0.12, 0.25, 0.4, 0.6, 0.9]
    pos = lo + span * np.array([0.3, 0.45, 0.8, 0.55, 0.7, 0.5])
    traj = PiecewiseQuintic(times, pos)
    t, d, dr, _ = _integrate_with_feedforward(p, traj, 1.2)
    assert np.ptp(dr) > 0.4 * span
    assert np.max(np.abs(d - dr)) < 2e-9          # m: exact up to the integrator tolerance
    # a sine near the resonance (the lightly damped mode is excited by any error: none appears)
    sine = SineReference(lo + 0.5 * span, 0.3 * span, 9.0, start_s=0.0, fade_periods=1.0)
    t, d, dr, _ = _integrate_with_feedforward(p, sine, 0.8)
    assert np.max(np.abs(d - dr)) < 2e-9


def test_positions_only_trajectory_is_the_cubic_spline_at_rest_at_the_ends_and_c2():
    times = [0.0, 0.1, 0.3, 0.35, 0.6]
    pos = [8e-4, 8.2e-4, 7.9e-4, 8.05e-4, 8e-4]
    traj = PiecewiseQuintic(times, pos)
    spline = CubicSpline(times, pos, bc_type=((1, 0.0), (1, 0.0)))
    ts = np.linspace(0.1, 0.35, 301)      # between the second and the second-to-last point
    got = traj.sample_many(ts)
    np.testing.assert_allclose(got[0], spline(ts), atol=1e-15)
    np.testing.assert_allclose(got[1], spline(ts, 1), atol=1e-12)
    np.testing.assert_allclose(got[2], spline(ts, 2), rtol=1e-9, atol=1e-9)
    assert traj.sample(0.0) == (8e-4, 0.0, 0.0) and traj.sample(0.6 - 1e-12)[2] == pytest.approx(0.0, abs=1e-6)
    # given velocities/accelerations are honoured at the knots
    traj2 = PiecewiseQuintic(times, pos, velocities=[0, 1e-3, None, 0, 0], accelerations=[0, None, 0.1, None, 0])
    assert traj2.sample(0.1)[1] == pytest.approx(1e-3) and traj2.sample(0.3)[2] == pytest.approx(0.1)
    for k in (0.1, 0.3, 0.35):   # continuity of d, v, a across knots
        np.testing.assert_allclose(traj2.sample(k - 1e-9), traj2.sample(k + 1e-9), rtol=1e-5, atol=1e-9)
    with pytest.raises(ValueError, match="strictly increasing"):
        PiecewiseQuintic([0, 0.1, 0.1], [1e-3] * 3)
    with pytest.raises(ValueError, match="velocities"):
        PiecewiseQuintic([0, 0.1], [1e-3] * 2, velocities=[0.0])


def test_quintic_move_meets_its_boundary_conditions():
    mv = QuinticMove(1.0, 8e-4, 8.5e-4, 0.03, v0_m_per_s=2e-3, a0_m_per_s2=-0.5)
    np.testing.assert_allclose(mv.sample(1.0), (8e-4, 2e-3, -0.5), atol=1e-12)
    np.testing.assert_allclose(mv.sample(1.03 - 1e-12), (8.5e-4, 0, 0), atol=1e-8)
    assert mv.sample(2.0) == (8.5e-4, 0.0, 0.0)


def test_unreachable_and_too_fast_references_are_refused(rig_truth):
    inv = ModelInverse(rig_truth, 3150.0)
    lo, hi = inv.reachable_range_m
    # outside the range
    out = PiecewiseQuintic([0, 0.5], [lo + 20e-6, lo - 20e-6])
    f = check_trajectory(out, inv, 3150.0, 1e5)
    assert not f and "reachable range" in f.message and "pull the mass down" in f.message
    # 60 um up in 6 ms: the membrane cannot lift the mass that fast (u^2 < 0)
    fast_up = QuinticMove(0.0, lo + 80e-6, lo + 20e-6, 0.006)
    f = check_trajectory(fast_up, inv, 3150.0, 1e9)
    assert not f and "u^2" in f.message and "< 0" in f.message and "slow it down" in f.message
    # a fast move down needs a voltage above the limit
    fast_down = QuinticMove(0.0, hi - 80e-6, hi - 10e-6, 0.006)
    f = check_trajectory(fast_down, inv, 3150.0, 1e9)
    assert not f and "above the 3150 V limit" in f.message
    # a feasible move in voltage that needs a faster slew than allowed
    mid = QuinticMove(0.0, lo + 80e-6, lo + 130e-6, 0.02)
    assert check_trajectory(mid, inv, 3150.0, 1e9)
    f = check_trajectory(mid, inv, 3150.0, 1e4)
    assert not f and "slew" in f.message
    with pytest.raises(UnreachableReferenceError, match="reachable range"):
        plan_move(inv, 0.0, (lo + 50e-6, 0.0, 0.0), hi + 1e-6, 3150.0, 1e5, 0.02)


def test_plan_move_shapes_the_fastest_feasible_move(rig_truth):
    inv = ModelInverse(rig_truth, 3150.0)
    lo, hi = inv.reachable_range_m
    move, feas = plan_move(inv, 0.0, (lo + 20e-6, 0.0, 0.0), lo + 120e-6, 3150.0, 1e5, 0.005)
    assert feas.ok and move.duration_s > 0.005
    assert feas.worst_slew_V_per_s <= 1e5
    # 5 % shorter is not feasible (the planner stops at the first feasible duration)
    shorter = QuinticMove(0.0, lo + 20e-6, lo + 120e-6, move.duration_s / 1.05)
    assert not check_trajectory(shorter, inv, 3150.0, 1e5)
