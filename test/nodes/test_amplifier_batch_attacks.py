"""Batched commands (voltage_cmd_batch, issue 22) attacked from ANOTHER PROCESS, judged on what reached
the amplifier (the mock backend's UDP datagrams, captured in this process).

amplifier_node runs as a user runs it, in simulated time (batches exist only there). This process is
the clock master in lockstep, as mock_hardware_node is: it publishes /clock t, waits for the
amplifier's datagram for t, sends batches and waits for their acknowledgement on ~/command_received.
It sends a valid batch (applied one sample per update, acknowledged once) and then attacks: a batch
while inactive, oversized, longer than the watchdog, stale, for a later update, with NaN, above the
ceiling, with slew violations inside, and a sender that dies after a batch (the dead-man). Every
datagram must stay within the start-up ceiling and the slew limit (amp_harness.check_safe).
"""
import importlib.util
import math
import time
from pathlib import Path

from builtin_interfaces.msg import Duration
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64, Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from dea_ros.nodes.common import COMMAND_QOS

HERE = Path(__file__).parent
_spec = importlib.util.spec_from_file_location("amp_harness", HERE / "amp_harness.py")
H = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(H)

SLEW = 20000.0      # V/s (harness default): 80 V per update
RAMP = 10000.0      # V/s (harness default): 40 V per update
CEILING = 0.9 * 100e6 * 35e-6
PERIOD = 1.0 / 250.0
WATCHDOG_S = 0.3
MAX_BATCH = 100     # max_command_batch: 100 samples, but a batch may not span more than the watchdog (75)


class LockstepMaster:
    """This process: the simulated clock in lockstep with the amplifier, and the batch sender."""

    def __init__(self, ctx, ns, capture):
        self.capture = capture
        self.node = Node("batch_attacker", context=ctx)
        self.ex = SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.clock = self.node.create_publisher(Clock, f"{ns}/clock", 10)
        self.cmd = self.node.create_publisher(Float64, f"{ns}/voltage_cmd", COMMAND_QOS)
        self.batch = self.node.create_publisher(JointTrajectory, f"{ns}/voltage_cmd_batch", COMMAND_QOS)
        self.acks = []
        self.node.create_subscription(Header, f"{ns}/amplifier_node/command_received",
                                      lambda m: self.acks.append(m.stamp.sec + m.stamp.nanosec * 1e-9), 10)
        self.change_state = self.node.create_client(ChangeState, f"{ns}/amplifier_node/change_state")
        self.t = 1_795_000_000.0

    def publish_clock(self):
        msg = Clock()
        msg.clock.sec = int(math.floor(self.t))
        msg.clock.nanosec = min(int(round((self.t - math.floor(self.t)) * 1e9)), 999_999_999)
        self.clock.publish(msg)

    def tick(self, n=1, timeout_s=5.0):
        """Advance the clock n updates, each once the amplifier's datagram for the previous one came."""
        for _ in range(n):
            self.t += PERIOD
            self.publish_clock()
            t_end = time.monotonic() + timeout_s
            t_again = time.monotonic() + 0.5
            while not self.capture.snapshot() or self.capture.snapshot()[-1].sent_s < self.t - PERIOD / 2:
                self.ex.spin_once(timeout_sec=0.001)
                if time.monotonic() > t_again:  # (start-up: the clock's subscriber not discovered yet)
                    self.publish_clock()
                    t_again = time.monotonic() + 0.5
                assert time.monotonic() < t_end, "no datagram for the update"

    def jump(self, n, timeout_s=5.0):
        """Advance the clock n updates in one /clock message (the mock rig over a batch's ticks); wait for the
        amplifier's datagram for the new time. Returns the datagrams it sent for the jump."""
        before = len(self.capture.snapshot())
        self.t += n * PERIOD
        self.publish_clock()
        t_end = time.monotonic() + timeout_s
        while self.capture.snapshot()[-1].sent_s < self.t - PERIOD / 2:
            self.ex.spin_once(timeout_sec=0.001)
            assert time.monotonic() < t_end, "no datagram for the update"
        time.sleep(0.05)   # (a second call of the timer at the jump's end must add nothing)
        self.ex.spin_once(timeout_sec=0.001)
        return self.capture.snapshot()[before:]

    def send(self, values, first_s=None, offsets=None):
        """A batch (default: for the next update, one sample per update); waits for the acknowledgement."""
        msg = JointTrajectory(joint_names=["dea_voltage"])
        first_s = self.t + PERIOD if first_s is None else first_s
        msg.header.stamp.sec = int(math.floor(first_s))
        msg.header.stamp.nanosec = min(int(round((first_s - math.floor(first_s)) * 1e9)), 999_999_999)
        offsets = [i * PERIOD for i in range(len(values))] if offsets is None else offsets
        for value, offset in zip(values, offsets):
            sec, nanosec = divmod(int(round(offset * 1e9)), 1_000_000_000)
            msg.points.append(JointTrajectoryPoint(positions=[float(value)],
                                                   time_from_start=Duration(sec=sec, nanosec=nanosec)))
        n_acks = len(self.acks)
        self.batch.publish(msg)
        t_end = time.monotonic() + 5.0
        while len(self.acks) == n_acks:
            self.ex.spin_once(timeout_sec=0.001)
            assert time.monotonic() < t_end, "the batch was not acknowledged"
        return self.acks[-1]

    def voltage_at(self, t):
        return next(d.voltage_V for d in reversed(self.capture.snapshot()) if abs(d.sent_s - t) < PERIOD / 2)

    def transition(self, transition_id):
        assert H.call(self.node, self.ex, self.change_state, H.transition_request(transition_id)).success

    def close(self):
        self.ex.shutdown()
        self.node.destroy_node()


def _start(ctx, capture, ns):
    proc = H.start_amplifier(capture.port, ns, sim_time=True, watchdog_timeout_s=WATCHDOG_S,
                             max_command_batch=MAX_BATCH)
    master = LockstepMaster(ctx, ns, capture)
    try:
        master.tick(1, timeout_s=H.READY_TIMEOUT_S)   # the node's start-up and discovery
    except AssertionError:
        raise AssertionError(H.stderr_of(proc)) from None
    master.tick(3)
    assert master.change_state.wait_for_service(timeout_sec=10.0)
    return proc, master


def test_a_batch_is_applied_one_sample_per_update_and_acknowledged_once(ros_context):
    capture = H.Capture()
    proc, master = _start(ros_context, capture, "/batch_ok")
    try:
        values = [40.0 * (i + 1) for i in range(20)]      # 40 V per update: under the 80 V slew step
        t0 = master.t
        ack = master.send(values)
        assert abs(ack - (t0 + 19 * PERIOD)) < 1e-6, "acknowledged up to the update before the last sample's"
        master.tick(20)
        assert [master.voltage_at(t0 + (i + 1) * PERIOD) for i in range(20)] == values
        # then the dead-man: no more commands, the output holds for the watchdog and ramps down
        master.tick(int(WATCHDOG_S / PERIOD) + 30)
        assert master.voltage_at(master.t) < values[-1]
        H.check_safe(capture.snapshot(), CEILING, SLEW, sim_period_s=PERIOD)
    finally:
        master.close()
        H.stop(proc)
        capture.close()


def test_a_clock_advancing_a_batch_at_once_is_one_update_per_period(ros_context):
    """The mock rig advances /clock over a batch's ticks in one message (max_ticks_per_clock): the amplifier
    runs one update per period, each sample at its own update through the limits, each datagram stamped
    with its update's time. A longer jump (> MAX_CATCH_UP_UPDATES periods) stays one update (ControlClock)."""
    from dea_ros.nodes.amplifier_node import MAX_CATCH_UP_UPDATES

    capture = H.Capture()
    proc, master = _start(ros_context, capture, "/batch_jump")
    try:
        values = [40.0 * (i + 1) for i in range(25)]      # 40 V per update: under the 80 V slew step
        t0 = master.t
        master.send(values)
        sent = master.jump(25)
        assert [round((d.sent_s - t0) / PERIOD, 3) for d in sent] == [float(i + 1) for i in range(25)]
        assert [d.voltage_V for d in sent] == values
        master.tick(3)
        before_V = capture.snapshot()[-1].voltage_V
        n_acks = len(master.acks)
        master.cmd.publish(Float64(data=before_V + 1000.0))   # a step, as one command
        t_end = time.monotonic() + 5.0
        while len(master.acks) == n_acks:
            master.ex.spin_once(timeout_sec=0.001)
            assert time.monotonic() < t_end, "the command was not acknowledged"
        sent = master.jump(MAX_CATCH_UP_UPDATES + 1)
        assert len(sent) == 1, "a jump beyond the catch-up limit is one update"
        assert 0.0 < sent[0].voltage_V - before_V <= SLEW * PERIOD + 1e-6   # one update's slew, not 65
        H.check_safe(capture.snapshot(), CEILING, SLEW, sim_period_s=PERIOD)
    finally:
        master.close()
        H.stop(proc)
        capture.close()


def _assert_nothing_applied(master, ticks=15):
    t0 = master.t
    master.tick(ticks)
    assert all(master.voltage_at(t0 + (i + 1) * PERIOD) == 0.0 for i in range(ticks))


def test_batch_attacks_from_another_process_never_pass_the_limits(ros_context):
    capture = H.Capture()
    proc, master = _start(ros_context, capture, "/batch_atk")
    try:
        # inactive: refused whole
        master.transition(Transition.TRANSITION_DEACTIVATE)
        master.send([2000.0] * 20)
        _assert_nothing_applied(master)
        master.transition(Transition.TRANSITION_ACTIVATE)
        master.tick(2)
        # oversized (101 > max_command_batch), longer than the watchdog (80 x 4 ms > 0.3 s), stale (for the
        # update already done; a replay 1 s old), for a later update, not one sample per update
        for batch in ([1000.0] * (MAX_BATCH + 1), [1000.0] * 80):
            master.send(batch)
            _assert_nothing_applied(master, 5)
        for first_s in (master.t, master.t - 1.0, master.t + 3 * PERIOD, -5.0):
            master.send([1000.0] * 10, first_s=first_s)
            _assert_nothing_applied(master, 5)
        master.send([1000.0] * 3, offsets=[0.0, 0.0, 0.0])
        _assert_nothing_applied(master, 5)
        # NaN inside a batch: the samples before it apply, the NaN is rejected and the rest dropped
        t0 = master.t
        master.send([40.0, 80.0, math.nan, 3000.0, 3000.0, 3000.0])
        master.tick(10)
        got = [master.voltage_at(t0 + (i + 1) * PERIOD) for i in range(10)]
        assert got[:2] == [40.0, 80.0] and max(got) == 80.0, got
        # above the ceiling inside a batch: rejected at its update, the rest dropped
        t0 = master.t
        master.send([80.0, 2 * CEILING, 3000.0, 3000.0])
        master.tick(6)
        assert max(master.voltage_at(t0 + (i + 1) * PERIOD) for i in range(6)) == 80.0
        # slew violations inside a batch: every step is limited to 80 V per update
        t0 = master.t
        master.send([3000.0, 0.0, 3000.0] + [3000.0] * 40)
        master.tick(43)
        got = [master.voltage_at(t0 + (i + 1) * PERIOD) for i in range(43)]
        assert max(got) == 3000.0 and all(abs(b - a) <= SLEW * PERIOD + 1e-6 for a, b in zip(got, got[1:]))
        # the sender dies after a full batch (75 samples = the watchdog): the output follows the queue, then
        # holds at most the watchdog as after the last of 75 single commands, then ramps to 0 V
        t0 = master.t
        master.send([3000.0] * 75)
        master.tick(75 + int(WATCHDOG_S / PERIOD) + 3)
        assert master.voltage_at(t0 + 75 * PERIOD) == 3000.0
        assert master.voltage_at(master.t) < 3000.0 - RAMP * PERIOD, "the watchdog did not end the batch"
        master.tick(int(CEILING / (RAMP * PERIOD)) + 5)
        assert master.voltage_at(master.t) == 0.0
        # a single voltage_cmd supersedes a queued batch
        master.send([80.0] * 50)
        master.tick(3)
        master.cmd.publish(Float64(data=0.0))
        master.tick(8)
        assert master.voltage_at(master.t) == 0.0
        H.check_safe(capture.snapshot(), CEILING, SLEW, sim_period_s=PERIOD)
    finally:
        master.close()
        H.stop(proc)
        capture.close()
