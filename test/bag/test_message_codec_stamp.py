"""header_stamp_ns reads a header's stamp from CDR bytes as rclpy serialized them (identifier_node's
trigger on its recorded applied-voltage messages)."""
import pytest

from dea_ros.bag.message_codec import header_stamp_ns


def test_stamp_of_rclpy_serialized_messages():
    pytest.importorskip("rclpy")
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import BatteryState, Range

    for msg_type, sec, nanosec in ((BatteryState, 1795646000, 123456789), (Range, 0, 999_999_999),
                                   (BatteryState, -3, 5)):
        msg = msg_type()
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.header.frame_id = "dea_laser"
        assert header_stamp_ns(serialize_message(msg)) == sec * 1_000_000_000 + nanosec


def test_big_endian_and_short_input():
    data = bytes([0, 0, 0, 0]) + (7).to_bytes(4, "big") + (8).to_bytes(4, "big")
    assert header_stamp_ns(data) == 7_000_000_008
    with pytest.raises(ValueError):
        header_stamp_ns(b"\x00\x01\x00\x00")
