"""Membrane health: findings in words with WARN/ERROR levels, persistence, the reachable range; and drift
detection on the simulated rig (a 3 % change reported, the unchanged plant quiet)."""
import math

import pytest

from dea_ros.control import (
    ControllerConfig,
    HealthMonitor,
    HealthThresholds,
    ModelTracker,
    PositionController,
    PredictionErrorStats,
    SimulatedRig,
    describe_drift,
    describe_payload,
    moving_mass_ratio,
    run_closed_loop,
)
from dea_ros.control.health import ERROR, OK, WARN

U_MAX = 3150.0


def test_the_words_say_what_changed_and_why():
    assert describe_drift("electrostatic_gain", 0.94) == \
        "electrostatic gain 6 % below the identified model: electrode ageing or a thickness change"
    assert describe_drift("static_stiffness", 1.05).startswith("static stiffness 5 % above the identified model")
    assert "lighter payload" in describe_drift("static_stiffness", 1.05)
    assert describe_drift("creep_time", 0.3).startswith("creep time eta1/k1 70 % shorter than identified")


def test_levels_persistence_and_thresholds():
    mon = HealthMonitor(HealthThresholds(persistence_s=3.0))
    same = {"electrostatic_gain": 1.0, "static_stiffness": 1.0, "viscoelastic_stiffness": 1.0, "creep_time": 1.0}
    assert mon.assess(0.0, same).level == OK
    low = dict(same, electrostatic_gain=0.96)
    assert mon.assess(1.0, low).level == OK                      # not yet persistent
    rep = mon.assess(4.5, low)
    assert rep.level == WARN and rep.message.startswith("electrostatic gain 4 % below")
    assert mon.assess(5.0, dict(low, electrostatic_gain=0.85)).level == ERROR
    assert mon.assess(6.0, same).level == OK                     # back: the persistence restarts
    assert mon.assess(7.0, low).level == OK
    # configurable: scaled thresholds
    loose = HealthMonitor(HealthThresholds.scaled(warn_scale=2.5, persistence_s=0.0))
    assert loose.assess(0.0, low).level == OK
    assert loose.assess(0.0, dict(same, electrostatic_gain=0.94)).level == WARN
    values = loose.assess(0.0, dict(same, electrostatic_gain=0.94)).values
    assert ("tracked_electrostatic_gain_ratio", "0.9400") in values


def test_prediction_errors_and_the_reachable_range():
    stats = PredictionErrorStats()
    for k in range(100):
        stats.add(1e-3 + 8e-6 * (1 if k % 2 else -1) + 2e-6, 1e-3)
    stats.add(math.nan, 1e-3)
    assert stats.n == 100 and stats.mean_m == pytest.approx(2e-6) and stats.max_abs == pytest.approx(10e-6)
    mon = HealthMonitor(HealthThresholds(persistence_s=0.0))
    rep = mon.assess(0.0, None, stats)
    assert rep.level == WARN and "prediction error 8.2 um RMS" in rep.message
    rep = mon.assess(0.0, None, None, reference_m=800e-6, reachable_m=(700e-6, 790e-6))
    assert rep.level == ERROR
    assert rep.message == ("reference 800.0 um is outside the reachable range [700.0, 790.0] um of the membrane "
                           "as it is now")


def _first_warning(ident, plant, seconds, seed):
    """Ordinary operation on the simulated rig; the first time (s) health reports WARN or worse, or None."""
    ctl = PositionController(ident, ControllerConfig(max_voltage_V=U_MAX, slew_rate_V_per_s=1e5))
    tracker = ModelTracker(ident)
    mon = HealthMonitor()
    lo, hi = ctl.reachable_range_m
    targets = [lo + f * (hi - lo) for f in (0.3, 0.55, 0.75, 0.45)]
    found = []

    def loop(t, d):
        if not ctl.started:
            ctl.start(t, d)
        k = int(round(t * 1000))
        if k % 1500 == 0:
            ctl.set_setpoint(t, targets[(k // 1500) % len(targets)])
        out = ctl.update(t, d)
        tracker.update(d, out.voltage_V, out.saturated != 0)
        if k % 1000 == 0 and not found:
            rep = mon.assess(t, tracker.ratios)
            if rep.level >= WARN:
                found.append((t, rep.message))
        return out.voltage_V

    run_closed_loop(SimulatedRig(plant, U_MAX, noise_m=1e-6, seed=seed), loop, seconds,
                    initial_voltage_V=ctl.inverse.static_voltage(targets[0]))
    return found[0] if found else None


@pytest.mark.parametrize("what", ["eps_r", "stiffness"])
def test_a_3_percent_change_is_reported_within_30_s(rig_truth, what):
    p = rig_truth
    plant = p.replace(relative_permittivity=p.relative_permittivity * 0.97) if what == "eps_r" else \
        p.replace(beta_Pa=tuple(b * 0.97 for b in p.beta_Pa), gamma_Pa=tuple(g * 0.97 for g in p.gamma_Pa))
    found = _first_warning(p, plant, 30.0, seed=21)
    assert found is not None
    assert ("electrostatic gain" if what == "eps_r" else "static stiffness") in found[1] and "below" in found[1]


def test_the_unchanged_plant_raises_no_alarm(rig_truth):
    assert _first_warning(rig_truth, rig_truth, 120.0, seed=22) is None


def test_a_common_change_of_gain_and_stiffness_is_one_payload_finding():
    ratios = {"electrostatic_gain": 0.905, "static_stiffness": 0.912, "viscoelastic_stiffness": 0.97,
              "creep_time": 1.05}
    assert moving_mass_ratio(ratios) == pytest.approx(2.0 / 1.817)
    mon = HealthMonitor()
    reports = [mon.assess(float(t), ratios) for t in range(5)]
    assert reports[0].level == 0 and reports[-1].level == 1
    assert reports[-1].message.startswith(describe_payload(moving_mass_ratio(ratios)) + "; electrostatic gain 9 %")
    assert reports[-1].message.startswith("moving mass 10 % above the identified model: payload changed")
    assert "static stiffness 9 % below" in reports[-1].message      # the alternative stays in the report
    assert ("tracked_moving_mass_ratio", f"{moving_mass_ratio(ratios):.4f}") in reports[-1].values
    # ERROR when the pair is beyond the ERROR threshold; a lighter payload reads "below"
    mon = HealthMonitor()
    light = dict(ratios, electrostatic_gain=1.12, static_stiffness=1.115)
    last = [mon.assess(float(t), light) for t in range(5)][-1]
    assert last.level == 2 and last.message.startswith("moving mass 11 % below")


@pytest.mark.parametrize("gain, static", [(0.94, 1.0), (0.94, 1.04), (0.94, 0.965), (1.0, 0.96)])
def test_separate_changes_are_not_called_a_payload(gain, static):
    """Only the gain, opposite directions, or the two apart by more than payload_agreement: separate findings."""
    mon = HealthMonitor()
    ratios = {"electrostatic_gain": gain, "static_stiffness": static, "viscoelastic_stiffness": 1.0,
              "creep_time": 1.0}
    last = [mon.assess(float(t), ratios) for t in range(5)][-1]
    assert last.level >= 1 and "moving mass" not in last.message, last.message
