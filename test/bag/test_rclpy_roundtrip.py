"""Round trip with real rclpy messages (skipped when rclpy is not importable)."""

import math

import pytest

rclpy = pytest.importorskip("rclpy")
serialization = pytest.importorskip("rclpy.serialization")
for _package in ("builtin_interfaces", "diagnostic_msgs", "rosgraph_msgs", "sensor_msgs", "std_msgs"):
    pytest.importorskip(f"{_package}.msg")  # rclpy without the message packages: skip, not fail

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import BatteryState, Range  # noqa: E402
from std_msgs.msg import Float64, Header, String  # noqa: E402

from dea_ros.bag import BagReader, BagWriter, sensor_data_qos  # noqa: E402


def _messages():
    header = Header(stamp=Time(sec=1_700_000_123, nanosec=456_789), frame_id="dea_laser")
    battery = BatteryState(
        header=header,
        voltage=11.5,
        current=-0.25,
        charge=math.nan,
        percentage=0.75,
        power_supply_status=BatteryState.POWER_SUPPLY_STATUS_DISCHARGING,
        present=True,
        cell_voltage=[3.75, 3.5, 3.25],
        location="rack 1",
        serial_number="HV-42",
    )
    diagnostics = DiagnosticArray(
        header=header,
        status=[
            DiagnosticStatus(
                level=DiagnosticStatus.WARN,
                name="dea/amplifier",
                message="temperature high",
                hardware_id="hv-amp-0",
                values=[KeyValue(key="temperature_C", value="71.5")],
            )
        ],
    )
    return [
        ("/dea/voltage_cmd", "std_msgs/msg/Float64", Float64(data=2500.125)),
        ("/dea/range", "sensor_msgs/msg/Range", Range(
            # float32 fields: values exactly representable in float32, so equality is exact
            header=header, radiation_type=Range.INFRARED, field_of_view=0.0625,
            min_range=2.0**-9, max_range=0.046875, range=0.015625,  # no variance: Humble lacks it
        )),
        ("/dea/state", "std_msgs/msg/String", String(data="holding ✓")),
        ("/dea/battery", "sensor_msgs/msg/BatteryState", battery),
        ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", diagnostics),
        ("/clock", "rosgraph_msgs/msg/Clock", Clock(clock=Time(sec=5, nanosec=6))),
    ]


def _equal_with_nan(a, b):
    """rclpy message equality, treating NaN == NaN (BatteryState.charge)."""
    if hasattr(a, "get_fields_and_field_types"):
        return type(a) is type(b) and all(
            _equal_with_nan(getattr(a, f), getattr(b, f)) for f in a.get_fields_and_field_types()
        )
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    if isinstance(a, (list, tuple)) or hasattr(a, "tolist"):
        a_list, b_list = list(a), list(b)
        return len(a_list) == len(b_list) and all(_equal_with_nan(x, y) for x, y in zip(a_list, b_list))
    return a == b


def _same_fields(original, decoded, where):
    """Every field of an rclpy message equals the BagReader-decoded (mcap_ros2) value."""
    if hasattr(original, "get_fields_and_field_types"):
        for name in original.get_fields_and_field_types():
            _same_fields(getattr(original, name), getattr(decoded, name), f"{where}.{name}")
    elif isinstance(original, (bytes, bytearray)) and len(original) == 1:  # rclpy 'byte' field
        assert decoded == original[0], where
    elif isinstance(original, (list, tuple)) or hasattr(original, "tolist"):
        assert len(list(original)) == len(list(decoded)), where
        for index, (a, b) in enumerate(zip(original, decoded)):
            _same_fields(a, b, f"{where}[{index}]")
    elif isinstance(original, float) and math.isnan(original):
        assert math.isnan(decoded), where
    else:
        assert original == decoded, f"{where}: {original!r} != {decoded!r}"


def test_serialized_rclpy_messages_round_trip_byte_exact(tmp_path):
    messages = _messages()
    # Keep the exact bytes: Fast-CDR leaves alignment padding uninitialized, so serializing the
    # same message twice need not give identical bytes.
    serialized = [serialization.serialize_message(message) for _, _, message in messages]
    with BagWriter(tmp_path / "rclpy") as writer:
        for index, (topic, type_name, _message) in enumerate(messages):
            qos = sensor_data_qos() if topic == "/dea/range" else None
            writer.add_topic(topic, type_name, qos)
            writer.write_serialized(topic, serialized[index], 1_000 + index)
    with BagReader(tmp_path / "rclpy") as reader:
        raw = list(reader.raw_messages())
        decoded = list(reader.messages())
    assert [r.topic for r in raw] == [topic for topic, _, _ in messages]
    for (topic, _type, original), data, stored, ours in zip(messages, serialized, raw, decoded):
        assert stored.data == data, topic
        assert stored.log_time_ns == stored.publish_time_ns and ours.log_time_ns == stored.log_time_ns
        _same_fields(original, ours.message, topic)
        back = serialization.deserialize_message(stored.data, type(original))
        assert _equal_with_nan(back, original), topic
    range_msg = decoded[1].message
    assert range_msg.header.frame_id == "dea_laser" and range_msg.header.stamp.nanosec == 456_789
    assert range_msg.radiation_type == Range.INFRARED
    assert decoded[4].message.status[0].values[0].value == "71.5"
    assert decoded[4].message.status[0].level == 1


def test_write_with_rclpy_objects_is_deserializable_by_rclpy(tmp_path):
    """``write()`` (mcap_ros2 CDR encoder) produces CDR that rclpy/Fast-CDR decodes identically."""
    messages = _messages()
    with BagWriter(tmp_path / "objects") as writer:
        for index, (topic, type_name, message) in enumerate(messages):
            writer.add_topic(topic, type_name)
            writer.write(topic, message, 1_000 + index)
    with BagReader(tmp_path / "objects") as reader:
        for (topic, _type, original), stored in zip(messages, reader.raw_messages()):
            back = serialization.deserialize_message(stored.data, type(original))
            assert _equal_with_nan(back, original), topic
