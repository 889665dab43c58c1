"""amplifier_node over real rclpy, in process: commands from another process (fuzzed, then killed),
lifecycle, start-up configuration slips, exceptions in callbacks, the uldaq backend on a fake board
with the amplifier monitor and the enable line, and the mock amplifier's dead-man.

Attacks from other processes on the node process (parameters, lifecycle, /clock, signals, fuzzing)
are in test_amplifier_attacks.py."""
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import BatteryState

from dea_ros.nodes.amplifier_node import AmplifierNode
from dea_ros.nodes.common import SENSOR_QOS
from fakes import load_fake

HERE = Path(__file__).parent
SLEW = 20000.0
MAX = 2430.0  # A1: 0.9 x 100 V/um x 27 um


def reactivation_refused(amp) -> bool:
    """A latched fault leaves the node in 'active' with 0 V; deactivate + activate must then fail.

    (Activating straight from 'active' is not a registered transition: Humble/Jazzy rclpy raise RCLError
    there while newer rclpy returns an error code, so the test goes through 'inactive' as a user would.)
    """
    assert amp.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
    return amp.trigger_activate() == TransitionCallbackReturn.FAILURE


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
    t_ns = np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in applied_msgs])
    t = t_ns * 1e-9
    u = np.array([m.voltage for m in applied_msgs], dtype=float)
    assert u.max() <= MAX + 2e-3
    du, dt = np.abs(np.diff(u)), np.diff(t_ns) * 1e-9
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
        # the fuzzed stream drives the output (the stream lasts 3 s from the match)
        assert spin_until(ex, lambda: applied and max(m.voltage for m in applied) > 500.0, timeout_s=10.0)
        spin_until(ex, lambda: False, timeout_s=1.0)
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


@pytest.mark.parametrize(
    "params, file_changes, message",
    [
        (dict(params_file="FILE"), dict(name="thick A1", thickness_m=2.7e-4),  # A1 thickness x10: 24.3 kV
         r"ceiling 24300.0 V .*rated output.*thickness or breakdown-field slip"),
        (dict(params_file="FILE"), dict(breakdown_field_V_per_m=8e8), r"breakdown_field_V_per_m.*8e7"),
        (dict(params_file="FILE"), dict(breakdown_field_V_per_m=None), r"breakdown_field_V_per_m.*never defaulted"),
        (dict(margin=1.0), None, r"margin.*strictly below 1"),
        (dict(ramp_down_rate_V_per_s=1.0, watchdog_timeout_s=1.0), None, r"ramp_down_rate_V_per_s.*reach 0 V"),
        (dict(watchdog_timeout_s=60.0), None, r"watchdog_timeout_s.*lower watchdog_timeout_s"),
        (dict(amplifier_gain_V_per_V=100.0), None, r"amplifier_gain_V_per_V = 100 V/V.*gain slip"),
        (dict(max_voltage_V=30000.0), None, r"max_voltage_V.*membrane limit"),
        (dict(use_sim_time=True), None, r"use_sim_time.*only with the mock backend"),
        (dict(backend="trek"), None, r"backend.*'trek'"),
        (dict(slew_rate_V_per_s=1e9), None, r"slew_rate_V_per_s"),
    ],
)
def test_configuration_slips_are_refused_at_start_up(ros_context, tmp_path, params, file_changes, message):
    """The reproductions of issue 9: each slip used to give a higher voltage; now configure fails, the
    node never opens the backend, and the message names the field and the likely slip."""
    import yaml

    from dea_ros.model import preset

    if file_changes is not None:
        data = preset("A1").to_dict()
        data.update({k: v for k, v in file_changes.items() if v is not None})
        for key in [k for k, v in file_changes.items() if v is None]:
            del data[key]
        path = tmp_path / "membrane.yaml"
        path.write_text(yaml.safe_dump(data))
        params = dict(params, params_file=str(path))
    amp = make_amp(ros_context, **params)
    assert amp.trigger_configure() == TransitionCallbackReturn.FAILURE
    assert amp.backend is None and amp.controller is None and amp.ceiling_V == 0.0
    assert re.search(message, amp.startup_error), amp.startup_error
    assert amp.get_parameter("enforced_max_voltage_V").value == 0.0
    amp.destroy_node()


def test_parameters_are_read_only_and_report_what_is_enforced(ros_context):
    amp = make_amp(ros_context)
    amp.trigger_configure()
    assert amp.get_parameter("enforced_max_voltage_V").value == pytest.approx(MAX)
    for name, value in [("max_voltage_V", 30000.0), ("margin", 1.0), ("use_sim_time", True),
                        ("enforced_max_voltage_V", 30000.0), ("params_file", "LP1")]:
        result = amp.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful and (name in result.reason or "read-only" in result.reason), result.reason
    assert amp.get_parameter("max_voltage_V").value == 0.0 and not amp.get_parameter("use_sim_time").value
    amp.trigger_cleanup()
    amp.destroy_node()


def test_exception_in_a_callback_is_a_latched_fault_that_ramps_to_zero(ros_context, spin_until):
    from std_msgs.msg import Float64

    amp = make_amp(ros_context, watchdog_timeout_s=2.0)
    peer = Node("peer", context=ros_context)
    pub = peer.create_publisher(Float64, "voltage_cmd", 10)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(amp)
    ex.add_node(peer)
    amp.trigger_configure()
    amp.trigger_activate()
    assert spin_until(ex, lambda: pub.publish(Float64(data=2000.0)) or amp.controller.output_V == 2000.0, 5.0)
    backend = amp.backend

    def broken(*_args):
        raise RuntimeError("a bug in a callback")

    amp.controller.command = broken
    pub.publish(Float64(data=1000.0))
    assert spin_until(ex, lambda: amp.fault_reason is not None, 5.0)
    assert "RuntimeError: a bug in a callback" in amp.fault_reason
    history = backend.history_V
    assert history[-1] == 0.0 and not backend.is_open
    tail = np.array(history[history.index(2000.0):])
    assert np.all(np.diff(tail) <= 0.0) and len(tail) > 10  # a ramp, not a jump
    assert reactivation_refused(amp)  # latched
    ex.shutdown()
    amp.destroy_node()
    peer.destroy_node()


def test_mock_amplifier_drops_to_zero_when_the_datagrams_stop(ros_context, spin_until):
    """The simulated amplifier's own interlock: a dead controller leaves 0 V, not its last value."""
    from dea_ros.hardware.amplifier.udp import MockAmplifierBackend
    from dea_ros.nodes.mock_hardware_node import MockHardwareNode

    mock = MockHardwareNode(context=ros_context, parameter_overrides=[
        Parameter("amplifier_port", value=0), Parameter("laser_output", value="topic"),
        Parameter("amplifier_deadman_s", value=0.2)])
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(mock)
    sender = MockAmplifierBackend(mock.receiver.port, max_voltage_V=3000.0)
    sender.open()

    def send_and_check():
        sender.write_voltage(2000.0)
        return mock.sim.voltage_V == 2000.0

    assert spin_until(ex, send_and_check, 5.0)
    sender._close_socket()  # dies without a word (no 0 V on close): SIGKILL
    assert spin_until(ex, lambda: mock.sim.voltage_V == 0.0, 5.0)
    assert mock.receiver.deadman_trip_count == 1
    ex.shutdown()
    mock.destroy_node()


# ---------------------------------------------------------------------------- uldaq on a fake board


@pytest.fixture
def board(monkeypatch):
    fake = load_fake("fake_uldaq")
    ul, rig = fake.make("USB-1208HS-4AO")
    monkeypatch.setitem(sys.modules, "uldaq", ul)
    rig.monitor_wiring = (ul.AiInputMode.SINGLE_ENDED, 2)
    rig.enable_wiring = (ul.DigitalPortType.AUXPORT, 5)
    return rig


def make_uldaq_amp(ctx, **extra):
    extra.setdefault("monitor_gain_V_per_V", 1000.0)
    return make_amp(ctx, backend="uldaq", monitor_channel=2, enable_port="AUXPORT", enable_bit=5, **extra)


def test_uldaq_node_follows_commands_with_monitor_and_enable(ros_context, board, spin_until):
    from std_msgs.msg import Float64

    amp = make_uldaq_amp(ros_context, watchdog_timeout_s=1.0)
    peer = Node("peer", context=ros_context)
    pub = peer.create_publisher(Float64, "voltage_cmd", 10)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(amp)
    ex.add_node(peer)
    assert amp.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert amp.backend.ao_range == "BIP10VOLTS" and not board.amplifier_enabled
    amp.trigger_activate()
    assert spin_until(ex, lambda: pub.publish(Float64(data=1500.0)) or amp.controller.output_V == 1500.0, 5.0)
    assert board.amplifier_enabled and board.amplifier_output_V == pytest.approx(1500.0)
    assert amp.monitor_V == pytest.approx(1500.0) and amp.fault_reason is None
    amp.trigger_deactivate()
    assert spin_until(ex, lambda: amp.controller.output_V == 0.0 and not amp.output_enabled, 5.0)
    assert not board.amplifier_enabled
    amp.trigger_cleanup()
    assert max(board.a_out_values()) <= MAX / 1000.0
    ex.shutdown()
    amp.destroy_node()
    peer.destroy_node()


@pytest.mark.parametrize("failure", ["gain", "lost", "saturated"])
def test_monitor_mismatch_or_loss_is_a_fault_that_disables_the_output(ros_context, board, spin_until, failure):
    """A 1000 V/V amplifier configured but a x10 one wired (or the monitor lost): the first update
    that disagrees drives 0 V and drops the enable line."""
    from std_msgs.msg import Float64

    amp = make_uldaq_amp(ros_context, watchdog_timeout_s=1.0)
    peer = Node("peer", context=ros_context)
    pub = peer.create_publisher(Float64, "voltage_cmd", 10)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(amp)
    ex.add_node(peer)
    assert amp.trigger_configure() == TransitionCallbackReturn.SUCCESS
    amp.trigger_activate()
    assert spin_until(ex, lambda: pub.publish(Float64(data=500.0)) or amp.controller.output_V == 500.0, 5.0)
    if failure == "gain":
        board.real_gain_V_per_V = 10000.0
    elif failure == "lost":
        board.monitor_override = board.uldaq.ULException(board.uldaq.ULError.DEAD_DEV)
    else:
        board.monitor_override = 0.0  # a broken monitor wire reads 0 V
    assert spin_until(ex, lambda: pub.publish(Float64(data=1000.0)) or amp.fault_reason is not None, 5.0)
    assert "monitor" in amp.fault_reason
    assert not board.amplifier_enabled and board.ao_values[0] == 0.0 and board.amplifier_output_V == 0.0
    assert reactivation_refused(amp)  # latched until cleanup + configure
    ex.shutdown()
    amp.destroy_node()
    peer.destroy_node()


def test_uldaq_configure_refuses_a_board_without_a_covering_range(ros_context, board):
    board.set_board("USB-1208FS-Plus")  # UNI5VOLTS only
    amp = make_amp(ros_context, backend="uldaq", params_file="A2", max_voltage_V=0.0, amplifier_gain_V_per_V=500.0,
                   amplifier_max_output_V=5000.0, amplifier_input_full_scale_V=10.0)
    assert amp.trigger_configure() == TransitionCallbackReturn.FAILURE  # 3150 V / 500 = 6.3 V > 5 V
    assert amp.backend is None and board.a_out_values() == []
    amp.destroy_node()
