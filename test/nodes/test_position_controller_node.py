"""position_controller_node over real rclpy: the node in its own process (installed config, a namespace),
the plant, the amplifier and the lifecycle manager in this one."""
import importlib.util
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import BatteryState, JointState, Range
from std_msgs.msg import Float64
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from dea_ros.control import ModelInverse
from dea_ros.model import config_dir, load_parameters
from dea_ros.nodes.amplifier_node import AmplifierNode
from dea_ros.nodes.common import COMMAND_QOS, SENSOR_QOS, make_range
from dea_ros.nodes.position_controller_node import PositionControllerNode
from dea_ros.solvers.integrate import RealTimeStepper

_spec = importlib.util.spec_from_file_location("amp_harness", Path(__file__).parent / "amp_harness.py")
H = importlib.util.module_from_spec(_spec)  # spawn_logged / stderr_of: node processes logging to files
_spec.loader.exec_module(H)

CONFIG = config_dir() / "position_controller.yaml"
TRUTH = config_dir() / "rig" / "mock_membrane.yaml"      # the plant: not the controller's model (A2)
U_MAX = 0.9 * 100e6 * 35e-6                              # A2: margin x breakdown x thickness
SLEW = 100000.0


def start_controller(ns, *extra, autostart=True):
    """position_controller_node in its own process, as `ros2 run` with the installed config."""
    cmd = [sys.executable, "-m", "dea_ros.nodes.position_controller_node", "--ros-args", "-r", f"__ns:={ns}",
           "--params-file", str(CONFIG), "-p", "params_file:=A2", "-p", f"autostart:={str(autostart).lower()}"]
    for e in extra:
        cmd += ["-p", e]
    return H.spawn_logged(cmd)


def stop(proc):
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()


class Plant:
    """The simulated membrane (true parameters) stepped in lockstep with the controller's commands."""

    def __init__(self, node, ns, voltage_V):
        self.stepper = RealTimeStepper(load_parameters(TRUTH), dt_s=2.5e-4, initial_voltage_V=voltage_V)
        self.pub = node.create_publisher(Range, f"{ns}/displacement", SENSOR_QOS)
        self.cmds = []
        node.create_subscription(Float64, f"{ns}/voltage_cmd", lambda m: self.cmds.append(m.data), COMMAND_QOS)
        self.u = voltage_V
        self.t0_ns = node.get_clock().now().nanoseconds
        self.k = 0
        self.history = []      # (t, d, command)

    def sample(self, ex, spin_until, timeout_s=5.0):
        """Publish the sample at t_k, wait for the command it produces, apply it for 1 ms."""
        n = len(self.cmds)
        d = self.stepper.displacement_m
        t_ns = self.t0_ns + self.k * 1_000_000
        self.pub.publish(make_range(d, t_ns, "dea_laser"))
        ok = spin_until(ex, lambda: len(self.cmds) > n, timeout_s=timeout_s)
        if ok:
            self.u = self.cmds[-1]
        self.history.append((t_ns * 1e-9, d, self.u if ok else np.nan))
        for _ in range(4):
            self.stepper.step(self.u, 2.5e-4)
        self.k += 1
        return ok


def test_setpoints_and_trajectories_drive_the_plant_within_the_amplifier_limits(ros_context, spin_until):
    ns = "/pc_track"
    inv = ModelInverse(load_parameters(TRUTH), U_MAX)
    lo, hi = inv.reachable_range_m
    d_start = lo + 60e-6
    u_start = inv.static_voltage(d_start)
    proc = start_controller(ns, "sensor_timeout_s:=2.0", "publish_stamped_command:=true")
    node = Node("plant", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    try:
        plant = Plant(node, ns, u_start)
        set_pub = node.create_publisher(Float64, f"{ns}/displacement_setpoint", COMMAND_QOS)
        traj_pub = node.create_publisher(JointTrajectory, f"{ns}/joint_trajectory", COMMAND_QOS)
        joints, diags, stamped = [], [], []
        node.create_subscription(JointState, f"{ns}/joint_states", joints.append, 10)
        node.create_subscription(
            BatteryState, f"{ns}/position_controller_node/command_stamped",
            lambda m: stamped.append((m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, m.voltage)), SENSOR_QOS)
        node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
        assert spin_until(ex, lambda: plant.pub.get_subscription_count() > 0 and
                          node.count_publishers(f"{ns}/voltage_cmd") > 0, timeout_s=30.0), H.stderr_of(proc)
        # the node answers the first sample once its subscription matched (best effort may drop early ones)
        assert spin_until(ex, lambda: plant.sample(ex, spin_until, timeout_s=0.2), timeout_s=20.0)
        for _ in range(50):
            assert plant.sample(ex, spin_until)
        target = d_start + 50e-6
        set_pub.publish(Float64(data=target))
        for _ in range(400):
            assert plant.sample(ex, spin_until)
        d_hold = np.array([h[1] for h in plant.history[-100:]])
        assert abs(d_hold.mean() - target) < 1.5e-6           # reached, with another plant than the model
        # a trajectory through points, as a robot sends it (positions only)
        msg = JointTrajectory()
        msg.joint_names = ["dea_joint"]
        for tfs, pos in ((0.1, target - 30e-6), (0.25, target + 20e-6), (0.4, target)):
            pt = JointTrajectoryPoint(positions=[pos])
            pt.time_from_start = Duration(sec=0, nanosec=int(tfs * 1e9))
            msg.points.append(pt)
        traj_pub.publish(msg)
        n_before = len(plant.history)
        for _ in range(450):
            assert plant.sample(ex, spin_until)
        d_traj = np.array([h[1] for h in plant.history[n_before:]])
        assert d_traj.min() < target - 20e-6 and d_traj.max() > target + 12e-6   # it did follow the points
        assert abs(d_traj[-50:].mean() - target) < 1.5e-6
        # refused: unreachable setpoint, wrong joint, too fast a trajectory; the plant keeps its position
        set_pub.publish(Float64(data=lo - 50e-6))
        bad = JointTrajectory(joint_names=["elbow"], points=[JointTrajectoryPoint(positions=[target])])
        bad.points[0].time_from_start = Duration(sec=1)
        traj_pub.publish(bad)
        fast = JointTrajectory(joint_names=["dea_joint"], points=[JointTrajectoryPoint(positions=[lo + 5e-6])])
        fast.points[0].time_from_start = Duration(sec=0, nanosec=5_000_000)
        traj_pub.publish(fast)
        for _ in range(150):
            assert plant.sample(ex, spin_until)
        d_after = np.array([h[1] for h in plant.history[-100:]])
        assert abs(d_after.mean() - target) < 1.5e-6
        assert spin_until(ex, lambda: any("refused" in kv.key and kv.value == "3"
                                          for a in diags for s in a.status for kv in s.values), timeout_s=5.0)
        texts = [kv.value for a in diags for s in a.status for kv in s.values if kv.key == "last_refusal"]
        assert any("joint" in t or "u^2" in t or "reachable" in t for t in texts)
        assert joints and joints[-1].name == ["dea_joint"] and abs(joints[-1].position[0] - target) < 5e-6
    finally:
        stop(proc)
        ex.shutdown()
        node.destroy_node()
    # every command within the amplifier's limits: [0, max], and its slew limit between the samples answered
    cmds = np.array(plant.cmds)
    assert cmds.min() >= 0.0 and cmds.max() <= U_MAX
    assert cmds.max() - cmds.min() > 200.0
    st = np.array(sorted(stamped))            # (sample stamp, command); BatteryState.voltage is float32
    assert len(st) > 0.9 * len(cmds)
    assert np.all(np.abs(np.diff(st[:, 1])) <= SLEW * np.diff(st[:, 0]) + 2e-3)


def test_laser_loss_stops_the_commands_and_the_amplifier_ramps_down(ros_context, spin_until):
    ns = "/pc_loss"
    amp = AmplifierNode(context=ros_context, namespace=ns, parameter_overrides=[
        Parameter("params_file", value="A2"), Parameter("backend", value="inprocess"),
        Parameter("slew_rate_V_per_s", value=SLEW), Parameter("ramp_down_rate_V_per_s", value=20000.0),
        Parameter("watchdog_timeout_s", value=0.2), Parameter("update_rate_hz", value=500.0)])
    amp.trigger_configure()
    amp.trigger_activate()
    proc = start_controller(ns, "sensor_timeout_s:=0.1")
    node = Node("laser", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(amp)
    inv = ModelInverse(load_parameters("A2"), U_MAX)
    d = inv.reachable_range_m[0] + 100e-6
    pub = node.create_publisher(Range, f"{ns}/displacement", SENSOR_QOS)
    cmds, applied, diags = [], [], []
    node.create_subscription(Float64, f"{ns}/voltage_cmd", lambda m: cmds.append((time.monotonic(), m.data)),
                             COMMAND_QOS)
    node.create_subscription(BatteryState, f"{ns}/voltage", applied.append, SENSOR_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    try:
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0, timeout_s=30.0)

        def feed(until, timeout_s=10.0):
            t_end = time.monotonic() + timeout_s
            while time.monotonic() < t_end and not until():
                pub.publish(make_range(d, node.get_clock().now().nanoseconds, "dea_laser"))
                ex.spin_once(timeout_sec=0.002)
            return until()

        assert feed(lambda: len(cmds) > 100 and applied and applied[-1].voltage > 0.5 * inv.static_voltage(d))
        # the laser goes silent: the node reports it, sends nothing more, the amplifier's watchdog ramps to 0 V
        assert spin_until(ex, lambda: any(s.level == DiagnosticStatus.ERROR and "laser lost" in s.message
                                          for a in diags for s in a.status), timeout_s=5.0)
        spin_until(ex, lambda: False, timeout_s=1.0)    # a loaded node may still answer samples it had queued
        n_silent = len(cmds)
        assert spin_until(ex, lambda: applied and applied[-1].voltage == 0.0, timeout_s=3.0)
        spin_until(ex, lambda: False, timeout_s=1.0)
        assert len(cmds) == n_silent
        # samples return: the controller resumes commanding
        n = len(cmds)
        assert feed(lambda: len(cmds) > n + 20)
    finally:
        stop(proc)
        ex.shutdown()
        node.destroy_node()
        amp.destroy_node()


#: the state each transition ends in when it succeeds
_GOAL_STATE = {Transition.TRANSITION_CONFIGURE: State.PRIMARY_STATE_INACTIVE,
               Transition.TRANSITION_ACTIVATE: State.PRIMARY_STATE_ACTIVE,
               Transition.TRANSITION_DEACTIVATE: State.PRIMARY_STATE_INACTIVE}


def _change_state(node, ex, spin_until, ns, transition_id):
    """``ros2 lifecycle set``; a lost service response (DDS may match the response channel after the
    request channel on a loaded machine) is settled by asking the node for its state, as a user would."""
    cli = node.create_client(ChangeState, f"{ns}/position_controller_node/change_state")
    get = node.create_client(GetState, f"{ns}/position_controller_node/get_state")
    assert spin_until(ex, lambda: cli.service_is_ready() and get.service_is_ready(), timeout_s=30.0)
    fut = cli.call_async(ChangeState.Request(transition=Transition(id=transition_id)))
    if spin_until(ex, fut.done, timeout_s=20.0):
        return fut.result().success
    t_end = time.monotonic() + 30.0
    while time.monotonic() < t_end:
        state = get.call_async(GetState.Request())
        if spin_until(ex, state.done, timeout_s=5.0) and state.result().current_state.id < 10:  # not transitioning
            return state.result().current_state.id == _GOAL_STATE[transition_id]
    raise AssertionError(f"{ns}/position_controller_node answers neither change_state nor get_state")


def test_inactive_node_publishes_nothing(ros_context, spin_until):
    ns = "/pc_idle"
    proc = start_controller(ns, autostart=False)
    node = Node("manager", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    got = []
    for topic, typ in (("voltage_cmd", Float64), ("joint_states", JointState)):
        node.create_subscription(typ, f"{ns}/{topic}", lambda m, topic=topic: got.append(topic), COMMAND_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: got.extend("diag" for s in m.status if "position_controller" in s.name), 10)
    pub = node.create_publisher(Range, f"{ns}/displacement", SENSOR_QOS)
    set_pub = node.create_publisher(Float64, f"{ns}/displacement_setpoint", COMMAND_QOS)
    d = ModelInverse(load_parameters("A2"), U_MAX).reachable_range_m[0] + 80e-6

    def feed(seconds):
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            pub.publish(make_range(d, node.get_clock().now().nanoseconds, "dea_laser"))
            set_pub.publish(Float64(data=d + 20e-6))
            ex.spin_once(timeout_sec=0.003)

    try:
        feed(1.0)                                                   # unconfigured
        assert _change_state(node, ex, spin_until, ns, Transition.TRANSITION_CONFIGURE)
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0, timeout_s=10.0)
        feed(1.5)                                                   # inactive
        assert got == []
        assert _change_state(node, ex, spin_until, ns, Transition.TRANSITION_ACTIVATE)
        feed(1.5)                                                   # active: it does talk
        assert {"voltage_cmd", "joint_states", "diag"} <= set(got)
        assert _change_state(node, ex, spin_until, ns, Transition.TRANSITION_DEACTIVATE)
        spin_until(ex, lambda: False, timeout_s=0.5)                # drain what was sent while active
        got.clear()
        feed(1.5)                                                   # inactive again
        assert got == []
    finally:
        stop(proc)
        ex.shutdown()
        node.destroy_node()


def test_bad_params_file_or_limit_fails_configure(ros_context, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\n")
    node = PositionControllerNode(context=ros_context, parameter_overrides=[Parameter("params_file", value=str(bad))])
    node.trigger_configure()
    assert node.ctl is None
    node.destroy_node()
    node = PositionControllerNode(context=ros_context, parameter_overrides=[
        Parameter("params_file", value="A2"), Parameter("max_voltage_V", value=5000.0)])
    node.trigger_configure()
    assert node.ctl is None        # above the membrane limit: refused, as the amplifier does
    node.destroy_node()
    node = PositionControllerNode(context=ros_context, parameter_overrides=[
        Parameter("params_file", value="A2"), Parameter("retune_worker", value="gpu")])
    node.trigger_configure()
    assert node.ctl is None and node.health is None   # where retunes are prepared: process, thread or off
    node.destroy_node()
    node = PositionControllerNode(context=ros_context, parameter_overrides=[
        Parameter("params_file", value="A2"), Parameter("retune_worker", value="thread")])
    node.trigger_configure()
    assert node.health.retune.worker is None and node.health.retune.mode == "thread"
    node.trigger_cleanup()
    node.destroy_node()


def test_config_file_matches_the_declared_parameters():
    """Every key of config/position_controller.yaml is a declared parameter of the same value (no typos)."""
    import rclpy
    import yaml
    from rclpy.context import Context

    data = yaml.safe_load(CONFIG.read_text())
    (key,), section = data.keys(), data["/**/position_controller_node"]["ros__parameters"]
    assert key == "/**/position_controller_node"
    ctx = Context()
    rclpy.init(context=ctx, args=["--ros-args", "--params-file", str(CONFIG)])
    try:
        node = PositionControllerNode(context=ctx)
        node.declare_parameter("autostart", False)
        for name, value in section.items():
            assert node.has_parameter(name), f"position_controller.yaml: '{name}' is not a parameter"
            assert node.get_parameter(name).value == value, name
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


if __name__ == "__main__":   # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
