"""Issue 20: position_controller_node at the edges, in-process with a fake clock (its callbacks called as the
executor would): range-end setpoints answered at once without planning in the callback, NaN / out-of-range
samples skipped, no (re)start on an implausible reading, the setpoint surviving a laser dropout."""
import math

import pytest
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

import dea_ros.control.reference as reference
from dea_ros.nodes.common import make_range
from dea_ros.nodes.position_controller_node import PositionControllerNode


class Clock:
    t = 100.0


@pytest.fixture
def node(ros_context, monkeypatch):
    n = PositionControllerNode(context=ros_context, parameter_overrides=[
        Parameter("params_file", value="A2"), Parameter("sensor_timeout_s", value=0.05)])
    clock = Clock()
    monkeypatch.setattr(n, "now_s", lambda: clock.t)
    assert n.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert n.trigger_activate() == TransitionCallbackReturn.SUCCESS
    n.clock = clock
    yield n
    n.destroy_node()


@pytest.fixture
def checks(monkeypatch):
    calls = []
    real = reference.check_trajectory
    monkeypatch.setattr(reference, "check_trajectory", lambda *a, **k: calls.append(1) or real(*a, **k))
    return calls


def sample(node, d, dt=1e-3):
    node.clock.t += dt
    node.on_displacement(make_range(d, node.clock.t, "dea_laser"))


def test_edges(node, checks):
    lo, hi = node.ctl.reachable_range_m
    u_lo, u_hi = node.ctl.usable_range_m
    # implausible and flagged readings: no start, counted
    for bad in (-542e-6, 2207e-6):
        sample(node, bad)
    sample(node, math.nan)
    node.clock.t += 1e-3
    node.on_displacement(make_range(0.004, node.clock.t, "dea_laser", -0.003, 0.003))   # outside max_range
    assert not node.ctl.started and node.commands == 0
    assert node.implausible_starts == 2 and node.stream.invalid == 2
    mid = 0.5 * (lo + hi)
    sample(node, mid)
    assert node.ctl.started and node.commands == 1
    # a range-end setpoint: answered at once (clamped), no planner check in the callback
    checks.clear()
    node.on_setpoint(Float64(data=lo))
    assert checks == [] and "clamped" in node.last_accept and node.ctl.plan is not None
    node.on_setpoint(Float64(data=hi + 1e-3))                           # far beyond: refused at once
    assert checks == [] and node.refused == 1 and "reachable range" in node.last_refusal
    # the samples plan it, at most one check each; a NaN sample in between changes nothing
    n = 0
    while node.ctl.plan is not None:
        before = len(checks)
        sample(node, mid if n != 3 else math.nan)
        assert len(checks) - before <= 1
        n += 1
    assert n <= node.ctl.plan_checks + 1
    assert node.ctl.state.trajectory.final_m == pytest.approx(u_lo)
    # a new setpoint, then the laser drops out while it is being planned: it survives the dropout
    node.on_setpoint(Float64(data=hi))
    sample(node, mid)
    node.clock.t += 0.2
    node.check_sensor()
    assert not node.ctl.started and node.sensor_losses == 1
    assert node.resume_target == pytest.approx(u_hi)
    sample(node, 5e-3)                                                # implausible: no restart
    assert not node.ctl.started
    sample(node, mid)
    assert node.ctl.started and node.ctl.goal_m(node.clock.t) == pytest.approx(u_hi)
    for _ in range(node.ctl.plan_checks + 2):
        sample(node, mid)
    assert node.ctl.plan is None and node.ctl.state.trajectory.final_m == pytest.approx(u_hi)
    assert node.commands > 0 and math.isfinite(node.last_output.voltage_V)
