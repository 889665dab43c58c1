"""model_node over real rclpy pub/sub: predictions equal the core stepper, services, diagnostics."""
import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import BatteryState, Range
from std_srvs.srv import Trigger

from dea_ros.model import preset, static_equilibrium
from dea_ros.nodes.common import SENSOR_QOS, make_voltage_state, stamp_to_s
from dea_ros.nodes.model_node import ModelNode
from dea_ros.solvers.integrate import RealTimeStepper


def test_predictions_follow_the_core_stepper(ros_context, spin_until):
    node = ModelNode(context=ros_context, parameter_overrides=[
        rclpy_param("params_file", "A2"), rclpy_param("rate_hz", 1000.0)])
    peer = Node("peer", context=ros_context)
    pub = peer.create_publisher(BatteryState, "voltage", SENSOR_QOS)
    got = []
    peer.create_subscription(Range, "displacement_predicted", got.append, SENSOR_QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(peer)
    assert spin_until(ex, lambda: pub.get_subscription_count() >
                      0 and peer.count_publishers("displacement_predicted") > 0)
    # a voltage step stamped in the far future, so the timer path never interferes
    t0 = round(node.now_ns() * 1e-9) + 1.0e6
    voltages = np.where(np.arange(300) < 50, 0.0, 2200.0)

    def n_pred():
        return len([m for m in got if stamp_to_s(m.header.stamp) >= t0])

    for k, u in enumerate(voltages):  # one at a time: best-effort QoS may drop a burst
        pub.publish(make_voltage_state(u, int(t0 * 1e9) + k * 1_000_000, True))
        assert spin_until(ex, lambda: n_pred() >= k + 1, timeout_s=5.0)
    pred = sorted((stamp_to_s(m.header.stamp), m.range) for m in got if stamp_to_s(m.header.stamp) >= t0)
    stepper = RealTimeStepper(preset("A2"), dt_s=1e-3)
    expected = [stepper.displacement_m] + [stepper.step(u) for u in voltages[:-1]]
    d = np.array([r for _, r in pred[:300]])
    # Range.range is float32: agreement to float32 precision of ~1 mm (1e-10 m)
    np.testing.assert_allclose(d, expected, atol=2e-10)
    assert d[-1] > static_equilibrium(preset("A2"), 0.0).displacement_m + 50e-6
    ex.shutdown()
    node.destroy_node()
    peer.destroy_node()


def test_reset_and_reload_services(ros_context, tmp_path, spin_until):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\n")
    node = ModelNode(context=ros_context, parameter_overrides=[rclpy_param("params_file", "LP1")])
    peer = Node("peer2", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(peer)
    reset = peer.create_client(Trigger, "/model_node/reset")
    reload_ = peer.create_client(Trigger, "/model_node/reload")
    assert spin_until(ex, lambda: reset.service_is_ready() and reload_.service_is_ready())
    fut = reset.call_async(Trigger.Request())
    assert spin_until(ex, fut.done)
    assert fut.result().success
    node.set_parameters([rclpy_param("params_file", str(bad))])
    fut = reload_.call_async(Trigger.Request())
    assert spin_until(ex, fut.done)
    assert not fut.result().success and "missing field" in fut.result().message
    assert node.stepper.params.name == "LP1"  # a bad file leaves the running model untouched
    ex.shutdown()
    node.destroy_node()
    peer.destroy_node()


def rclpy_param(name, value):
    from rclpy.parameter import Parameter

    return Parameter(name, value=value)


def test_bad_params_file_stops_with_a_clear_message(ros_context):
    with pytest.raises(SystemExit, match="params_file"):
        ModelNode(context=ros_context, parameter_overrides=[rclpy_param("params_file", "Z9")])


def test_prediction_stamps_never_go_backwards_when_inputs_arrive_late(ros_context, spin_until):
    """Timer extrapolations are stamped now; a voltage message older than one of them (late input)
    updates the model but publishes nothing older: every stamp is later than the one before."""
    node = ModelNode(context=ros_context, parameter_overrides=[
        rclpy_param("params_file", "A2"), rclpy_param("rate_hz", 100.0), rclpy_param("input_timeout_s", 0.03)])
    peer = Node("late_peer", context=ros_context)
    pub = peer.create_publisher(BatteryState, "voltage", SENSOR_QOS)
    got = []
    peer.create_subscription(Range, "displacement_predicted", got.append, SENSOR_QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(peer)
    assert spin_until(ex, lambda: pub.get_subscription_count() > 0
                      and peer.count_publishers("displacement_predicted") > 0)

    def stamp_ns(msg):
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    t_first = node.now_ns()
    pub.publish(make_voltage_state(0.0, t_first, True))
    assert spin_until(ex, lambda: any(stamp_ns(m) == t_first for m in got))
    # no input for a while: the timer extrapolates, stamped with the node's clock
    assert spin_until(ex, lambda: len([m for m in got if stamp_ns(m) > t_first + 30_000_000]) >= 2)
    last_before = max(stamp_ns(m) for m in got)
    before_d = [m.range for m in got if stamp_ns(m) == last_before][0]
    # a 2200 V input stamped before the last extrapolation arrives late
    t_late = last_before - 20_000_000
    pub.publish(make_voltage_state(2200.0, t_late, True))
    assert spin_until(ex, lambda: node.superseded_inputs == 1)
    assert not any(stamp_ns(m) == t_late for m in got)
    assert node.voltage_V == 2200.0  # the model took the input all the same
    # the next predictions (extrapolated from the late input's time) include the step
    assert spin_until(ex, lambda: max(stamp_ns(m) for m in got) > last_before + 30_000_000)
    assert got[-1].range > before_d + 1e-6
    t_now = node.now_ns() + 500_000_000  # ahead of any extrapolation published while it is in flight
    pub.publish(make_voltage_state(2200.0, t_now, True))
    assert spin_until(ex, lambda: any(stamp_ns(m) == t_now for m in got))
    stamps = [stamp_ns(m) for m in got]
    assert len(stamps) >= 5 and all(b > a for a, b in zip(stamps, stamps[1:])), stamps
    ex.shutdown()
    node.destroy_node()
    peer.destroy_node()
