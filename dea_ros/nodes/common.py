"""Shared pieces of the rclpy nodes: topic names, QoS, message conversions, parameter helpers.

Topics (namespace ``/dea`` by default; every name is relative so ``--ros-args -r __ns:=/rig2``
moves a whole rig):

===========================  ==============================  ====================================
topic                        type                            content (SI units)
===========================  ==============================  ====================================
voltage_cmd                  std_msgs/msg/Float64            commanded voltage, V
voltage_cmd_batch            trajectory_msgs/msg/             simulated time only: the voltages of the
                             JointTrajectory                 next updates (open-loop protocols), one
                                                             point per update, ``positions[0]`` in V
voltage                      sensor_msgs/msg/BatteryState    applied voltage (``voltage``, V), stamped
                                                             when applied; ``present`` = output on
displacement                 sensor_msgs/msg/Range           measured displacement (``range``, m),
                                                             stamped with the acquisition time
displacement_predicted       sensor_msgs/msg/Range           model prediction, stamped like its input
===========================  ==============================  ====================================

Why these types: ROS has no standard stamped scalar. ``Range`` is the standard
message of single-point distance sensors (the laser triangulation head), and
``BatteryState`` is the standard state of a power supply with a ``voltage`` field
(the high-voltage amplifier is one). Both carry a header, so identification can
align signals by acquisition time, and both open in every ROS tool.
"""
from __future__ import annotations

import math

from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from sensor_msgs.msg import BatteryState, Range

from ..bag import QosProfile, qos_from_dict

__all__ = [
    "TOPIC_VOLTAGE_CMD", "TOPIC_VOLTAGE_CMD_BATCH", "TOPIC_VOLTAGE", "TOPIC_DISPLACEMENT",
    "TOPIC_DISPLACEMENT_IMPLAUSIBLE", "TOPIC_DISPLACEMENT_PREDICTED",
    "SENSOR_QOS", "COMMAND_QOS", "LATCHED_QOS", "declare_float", "declare_int", "declare_str",
    "declare_bool", "make_range", "make_voltage_state", "stamp_to_s", "stamp_to_ns", "s_to_stamp", "publish_diagnostic",
    "qos_to_bag", "with_pending",
]

TOPIC_VOLTAGE_CMD = "voltage_cmd"
TOPIC_VOLTAGE_CMD_BATCH = "voltage_cmd_batch"
TOPIC_VOLTAGE = "voltage"
TOPIC_DISPLACEMENT = "displacement"
#: Samples laser_sensor_node's plausibility checks discarded (their decoded value; ``displacement``
#: carries NaN at the same stamp).
TOPIC_DISPLACEMENT_IMPLAUSIBLE = "displacement_implausible"
TOPIC_DISPLACEMENT_PREDICTED = "displacement_predicted"

#: high-rate streams (displacement, predictions, applied voltage): best effort, keep last 50
SENSOR_QOS = QoSProfile(
    reliability=ReliabilityPolicy.BEST_EFFORT,
    history=HistoryPolicy.KEEP_LAST,
    depth=50,
    durability=DurabilityPolicy.VOLATILE,
)
#: commands: reliable, keep last 50 (a burst of commands is not silently dropped)
COMMAND_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    history=HistoryPolicy.KEEP_LAST,
    depth=50,
    durability=DurabilityPolicy.VOLATILE,
)
#: status/metadata that late joiners (the recorder) must still get
LATCHED_QOS = QoSProfile(
    reliability=ReliabilityPolicy.RELIABLE,
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# (rclpy's qos_profile_sensor_data has depth 5: too shallow for 1-2 kHz bursts.)


def declare_float(node: Node, name: str, default: float, description: str,
                  low: float | None = None, high: float | None = None, read_only: bool = False) -> float:
    """Declare a double parameter with a descriptor (and range) and return its value."""
    desc = ParameterDescriptor(description=description, read_only=read_only)
    if low is not None and high is not None:
        desc.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]
    return float(node.declare_parameter(name, float(default), desc).value)


def declare_int(node: Node, name: str, default: int, description: str,
                low: int | None = None, high: int | None = None, read_only: bool = False) -> int:
    desc = ParameterDescriptor(description=description, read_only=read_only)
    if low is not None and high is not None:
        desc.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
    return int(node.declare_parameter(name, int(default), desc).value)


def declare_str(node: Node, name: str, default: str, description: str, read_only: bool = False) -> str:
    desc = ParameterDescriptor(description=description, read_only=read_only)
    return str(node.declare_parameter(name, str(default), desc).value)


def declare_bool(node: Node, name: str, default: bool, description: str) -> bool:
    return bool(node.declare_parameter(name, bool(default), ParameterDescriptor(description=description)).value)


def stamp_to_s(stamp) -> float:
    """A builtin_interfaces/Time in seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def stamp_to_ns(stamp) -> int:
    """A builtin_interfaces/Time in integer nanoseconds (exact)."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def s_to_stamp(t_s: float, stamp) -> None:
    """Fill a builtin_interfaces/Time in place from seconds (an int is taken as nanoseconds)."""
    if isinstance(t_s, int):
        stamp.sec, stamp.nanosec = divmod(t_s, 1_000_000_000)
        return
    sec = math.floor(t_s)
    stamp.sec = int(sec)
    stamp.nanosec = min(int(round((t_s - sec) * 1e9)), 999_999_999)


def make_range(displacement_m: float, t_s, frame_id: str, min_m: float = -0.005,
               max_m: float = 0.005) -> Range:
    """A Range message carrying a displacement (m) stamped at t_s (s as float, or ns as int)."""
    msg = Range()
    s_to_stamp(t_s, msg.header.stamp)
    msg.header.frame_id = frame_id
    msg.radiation_type = Range.INFRARED  # laser triangulation: the closest standard constant
    msg.field_of_view = 0.0
    msg.min_range = float(min_m)
    msg.max_range = float(max_m)
    msg.range = float(displacement_m)
    return msg


def make_voltage_state(voltage_V: float, t_s: float, output_enabled: bool, frame_id: str = "dea_amplifier",
                       current_A: float = float("nan")) -> BatteryState:
    """A BatteryState carrying the applied high voltage (V) of the amplifier, stamped at t_s."""
    msg = BatteryState()
    s_to_stamp(t_s, msg.header.stamp)
    msg.header.frame_id = frame_id
    msg.voltage = float(voltage_V)
    msg.current = float(current_A)
    msg.charge = float("nan")
    msg.capacity = float("nan")
    msg.design_capacity = float("nan")
    msg.percentage = float("nan")
    msg.temperature = float("nan")
    msg.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_UNKNOWN
    msg.power_supply_health = BatteryState.POWER_SUPPLY_HEALTH_GOOD
    msg.power_supply_technology = BatteryState.POWER_SUPPLY_TECHNOLOGY_UNKNOWN
    msg.present = bool(output_enabled)
    return msg


def publish_diagnostic(node: Node, publisher, name: str, hardware_id: str, level, message: str, values) -> None:
    """Publish one DiagnosticStatus (``values``: (key, value) pairs) on /diagnostics, stamped now."""
    status = DiagnosticStatus()
    status.name = name
    status.hardware_id = hardware_id
    status.level = level
    status.message = message
    status.values = [KeyValue(key=str(k), value=str(v)) for k, v in values]
    arr = DiagnosticArray()
    arr.header.stamp = node.get_clock().now().to_msg()
    arr.status = [status]
    publisher.publish(arr)


def qos_to_bag(profile) -> QosProfile:
    """An rclpy QoSProfile (e.g. a discovered publisher's offered QoS) as rosbag2 stores it.

    Every field is kept (rmw enum values; durations as {sec, nsec}: rmw's infinite duration
    stays 9223372036 s 854775807 ns). Discovery reports history ``unknown`` and depth 0, as
    ``ros2 bag record`` then records too.
    """
    def duration(value) -> dict:
        sec, nsec = divmod(int(value.nanoseconds), 1_000_000_000)
        return {"sec": sec, "nsec": nsec}

    return qos_from_dict({
        "history": int(profile.history), "depth": int(profile.depth),
        "reliability": int(profile.reliability), "durability": int(profile.durability),
        "deadline": duration(profile.deadline), "lifespan": duration(profile.lifespan),
        "liveliness": int(profile.liveliness),
        "liveliness_lease_duration": duration(profile.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": bool(profile.avoid_ros_namespace_conventions),
    })


def with_pending(subscription, first, limit: int = 64):
    """``first`` (the message a subscription's callback got), then the messages already waiting in
    ``subscription``'s queue (at most ``limit``), oldest first.

    rclpy's executors deliver one message per subscription per wait round, and a round costs far more
    than the callback of a recorder: a callback that takes what else is waiting saves the rounds (the
    mock rig's laser samples arrive two per simulated tick, issue 22). Same messages, same order; the
    take is the executor's own (``handle.take_message``, rclpy Humble to Kilted). ``subscription``
    None, or a take that fails: ``first`` only."""
    yield first
    if subscription is None:
        return
    for _ in range(limit):
        try:
            with subscription.handle:
                taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
        except (AttributeError, RuntimeError):  # not this rclpy's API, or the subscription was destroyed
            return
        if taken is None:
            return
        yield taken[0]
