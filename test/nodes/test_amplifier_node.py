"""amplifier_node safety over real rclpy, with commands from another process (fuzzed, then killed)."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import BatteryState

from dea_ros.hardware.amplifier_backends import MockAmplifierReceiver
from dea_ros.nodes.amplifier_node import AmplifierNode
from dea_ros.nodes.common import SENSOR_QOS

HERE = Path(__file__).parent
SLEW = 20000.0
MAX = 2430.0  # A1: 0.9 x 100 V/um x 27 um


def make_amp(ctx, **extra):
    params = dict(params_file="A1", backend="inprocess", slew_rate_V_per_s=SLEW,
                  ramp_down_rate_V_per_s=10000.0, watchdog_timeout_s=0.2, update_rate_hz=500.0)
    params.update(extra)
    return AmplifierNode(context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])


def check_writes(backend_history_V, applied_msgs):
    """Every value written to the backend is within [0, max]; the stamped stream obeys the slew limit.

    (A dropped best-effort message cannot hide a violation: the bound holds between any two samples.
    BatteryState.voltage is float32, hence the 2e-3 V tolerance.)
    """
    w = np.asarray(backend_history_V)
    assert np.all(np.isfinite(w)) and w.min() >= 0.0 and w.max() <= MAX
    t = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in applied_msgs])
    u = np.array([m.voltage for m in applied_msgs], dtype=float)
    assert u.max() <= MAX + 2e-3
    du, dt = np.abs(np.diff(u)), np.diff(t)
    assert np.all(du <= SLEW * dt + 2e-3), "slew limit violated"
    return t, u


def test_fuzzed_commands_from_a_killed_process(ros_context, spin_until):
    amp = make_amp(ros_context)
    observer = Node("observer", context=ros_context)
    applied = []
    observer.create_subscription(BatteryState, "voltage", applied.append, SENSOR_QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(amp)
    ex.add_node(observer)
    amp.trigger_configure()
    amp.trigger_activate()
    env = dict(os.environ)
    proc = subprocess.Popen([sys.executable, str(HERE / "commander_process.py"), "7", "3.0"],
                            stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "ready"
        t_end = time.monotonic() + 3.0
        while time.monotonic() < t_end:
            ex.spin_once(timeout_sec=0.005)
        peak = max(m.voltage for m in applied)
        assert peak > 500.0  # the fuzzed stream did drive the output
        proc.send_signal(signal.SIGKILL)  # the commanding process dies mid-stream
        proc.wait(timeout=5)
        # watchdog 0.2 s + ramp at 10 kV/s from <= 2430 V: 0 V within ~0.5 s
        assert spin_until(ex, lambda: applied and applied[-1].voltage == 0.0, timeout_s=3.0)
    finally:
        proc.kill()
    rejected = amp.controller.rejected_counts
    assert sum(rejected.values()) > 10 and rejected.get("nan", 0) > 0 and rejected.get("above_max", 0) > 0
    check_writes(amp.backend.history_V, applied)
    ex.shutdown()
    amp.destroy_node()
    observer.destroy_node()


def test_zero_volts_unless_active_and_ramp_on_deactivate(ros_context, spin_until):
    from std_msgs.msg import Float64

    amp = make_amp(ros_context, watchdog_timeout_s=5.0)
    peer = Node("peer", context=ros_context)
    pub = peer.create_publisher(Float64, "voltage_cmd", 10)
    applied = []
    peer.create_subscription(BatteryState, "voltage", applied.append, SENSOR_QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(amp)
    ex.add_node(peer)
    amp.trigger_configure()
    for _ in range(50):  # inactive: commands are rejected, output stays 0 V
        pub.publish(Float64(data=1000.0))
        ex.spin_once(timeout_sec=0.005)
    assert amp.controller.output_V == 0.0 and amp.controller.rejected_counts.get("inactive", 0) > 0
    amp.trigger_activate()
    t_end = time.monotonic() + 0.6
    while time.monotonic() < t_end:
        pub.publish(Float64(data=1500.0))
        ex.spin_once(timeout_sec=0.01)
    assert amp.controller.output_V == pytest.approx(1500.0)
    amp.trigger_deactivate()
    assert spin_until(ex, lambda: amp.controller.output_V == 0.0, timeout_s=2.0)
    t, u = check_writes(amp.backend.history_V, applied)
    assert amp.backend.history_V[-1] == 0.0
    backend = amp.backend
    amp.trigger_cleanup()
    assert not backend.is_open and backend.voltage_V == 0.0
    ex.shutdown()
    amp.destroy_node()
    peer.destroy_node()


def test_configured_max_above_the_membrane_limit_is_refused(ros_context):
    amp = make_amp(ros_context, max_voltage_V=3000.0)  # A1 limit is 2430 V
    amp.trigger_configure()
    assert amp.controller is None and amp.backend is None  # configure failed: no output possible
    amp.destroy_node()


def test_sigterm_ramps_the_output_to_zero():
    """A separate amplifier process at high voltage gets SIGTERM: it ramps to 0 V before exiting."""
    receiver = MockAmplifierReceiver(port=0)
    env = dict(os.environ)
    cmd = [sys.executable, "-m", "dea_ros.nodes.amplifier_node", "--ros-args",
           "-p", "autostart:=true", "-p", "backend:=mock", "-p", f"mock_port:={receiver.port}",
           "-p", "params_file:=A1", "-p", "watchdog_timeout_s:=30.0", "-p", "ramp_down_rate_V_per_s:=5000.0",
           "-r", "voltage_cmd:=/sigterm_test/voltage_cmd"]
    amp = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    commander = subprocess.Popen(
        [sys.executable, "-c",
         "import rclpy,time\nfrom rclpy.node import Node\nfrom std_msgs.msg import Float64\n"
         "rclpy.init(); n=Node('c'); p=n.create_publisher(Float64,'/sigterm_test/voltage_cmd',10)\n"
         "while True:\n    p.publish(Float64(data=2000.0)); time.sleep(0.01)\n"],
        env=env)
    try:
        values = []
        t_end = time.monotonic() + 20.0
        while time.monotonic() < t_end:
            got = receiver.poll_all()
            values += [g.voltage_V for g in got]
            if values and values[-1] == pytest.approx(2000.0):
                break
            time.sleep(0.01)
        assert values and values[-1] == pytest.approx(2000.0), "the amplifier never reached 2 kV"
        commander.kill()
        amp.send_signal(signal.SIGTERM)
        amp.wait(timeout=10)
        time.sleep(0.05)
        values += [g.voltage_V for g in receiver.poll_all()]
        assert values[-1] == 0.0
        tail = np.array(values[values.index(max(values)):])
        assert np.all(np.diff(tail) <= 1e-9)  # a monotone ramp down, no jump up
        assert len(tail) > 10  # a ramp (5 kV/s from 2 kV: 0.4 s), not a single step
    finally:
        commander.kill()
        amp.kill()
        receiver.close()
