"""StreamedReference: ros2_control's joint command stream as the controller's reference, on a simulated rig
whose membrane is not the controller's model."""
import math

import numpy as np
import pytest

from dea_ros.control import (
    ControllerConfig,
    PositionController,
    SimulatedRig,
    StreamedReference,
    UnreachableReferenceError,
    run_closed_loop,
)
from dea_ros.model import preset

U_MAX = 3150.0


def _controller():
    return PositionController(preset("A2"), ControllerConfig(max_voltage_V=U_MAX, slew_rate_V_per_s=1e5))


@pytest.mark.parametrize("with_velocity", [True, False])
def test_a_100_hz_stream_of_a_sine_is_tracked_on_the_simulated_rig(rig_truth, with_velocity):
    ctl = _controller()
    stream = StreamedReference()
    lo, hi = ctl.reachable_range_m
    centre, amp, f = lo + 0.5 * (hi - lo), 20e-6, 5.0
    rig = SimulatedRig(rig_truth, U_MAX, noise_m=0.5e-6, seed=3)
    t_stream = 0.3

    def desired(t):
        tau = max(t - t_stream, 0.0)
        return centre + amp * math.sin(2 * math.pi * f * tau), amp * 2 * math.pi * f * math.cos(2 * math.pi * f * tau)

    def loop(t, d):
        if not ctl.started:
            ctl.start(t, d)
            ctl.set_setpoint(t, centre)
        k = int(round(t * 1e3))
        if t >= t_stream and k % 10 == 0:          # the controller manager's 100 Hz
            pos, vel = desired(t)
            stream.command(ctl, t + 1e-3, pos, vel if with_velocity else None)
        return ctl.update(t, d).voltage_V

    res = run_closed_loop(rig, loop, 1.5, initial_voltage_V=ctl.inverse.static_voltage(centre))
    sel = res.time_s > t_stream + 0.4
    err = res.true_m[sel] - np.array([desired(t)[0] for t in res.time_s[sel]])
    rms = float(np.sqrt(np.mean(err ** 2)))
    assert rms < 2.5e-6          # 20 um at 5 Hz through 10 ms samples: the extrapolation keeps it close
    assert stream.followed > 100 and stream.shaped == 0


def test_a_jump_is_shaped_and_an_unreachable_sample_refused():
    ctl = _controller()
    lo, hi = ctl.reachable_range_m
    d0 = lo + 40e-6
    ctl.start(0.0, d0)
    stream = StreamedReference()
    assert stream.command(ctl, 0.01, d0 + 1e-6).kind == "followed"
    jump = stream.command(ctl, 0.02, d0 + 150e-6)
    assert jump.kind == "shaped" and "move to" in jump.text
    before = ctl.reference_at(0.03)
    for bad in (lo - 20e-6, hi + 20e-6, math.nan):
        with pytest.raises(UnreachableReferenceError):
            stream.command(ctl, 0.03, bad)
    assert ctl.reference_at(0.03) == before
    # after the move the held stream is followed again and ends at rest
    for k in range(60):
        stream.command(ctl, 0.5 + 0.01 * k, d0 + 150e-6)
    assert ctl.reference_at(2.0) == pytest.approx((d0 + 150e-6, 0.0, 0.0), abs=1e-12)


def test_a_paused_stream_restarts_from_rest():
    ctl = _controller()
    d0 = ctl.reachable_range_m[0] + 40e-6
    ctl.start(0.0, d0)
    stream = StreamedReference()
    for k in range(10):
        stream.command(ctl, 0.01 * k, d0 + 1e-6 * k, None)
    assert stream.period_s == pytest.approx(0.01)
    stream.command(ctl, 2.0, d0 + 12e-6, None)     # the threshold kept the interface silent for 2 s
    assert math.isnan(stream.period_s)
    d, v, _ = ctl.reference_at(2.5)
    assert d == pytest.approx(d0 + 12e-6) and v == 0.0
