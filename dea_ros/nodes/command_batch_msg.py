"""``voltage_cmd_batch``: the commands of K amplifier updates in one trajectory_msgs/JointTrajectory.

The one place that knows the message's layout (identifier_node builds it, amplifier_node reads it):
``header.stamp`` = the simulated time of the first update the batch is for, point i at ``time_from_start``
= i update periods, ``positions[0]`` = its voltage in V, joint ``dea_voltage``. The amplifier's
:class:`~dea_ros.hardware.amplifier.command_batch.CommandQueue` decides what it accepts.
"""
from __future__ import annotations

from typing import Sequence

from builtin_interfaces.msg import Duration, Time
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

__all__ = ["BATCH_JOINT", "batch_message", "parse_batch"]

#: The joint name of the batches.
BATCH_JOINT = "dea_voltage"


def batch_message(first_update_ns: int, voltages_V: Sequence[float], period_ns: int) -> JointTrajectory:
    """The batch of ``voltages_V`` (V) for the updates at ``first_update_ns + i period_ns`` (ns)."""
    msg = JointTrajectory(joint_names=[BATCH_JOINT])
    sec, nanosec = divmod(int(first_update_ns), 1_000_000_000)
    msg.header.stamp = Time(sec=sec, nanosec=nanosec)
    for i, voltage in enumerate(voltages_V):
        sec, nanosec = divmod(i * int(period_ns), 1_000_000_000)
        msg.points.append(JointTrajectoryPoint(positions=[float(voltage)],
                                               time_from_start=Duration(sec=sec, nanosec=nanosec)))
    return msg


def parse_batch(msg: JointTrajectory) -> tuple[float, list[float], list[float]]:
    """(first update's time s, each point's offset s, each point's voltage V). A point without exactly one
    position makes the whole batch malformed: no values, and one offset more than values (CommandQueue
    refuses it as malformed)."""
    values, offsets = [], []
    for point in msg.points:
        if len(point.positions) != 1:
            return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, [0.0] * (len(msg.points) + 1), []
        values.append(float(point.positions[0]))
        offsets.append(point.time_from_start.sec + point.time_from_start.nanosec * 1e-9)
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, offsets, values
