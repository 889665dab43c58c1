"""CDR encoding and decoding of ROS 2 messages from the ``ros2msg`` schema text stored in a bag.

mcap_ros2's dynamic (de)serializers are built from the schema text, so no ROS message packages
are needed: :func:`message_decoder` returns a function turning CDR bytes into an object with
attribute access (``msg.header.stamp.sec``), :func:`message_encoder` one turning a dict (or any
object with the type's fields) into CDR bytes; :func:`plain_message` converts rclpy message
objects to the dicts the encoder takes.
"""
from __future__ import annotations

import contextlib
import io
import struct
from typing import Any, Callable

from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic

__all__ = ["header_stamp_ns", "message_decoder", "message_encoder", "plain_message"]


def message_decoder(type_name: str, schema_data: bytes) -> Callable[[bytes], Any]:
    """mcap_ros2's dynamic CDR decoder for a ``ros2msg`` schema (its parser's prints silenced)."""
    text = schema_data.decode("utf-8")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return generate_dynamic(type_name, text)[type_name]


def message_encoder(type_name: str, schema_text: str) -> Callable[[Any], bytes]:
    """mcap_ros2's dynamic CDR encoder for ``type_name`` (``pkg/msg/Type``) from its schema text.

    Missing fields take their default (0, "", empty); nested messages may be dicts too.
    """
    return serialize_dynamic(type_name, schema_text)[type_name]


def plain_message(message: Any) -> Any:
    """rclpy message objects -> nested dicts (``byte``/``octet`` bytes -> int); others unchanged."""
    get_fields = getattr(message, "get_fields_and_field_types", None)
    if get_fields is None:
        return message
    plain: dict[str, Any] = {}
    for field_name, field_type in get_fields().items():
        value = getattr(message, field_name)
        if field_type in ("octet", "byte") and isinstance(value, (bytes, bytearray)) and len(value) == 1:
            value = value[0]
        elif hasattr(value, "get_fields_and_field_types"):
            value = plain_message(value)
        elif isinstance(value, (list, tuple)):
            value = [
                item[0]
                if isinstance(item, (bytes, bytearray)) and len(item) == 1
                else plain_message(item)
                for item in value
            ]
        plain[field_name] = value
    return plain


def header_stamp_ns(data: bytes) -> int:
    """The header stamp (integer ns) of a CDR-serialized message whose first field is a std_msgs/Header
    (sensor_msgs/BatteryState, Range, ...): ``sec`` (int32) and ``nanosec`` (uint32) right after the
    4-byte encapsulation header, little- or big-endian as it says. For a recorder that also needs the
    stamp without deserializing the message a second time."""
    if len(data) < 12:
        raise ValueError(f"header_stamp_ns: {len(data)} bytes is no CDR message with a header")
    order = "<" if data[1] & 1 else ">"  # encapsulation kind: CDR_LE = 0x0001, CDR_BE = 0x0000
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    return sec * 1_000_000_000 + nanosec
