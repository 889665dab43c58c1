"""sensor_msgs/JointState commands and states as ros2_control's topic-based hardware interfaces use them.

Both interfaces (``joint_state_topic_hardware_interface/JointStateTopicSystem`` on Jazzy and later,
``topic_based_ros2_control/TopicBasedSystem`` on Humble) publish, in ``write()`` at the controller
manager's update rate, one JointState on ``joint_commands_topic`` (QoS: reliable, keep last 1):
``name`` = every joint of the ``<ros2_control>`` tag in its order, ``position`` / ``velocity`` /
``effort`` = the command interfaces' values, appended joint by joint for the joints that have such a
command interface (so ``velocity`` lines up with ``name`` only when every joint commands velocity),
``header.stamp`` = the controller manager's clock. They read ``joint_states_topic`` (SensorDataQoS:
best effort) by joint name; position, velocity and effort are taken when present (non-finite values
are skipped by JointStateTopicSystem).

Here: :func:`parse_joint_command` takes the actuator's joint out of such a message; position_controller_node's
``joint_states`` (one joint, position and velocity) is the state the interfaces read.
"""
from __future__ import annotations

import math

from sensor_msgs.msg import JointState

__all__ = ["JointCommand", "parse_joint_command"]


class JointCommand:
    """The actuator's joint in a JointState command: position (m, NaN: none yet), velocity (m/s or None)."""

    __slots__ = ("position_m", "velocity_m_per_s")

    def __init__(self, position_m: float, velocity_m_per_s: float | None):
        self.position_m = position_m
        self.velocity_m_per_s = velocity_m_per_s

    @property
    def valid(self) -> bool:
        return math.isfinite(self.position_m)


def parse_joint_command(msg: JointState, joint_name: str) -> JointCommand | None:
    """The command of ``joint_name`` in ``msg``; None when the message does not name the joint.

    ValueError when the joint is named but its position cannot be found unambiguously (``position``
    not one per name: some joints of the ros2_control tag have no position command interface, and
    the interfaces then pack the array without gaps).
    """
    names = list(msg.name)
    if joint_name not in names:
        return None
    j = names.index(joint_name)
    if len(msg.position) != len(names):
        raise ValueError(
            f"JointState command: {len(msg.position)} positions for joints {names}; every joint of the "
            f"<ros2_control> tag needs a position command interface so that '{joint_name}' can be found")
    velocity = float(msg.velocity[j]) if len(msg.velocity) == len(names) else None
    if velocity is not None and not math.isfinite(velocity):
        velocity = None
    return JointCommand(float(msg.position[j]), velocity)
