"""Issue 20: the controller at the ends of its range -- answered at once, planned off the callback
(one feasibility check per sample), setpoints that survive a stop, no start on implausible readings.
Timings are measured by bench/bench_range_ends.py, not asserted here."""
import math

import numpy as np
import pytest

import dea_ros.control.reference as reference
from dea_ros.control import (
    ControllerConfig,
    PositionController,
    SampleStream,
    SimulatedRig,
    UnreachableReferenceError,
    plan_move,
    run_closed_loop,
)
from dea_ros.model import config_dir, load_parameters

U_MAX = 0.9 * 100e6 * 35e-6


@pytest.fixture(scope="module")
def a2():
    return load_parameters("A2")


@pytest.fixture
def checks(monkeypatch):
    """Counts the planner's feasibility checks."""
    calls = []
    real = reference.check_trajectory

    def counting(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(reference, "check_trajectory", counting)
    return calls


def make(a2, **kw):
    return PositionController(a2, ControllerConfig(max_voltage_V=U_MAX, slew_rate_V_per_s=1e5, **kw))


def test_range_end_setpoints_are_answered_at_once_and_planned_one_check_per_sample(a2, checks):
    ctl = make(a2)
    lo, hi = ctl.reachable_range_m
    u_lo, u_hi = ctl.usable_range_m
    assert lo < u_lo < u_hi < hi
    for end, usable in ((lo, u_lo), (hi, u_hi), (lo - 1.5e-6, u_lo), (hi + 1.5e-6, u_hi), (lo + 0.5e-6, u_lo)):
        ctl.start(0.0, 0.5 * (lo + hi))
        checks.clear()
        text = ctl.request_setpoint(0.0, end)
        assert checks == [], "the setpoint callback must not plan"
        assert "clamped" in text and f"{usable * 1e6:.1f} um" in text
        assert ctl.goal_m(0.0) == pytest.approx(usable)
        t, n = 0.0, 0
        while ctl.plan is not None:
            before = len(checks)
            ctl.update(t, 0.5 * (lo + hi))
            assert len(checks) - before <= 1, "at most one planner check per sample"
            t += 1e-3
            n += 1
        assert n <= ctl.plan_checks
        ok, note = ctl.take_plan_note()
        assert ok, note
        assert ctl.state.trajectory.final_m == pytest.approx(usable)
        assert ctl.goal_m(t) == pytest.approx(usable)
    for far in (lo - 3e-6, hi + 3e-6, lo - 500e-6, math.nan, math.inf):
        checks.clear()
        with pytest.raises(UnreachableReferenceError, match=r"reachable range \[731.5 um, 1005.7 um\]"):
            ctl.request_setpoint(0.0, far)
        assert checks == []


def test_planning_cost_is_bounded_at_the_ends(a2, checks):
    """The same plans synchronously: never more than plan_checks checks (before: a linear search to 30 s)."""
    ctl = make(a2)
    lo, hi = ctl.reachable_range_m
    for start in (lo + 1e-6, 0.5 * (lo + hi), hi - 1e-6):
        for target in ctl.usable_range_m + (lo + 40e-6, hi - 40e-6):
            checks.clear()
            plan_move(ctl.inverse, 0.0, (start, 0.0, 0.0), target, ctl.max_voltage_V, ctl.reference_slew_V_per_s,
                      ctl.config.min_move_time_s)
            assert 1 <= len(checks) <= ctl.plan_checks
    checks.clear()    # exactly at an end: refused by the planner, still within the bound
    with pytest.raises(UnreachableReferenceError, match="no move up to"):
        plan_move(ctl.inverse, 0.0, (0.5 * (lo + hi), 0.0, 0.0), lo, ctl.max_voltage_V, ctl.reference_slew_V_per_s,
                  ctl.config.min_move_time_s)
    assert len(checks) <= ctl.plan_checks


def test_randomized_stream_with_both_ends_on_the_simulated_rig(a2, checks):
    """2 simulated minutes (the bench runs 10): every setpoint answered at once, every plan finished within
    plan_checks samples with at most one check per sample, no plan refused, the reference in the range."""
    truth = load_parameters(config_dir() / "rig" / "mock_membrane.yaml")
    ctl = make(a2)
    lo, hi = ctl.reachable_range_m
    rng = np.random.default_rng(7)
    times = np.cumsum(rng.uniform(0.3, 2.0, 200)) + 0.2
    times = times[times < 120.0]
    targets = rng.choice([lo, hi, lo - 1e-6, hi + 1e-6, np.nan], size=times.size)
    inside = np.isnan(targets)
    targets[inside] = rng.uniform(lo, hi, inside.sum())
    log = {"k": 0, "refused": [], "max_checks": 0, "plan_samples": 0, "longest_plan": 0, "outside": 0}

    def loop(t, m):
        if not ctl.started:
            ctl.start(t, m)
        while log["k"] < times.size and times[log["k"]] <= t:
            n = len(checks)
            ctl.request_setpoint(t, float(targets[log["k"]]))
            assert len(checks) == n
            log["k"] += 1
            log["plan_samples"] = 0
        n = len(checks)
        planning = ctl.plan is not None
        out = ctl.update(t, m)
        log["max_checks"] = max(log["max_checks"], len(checks) - n)
        if planning:
            log["plan_samples"] += 1
            log["longest_plan"] = max(log["longest_plan"], log["plan_samples"])
        note = ctl.take_plan_note()
        if note is not None and not note[0]:
            log["refused"].append(note[1])
        if not lo - 1e-9 <= out.reference_m <= hi + 1e-9:
            log["outside"] += 1
        return out.voltage_V

    d0 = 0.5 * (lo + hi)
    run_closed_loop(SimulatedRig(truth, U_MAX, seed=3), loop, 120.0,
                    initial_voltage_V=math.sqrt(ctl.inverse.static_u2(d0)))
    assert log["k"] == times.size > 50
    assert log["refused"] == []
    assert log["max_checks"] <= 1
    assert log["longest_plan"] <= 2 * ctl.plan_checks   # a refused plan from a moving reference is retried once
    assert log["outside"] == 0


def test_no_start_on_implausible_readings(a2):
    ctl = make(a2)
    lo, hi = ctl.reachable_range_m
    for bad in (-542e-6, 2207e-6, math.nan, math.inf):
        assert not ctl.plausible_start(bad)
        with pytest.raises(ValueError, match="implausible"):
            ctl.start(0.0, bad)
        assert not ctl.started
    assert ctl.plausible_start(lo - 10e-6) and ctl.plausible_start(hi + 10e-6)


def test_stream_skips_flagged_and_out_of_range_samples():
    s = SampleStream(1e-3)
    assert not s.accept(0.0, math.nan)
    assert not s.accept(0.001, 0.006, -0.005, 0.005)
    assert not s.accept(0.002, -0.0051, -0.005, 0.005)
    assert s.accept(0.003, 0.0008, -0.005, 0.005)
    assert s.invalid == 3 and s.samples == 1
