"""The controller: gains from the model by the stated rule, and the closed loop on a simulated rig whose
parameters differ from the controller's model (noise, quantisation, the amplifier's safety core)."""
import math

import numpy as np
import pytest

from dea_ros.control import (
    ControllerConfig,
    ModelInverse,
    PIDOnU2,
    PositionController,
    SimulatedRig,
    SineReference,
    UnreachableReferenceError,
    design_gains,
    loop_margins,
    run_closed_loop,
)
from dea_ros.model import preset, static_equilibrium

U_MAX = 3150.0


@pytest.mark.parametrize("name", ["unlike", "rig"])
def test_gains_follow_the_pole_placement_rule(name, unlike, rig_truth):
    p = unlike if name == "unlike" else rig_truth
    inv = ModelInverse(p, 0.9 * p.breakdown_voltage_V())
    d_op = sum(inv.reachable_range_m) / 2
    g = design_gains(inv, d_op, loop_delay_s=1e-3)
    k, c, _ = inv.linearisation(d_op)
    # closed loop of the model linearised with eps1 frozen: s^3 + (c + kd) s^2 + (k + kp) s + ki
    poles = np.sort_complex(np.roots([1.0, c + g.kd_per_s, k + g.kp_per_s2, g.ki_per_s3]))
    w = math.sqrt(k)
    z = g.damping_ratio
    placed = np.sort_complex(np.array([-g.integrator_pole_rad_per_s, complex(-z * w, w * math.sqrt(1 - z * z)),
                                       complex(-z * w, -w * math.sqrt(1 - z * z))]))
    np.testing.assert_allclose(poles, placed, rtol=1e-9)
    assert 0.05 < z <= 1.0
    m = loop_margins(inv, d_op, g.kp_per_s2, g.ki_per_s3, g.kd_per_s, g.derivative_filter_s, 1e-3)
    assert m["stable"] and m["max_sensitivity"] <= 1.6 + 1e-9 and m["phase_margin_deg"] > 30.0
    assert g.noise_gain <= 0.2 + 1e-9
    # a longer loop delay leaves less room: less damping, and a clear refusal when nothing fits
    # (at max_noise_gain 0.2 the largest design delay admitted is 1.7 ms on the rig, 1.9 ms on unlike; 0.25: 2.0 / 2.3)
    g2 = design_gains(inv, d_op, loop_delay_s=1.5e-3)
    assert g2.damping_ratio < z
    with pytest.raises(ValueError, match="loop_delay_s"):
        design_gains(inv, d_op, loop_delay_s=0.01)


def test_anti_windup_freezes_the_integrator_while_saturated(rig_truth):
    inv = ModelInverse(rig_truth, U_MAX)
    pid = PIDOnU2(design_gains(inv, sum(inv.reachable_range_m) / 2, 1e-3))
    pid.update(1e-6, 1e-3)
    pid.update(1e-6, 1e-3)
    i0 = pid.integral
    pid.saturated(+1)                       # command cut at its upper bound
    pid.update(1e-6, 1e-3)                  # the error pushes further up: no integration
    assert pid.integral == i0
    pid.update(-1e-6, 1e-3)                 # pushes back down: integrates
    assert pid.integral < i0
    pid.saturated(-1)
    i1 = pid.integral
    pid.update(-1e-6, 1e-3)
    assert pid.integral == i1


def _run(ctl, rig, reference, duration, d0, seed=0):
    import dataclasses

    rig = dataclasses.replace(rig, seed=seed)
    state = {}

    def controller(t, measured):
        if not state:
            ctl.start(t, d0)
            state["msg"] = reference(ctl, t)
        return ctl.update(t, measured).voltage_V

    u0 = float(ctl.inverse.static_voltage(d0))
    return run_closed_loop(rig, controller, duration, initial_voltage_V=u0), state


def test_feedforward_alone_tracks_the_sampled_rig_on_the_model(rig_truth):
    """Exact model, no noise: zero-order hold, latency and amplifier phase are compensated by the lead."""
    ctl = PositionController(rig_truth, ControllerConfig(U_MAX, 1e5, loop_delay_s=5e-4, feedback=False))
    rig = SimulatedRig(rig_truth, U_MAX, noise_m=0.0, quantisation_m=0.0)
    mid = sum(ctl.reachable_range_m) / 2
    sine = SineReference(mid, 30e-6, 10.0, start_s=0.0, fade_periods=2)
    res, _ = _run(ctl, rig, lambda c, t: c.set_trajectory(t, sine), 0.6, mid)
    ref = sine.sample_many(res.time_s)[0]
    assert np.ptp(res.true_m) > 55e-6
    assert np.max(np.abs(res.true_m - ref)) < 0.05e-6


@pytest.mark.parametrize("seed", [1, 2])
def test_closed_loop_with_model_mismatch_tracks(seed, rig_truth):
    """Controller with the nominal A2 model; the plant is the mock rig's membrane (eps_r -7 %, k1 +15 %,
    eta1 -10 %, eta2 -20 %, other prestress), with 1 um laser noise and the ILD1320 quantisation."""
    model = preset("A2")
    cfg = ControllerConfig(U_MAX, 1e5, loop_delay_s=5e-4)
    rig = SimulatedRig(rig_truth, U_MAX, seed=seed)
    lo = max(ModelInverse(model, U_MAX).reachable_range_m[0], static_equilibrium(rig_truth, 0).displacement_m)
    d0 = lo + 40e-6
    # a 50 um setpoint step, shaped by the controller
    ctl = PositionController(model, cfg)
    res, state = _run(ctl, rig, lambda c, t: c.set_setpoint(t + 0.05, d0 + 50e-6), 0.5, d0, seed)
    assert "move to" in state["msg"]
    e = res.true_m - (d0 + 50e-6)
    late = res.time_s > 0.25
    assert abs(e[late].mean()) < 0.5e-6 and np.sqrt(np.mean(e[late] ** 2)) < 1.0e-6
    assert e.max() < 0.1 * 50e-6                      # overshoot < 10 % with a 7 % wrong permittivity
    # a 30 um sine at 5 Hz
    ctl = PositionController(model, cfg)
    sine = SineReference(d0 + 40e-6, 30e-6, 5.0, start_s=0.0, fade_periods=1)
    res, _ = _run(ctl, rig, lambda c, t: c.set_trajectory(t, sine), 0.8, d0 + 40e-6, seed)
    err = (res.true_m - sine.sample_many(res.time_s)[0])[res.time_s > 0.3]
    assert np.sqrt(np.mean(err ** 2)) < 4e-6
    # without feedback the same mismatch leaves a larger error
    ff = PositionController(model, ControllerConfig(U_MAX, 1e5, loop_delay_s=5e-4, feedback=False))
    res_ff, _ = _run(ff, rig, lambda c, t: c.set_trajectory(t, sine), 0.8, d0 + 40e-6, seed)
    err_ff = (res_ff.true_m - sine.sample_many(res_ff.time_s)[0])[res_ff.time_s > 0.3]
    assert np.sqrt(np.mean(err_ff ** 2)) > 2 * np.sqrt(np.mean(err ** 2))
    assert np.nanmax(res.command_V) <= U_MAX and np.nanmin(res.command_V) >= 0.0


def test_unreachable_setpoint_is_refused_and_the_reference_kept(rig_truth):
    ctl = PositionController(rig_truth, ControllerConfig(U_MAX, 1e5))
    lo, hi = ctl.reachable_range_m
    ctl.start(0.0, lo + 50e-6)
    with pytest.raises(UnreachableReferenceError, match="reachable range"):
        ctl.set_setpoint(0.01, hi + 5e-6)
    assert ctl.reference_at(0.5) == (pytest.approx(lo + 50e-6), 0.0, 0.0)
    with pytest.raises(ValueError, match="slew_rate_V_per_s"):
        ControllerConfig(U_MAX, -1.0)
    with pytest.raises(RuntimeError, match="start"):
        PositionController(rig_truth, ControllerConfig(U_MAX, 1e5)).update(0.0, lo)


@pytest.mark.parametrize("extra_delay_s", [0.0, 1e-3])
def test_a_setpoint_move_starts_when_its_feedforward_acts(rig_truth, extra_delay_s):
    """set_setpoint starts the move lead_s after the request (the command acts only after the loop delay): the
    reference holds until then; on a noise-free rig with the model = the plant and the delay known, a 40 um
    step then overshoots < 1 % (started at once, the skipped feedforward rang the mode: 2-4 % with +1 ms)."""
    # Ms 1.6 x 1.3 for the longer delay, as a retune relaxes it (no design at 1.6)
    cfg = ControllerConfig(U_MAX, 1e5, loop_delay_s=0.75e-3 + extra_delay_s,
                           max_sensitivity=1.6 if extra_delay_s == 0.0 else 2.08)
    ctl = PositionController(rig_truth, cfg)
    lo, hi = ctl.reachable_range_m
    d0 = 0.5 * (lo + hi)
    target = d0 + 40e-6
    rig = SimulatedRig(rig_truth, U_MAX, noise_m=0.0, quantisation_m=0.0, latency_s=0.5e-3 + extra_delay_s,
                       amplifier_phase_s=0.75e-3 + extra_delay_s)

    def loop(t, d):
        if not ctl.started:
            ctl.start(t, d0)
        if abs(t - 0.3) < 1e-9:
            ctl.set_setpoint(t, target)
            assert ctl.reference_at(t + cfg.lead_s - 1e-6) == (d0, 0.0, 0.0)
            assert ctl.reference_at(t + cfg.lead_s + 1e-3)[0] > d0
        return ctl.update(t, d).voltage_V

    res = run_closed_loop(rig, loop, 0.6, initial_voltage_V=ctl.inverse.static_voltage(d0))
    after = res.time_s >= 0.3
    over = (np.max(res.true_m[after]) - target) / 40e-6
    assert over < 0.01, over
    late = res.time_s >= 0.3 + 0.04
    assert np.max(np.abs(res.true_m[late] - target)) < 0.8e-6
