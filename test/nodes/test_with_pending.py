"""nodes.common.with_pending with this rclpy: a subscription's callback takes the messages already waiting.

identifier_node's recorders rely on it (issue 22, session 11): the take is rclpy's own
``handle.take_message``, an API below the documented one, so the test runs on every stack the CI has.
"""
import time

import pytest

rclpy = pytest.importorskip("rclpy")


def test_a_raw_callback_takes_the_waiting_messages_in_order_up_to_the_limit(ros_context, spin_until):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Header

    from dea_ros.nodes.common import with_pending

    node = Node("with_pending_probe", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    try:
        calls = []  # per callback: the frame ids it recorded
        subs = {}

        def on_message(data: bytes) -> None:
            calls.append([deserialize_message(m, Header).frame_id for m in with_pending(subs["probe"], data, limit=3)])

        qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=50)
        subs["probe"] = node.create_subscription(Header, "pending_probe", on_message, qos, raw=True)
        pub = node.create_publisher(Header, "pending_probe", qos)
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0)
        for i in range(6):
            pub.publish(Header(frame_id=str(i)))
        time.sleep(1.0)  # all six in the reader's queue before the executor runs the first callback
        assert spin_until(executor, lambda: sum(len(c) for c in calls) >= 6)
        assert [f for c in calls for f in c] == ["0", "1", "2", "3", "4", "5"]   # same messages, same order
        assert calls == [["0", "1", "2", "3"], ["4", "5"]]                        # the first and 3 waiting
    finally:
        executor.remove_node(node)
        node.destroy_node()


def test_without_a_subscription_only_the_message_itself():
    from dea_ros.nodes.common import with_pending

    assert list(with_pending(None, b"x")) == [b"x"]
