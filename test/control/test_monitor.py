"""What the control loop watches (no ROS): sample stream counts and velocity, the tracking window, the
settings for a membrane and trajectories through a JointTrajectory's points."""
import math

import pytest

from dea_ros.control import (
    ControllerConfig,
    ControlOutput,
    SampleStream,
    TrackingWindow,
    trajectory_from_points,
)
from dea_ros.errors import SafetyConfigError
from dea_ros.model import preset


def test_samples_are_counted_invalid_stale_or_skipped():
    stream = SampleStream(1e-3)
    assert stream.accept(1.000, 5e-4)
    assert not stream.accept(1.0005, math.nan) and stream.invalid == 1
    assert not stream.accept(1.000, 6e-4) and stream.stale == 1   # not newer
    assert stream.accept(1.001, 5e-4)
    assert stream.accept(1.004, 5e-4)                              # 1.002 and 1.003 never arrived
    assert (stream.samples, stream.skipped, stream.last_t_s, stream.last_m) == (3, 2, 1.004, 5e-4)


def test_the_velocity_is_a_5_ms_first_order_filter_of_the_difference_quotient():
    stream = SampleStream(1e-3)
    t, v = 0.0, 1e-3  # a constant velocity of 1 mm/s
    for k in range(200):
        stream.accept(t + k * 1e-3, v * k * 1e-3)
    assert stream.velocity_m_per_s == pytest.approx(v, rel=1e-9)
    one = SampleStream(1e-3)
    one.accept(0.0, 0.0)
    one.accept(1e-3, 1e-6)
    assert one.velocity_m_per_s == pytest.approx(1e-3 / 6e-3 * 1e-3)   # a = dt / (dt + 5 ms)
    one.accept(0.2, 5e-6)                                              # after a gap of 0.1 s or more: held
    assert one.velocity_m_per_s == pytest.approx(1e-3 / 6e-3 * 1e-3)


def test_the_tracking_window():
    window = TrackingWindow()
    assert math.isnan(window.rms_m)
    for error, sat in ((3e-6, 0), (-4e-6, 1), (0.0, -1)):
        window.add(ControlOutput(100.0, 0.0, error, 0.0, 0.0, sat))
    assert window.rms_m == pytest.approx(math.sqrt(25e-12 / 3)) and window.max_abs_m == 4e-6
    window.clear()
    assert window.n == 0 and window.max_abs_m == 0.0 and window.saturations == 2


def test_the_voltage_ceiling_for_a_membrane():
    a2 = preset("A2")
    limit = 0.9 * a2.breakdown_field_V_per_m * a2.thickness_m
    assert ControllerConfig.for_membrane(a2, 0.9, slew_rate_V_per_s=1e5).max_voltage_V == pytest.approx(limit)
    cfg = ControllerConfig.for_membrane(a2, 0.9, max_voltage_V=2000.0, slew_rate_V_per_s=1e5, feedback=False)
    assert (cfg.max_voltage_V, cfg.feedback) == (2000.0, False)
    with pytest.raises(SafetyConfigError, match="parameter 'max_voltage_V'.*exceeds the membrane limit"):
        ControllerConfig.for_membrane(a2, 0.9, max_voltage_V=limit + 1.0, slew_rate_V_per_s=1e5)


def test_a_trajectory_through_points_continues_the_reference():
    now, state = 10.0, (5e-4, 1e-3, 0.0)
    points = [(9.9, 4e-4, None, None), (10.00005, 4e-4, None, None), (10.1, 6e-4, 0.0, None), (10.3, 7e-4, None, 0.0)]
    traj = trajectory_from_points(now, state, points)
    assert list(traj.times) == [10.0, 10.1, 10.3]                   # points now or in the past are left out
    assert traj.sample(now) == pytest.approx(state)
    assert traj.sample(10.3) == pytest.approx((7e-4, 0.0, 0.0))     # the last velocity defaults to rest
    with pytest.raises(ValueError, match="every point is in the past"):
        trajectory_from_points(now, state, points[:2])
