"""model_node's pairing of laser samples with the applied voltage (control/voltage_pairing.py).

By stamps, whatever order the two topics arrive in, the pairing is the amplifier's output in effect at the
sample time (``ClosedLoopResult.applied_V`` of the core's simulated rig, the bag extraction's zero-order
hold), and on those pairs the window fit with ``voltage_delay_samples=0`` reads the drift and an
informative loop delay of about zero, while the controller's ``voltage_delay_samples=1`` (the voltage a
sample late, as model_node first ran it) leaves the delay at the grid's edge and biases k1 (a membrane
unlike the presets with a fast creep, a k1 drift, 1 um laser noise, two seeds)."""
import math

import numpy as np
import pytest

from dea_ros.control import (
    APPLIED_VOLTAGE_DELAY_SAMPLES,
    ControllerConfig,
    ModelTracker,
    PositionController,
    SimulatedRig,
    StampedVoltagePairing,
    TrackerConfig,
    run_closed_loop,
)

U_MAX = 3150.0


def _record(ident, plant, seed, seconds, amplifier_phase_s=5e-4):
    """Ordinary operation (a setpoint every second, the controller on ``ident``): the result and the
    amplifier's stamped outputs [(t s, V)]."""
    ctl = PositionController(ident, ControllerConfig(max_voltage_V=U_MAX, slew_rate_V_per_s=1e5))
    lo, hi = ctl.reachable_range_m
    targets = [lo + f * (hi - lo) for f in (0.3, 0.55, 0.75, 0.45, 0.65, 0.35, 0.6, 0.4, 0.7, 0.5)]
    rig = SimulatedRig(plant, U_MAX, noise_m=1e-6, seed=seed, amplifier_phase_s=amplifier_phase_s)
    outputs = []

    def loop(t, d):
        if not ctl.started:
            ctl.start(t, d)
        k = int(round(t * 1000))
        if k % 1000 == 0:
            ctl.set_setpoint(t, targets[(k // 1000) % len(targets)])
        return ctl.update(t, d).voltage_V

    res = run_closed_loop(rig, loop, seconds, initial_voltage_V=ctl.inverse.static_voltage(targets[0]),
                          applied_hook=lambda t, u: outputs.append((t, u)))
    return res, outputs


@pytest.mark.parametrize("amplifier_phase_s", [0.0, 2.5e-4, 7.5e-4])
def test_pairs_by_stamp_are_the_output_in_effect_at_the_sample(unlike, amplifier_phase_s):
    res, outputs = _record(unlike, unlike, 3, 0.5, amplifier_phase_s)
    stamped = [(int(round(t * 1e9)), u) for t, u in outputs]
    for voltage_lag_ms in (-1, 0, 1, 3):
        _check_pairs(res, stamped, voltage_lag_ms, amplifier_phase_s)


def _check_pairs(res, stamped, voltage_lag_ms, amplifier_phase_s):
    pairing, pairs, i = StampedVoltagePairing(), [], 0
    for t, d in zip(res.time_s, res.measured_m):      # the outputs arrive voltage_lag_ms after the laser's
        t_ns = int(round(t * 1e9))
        while i < len(stamped) and stamped[i][0] <= t_ns + voltage_lag_ms * 1_000_000:
            pairs += pairing.add_voltage(*stamped[i])
            i += 1
        pairs += pairing.add_sample(t_ns, d)
    for v in stamped[i:]:
        pairs += pairing.add_voltage(*v)
    d, u = np.array(pairs).T
    np.testing.assert_array_equal(d, res.measured_m[:len(d)])
    assert len(d) >= len(res.time_s) - 1
    known = np.isfinite(u)            # NaN only before the first stamped output (none at t = 0 with phase 0)
    assert np.count_nonzero(~known) == (0 if amplifier_phase_s == 0.0 else 1)
    np.testing.assert_array_equal(u[known], res.applied_V[:len(u)][known])


def test_stale_stamps_are_ignored_and_a_silent_amplifier_holds():
    pairing = StampedVoltagePairing(max_pending=2)
    assert pairing.add_voltage(1000, 10.0) == []
    assert pairing.add_sample(1000, 1e-3) == [(1e-3, 10.0)]     # an output stamped t holds from t on
    assert pairing.add_voltage(900, 99.0) == [] and pairing.stale_voltages == 1
    assert pairing.add_sample(1000, 2e-3) == [] and pairing.stale_samples == 1
    assert pairing.add_sample(2000, 3e-3) == [] and pairing.add_sample(3000, 4e-3) == []
    assert pairing.add_sample(4000, 5e-3) == [(3e-3, 10.0)]     # more than max_pending wait: the held output
    assert pairing.add_voltage(3000, 20.0) == [(4e-3, 20.0)]    # the voltage at 3000 is known now
    early = StampedVoltagePairing()
    early.add_voltage(1000, 10.0)
    (d, u), = early.add_sample(500, 1e-3)                       # before every buffered output: NaN
    assert d == 1e-3 and math.isnan(u)


def _window_fit(ident, res, voltage_delay_samples):
    tracker = ModelTracker(ident, TrackerConfig(voltage_delay_samples=voltage_delay_samples))
    for d, u in zip(res.measured_m, res.applied_V):
        tracker.update(float(d), float(u))
    return tracker.fit(tracker.window())


@pytest.mark.parametrize("seed", [3, 8])
def test_window_fit_on_the_applied_voltage_at_the_stamp_reads_no_extra_delay(unlike, seed):
    """k1 +25 % (eta2 x0.5); the amplifier updates half a sample after the laser (SimulatedRig's default):
    the voltage at the sample stamp is the membrane's over the sample's interval on average, no delay left."""
    assert APPLIED_VOLTAGE_DELAY_SAMPLES == 0
    plant = unlike.replace(k1_Pa=unlike.k1_Pa * 1.25, eta2_Pa_s=unlike.eta2_Pa_s * 0.5)
    res, _ = _record(unlike, plant, seed, 10.0)
    now = _window_fit(unlike, res, APPLIED_VOLTAGE_DELAY_SAMPLES)
    late = _window_fit(unlike, res, 1)        # the controller's setting: right for its command, not here
    assert now.delay_informative and abs(now.extra_delay_s) < 0.2e-3, now.extra_delay_s
    # (gain, static stiffness, k1, ln creep time): truth 1, 1, 1.25, ln 0.8 (tau = eta1 / k1)
    assert abs(now.x[2] - 1.25) < 0.04 and abs(math.exp(now.x[3]) - 0.8) < 0.05, now.x
    assert abs(now.x[0] - 1.0) < 0.01 and abs(now.x[1] - 1.0) < 0.01, now.x
    assert not late.delay_informative and late.extra_delay_s <= -0.45e-3, late.extra_delay_s
    assert abs(late.x[2] - 1.25) > 0.15 and math.exp(late.x[3]) > 0.88, late.x
