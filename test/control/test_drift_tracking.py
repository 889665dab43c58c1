"""model_node's tracking path (DriftTracking: the controller's tracker and window fit on measured d and the
APPLIED voltage, without a controller) against the controller's path (AdaptiveModel), on the same samples of
the core's simulated rig: the same drift reported as early, and nothing on the unchanged plant."""
import numpy as np
import pytest

from dea_ros.control import (
    AdaptiveModel,
    ControllerConfig,
    DriftTracking,
    HealthMonitor,
    PositionController,
    SimulatedRig,
    run_closed_loop,
)

U_MAX = 3150.0


def _operate(ident, plant, seconds, seed):
    """The controller (tracking, window fit, retune) in ordinary operation: its first WARN per finding
    (health assessed every second) and the recorded run (measured d, applied voltage)."""
    ctl = PositionController(ident, ControllerConfig(max_voltage_V=U_MAX, slew_rate_V_per_s=1e5))
    ad = AdaptiveModel(ctl)
    mon = HealthMonitor()
    lo, hi = ctl.reachable_range_m
    targets = lo + (0.25 + 0.5 * np.random.default_rng(seed).random(int(seconds / 1.5) + 2)) * (hi - lo)
    first = {}

    def loop(t, d):
        if not ctl.started:
            ctl.start(t, d)
        k = int(round(t * 1000))
        if k % 1500 == 0:
            ctl.set_setpoint(t, float(targets[k // 1500]))
        out = ctl.update(t, d)
        ad.step(t, d, out)
        if k % 1000 == 0:
            for f in mon.assess(t, ad.tracker.ratios).findings:
                first.setdefault(f.key, t)
        return out.voltage_V

    res = run_closed_loop(SimulatedRig(plant, U_MAX, noise_m=1e-6, seed=seed), loop, seconds,
                          initial_voltage_V=ctl.inverse.static_voltage(float(targets[0])))
    return first, res


def _observe(ident, res, fits=True):
    """model_node's path on the recorded samples: the first WARN per finding, the tracking object."""
    tracking = DriftTracking(ident)
    mon = HealthMonitor()
    first = {}
    for j, (t, d, u) in enumerate(zip(res.time_s, res.measured_m, res.applied_V)):
        t = float(t)
        if fits:
            tracking.step(t, float(d), float(u))
        else:
            tracking.observe(t, float(d), float(u))
        if j % 1000 == 0:
            for f in mon.assess(t, tracking.tracker.ratios).findings:
                first.setdefault(f.key, t)
    return first, tracking


def _drift(p, case):
    return {"k1 +25 %": p.replace(k1_Pa=p.k1_Pa * 1.25, eta2_Pa_s=p.eta2_Pa_s * 0.5),
            "eta1 x0.3": p.replace(eta1_Pa_s=p.eta1_Pa_s * 0.3)}[case]


@pytest.mark.parametrize("case,key,base,seed", [("k1 +25 %", "viscoelastic_stiffness", "rig", 3),
                                                ("eta1 x0.3", "creep_time", "unlike", 8)])
def test_model_node_reports_k1_and_creep_drift_as_early_as_the_controller(case, key, base, seed, unlike,
                                                                          rig_truth):
    ident = unlike if base == "unlike" else rig_truth
    ctl_first, res = _operate(ident, _drift(ident, case), 10.0, seed)
    assert key in ctl_first, ctl_first
    first, tracking = _observe(ident, res)
    assert key in first and first[key] <= ctl_first[key] + 1.0, (first, ctl_first)   # one report at most later
    assert tracking.tracker.fits >= 2 and tracking.fits_absorbed >= 3
    assert not set(first) & {"electrostatic_gain", "static_stiffness", "moving_mass"}, first   # no false cause
    if case == "k1 +25 %":               # the EKF alone (model_node before): not within the run
        assert key not in _observe(ident, res, fits=False)[0]


def test_model_node_holds_still_on_the_unchanged_plant(rig_truth):
    _, res = _operate(rig_truth, rig_truth, 12.0, seed=5)
    first, tracking = _observe(rig_truth, res)
    assert not first, first
    assert tracking.fits_absorbed >= 5
    r = tracking.tracker.ratios
    assert abs(r["electrostatic_gain"] - 1) < 0.01 and abs(r["static_stiffness"] - 1) < 0.01, r
