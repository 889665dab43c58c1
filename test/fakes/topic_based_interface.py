"""ros2_control's topic-based hardware interface and a joint_trajectory_controller, played in Python.

Written from the sources (not copied): ros-controls/topic_based_hardware_interfaces
``joint_state_topic_hardware_interface/src/joint_state_topic_hardware_interface.cpp`` (Jazzy, Kilted;
commit d115f23) and PickNikRobotics/topic_based_ros2_control ``src/topic_based_system.cpp`` (Humble;
0.3.0). What they do, and what :class:`TopicBasedSystemDouble` does the same way:

* on_init: a publisher of sensor_msgs/JointState on ``joint_commands_topic`` with ``rclcpp::QoS(1)``
  (reliable, volatile, keep last 1) and a subscription of ``joint_states_topic`` with
  ``rclcpp::SensorDataQoS()`` (best effort, keep last 5) keeping the latest message;
* read() (every controller manager cycle): for each name of the latest state message that is a joint
  of the hardware, its position, velocity and effort become the state interfaces' values when the
  array is not empty (JointStateTopicSystem also skips non-finite values);
* write() (every cycle, after the controllers): ``diff`` = sum over the joints and their position,
  velocity and effort command interfaces of |state - command|; nothing is sent when
  ``diff <= trigger_joint_command_threshold`` (default 1e-5; -1: always). Otherwise one JointState:
  ``name`` = every joint in the order of the <ros2_control> tag, ``header.stamp`` = now, and for each
  joint, in the order of its command interfaces, its position / velocity / effort command appended to
  ``position`` / ``velocity`` / ``effort`` (only the joints with that interface contribute). Command
  interfaces start at NaN, so before a controller writes them the difference is NaN, the threshold test
  fails and NaN commands are published.

:class:`TrajectorySampler` samples a JointTrajectory as joint_trajectory_controller does with
positions and velocities (cubic Hermite between the points, from the state at the trajectory's start).
"""
from __future__ import annotations

import math

from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import JointState

__all__ = ["TopicBasedSystemDouble", "TrajectorySampler"]

SUPPORTED = ("position", "velocity", "effort")


class TopicBasedSystemDouble:
    """The hardware interface: ``joints`` = [(name, [command interfaces...]), ...] in the tag's order."""

    def __init__(self, node, joints, commands_topic: str, states_topic: str, threshold: float = 1e-5):
        self.joints = [(name, list(ifaces)) for name, ifaces in joints]
        self.threshold = float(threshold)
        self.state = {(name, i): 0.0 for name, _ in self.joints for i in SUPPORTED}
        self.command = {(name, i): math.nan for name, ifaces in self.joints for i in ifaces}
        self.latest = JointState()
        self.published = []          # the JointState messages sent
        self.suppressed = 0          # write() calls the threshold kept silent
        self.pub = node.create_publisher(JointState, commands_topic, QoSProfile(depth=1))
        self.sub = node.create_subscription(JointState, states_topic, self._on_state, qos_profile_sensor_data)
        self.clock = node.get_clock()

    def _on_state(self, msg: JointState) -> None:
        self.latest = msg

    def read(self) -> None:
        msg = self.latest
        names = {name for name, _ in self.joints}
        for i, name in enumerate(msg.name):
            if name not in names:
                continue
            for iface, values in (("position", msg.position), ("velocity", msg.velocity), ("effort", msg.effort)):
                if len(values) and math.isfinite(values[i]):
                    self.state[(name, iface)] = float(values[i])

    def write(self, stamp_ns: int | None = None) -> bool:
        diff = 0.0
        for name, ifaces in self.joints:
            for iface in ifaces:
                if iface in SUPPORTED:
                    diff += abs(self.state[(name, iface)] - self.command[(name, iface)])
        if diff <= self.threshold:
            self.suppressed += 1
            return False
        msg = JointState()
        stamp = self.clock.now().nanoseconds if stamp_ns is None else int(stamp_ns)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        pos, vel, eff = [], [], []
        for name, ifaces in self.joints:
            msg.name.append(name)
            for iface in ifaces:
                {"position": pos, "velocity": vel, "effort": eff}[iface].append(self.command[(name, iface)])
        msg.position, msg.velocity, msg.effort = pos, vel, eff
        self.pub.publish(msg)
        self.published.append(msg)
        return True


class TrajectorySampler:
    """Desired (position, velocity) of one joint along timed points, as joint_trajectory_controller samples.

    ``start_s``: when the trajectory starts (the controller received it), ``state``: the joint's
    (position, velocity) then; ``points``: [(time_from_start s, position, velocity)].
    """

    def __init__(self, start_s: float, state, points):
        self.knots = [(float(start_s), float(state[0]), float(state[1]))]
        self.knots += [(start_s + t, float(p), float(v)) for t, p, v in points]

    @property
    def end_s(self) -> float:
        return self.knots[-1][0]

    def sample(self, t_s: float):
        k = self.knots
        if t_s <= k[0][0]:
            return k[0][1], k[0][2]
        if t_s >= k[-1][0]:
            return k[-1][1], 0.0
        i = max(j for j in range(len(k) - 1) if k[j][0] <= t_s)
        (t0, p0, v0), (t1, p1, v1) = k[i], k[i + 1]
        h = t1 - t0
        s = (t_s - t0) / h
        h00, h10 = 2 * s ** 3 - 3 * s ** 2 + 1, s ** 3 - 2 * s ** 2 + s
        h01, h11 = -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
        d00, d10, d01, d11 = 6 * s ** 2 - 6 * s, 3 * s ** 2 - 4 * s + 1, -6 * s ** 2 + 6 * s, 3 * s ** 2 - 2 * s
        pos = h00 * p0 + h10 * h * v0 + h01 * p1 + h11 * h * v1
        vel = (d00 * p0 + d10 * h * v0 + d01 * p1 + d11 * h * v1) / h
        return pos, vel
