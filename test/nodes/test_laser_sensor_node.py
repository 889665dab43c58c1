"""laser_sensor_node over rclpy, reading an ILD1320 emulator on a pty like the real sensor.

The emulator plays a healthy sensor (served by mock_hardware_node), a misbehaving one (bad replies,
a wrong measuring range, a corrupted stream) and one a previous user left mastered; a peer node
judges what reaches the ``displacement`` topic and ``/diagnostics``.
"""
import math
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Range
from std_srvs.srv import Trigger

from dea_ros.hardware.laser.ild1320_protocol import quantum_m
from dea_ros.hardware.laser.plausibility import DEFAULT_JUMP_TOLERANCE_M, DEFAULT_MAX_SPEED_M_PER_S
from dea_ros.model import preset, static_equilibrium
from dea_ros.nodes.common import stamp_to_s
from dea_ros.nodes.laser_sensor_node import LaserSensorNode
from dea_ros.nodes.mock_hardware_node import MockHardwareNode
from fakes import load_fake

ILD1320Emulator = load_fake("faulty_ild1320").FaultyILD1320Emulator  # the emulator with fault injection (test/fakes)

P = Parameter
Q = quantum_m(0.010)
#: The peer keeps every sample even when the shared executor falls behind (the node's publisher is
#: best effort; a shallow subscriber queue would lose messages on a loaded machine, not the node).
DEEP_QOS = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST, depth=10000)


def spin_for(ex, seconds):
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.002)


def spin_until_count(ex, messages, n, timeout_s=20.0):
    """Spin until ``messages`` holds more than ``n`` (the executor drains a backlog slowly under load)."""
    t_end = time.monotonic() + timeout_s
    while len(messages) <= n and time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.01)
    return len(messages) > n


def drain(ex, messages, producers):
    """Pause the publishing nodes and spin until the peer has taken every queued message.

    On a loaded machine a shared single-threaded executor takes 2 kHz messages more slowly than
    they come; the subscriber's deep queue keeps them until then.
    """
    for node in producers:
        ex.remove_node(node)
    while True:
        before = len(messages)
        spin_for(ex, 0.5)
        if len(messages) == before:
            break
    for node in producers:
        ex.add_node(node)


def wait_matched(ex, laser, timeout_s=15.0):
    """Spin until the peer's subscriptions are discovered (slow on a loaded machine): then count."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if laser.pub.get_subscription_count() > 0 and laser.diag_pub.get_subscription_count() > 0:
            return
        ex.spin_once(timeout_sec=0.01)
    raise AssertionError("the peer's subscriptions were not discovered")


class Peer:
    """Another node on the graph: collects displacement messages and the laser's diagnostics."""

    def __init__(self, ctx):
        self.node = Node("peer", context=ctx)
        self.ranges = []
        self.statuses = []
        self.implausible = []
        self.node.create_subscription(Range, "displacement", self.ranges.append, DEEP_QOS)
        self.node.create_subscription(Range, "displacement_implausible", self.implausible.append, DEEP_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)

    def _on_diag(self, msg):
        self.statuses += [s for s in msg.status if "laser_sensor_node" in s.name]

    def last_values(self) -> dict:
        return {kv.key: kv.value for kv in self.statuses[-1].values}


@pytest.fixture
def rig(ros_context, tmp_path):
    """(executor, peer, start_emulator, make_node): nodes and emulators are cleaned up afterwards."""
    ex = SingleThreadedExecutor(context=ros_context)
    peer = Peer(ros_context)
    ex.add_node(peer.node)
    emulators, nodes = [], []
    link = str(tmp_path / "laser")

    def start_emulator(source, **kwargs):
        emu = ILD1320Emulator(source, symlink=link, **kwargs).start()
        emulators.append(emu)
        return emu

    def make_node(**params):
        values = {"port": link, "zero_offset_m": -1.0, "measuring_rate_hz": 2000.0, **params}
        node = LaserSensorNode(context=ros_context, parameter_overrides=[P(k, value=v) for k, v in values.items()])
        nodes.append(node)
        ex.add_node(node)
        return node

    yield ex, peer, start_emulator, make_node
    ex.shutdown()
    for node in nodes:
        node.shutdown_safely()
        node.destroy_node()
    peer.node.destroy_node()
    for emu in emulators:
        emu.stop()
        assert emu.thread_error is None


def test_serial_path_delivers_the_mock_membrane_at_2kHz(ros_context, spin_until, tmp_path):
    link = str(tmp_path / "laser")
    mock = MockHardwareNode(context=ros_context, parameter_overrides=[
        P("params_file", value="A2"), P("laser_output", value="emulator"), P("laser_port", value=link),
        P("amplifier_port", value=0), P("noise_m", value=0.5e-6), P("laser_standoff_m", value=2e-3)])
    laser = LaserSensorNode(context=ros_context, parameter_overrides=[
        P("port", value=link), P("zero_offset_m", value=2e-3), P("measuring_rate_hz", value=2000.0)])
    peer = Node("peer", context=ros_context)
    got = []
    peer.create_subscription(Range, "displacement", got.append, DEEP_QOS)
    peer.create_subscription(DiagnosticArray, "/diagnostics", lambda msg: None, 10)
    ex = SingleThreadedExecutor(context=ros_context)
    for n in (mock, laser, peer):
        ex.add_node(n)
    wait_matched(ex, laser)
    published_before_match = laser.published  # these may have gone out before the match
    spin_for(ex, 0.1)
    t0 = peer.get_clock().now().nanoseconds * 1e-9
    spin_for(ex, 2.0)
    t1 = peer.get_clock().now().nanoseconds * 1e-9
    assert laser.connected
    # judge the samples acquired in [t0, t1] by their stamps, all of them taken
    drain(ex, got, (laser, mock))
    window = [m for m in got if t0 <= stamp_to_s(m.header.stamp) <= t1 and math.isfinite(m.range)]
    # the published messages reach the subscriber (the real-time rate is measured in bench/, a loaded
    # test machine cannot promise it; here only that the stream flows). Best effort (the sensor QoS)
    # may drop what a full receive buffer cannot take while the shared executor is descheduled: CI of
    # session 10 at load ~8 lost 118 of ~4,000 after the match; at most 5 % is transport, not the node
    lost = laser.published - len(got)
    assert lost <= published_before_match + 0.05 * laser.published, (lost, laser.published)
    n = len(window)
    assert n > 2000 * 0.5, f"only {n} samples in 2 s at 2 kHz ({laser.published} published)"
    t = np.array([stamp_to_s(m.header.stamp) for m in window])
    d = np.array([m.range for m in window])
    assert np.all(np.diff(t) > 0)
    assert abs(np.median(np.diff(t)) - 0.5e-3) < 0.02e-3
    rest = static_equilibrium(preset("A2"), 0.0).displacement_m
    # quantisation of the 10 mm head (~38 nm) and 0.5 um noise around the static equilibrium
    assert abs(np.mean(d) - rest) < 0.2e-6
    assert 0.3e-6 < np.std(d) < 0.8e-6
    # a clean stream: only a handful discarded (the first samples await confirmation; a loaded
    # machine may overflow the pty, a framing error), never a sample judged implausible
    assert set(laser.error_counts) <= {"unconfirmed", "after_framing_error"}, laser.error_counts
    assert sum(laser.error_counts.values()) <= max(10, 0.002 * laser.published)
    # tare service: zero on the current position
    client = peer.create_client(Trigger, "/laser_sensor_node/tare")
    assert spin_until(ex, client.service_is_ready)
    fut = client.call_async(Trigger.Request())
    assert spin_until(ex, fut.done)
    assert fut.result().success
    # judge the newest 500 messages once 2000 more were published: all of them after the tare (a
    # subscriber queue that overflows on a loaded machine drops the oldest ones)
    published_at_tare = laser.published
    assert spin_until(ex, lambda: laser.published > published_at_tare + 2000, 60.0)
    drain(ex, got, (laser, mock))
    after = [m.range for m in got[-500:] if math.isfinite(m.range)]
    assert abs(np.mean(after)) < 1e-6
    assert abs(np.mean(after) + laser.sensor.tare_offset_m - 2e-3 - rest) < 0.5e-6
    # a reconnect keeps the tare made by the service (zero_offset_m applies at the first connect)
    offset = laser.sensor.tare_offset_m
    laser.sensor.close()
    laser.connected = False
    laser.reconnect_at = 0.0
    assert spin_until(ex, lambda: laser.connected)
    assert laser.sensor.tare_offset_m == offset
    ex.shutdown()
    for node in (laser, mock, peer):
        node.destroy_node()


def test_node_survives_bad_replies_and_streams_once_the_sensor_behaves(rig, spin_until):
    ex, peer, start_emulator, make_node = rig
    emu = start_emulator(lambda t: 0.004)
    emu.misbehave(reported_rate_khz="0")  # MEASRATE 0: once a ZeroDivisionError in the constructor
    node = make_node()
    assert not node.connected and "rate" in node.last_error
    emu.misbehave(reported_rate_khz=None, reply_overrides={"GETINFO": b"\xff\x80\x00garbage\r\n->"})
    wait_matched(ex, node)
    node.reconnect_at = 0.0
    assert spin_until(ex, lambda: node.connect_failures >= 2 and peer.statuses, 20.0)
    assert not node.connected and peer.ranges == []
    assert peer.statuses[-1].level == DiagnosticStatus.ERROR
    assert peer.last_values()["published"] == "0"
    emu.misbehave(reply_overrides=None)
    assert spin_until_count(ex, peer.ranges, 200)  # reconnects within the back-off (<= 5 s)
    assert node.connected
    assert max(abs(m.range - 0.004) for m in peer.ranges if math.isfinite(m.range)) <= 0.5 * Q + 1e-12
    # only the first samples of a connect wait for confirmation (published as NaN: invalid); a frame right
    # after a framing error (a partial frame when the stream restarts, under load) is flagged and restarts
    # the confirmation: at most 3 NaN per chain start
    chain_starts = node.disconnects + 1 + node.error_counts.get("after_framing_error", 0)
    assert sum(math.isnan(m.range) for m in peer.ranges) <= 3 * chain_starts, node.error_counts
    assert set(node.error_counts) <= {"unconfirmed", "after_framing_error"}, node.error_counts


def test_node_refuses_a_sensor_that_differs_from_its_parameters(rig, spin_until):
    ex, peer, start_emulator, make_node = rig
    emu = start_emulator(lambda t: 0.004)
    emu.misbehave(reported_range_mm=1000.0)  # once: every reading scaled x100 and reported valid
    node = make_node(measuring_range_m=0.01)
    wait_matched(ex, node)
    assert spin_until(ex, lambda: peer.statuses, 20.0)
    spin_for(ex, 0.2)
    assert not node.connected and node.mismatch
    assert "1000 mm" in node.last_error and "measuring_range_m" in node.last_error
    assert peer.ranges == [] and node.published == 0
    assert peer.statuses[-1].level == DiagnosticStatus.ERROR
    assert peer.statuses[-1].message.startswith("refused:") and "measuring_range_m" in peer.statuses[-1].message
    found = peer.last_values()
    assert found["sensor_model"] == "ILD1320-10" and found["sensor_measuring_range_mm"] == "1000"
    assert "1000 mm" in found["mismatch_0"] or "1000 mm" in found["mismatch_1"]
    # a rate the ILD1320 does not have is refused at start-up, naming the parameter
    with pytest.raises(SystemExit, match="measuring_rate_hz"):
        make_node(measuring_rate_hz=700.0)


def test_node_resets_a_mastered_sensor_and_publishes_the_truth(rig):
    ex, peer, start_emulator, make_node = rig
    # a previous user zeroed the sensor with the target at 3 mm, added a counter and held errors
    emu = start_emulator(lambda t: 0.004, mastering=(0.003, 0.0), additional_outputs=("COUNTER",),
                         output_hold="0", measuring_rate_hz=500.0)
    node = make_node()
    assert node.connected, node.last_error
    wait_matched(ex, node)
    assert emu.mastering is None and emu.additional_outputs == () and emu.output_hold == "NONE"
    assert emu.measuring_rate_hz == 2000.0
    assert len(node.sensor.connect_report.to_reset) == 4  # rate, additional outputs, hold, mastering
    skipped_at_connect = node.sensor.decoder.additional_values_skipped
    # read as mastered, the 4 mm target would be 6 mm (4 - 3 + 5); reset: the truth
    assert spin_until_count(ex, peer.ranges, 200)
    assert max(abs(m.range - 0.004) for m in peer.ranges if math.isfinite(m.range)) <= 0.5 * Q + 1e-12
    # only the first samples of a connect wait for confirmation (published as NaN: invalid); a frame right
    # after a framing error (a partial frame when the stream restarts, under load) is flagged and restarts
    # the confirmation: at most 3 NaN per chain start
    chain_starts = node.disconnects + 1 + node.error_counts.get("after_framing_error", 0)
    assert sum(math.isnan(m.range) for m in peer.ranges) <= 3 * chain_starts, node.error_counts
    assert set(node.error_counts) <= {"unconfirmed", "after_framing_error"}, node.error_counts
    assert node.sensor.decoder.additional_values_skipped == skipped_at_connect  # no counter values any more


def test_node_diagnostics_count_discarded_samples_and_publish_only_plausible_values(rig):
    ex, peer, start_emulator, make_node = rig

    def truth(t):
        return 0.004 + 0.0005 * math.sin(2.0 * math.pi * 2.0 * t)

    emu = start_emulator(truth, seed=5)
    node = make_node(params_file="A2")  # limits from the model (config/laser_sensor.yaml)
    assert node.connected, node.last_error
    assert node.max_acceleration_m_per_s2 is not None and node.max_speed_m_per_s < DEFAULT_MAX_SPEED_M_PER_S
    wait_matched(ex, node)
    spin_for(ex, 0.1)
    emu.misbehave(random_byte_probability=0.01, drop_byte_probability=0.01)
    for _ in range(4):
        emu.inject_garbage(400, raw=True)
        spin_for(ex, 0.05)
    spin_for(ex, 1.3)  # at least one diagnostics period with the corruption
    n_diag = len(peer.statuses)
    assert spin_until_count(ex, peer.statuses, n_diag)  # a report published after the corruption
    emu.misbehave(random_byte_probability=None, drop_byte_probability=None)
    assert spin_until_count(ex, peer.ranges, 500), (node.last_error, node.published, len(peer.ranges))
    drain(ex, peer.ranges, [node])
    # every finite value is within the speed-limit allowance of the true signal's span; the flagged
    # ones are NaN (REP 117 invalid), each with its decoded value on displacement_implausible
    allowance = node.max_speed_m_per_s * 2e-3 + DEFAULT_JUMP_TOLERANCE_M
    values = [m.range for m in peer.ranges if math.isfinite(m.range)]
    assert 0.0035 - allowance <= min(values) and max(values) <= 0.0045 + allowance
    flagged = [m for m in peer.ranges if math.isnan(m.range)]
    assert len(flagged) > 10 and len(peer.implausible) == len(flagged) == node.implausible
    assert [stamp_to_s(m.header.stamp) for m in flagged] == [stamp_to_s(m.header.stamp) for m in peer.implausible]
    assert all(math.isfinite(m.range) for m in peer.implausible)
    values = peer.last_values()
    assert int(values["implausible"]) > 0
    assert int(values["errors_after_framing_error"]) > 10
    assert int(values["bytes_discarded"]) > 1000 and int(values["partial_frames_dropped"]) > 0
    assert int(values["published"]) > 500
    assert "invalid_bytes" not in values and "resyncs" not in values  # no invented counters
