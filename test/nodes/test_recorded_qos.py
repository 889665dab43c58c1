"""identifier_node records the QoS its topics' publishers really offer (one profile per publisher, as
``ros2 bag record``) and writes the rosbag2 format chosen by its ``rosbag2_format`` parameter."""
import importlib.util
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from rclpy.duration import Duration  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import BatteryState, Range  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from dea_ros.bag import BagReader  # noqa: E402
from dea_ros.nodes.common import COMMAND_QOS, SENSOR_QOS, make_range, make_voltage_state  # noqa: E402
from dea_ros.nodes.identifier_node import IdentifierNode  # noqa: E402

_spec = importlib.util.spec_from_file_location(
    "rosbag2_rules", Path(__file__).resolve().parents[1] / "bag" / "rosbag2_rules.py")
rules = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rules)

#: a second displacement publisher with QoS unlike the package's constants
ODD_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST, depth=3, deadline=Duration(seconds=2, nanoseconds=500))


class TwoSensorRig(Node):
    """Applied voltage from one publisher; displacement from two, with different QoS; it listens to the
    commands as the amplifier does (identifier_node starts only once someone does)."""

    def __init__(self, context, namespace):
        super().__init__("two_sensor_rig", context=context, namespace=namespace)
        self.create_subscription(Float64, "voltage_cmd", lambda _msg: None, COMMAND_QOS)
        self.v_pub = self.create_publisher(BatteryState, "voltage", SENSOR_QOS)
        self.d_pubs = [self.create_publisher(Range, "displacement", SENSOR_QOS),
                       self.create_publisher(Range, "displacement", ODD_QOS)]
        self.publishing = False
        self.create_timer(0.005, self.tick)

    def tick(self):
        if self.publishing:
            t = self.get_clock().now().nanoseconds
            self.v_pub.publish(make_voltage_state(0.0, t, True))
            for pub in self.d_pubs:
                pub.publish(make_range(7e-4, t, "laser"))


def _identifier(ctx, tmp_path, fmt, namespace="/"):
    params = dict(protocol="quick", output_dir=str(tmp_path), run_name="run", identify=False,
                  command_rate_hz=100.0, wait_for_rig_s=10.0, rosbag2_format=fmt)
    return IdentifierNode(context=ctx, namespace=namespace,
                          parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])


@pytest.mark.parametrize("fmt, version", [("humble", 5), ("jazzy", 9)])
def test_bag_holds_each_discovered_publishers_qos(ros_context, spin_until, tmp_path, fmt, version):
    ns = f"/qos_{fmt}"  # its own namespace: publishers of other tests on this graph cannot be counted in
    rig = TwoSensorRig(ros_context, ns)
    node = _identifier(ros_context, tmp_path, fmt, ns)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(rig)
    ex.add_node(node)
    try:
        assert spin_until(ex, lambda: node.count_publishers(f"{ns}/displacement") == 2
                          and node.count_publishers(f"{ns}/voltage") == 1, timeout_s=10.0)
        rig.publishing = True
        assert spin_until(ex, lambda: node.state == "running", timeout_s=10.0)
        spin_until(ex, lambda: False, timeout_s=0.3)
        assert node.abort("test")
    finally:
        ex.shutdown()
        node.destroy_node()
        rig.destroy_node()
    bag = tmp_path / "run" / "bag"
    with BagReader(bag) as reader:
        topics = reader.topics()
    displacement = topics[f"{ns}/displacement"].qos_profiles
    assert len(displacement) == 2  # one per publisher, not the package's constant
    by_reliability = {p.reliability: p for p in displacement}
    assert set(by_reliability) == {"best_effort", "reliable"}
    odd = by_reliability["reliable"]
    assert odd.durability == "transient_local" and tuple(odd.deadline) == (2, 500)
    assert by_reliability["best_effort"].durability == "volatile"
    assert [p.reliability for p in topics[f"{ns}/voltage"].qos_profiles] == ["best_effort"]
    assert [(p.reliability, p.durability) for p in topics[f"{ns}/voltage_cmd"].qos_profiles] == [
        ("reliable", "volatile")]
    assert f"{ns}/displacement_predicted" not in topics  # never published: not recorded, as rosbag2
    for distro in ("humble", "jazzy") if fmt == "humble" else ("jazzy",):
        info = rules.check_bag(bag, distro)
        assert info["version"] == version
        assert len(info["topics"][f"{ns}/displacement"]["qos"]) == 2


def test_bad_rosbag2_format_stops_with_the_parameter_named(ros_context, tmp_path):
    with pytest.raises(SystemExit, match="parameter 'rosbag2_format'.*use 'jazzy'"):
        _identifier(ros_context, tmp_path, "iron")


def test_replay_offers_what_rosbag2_play_offers():
    """Recorded discovered profiles say history unknown / depth 0: playback uses keep_last 10 and the
    recorded reliability/durability when all publishers agreed (Rosbag2QoS::adapt_offer_to_recorded_offers)."""
    from dea_ros.bag import QosProfile
    from dea_ros.nodes.replay_node import playback_qos

    best_effort = QosProfile("unknown", 0, "best_effort", "volatile")
    latched = QosProfile("unknown", 0, "reliable", "transient_local")
    offer = playback_qos([best_effort, best_effort])
    assert (offer.history, offer.depth) == (HistoryPolicy.KEEP_LAST, 10)
    assert (offer.reliability, offer.durability) == (ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE)
    offer = playback_qos([latched])
    assert (offer.reliability, offer.durability) == (ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL)
    mixed = playback_qos([best_effort, latched])  # publishers disagreed: rosbag2's default offer
    assert (mixed.reliability, mixed.durability, mixed.depth) == (
        ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, 10)
