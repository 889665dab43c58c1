"""identifier_node over real rclpy with a fake rig peer: pre-flight checks, abort, recording, replay, SIGKILL."""
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import BatteryState, Range
from std_msgs.msg import Float64, String
from std_srvs.srv import Trigger

from dea_ros.bag import BagReader, recover_bag
from dea_ros.bag.mcap_scan import scan_mcap
from dea_ros.identify.bag_experiments import EXPERIMENT_METADATA
from dea_ros.nodes.common import COMMAND_QOS, SENSOR_QOS, make_range, make_voltage_state
from dea_ros.nodes.identifier_node import IdentifierNode

HERE = Path(__file__).parent


class FakeRig(Node):
    """Applies voltage_cmd instantly and 'measures' a displacement proportional to it."""

    def __init__(self, context):
        super().__init__("fake_rig", context=context)
        self.u = 0.0
        self.commands = []
        self.ticks = 0
        self.create_subscription(Float64, "voltage_cmd", self.on_cmd, COMMAND_QOS)
        self.v_pub = self.create_publisher(BatteryState, "voltage", SENSOR_QOS)
        self.d_pub = self.create_publisher(Range, "displacement", SENSOR_QOS)
        self.create_timer(0.002, self.tick)

    def on_cmd(self, msg):
        self.u = msg.data
        self.commands.append(msg.data)

    def tick(self):
        self.ticks += 1
        t = self.get_clock().now().nanoseconds
        self.v_pub.publish(make_voltage_state(self.u, t, True))
        self.d_pub.publish(make_range(7e-4 + 1e-7 * self.u, t, "laser"))


def make_identifier(ctx, tmp_path, **extra):
    params = dict(protocol="quick", output_dir=str(tmp_path), run_name="run", identify=False,
                  command_rate_hz=200.0, wait_for_rig_s=5.0)
    params.update(extra)
    return IdentifierNode(context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])


def test_unwritable_output_fails_before_any_voltage(ros_context, spin_until):
    rig = FakeRig(ros_context)
    node = make_identifier(ros_context, Path("/proc/dea_ros_cannot_write_here"))
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(rig)
    ex.add_node(node)
    spin_until(ex, lambda: False, timeout_s=1.0)
    assert node.state == "error" and "no voltage was applied" in node.error
    assert all(u == 0.0 for u in rig.commands)
    ex.shutdown()
    node.destroy_node()
    rig.destroy_node()


def test_abort_keeps_the_recording_and_commands_zero(ros_context, spin_until, tmp_path):
    rig = FakeRig(ros_context)
    node = make_identifier(ros_context, tmp_path)
    peer = Node("operator", context=ros_context)
    abort = peer.create_client(Trigger, "/identifier_node/abort")
    ex = SingleThreadedExecutor(context=ros_context)
    for n in (rig, node, peer):
        ex.add_node(n)
    assert spin_until(ex, lambda: node.state == "running", timeout_s=10.0)
    # the staircase is under way: the 2 kV level reaches the rig (after the protocol's 10 s at 0 V)
    assert spin_until(ex, lambda: rig.commands and max(rig.commands) > 1000.0, timeout_s=40.0)
    # enough recorded to count (in wall time: a loaded machine runs the timers slower)
    assert spin_until(ex, lambda: rig.ticks > 700 and len(rig.commands) > 150, timeout_s=60.0)
    fut = abort.call_async(Trigger.Request())
    assert spin_until(ex, fut.done)
    assert fut.result().success
    spin_until(ex, lambda: False, timeout_s=0.3)
    assert rig.commands[-1] == 0.0
    assert node.state == "done" and "aborted" in node.error
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    with BagReader(summary["bag"]) as bag:
        meta = bag.metadata()[EXPERIMENT_METADATA]
        assert meta["aborted"] == "true"
        counts = {k: v.message_count for k, v in bag.topics().items()}
    assert counts["/voltage_cmd"] > 100 and counts["/displacement"] > 500 and counts["/voltage"] > 500
    ex.shutdown()
    for n in (rig, node, peer):
        n.destroy_node()


def test_replay_republishes_with_the_original_timing(ros_context, spin_until, tmp_path):
    from dea_ros.bag import BagWriter

    bag_dir = tmp_path / "replay_bag"
    t0 = 1_700_000_000_000_000_000
    with BagWriter(bag_dir) as bag:
        bag.add_topic("/replay_test/cmd", "std_msgs/msg/Float64")
        for k in range(100):
            bag.write("/replay_test/cmd", {"data": float(k)}, t0 + k * 10_000_000)  # 100 Hz for 1 s
    peer = Node("listener", context=ros_context)
    got = []
    peer.create_subscription(Float64, "/replay_test/cmd", lambda m: got.append((time.monotonic(), m.data)), 10)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(peer)
    # --loop: if discovery is slow the first loop may be cut; judge the first complete 0..99 cycle
    proc = subprocess.Popen([sys.executable, "-m", "dea_ros.cli", "replay", str(bag_dir), "--rate", "2",
                             "--loop"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def full_cycle():
        values = [v for _, v in got]
        for i, v in enumerate(values):
            if v == 0.0 and values[i:i + 100] == [float(k) for k in range(100)]:
                return got[i:i + 100]
        return None

    try:
        assert spin_until(ex, lambda: full_cycle() is not None, timeout_s=30.0)
    finally:
        proc.kill()
        proc.wait(timeout=10)
    cycle = full_cycle()
    duration = cycle[-1][0] - cycle[0][0]
    assert 0.4 < duration < 0.7  # 0.99 s recorded, replayed at rate 2
    ex.shutdown()
    peer.destroy_node()


def test_sigkill_of_the_recorder_loses_at_most_a_second(tmp_path):
    """identifier_node (own process) records a fake rig; SIGKILL; the bag is recovered and readable."""
    env = dict(os.environ)
    rig = subprocess.Popen([sys.executable, "-c", (
        "import rclpy\nfrom rclpy.context import Context\nimport sys\nsys.path.insert(0, %r)\n"
        "from test_identifier_node import FakeRig\nrclpy.init()\nn = FakeRig(None)\nrclpy.spin(n)\n") % str(HERE)],
        env=env)
    ident = subprocess.Popen([sys.executable, "-m", "dea_ros.nodes.identifier_node", "--ros-args",
                              "-p", "protocol:=quick", "-p", f"output_dir:={tmp_path}", "-p", "run_name:=killed",
                              "-p", "identify:=false", "-p", "command_rate_hz:=200.0"], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        t_end = time.monotonic() + 30
        started = False
        for line in ident.stdout:
            if "protocol started" in line:
                started = True
                break
            if time.monotonic() > t_end:
                break
        assert started
        time.sleep(3.0)
        t_kill = time.time()
        ident.send_signal(signal.SIGKILL)
        ident.wait(timeout=10)
    finally:
        ident.kill()
        rig.kill()
    bag_dir = tmp_path / "killed" / "bag"
    recover_bag(bag_dir)
    with BagReader(bag_dir) as bag:
        last = max(m.log_time_ns for m in bag.raw_messages(["/displacement"]))
        assert EXPERIMENT_METADATA in bag.metadata()
    assert t_kill - last * 1e-9 < 1.0 + 0.5  # flushed every 0.5 s (+ scheduling slack)


@pytest.mark.skipif(not hasattr(__import__("resource"), "prlimit"), reason="needs Linux prlimit")
def test_disk_full_while_recording_commands_0V_reports_and_keeps_the_bag(ros_context, spin_until, tmp_path):
    """The recorder's disk fills up in the middle of the 2 kV level (attack from this process).

    identifier_node runs in its own process; this process is the rig (it receives voltage_cmd)
    and an operator watching ~/status. When the 2 kV level reaches the rig, the node's file size
    limit is lowered to just above its bag's size (prlimit from outside: the next chunk write fails
    with EFBIG, as on a full disk). Expected: 0 V at once, the protocol never reaches its next
    level, status 'error' naming the cause, exit code 1 without a traceback, and the bag holds
    the recording up to the fault and reads back with every reader.
    """
    import resource

    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    from dea_ros.nodes.common import LATCHED_QOS

    rig = FakeRig(ros_context)
    operator = Node("operator", context=ros_context)
    statuses = []
    operator.create_subscription(String, "/identifier_node/status",
                                 lambda m: statuses.append(json.loads(m.data)), LATCHED_QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(rig)
    ex.add_node(operator)
    log = open(tmp_path / "identifier.log", "w+")  # noqa: SIM115 - closed below
    ident = subprocess.Popen(
        [sys.executable, "-m", "dea_ros.nodes.identifier_node", "--ros-args", "-p", "protocol:=quick",
         "-p", f"output_dir:={tmp_path}", "-p", "run_name:=full", "-p", "identify:=false",
         "-p", "command_rate_hz:=200.0", "-p", "min_free_mb:=1.0"],
        stdout=log, stderr=subprocess.STDOUT, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGXFSZ, signal.SIG_IGN))  # EFBIG, not death
    mcap = tmp_path / "full" / "bag" / "bag_0.mcap"
    try:
        assert spin_until(ex, lambda: rig.commands and max(rig.commands) > 1000.0, timeout_s=60.0), \
            "the protocol did not reach 2 kV"
        level = max(rig.commands)  # the 2 kV level of the staircase (the next one is 2250 V)
        n_before = len(rig.commands)
        limit = mcap.stat().st_size + 8192
        resource.prlimit(ident.pid, resource.RLIMIT_FSIZE, (limit, limit))
        assert spin_until(ex, lambda: ident.poll() is not None, timeout_s=60.0), "the node did not exit"
        spin_until(ex, lambda: False, timeout_s=0.5)  # last datagrams
    finally:
        if ident.poll() is None:
            ident.kill()
        ident.wait(timeout=10)
        ex.shutdown()
        rig.destroy_node()
        operator.destroy_node()
    log.seek(0)
    output = log.read()
    log.close()
    assert ident.returncode == 1, output
    assert "Traceback" not in output
    # what reached the amplifier: 0 V at once; the protocol never went on to its next level
    after = rig.commands[n_before:]
    assert after and after[-1] == 0.0
    assert max(after) <= level
    first_zero = after.index(0.0)
    assert all(u == 0.0 for u in after[first_zero:])
    # the operator sees the fault, not 'running'
    assert statuses and statuses[-1]["state"] == "error", statuses[-3:]
    assert "File too large" in statuses[-1]["error"] and "0 V was commanded" in statuses[-1]["error"]
    summary = json.loads((tmp_path / "full" / "summary.json").read_text())
    assert summary["state"] == "error"
    finished_in_place = "messages written before the fault are kept" in summary["error"]
    if not finished_in_place:
        # the documented fallback (bag/mcap_finish.py): the file is cut back to its valid prefix and the
        # note says to run recover once there is space. Seen once, in the CI of session 10 at load ~4
        # (3 of 3 local runs and every earlier CI finished in place); why the finish did not fit is not
        # diagnosed: the note is what the user gets, and the recover it names must keep the messages
        assert "once there is space run 'dea-ros bag recover --in-place" in summary["error"], summary["error"]
        recover_bag(mcap.parent, in_place=True, keep_original=False)
    else:  # the bag: finished where it lies, within the limit, readable by every reader
        assert mcap.stat().st_size <= limit
    bag_dir = mcap.parent
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with BagReader(bag_dir) as bag:
            assert not bag.truncated and bag.verify() == []
            meta = bag.metadata()[EXPERIMENT_METADATA]
            counts = {k: v.message_count for k, v in bag.topics().items()}
            recorded_cmds = [m.message.data for m in bag.messages(["/voltage_cmd"])]
    # the record marking the experiment aborted is added whenever it fits in the room left
    # below the limit (the cut-off chunk's bytes); else the bag ends with a bare footer (50 bytes)
    scan = scan_mcap(mcap)
    if not finished_in_place:
        pass  # recovered afterwards, without the node's aborted marker
    elif meta["aborted"] != "true":
        first_record = next(m.length for m in scan.metadata_indexes if m.name == EXPERIMENT_METADATA)
        marker = first_record + 1024  # + the error text
        assert mcap.stat().st_size - 50 + marker > limit, "the aborted marker fitted but is missing"
    else:
        assert "File too large" in meta["error"] and int(meta["segments_completed"]) == 1
    assert counts["/displacement"] > 100 and max(recorded_cmds) <= level  # the cut chunk may hold the 2 kV
    with AnyReader([bag_dir]) as reader:
        assert reader.message_count == sum(counts.values())
    with open(mcap, "rb") as handle:
        assert sum(1 for _ in make_reader(handle).iter_messages()) == sum(counts.values())
    info = subprocess.run([sys.executable, "-m", "dea_ros.cli", "bag", "info", str(bag_dir)],
                          capture_output=True, text=True, timeout=120)
    assert info.returncode == 0, info.stderr
    assert "Traceback" not in info.stderr


def test_the_protocol_starts_at_the_tick_after_the_rig_was_found_ready(ros_context, tmp_path):
    """The tick that finds the rig ready may carry a clock that is behind (the wall-clock wait tick runs
    before its executor round's /clock message; CI: after a stall the protocol started ahead by the
    stall and skipped its first two segments): the protocol's time origin is the next tick's."""
    node = make_identifier(ros_context, tmp_path)
    try:
        node.rig_seen = dict.fromkeys(node.rig_seen, True)
        behind_ns, current_ns = 1_000_000_000_000, 1_000_400_000_000  # the clock 0.4 s behind the rig
        node.on_tick(behind_ns)
        assert node.state == "running" and node.t0_ns is None
        node.on_tick(current_ns)
        assert node.t0_ns == current_ns and node.segment_index == 0
        node.on_tick(current_ns + 5_000_000)
        assert node.segment_index == 0
    finally:
        node.destroy_node()
