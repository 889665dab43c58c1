"""ros2_control through the topic-based hardware interface, over real rclpy.

position_controller_node runs in its own process (installed config, a namespace); this process plays
the plant (lockstep, 1 kHz laser) and the ros2_control side as the hardware interface's source does it
(test/fakes/topic_based_interface.py): a controller manager at 100 Hz of the plant's time whose
joint_trajectory_controller samples a JointTrajectory (positions + velocities: cubic Hermite), the
interface's write() with its threshold test and the joints in the order of the <ros2_control> tag
(another joint first), and read() of the node's joint_states. The mass must follow the trajectory
as closely as when the same trajectory is sent on ``joint_trajectory``.
"""
import importlib.util
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from dea_ros.control import ModelInverse
from dea_ros.model import load_parameters
from dea_ros.nodes.common import COMMAND_QOS
from fakes import load_fake

_spec = importlib.util.spec_from_file_location("pc_test", Path(__file__).parent / "test_position_controller_node.py")
PC = importlib.util.module_from_spec(_spec)   # start_controller, stop, Plant: the lockstep harness
_spec.loader.exec_module(PC)

CM_PERIOD_SAMPLES = 10      # controller manager update_rate 100 Hz against the 1 kHz laser


def _points(d0):
    """(time_from_start s, position m, velocity m/s): 40 um down, 30 up, 20 down, as a robot plans it."""
    return [(0.12, d0 + 40e-6, 0.0), (0.20, d0 + 25e-6, -2.0e-4), (0.30, d0 + 10e-6, 0.0),
            (0.45, d0 + 30e-6, 0.0)]


def _msg(points):
    msg = JointTrajectory(joint_names=["dea_joint"])
    for t, p, v in points:
        pt = JointTrajectoryPoint(positions=[p], velocities=[v])
        pt.time_from_start = Duration(sec=0, nanosec=int(round(t * 1e9)))
        msg.points.append(pt)
    return msg


def _rms_error(plant, n_from, sampler):
    """RMS of true displacement - desired over the trajectory and 100 ms after, m (plant's clock)."""
    t0 = plant.t0_ns * 1e-9
    err = [d - sampler.sample(t - t0)[0] for t, d, _ in plant.history[n_from:] if t - t0 <= sampler.end_s + 0.1]
    return float(np.sqrt(np.mean(np.square(err))))


def test_a_joint_trajectory_through_the_topic_based_interface_moves_the_mass(ros_context, spin_until):
    ns = "/pc_ros2_control"
    tbi = load_fake("topic_based_interface")
    inv = ModelInverse(load_parameters(PC.TRUTH), PC.U_MAX)
    d_start = inv.reachable_range_m[0] + 60e-6
    proc = PC.start_controller(ns, "sensor_timeout_s:=2.0")
    node = Node("robot", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    try:
        plant = PC.Plant(node, ns, inv.static_voltage(d_start))
        hw = tbi.TopicBasedSystemDouble(node, [("gripper_joint", ["position", "velocity"]),
                                               ("dea_joint", ["position", "velocity"])],
                                        f"{ns}/joint_commands", f"{ns}/joint_states", threshold=-1.0)
        traj_pub = node.create_publisher(JointTrajectory, f"{ns}/joint_trajectory", COMMAND_QOS)
        assert spin_until(ex, lambda: plant.pub.get_subscription_count() > 0 and
                          hw.pub.get_subscription_count() > 0, timeout_s=30.0), PC.H.stderr_of(proc)
        assert spin_until(ex, lambda: plant.sample(ex, spin_until, timeout_s=0.2), timeout_s=20.0)
        state = {"jtc": None, "t0": None}

        def cycle(k):
            """One controller manager cycle every CM_PERIOD_SAMPLES laser samples: read, update, write."""
            if k % CM_PERIOD_SAMPLES == 0:
                hw.read()
                t = plant.k * 1e-3
                if state["jtc"] is not None:
                    pos, vel = state["jtc"].sample(t)
                    hw.command[("dea_joint", "position")], hw.command[("dea_joint", "velocity")] = pos, vel
                hw.write(plant.t0_ns + plant.k * 1_000_000)
                ex.spin_once(timeout_sec=0.0)
            assert plant.sample(ex, spin_until)

        # before a controller claims the joint the interface sends NaN commands: ignored, the mass holds
        # (after the start transient: the controller's model A2 is not the plant)
        for k in range(400):
            cycle(k)
        assert hw.published and np.isnan(hw.published[0].position[1])
        assert list(hw.published[0].name) == ["gripper_joint", "dea_joint"]
        assert abs(hw.state[("dea_joint", "position")] - d_start) < 5e-6      # read() saw the node's joint_states
        d_hold = np.array([h[1] for h in plant.history[-50:]])
        assert abs(d_hold.mean() - d_start) < 2e-6
        # the trajectory controller activates (holding the state it reads: gripper too), then gets the goal
        hw.command[("gripper_joint", "position")] = hw.command[("gripper_joint", "velocity")] = 0.0
        t_start = plant.k * 1e-3
        d_read = hw.state[("dea_joint", "position")]
        sampler = tbi.TrajectorySampler(t_start, (d_read, 0.0), _points(d_read))
        state["jtc"] = sampler
        n0 = len(plant.history)
        for k in range(700):
            cycle(k)
        rms_stream = _rms_error(plant, n0, sampler)
        assert len(hw.published) > 70
        assert all(list(m.name) == ["gripper_joint", "dea_joint"] and len(m.velocity) == 2
                   for m in hw.published)
        # the same trajectory on joint_trajectory, from the same position
        state["jtc"] = None
        for k in range(200):
            cycle(k)
        d_back = np.array([h[1] for h in plant.history[-50:]])
        assert abs(d_back.mean() - (d_read + 30e-6)) < 2e-6
        d1 = d_read + 30e-6
        n1 = len(plant.history)
        t1 = plant.k * 1e-3          # the node starts a trajectory at the next sample
        traj_pub.publish(_msg(_points(d1)))
        for k in range(700):
            assert plant.sample(ex, spin_until)
        sampler1 = tbi.TrajectorySampler(t1, (d1, 0.0), _points(d1))
        rms_direct = _rms_error(plant, n1, sampler1)
        print(f"RMS tracking error: ros2_control stream {rms_stream * 1e6:.2f} um, "
              f"joint_trajectory {rms_direct * 1e6:.2f} um")
        assert rms_stream < 3e-6
        assert rms_stream < 1.5 * rms_direct + 1e-6
    finally:
        PC.stop(proc)
        ex.shutdown()
        node.destroy_node()


def test_the_default_threshold_keeps_small_moves_from_the_actuator(ros_context, spin_until):
    """trigger_joint_command_threshold 1e-5 (the interfaces' default) is 10 um on this joint: a 5 um
    command never leaves the interface; -1 (urdf/dea_rig.ros2_control.xacro) sends it and the mass moves."""
    ns = "/pc_threshold"
    tbi = load_fake("topic_based_interface")
    inv = ModelInverse(load_parameters(PC.TRUTH), PC.U_MAX)
    d_start = inv.reachable_range_m[0] + 60e-6
    proc = PC.start_controller(ns, "sensor_timeout_s:=2.0")
    node = Node("robot_threshold", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    try:
        plant = PC.Plant(node, ns, inv.static_voltage(d_start))
        hw = tbi.TopicBasedSystemDouble(node, [("dea_joint", ["position"])], f"{ns}/joint_commands",
                                        f"{ns}/joint_states", threshold=1e-5)
        assert spin_until(ex, lambda: plant.pub.get_subscription_count() > 0 and
                          hw.pub.get_subscription_count() > 0, timeout_s=30.0), PC.H.stderr_of(proc)
        assert spin_until(ex, lambda: plant.sample(ex, spin_until, timeout_s=0.2), timeout_s=20.0)
        for _ in range(400):           # past the start transient (the controller's model is not the plant)
            assert plant.sample(ex, spin_until)
        assert spin_until(ex, lambda: abs(hw.latest.position[0] - d_start) < 2e-6 if hw.latest.position else False,
                          timeout_s=10.0)

        def run(n):
            for k in range(n):
                if k % CM_PERIOD_SAMPLES == 0:
                    hw.read()
                    hw.write()
                    ex.spin_once(timeout_sec=0.0)
                assert plant.sample(ex, spin_until)

        hw.read()
        hw.command[("dea_joint", "position")] = d_start + 5e-6
        n_pub = len(hw.published)
        run(200)
        assert len(hw.published) == n_pub and hw.suppressed >= 20
        assert abs(np.mean([h[1] for h in plant.history[-50:]]) - d_start) < 1.5e-6
        hw.threshold = -1.0
        run(200)
        assert len(hw.published) >= 19
        assert abs(np.mean([h[1] for h in plant.history[-50:]]) - (d_start + 5e-6)) < 1.5e-6
    finally:
        PC.stop(proc)
        ex.shutdown()
        node.destroy_node()
