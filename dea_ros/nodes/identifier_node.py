"""identifier_node: runs an experiment protocol on the rig, records an MCAP bag, identifies offline.

1. Checks before any high voltage: the bag directory is writable and the disk has
   ``min_free_mb``; the protocol's peak voltage is within ``max_voltage_V`` (if set).
2. Waits (``wait_for_rig_s``) until the amplifier reports an enabled output and subscribes to
   the commands, and displacement flows; then commands ``voltage_cmd`` from the protocol
   (:mod:`dea_ros.identify.protocols`) at ``command_rate_hz``, marking every segment boundary
   (``~/segment``, std_msgs/String JSON, and an MCAP metadata record ``dea_ros.experiment`` with
   the whole schedule).
3. Records every rig topic (``voltage_cmd``, ``voltage_cmd_batch``, ``voltage``, ``displacement``,
   ``displacement_predicted``) as raw CDR in a rosbag2 MCAP bag (``output_dir/<run>/bag``),
   flushed at least once a second. As ``ros2 bag record``, a topic enters the bag with the QoS
   offered by each of its publishers discovered when its first message arrives (one profile per
   publisher). ``rosbag2_format``: ``auto`` (= ``humble``, read by every distro), ``humble`` or ``jazzy``.
4. At the end: 0 V, bag closed, then in a background thread the offline identification writes
   ``params.yaml``, ``report/`` and ``summary.json`` beside the bag. A protocol with ``adaptive: true``
   first runs a second pass (:mod:`dea_ros.identify.adaptive`): 0 V (state ``planning``) while a thread
   fits the bag so far and plans, then the planned segments from the tick the plan is ready at (same bag,
   metadata ``dea_ros.experiment.pass2``); the identification uses both passes.

Progress on ``~/status`` (std_msgs/String JSON, 2 Hz) and in the log. Every tick ends with a
``~/tick_done`` (std_msgs/Header, stamp = the tick's time): in simulated time the mock rig waits for it
before advancing (lockstep). With ``command_trigger: applied_voltage`` (the demo) a tick is the amplifier's
applied-voltage message of its update t_k and the command is for t_k + 1/``command_rate_hz``: with
amplifier_node's ``~/command_received`` in the mock rig's ``lockstep_topics`` every command is applied
exactly one update after it was computed. With ``command_batch`` K > 1 (open loop) the commands of the next
K updates go out as one ``voltage_cmd_batch`` (amplifier_node applies one per update, each through its
limits, and acknowledges the batch once; the mock rig then advances its clock over them at once); the
applied voltage is the same. ``~/abort`` (std_srvs/Trigger) or Ctrl-C: 0 V commanded at once, the bag
closed with everything recorded so far (metadata ``aborted: true``), no identification.

A recording fault (any write error of the bag: disk full, I/O error, ...) stops the experiment: 0 V at
once, the protocol aborted, the bag finished in place with everything written before the fault (works
on a full disk: :func:`dea_ros.bag.recover_bag` ``in_place``), ``state: error`` with the cause, exit code 1.
"""
from __future__ import annotations

import json
import math
import sys
import threading
import time
import traceback
from datetime import datetime
from pathlib import Path

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.time import Time
from rclpy.qos import HistoryPolicy, QoSProfile
from sensor_msgs.msg import BatteryState, Range
from std_msgs.msg import Float64, Header, String
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from ..bag import BagError, BagWriter, check_writable, recover_bag, resolve_rosbag2_format
from ..bag.message_codec import header_stamp_ns
from ..identify.adaptive import plan_second_pass
from ..identify.bag_experiments import experiment_record, pass_metadata_name
from ..identify.from_bag import fit_bag, identify_bag
from ..identify.protocols import ProtocolError, commands_ahead, load_protocol, segment_at
from .command_batch_msg import batch_message
from .common import (COMMAND_QOS, LATCHED_QOS, SENSOR_QOS, TOPIC_DISPLACEMENT, TOPIC_DISPLACEMENT_PREDICTED,
                     TOPIC_VOLTAGE, TOPIC_VOLTAGE_CMD, TOPIC_VOLTAGE_CMD_BATCH, declare_bool, declare_float,
                     declare_int, declare_str, qos_to_bag, with_pending)
from .runner import run_nodes

__all__ = ["IdentifierNode", "main"]

#: ``command_trigger: applied_voltage``: wall-clock s without a triggering amplifier output, while running,
#: after which the node commands from its clock again (below amplifier_node's 2 s clock-stall backstop).
TRIGGER_SILENCE_S = 1.0

#: ``command_trigger: applied_voltage``: ticks of 0 V with the rig ready before the protocol starts (0.1 s at
#: 250 Hz; 1 with ``timer``). The mock rig's clock runs on its own until its lockstep engages on the first
#: acknowledged command: a protocol started then sent its first batch for an update already passed (stale).
READY_TICKS = 25

RECORDED = (
    (TOPIC_VOLTAGE_CMD, "std_msgs/msg/Float64", Float64, COMMAND_QOS),
    (TOPIC_VOLTAGE_CMD_BATCH, "trajectory_msgs/msg/JointTrajectory", JointTrajectory, COMMAND_QOS),
    (TOPIC_VOLTAGE, "sensor_msgs/msg/BatteryState", BatteryState, SENSOR_QOS),
    (TOPIC_DISPLACEMENT, "sensor_msgs/msg/Range", Range, SENSOR_QOS),
    (TOPIC_DISPLACEMENT_PREDICTED, "sensor_msgs/msg/Range", Range, SENSOR_QOS),
)


class IdentifierNode(Node):
    def __init__(self, **kwargs):
        super().__init__("identifier_node", **kwargs)
        run_name = self._declare_parameters()
        self._reset_state()
        self._load_protocol()
        self.run_dir = (self.output_dir / (run_name or datetime.now().strftime("%Y%m%d_%H%M%S"))).resolve()
        self.bag_dir = self.run_dir / "bag"
        self.cmd_pub = self.create_publisher(Float64, TOPIC_VOLTAGE_CMD, COMMAND_QOS)
        self.batch_pub = self.create_publisher(JointTrajectory, TOPIC_VOLTAGE_CMD_BATCH, COMMAND_QOS) \
            if self.command_batch > 1 else None
        self.ack_pub = self.create_publisher(Header, "~/tick_done", 10)
        self.status_pub = self.create_publisher(String, "~/status", LATCHED_QOS)
        self.segment_pub = self.create_publisher(String, "~/segment", LATCHED_QOS)
        self.create_service(Trigger, "~/abort", self.on_abort)
        if not self._preflight():
            return
        self._create_ticks()
        self.create_timer(0.5, self.publish_status)
        if self.progress_period_s > 0:  # wall clock: a line a person (or dea-ros rig demo) can follow
            self.create_timer(self.progress_period_s, self.log_progress, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"protocol '{self.protocol.name}': {len(self.segments)} segments, "
                               f"{self.segments[-1].end_s:.1f} s; recording to {self.bag_dir}")

    # ------------------------------------------------------------------ start-up
    def _declare_parameters(self) -> str:
        """Declare the parameters (read into attributes); returns the run name (may be empty)."""
        self.protocol_ref = declare_str(self, "protocol", "paper", "protocol name in config/protocols or a YAML path")
        self.output_dir = Path(declare_str(self, "output_dir", "runs", "folder of the runs"))
        run_name = declare_str(self, "run_name", "", "name of this run (default: date and time)")
        self.identify = declare_bool(self, "identify", True, "fit the parameters when the protocol ends (an adaptive "
                                     "protocol plans its second pass from a first fit regardless)")
        self.exit_when_done = declare_bool(self, "exit_when_done", False, "stop the node when done (demo)")
        self.command_rate_hz = declare_float(self, "command_rate_hz", 500.0, "voltage_cmd rate, Hz", 10.0, 5000.0)
        self.period_ns = int(round(1e9 / self.command_rate_hz))  # one command period (update), ns
        self.command_trigger = declare_str(
            self, "command_trigger", "timer",
            "timer (a command every 1/command_rate_hz) or applied_voltage (simulated lockstep: one command per "
            "applied-voltage message of the amplifier, for its next update; command_rate_hz = its update rate)")
        if self.command_trigger not in ("timer", "applied_voltage"):
            raise SystemExit(f"identifier_node: parameter 'command_trigger': timer or applied_voltage, "
                             f"got {self.command_trigger!r}")
        self.command_batch = declare_int(
            self, "command_batch", 1, "command_trigger applied_voltage: send the commands of this many updates as "
            "one voltage_cmd_batch (open loop; amplifier_node max_command_batch bounds it; 1: one voltage_cmd "
            "per update)", 1, 1000)
        if self.command_batch > 1 and self.command_trigger != "applied_voltage":
            raise SystemExit("identifier_node: parameter 'command_batch': > 1 only with command_trigger "
                             "applied_voltage (simulated lockstep)")
        self.wait_for_rig_s = declare_float(self, "wait_for_rig_s", 30.0,
                                            "wait this long for the amplifier and the sensor, s", 0.0, 600.0)
        self.min_free_mb = declare_float(self, "min_free_mb", 100.0, "free disk needed before starting, MB", 0.0, 1e6)
        self.max_voltage_V = declare_float(self, "max_voltage_V", 0.0, "refuse protocols above this (0: no check)",
                                           0.0, 30000.0)
        self.bag_format = declare_str(self, "rosbag2_format", "auto",
                                      "bag format: auto (= humble), humble (Humble and newer read it) "
                                      "or jazzy (Jazzy and newer)")
        self.progress_period_s = declare_float(
            self, "progress_period_s", 0.0, "log a 'progress {json}' line (the ~/status fields, the segment's kind "
            "and frequency) this often, wall-clock s (0: never)", 0.0, 3600.0)
        self.membrane_override = declare_str(self, "membrane", "", "geometry for the fit (default: the protocol's)")
        return run_name

    def _reset_state(self) -> None:
        """The run's state before anything happened."""
        self.last_trigger_ns = -1
        self.state = "starting"
        self.error = ""
        self.summary: dict = {}
        self.exit_at: float | None = None  # time.monotonic() at which main() lets the node exit
        self.exit_code = 0
        self.recording_error = ""
        self.fault_handled = False
        self.segment_index = -1
        self.t0_ns: int | None = None
        self.rig_seen = {"voltage_enabled": False, "displacement": False, "amplifier_listening": False}
        self.wait_started = time.monotonic()
        self.ready_ticks, self.last_ready_ns = 0, -1   # ticks with the rig ready while waiting; the last's time
        self.lock = threading.Lock()
        self.bag: BagWriter | None = None
        self.skipped_before_clock = 0
        self.trigger_topic = None  # command_trigger applied_voltage: the recorded topic whose messages trigger
        self.batch_end_ns: int | None = None  # command_batch: update time of the last command sent, ns
        self.outputs_behind_clock = 0  # applied-voltage outputs older than the clock (recorded, no command)
        self.last_trigger_wall_s = time.monotonic()  # time.monotonic() of the last output that triggered a tick
        self.restarts = 0  # ticks from the clock after TRIGGER_SILENCE_S without a triggering output
        self.pass_number = 1  # adaptive protocol: 2 once the planned second pass started
        self.second_pass = None  # its SecondPass (the plan)
        self.plan_outcome = None  # set by the first fit's thread: (SecondPass, segments) or why there is none

    def _load_protocol(self) -> None:
        """The protocol and its schedule (checked against ``max_voltage_V``), the bag format: SystemExit naming
        the parameter when refused."""
        try:
            self.protocol = load_protocol(self.protocol_ref)
            self.segments = self.protocol.schedule(self.max_voltage_V or None)
        except ProtocolError as exc:
            raise SystemExit(f"identifier_node: parameter 'protocol': {exc}") from None
        except (RecursionError, UnicodeDecodeError) as exc:
            raise SystemExit(f"identifier_node: parameter 'protocol': {self.protocol_ref} is not a protocol "
                             f"YAML ({type(exc).__name__})") from None
        try:
            self.bag_format = resolve_rosbag2_format(self.bag_format)
        except BagError as exc:
            raise SystemExit(f"identifier_node: parameter 'rosbag2_format': {exc}") from None

    def _preflight(self) -> bool:
        """Nothing is commanded unless the bag can be written: the run folder, free disk, the bag opened.
        False (the node reports the error and stays idle) when it cannot."""
        try:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            check_writable(self.bag_dir, int(self.min_free_mb * 1e6))
        except (BagError, OSError) as exc:
            self.fail(f"cannot record to {self.bag_dir}: {exc}; no voltage was applied")
            return False
        try:
            self.open_bag()
        except BagError as exc:
            if self.bag is not None:
                try:
                    self.bag.close()
                except BagError:
                    pass
            self.fail(f"cannot record to {self.bag_dir}: {exc}; no voltage was applied")
            return False
        return True

    def _create_ticks(self) -> None:
        """What triggers a command: a timer, or the amplifier's applied voltage (``command_trigger``)."""
        if self.command_trigger == "timer":
            self.create_timer(1.0 / self.command_rate_hz, self.on_tick)
            return
        # a command computed at a clock tick races the amplifier's update of the same tick (it is
        # applied at once or one update later: a jittered staircase). After the amplifier's output
        # for t_k is seen, the command is for its update at t_k + 1/rate, always; the mock rig's
        # lockstep (amplifier_node/command_received) lets the clock advance only once it arrived.
        # The recorder's subscription of the applied voltage is the trigger (one delivery per tick, not two).
        self.trigger_topic = self.topic_names[TOPIC_VOLTAGE]
        self.create_timer(0.1, self.on_wait_tick, clock=Clock(clock_type=ClockType.STEADY_TIME))

    # ------------------------------------------------------------------ recording
    def open_bag(self) -> None:
        self.bag = BagWriter(self.bag_dir, flush_period_s=0.5, rosbag2_format=self.bag_format,
                             min_free_bytes=int(self.min_free_mb * 1e6))
        self.topic_names = {}
        self.pending_topics = {}  # topic -> (type, fallback QoS): registered on its first message
        self.topic_lock, self.record_subs = threading.Lock(), {}  # record_subs: topic -> its recording subscription
        for rel, type_name, msg_type, qos in RECORDED:
            full = self.resolve_topic_name(rel)
            self.topic_names[rel] = full
            self.pending_topics[full] = (type_name, qos)
            # deep queues: the recorder must not drop a burst (best effort drops only on overflow)
            record_qos = QoSProfile(reliability=qos.reliability, durability=qos.durability,
                                    history=HistoryPolicy.KEEP_LAST, depth=5000)
            self.record_subs[full] = self.create_subscription(msg_type, rel, self._recorder(full), record_qos, raw=True)
        self.segment_topic = self.resolve_topic_name("~/segment")
        self.bag.add_topic(self.segment_topic, "std_msgs/msg/String", self.offered_qos(self.segment_topic, LATCHED_QOS))
        self.ready_subs = [
            self.create_subscription(BatteryState, TOPIC_VOLTAGE, self.on_voltage_seen, SENSOR_QOS),
            self.create_subscription(Range, TOPIC_DISPLACEMENT, self.on_displacement_seen, SENSOR_QOS),
        ]

    def offered_qos(self, topic: str, fallback) -> list:
        """One profile per discovered publisher of ``topic`` (``fallback`` if none is known yet)."""
        profiles = [qos_to_bag(info.qos_profile) for info in self.get_publishers_info_by_topic(topic)]
        if not profiles:
            self.get_logger().warning(f"no publisher of {topic} discovered yet: recording its QoS as configured")
            profiles = [qos_to_bag(fallback)]
        return profiles

    def register_topic(self, topic: str, only_if_published: bool = False) -> None:
        """Add a recorded topic to the bag with its publishers' QoS (once; thread-safe)."""
        with self.topic_lock:
            pending = self.pending_topics.get(topic)
            if pending is None:
                return
            if only_if_published and not self.get_publishers_info_by_topic(topic):
                return  # never published: not in the bag, as with ros2 bag record
            del self.pending_topics[topic]
            self.bag.add_topic(topic, pending[0], self.offered_qos(topic, pending[1]))

    def _recorder(self, topic: str):
        def record(data: bytes) -> None:  # and what else waits: one executor round, not one each (issue 22)
            for message in with_pending(self.record_subs.get(topic), data):
                if not record_one(message):  # the bag is closed or failed: stop taking
                    break

        def record_one(data: bytes) -> bool:
            bag = self.bag
            if bag is None or bag.closed:
                return False
            if topic in self.pending_topics:
                try:
                    self.register_topic(topic)
                except BagError as exc:  # adding a channel writes (and flushes) too: a write error
                    self.recording_failed(exc)
                    return False
            now_ns = self.get_clock().now().nanoseconds
            if now_ns == 0:  # simulated time before the first /clock: no valid log time yet
                self.skipped_before_clock += 1
                return True
            try:
                bag.write_serialized(topic, data, now_ns)
            except BagError as exc:
                self.recording_failed(exc)
                return False
            if topic == self.trigger_topic:
                self.on_applied_voltage(header_stamp_ns(data))
            return True
        return record

    def on_voltage_seen(self, msg: BatteryState) -> None:
        self.rig_seen["voltage_enabled"] |= bool(msg.present)

    def amplifier_listening(self) -> bool:
        """Another node (the amplifier) subscribes to the topic this node commands on: a command sent
        before that is lost (the first batch; the clock runs free until the lockstep engages)."""
        topic = (self.batch_pub or self.cmd_pub).topic_name
        me = (self.get_name(), self.get_namespace())
        return any((i.node_name, i.node_namespace) != me for i in self.get_subscriptions_info_by_topic(topic))

    def on_displacement_seen(self, msg: Range) -> None:
        if math.isfinite(msg.range):  # NaN: a sample laser_sensor_node flagged implausible (REP 117)
            self.rig_seen["displacement"] = True

    def experiment_metadata(self, completed: int, aborted: bool) -> dict:
        extra = self.second_pass.record_extra() if self.pass_number == 2 else {}
        if self.recording_error:
            extra["error"] = self.recording_error
        protocol = self.second_pass.protocol if self.pass_number == 2 else self.protocol
        return experiment_record(protocol, self.segments, self.t0_ns, completed, aborted, self.command_rate_hz,
                                 self.membrane_override or self.protocol.membrane, self.pass_number, extra)

    def record_experiment_metadata(self, completed: int, aborted: bool) -> None:
        self.bag.add_metadata(pass_metadata_name(self.pass_number), self.experiment_metadata(completed, aborted))

    @property
    def finished(self) -> bool:
        """main() stops spinning once this is True."""
        return self.exit_at is not None and time.monotonic() >= self.exit_at

    @finished.setter
    def finished(self, value: bool) -> None:
        self.exit_at = time.monotonic() if value else None

    def recording_failed(self, exc: Exception) -> None:
        """A write error of the bag: 0 V now, abort the protocol, keep what was written, report, exit."""
        if self.fault_handled:
            return
        self.fault_handled = True
        self.recording_error = self.recording_error or f"recording to {self.bag_dir} failed: {exc}"
        for _ in range(3):
            self.cmd_pub.publish(Float64(data=0.0))
        self.publish_ack()
        was = self.state
        self.state = "error"  # stops the protocol (on_tick) before anything else can fail
        self.get_logger().error(f"{self.recording_error}; 0 V commanded, protocol aborted ({was})")
        self.finish_recording(aborted=True)
        self.fail(f"{self.recording_error}; 0 V was commanded and the protocol aborted; "
                  f"{self.summary.get('bag_note', '')}")
        # exit even without exit_when_done, after a second for the status to reach its subscribers
        self.exit_at = time.monotonic() + 1.0

    # ------------------------------------------------------------------ protocol
    def now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def on_applied_voltage(self, stamp_ns: int) -> None:
        """``command_trigger: applied_voltage``: one tick per amplifier update (its output's stamp, ns).

        An output older than the clock by half an update or more is a backlog (the clock ran while this node
        was busy): a command from it would be for an update already done, and its acknowledgement would let
        the mock rig advance with this node behind (the protocol late, or its first batch refused as stale).
        Such outputs are recorded but trigger nothing (/clock keeps only its newest message)."""
        now_ns = self.now_ns()
        if stamp_ns <= self.last_trigger_ns or now_ns <= 0:  # (not before the first /clock)
            return
        self.last_trigger_ns = stamp_ns
        if stamp_ns < now_ns - self.period_ns // 2:
            if self.batch_end_ns is None or stamp_ns > self.batch_end_ns + self.period_ns // 2:
                self.outputs_behind_clock += 1   # (not an update of the batch in hand: the rig's /clock advances
            return                               # a batch's ticks at once, and its outputs come after it)
        self.last_trigger_wall_s = time.monotonic()
        self.on_tick(stamp_ns)

    def on_wait_tick(self) -> None:
        """``command_trigger: applied_voltage``, every 0.1 s of wall time: the wait for the rig (times out
        without amplifier output); running, a tick from the clock after ``TRIGGER_SILENCE_S`` without one
        (a lost or refused command leaves a lockstep rig that pauses when idle waiting for good)."""
        if self.now_ns() <= 0:
            return
        if self.state in ("starting", "waiting"):
            self.on_tick()
        elif self.state in ("running", "planning") and time.monotonic() - self.last_trigger_wall_s > \
                TRIGGER_SILENCE_S:
            self.restarts += 1
            self.get_logger().warning(f"no amplifier output for {TRIGGER_SILENCE_S:g} s (wall) while {self.state}: "
                                      f"commanding from the current clock again (restart {self.restarts})")
            self.batch_end_ns = None
            self.last_trigger_wall_s = time.monotonic()
            self.on_tick()

    def wait_for_rig(self, now_ns: int) -> None:
        """A tick before the protocol: 0 V, acknowledged; the rig ready for a few ticks: the protocol next."""
        self.cmd_pub.publish(Float64(data=0.0))
        self.publish_ack(now_ns)
        if not self.rig_seen["amplifier_listening"]:
            self.rig_seen["amplifier_listening"] = self.amplifier_listening()
        if all(self.rig_seen.values()) and now_ns > self.last_ready_ns:   # a tick with the rig ready
            self.ready_ticks, self.last_ready_ns = self.ready_ticks + 1, now_ns
        if self.ready_ticks >= (READY_TICKS if self.command_trigger == "applied_voltage" else 1):
            self.state, self.t0_ns = "running", None
            for sub in self.ready_subs:  # only needed to start: halve the callbacks
                self.destroy_subscription(sub)
            self.ready_subs = []
            self.last_trigger_wall_s = time.monotonic()  # (no restart tick from a clock that may be behind)
            self.get_logger().info("rig ready")
        elif time.monotonic() - self.wait_started > self.wait_for_rig_s:
            missing = [k for k, v in self.rig_seen.items() if not v]
            self.finish_recording(aborted=True)
            self.fail(f"rig not ready after {self.wait_for_rig_s:g} s (missing: {missing}); is the amplifier "
                      "active and the sensor publishing? nothing was commanded")

    def start_protocol(self, now_ns: int) -> bool:
        """The protocol's time origin: the tick after the one that found the rig ready (that may be the wait
        tick, run before its round's /clock: after a stall its clock is behind and the protocol ran ahead)."""
        self.t0_ns = now_ns
        try:
            self.record_experiment_metadata(0, aborted=False)
        except BagError as exc:
            self.recording_failed(exc)
            return False
        self.get_logger().info(f"protocol started at simulated t = {now_ns * 1e-9:.6f} s")
        return True

    def on_tick(self, now_ns: int | None = None) -> None:
        """One command. ``now_ns``: the tick's time (default: the node's clock)."""
        now_ns = self.now_ns() if now_ns is None else int(now_ns)
        if self.state == "starting":
            self.state = "waiting"
            self.wait_started = time.monotonic()
        if self.state == "waiting":
            self.wait_for_rig(now_ns)
            return
        if self.state == "planning" and not self.on_planning_tick(now_ns):
            return
        if self.state != "running" or (self.t0_ns is None and not self.start_protocol(now_ns)):
            return
        t = (now_ns - self.t0_ns) * 1e-9
        k = segment_at(self.segments, t, max(self.segment_index, 0))
        if k >= len(self.segments):
            self.cmd_pub.publish(Float64(data=0.0))
            self.segment_index = len(self.segments)
            self.get_logger().info(f"protocol complete (pass {self.pass_number})")
            if self.pass_number == 1 and self.protocol.adaptive:  # (identify: false: the final fit is left out)
                self.end_first_pass()
                self.publish_ack(now_ns)
                return
            self.finish_recording(aborted=False)
            if self.state != "error":  # not after a recording fault
                self.start_identification()
            return
        if k != self.segment_index:
            self.segment_index = k
            seg = self.segments[k]
            event = json.dumps({"event": "segment_start", **seg.to_dict()})
            self.segment_pub.publish(String(data=event))
            try:
                self.bag.write(self.segment_topic, {"data": event}, now_ns)
            except BagError as exc:
                self.recording_failed(exc)
                return
            self.get_logger().info(
                f"segment {k + 1}/{len(self.segments)}: {seg.kind} "
                + ", ".join(f"{key} {val:g}" for key, val in seg.info.items() if isinstance(val, (int, float)))
            )
        self.send_commands(k, t, now_ns)
        self.publish_ack(now_ns)

    def end_first_pass(self) -> None:
        """Adaptive protocol, pass 1 done: its record completed and flushed, then the first fit and the plan
        in a thread (:mod:`dea_ros.identify.adaptive`) while the ticks command 0 V."""
        try:
            self.record_experiment_metadata(len(self.segments), aborted=False)
            self.bag.flush()
        except BagError as exc:
            self.recording_failed(exc)
            return
        self.state = "planning"
        threading.Thread(target=self.run_first_fit, daemon=True).start()

    def run_first_fit(self) -> None:
        """The first fit from the bag recorded so far and the second pass planned from it (thread)."""
        try:
            result, _timings = fit_bag(self.bag_dir, membrane=self.membrane_override or None,
                                       progress=lambda msg: self.get_logger().info(f"first fit: {msg}"))
            second = plan_second_pass(result, self.protocol, self.max_voltage_V or None)
            self.plan_outcome = (second, second.segments(self.max_voltage_V or None))
        except Exception as exc:  # noqa: BLE001 - report; the first pass is identified alone
            self.get_logger().error(traceback.format_exc())
            self.plan_outcome = f"no second pass: {exc}"

    def on_planning_tick(self, now_ns: int) -> bool:
        """0 V while the first fit runs (the tick acknowledged: the clock runs on, the membrane rests); True
        once the planned second pass starts at this tick, from the current clock."""
        outcome = self.plan_outcome
        if outcome is None:
            self.cmd_pub.publish(Float64(data=0.0))
            self.publish_ack(now_ns)
            return False
        if isinstance(outcome, str):  # no plan: the bag holds one pass, identified as such
            self.get_logger().warning(f"{outcome}; identifying from the first pass")
            self.summary["adaptive"] = {"passes": 1, "note": outcome}
            self.finish_recording(aborted=False)
            if self.state != "error":
                self.start_identification()
            return False
        self.second_pass, self.segments = outcome
        self.pass_number, self.segment_index, self.batch_end_ns, self.t0_ns = 2, -1, None, now_ns
        self.state = "running"
        picks = "; ".join(p.record.label() for p in self.second_pass.plan.picks)
        self.get_logger().info(f"second pass planned ({self.segments[-1].end_s:.1f} s): {picks}")
        try:
            self.record_experiment_metadata(0, aborted=False)
        except BagError as exc:
            self.recording_failed(exc)
            return False
        return True

    def send_commands(self, k: int, t: float, now_ns: int) -> None:
        """The command for the next update (segment ``k``, protocol time ``t``, s), or with ``command_batch``
        K > 1, once the last batch is used up, the commands of the next K updates as one batch."""
        period = 1.0 / self.command_rate_hz
        if self.batch_pub is None:  # one command period ahead: the amplifier applies it at its next update
            self.cmd_pub.publish(Float64(data=float(self.segments[k].voltage_at(t + period))))
            return
        period_ns = int(round(1e9 * period))
        if self.batch_end_ns is not None and now_ns < self.batch_end_ns - period_ns // 2:
            return  # the amplifier still holds commands up to batch_end_ns
        voltages = commands_ahead(self.segments, k, t, period, self.command_batch)
        self.batch_pub.publish(batch_message(now_ns + period_ns, voltages, period_ns))
        self.batch_end_ns = now_ns + self.command_batch * period_ns

    def publish_ack(self, stamp_ns: int | None = None) -> None:
        """Simulated-time lockstep: tell the mock rig this tick's command is out (header stamp = the
        tick's time, at least now)."""
        ack = Header()
        ack.stamp = Time(nanoseconds=max(self.now_ns(), int(stamp_ns or 0)), clock_type=ClockType.ROS_TIME).to_msg()
        ack.frame_id = self.get_name()
        self.ack_pub.publish(ack)

    def finish_recording(self, aborted: bool) -> None:
        with self.lock:
            if self.bag is None or self.bag.closed:
                return
            completed = max(0, min(self.segment_index, len(self.segments)))
            failure = None
            try:
                for topic in list(self.pending_topics):  # published but no message arrived: count 0
                    self.register_topic(topic, only_if_published=True)
                if self.t0_ns is not None:
                    self.record_experiment_metadata(completed, aborted or bool(self.recording_error))
            except BagError as exc:
                failure = exc
            try:
                self.bag.close()
            except BagError as exc:
                failure = failure or exc
            self.summary["bag"] = str(self.bag_dir)
            self.summary["messages"] = self.bag.topic_message_counts()
            if failure is not None:
                if not self.recording_error:
                    self.recording_error = f"recording to {self.bag_dir} failed: {failure}"
                self.salvage_bag(completed)
            else:
                self.get_logger().info(f"bag closed: {self.bag_dir} ({self.bag.message_count} messages)")
        if failure is not None and not self.fault_handled:
            self.recording_failed(failure)  # the fault showed only on closing (protocol end, abort)
        if self.state != "error":
            self.state = "aborted" if aborted else "recorded"

    def salvage_bag(self, completed: int) -> None:
        """After a write error: finish the bag where it lies, with the experiment marked aborted."""
        metadata = []
        if self.t0_ns is not None:
            metadata.append((pass_metadata_name(self.pass_number), self.experiment_metadata(completed, aborted=True)))
        try:
            report = recover_bag(self.bag_dir, in_place=True, keep_original=False, extra_metadata=metadata)
        except BagError as exc:
            note = (f"the bag could not be finished ({exc}); once there is space run "
                    f"'dea-ros bag recover --in-place {self.bag_dir}'")
            self.get_logger().error(note)
        else:
            self.summary["messages"] = report.topic_message_counts
            note = f"the {report.message_count} messages written before the fault are kept in {self.bag_dir}"
            self.get_logger().warning(f"bag finished after the fault: {note}")
        self.summary["bag_note"] = note

    def start_identification(self) -> None:
        if not self.identify:
            self.done()
            return
        self.state = "identifying"
        threading.Thread(target=self.run_identification, daemon=True).start()

    def run_identification(self) -> None:
        t_start = time.perf_counter()
        try:
            result = identify_bag(self.bag_dir, self.run_dir, membrane=self.membrane_override or None,
                                  progress=lambda msg: self.get_logger().info(msg))
            self.summary.update(result)
            self.summary["identification_wall_time_s"] = time.perf_counter() - t_start
            self.get_logger().info(
                f"identified in {self.summary['identification_wall_time_s']:.1f} s: parameters "
                f"{self.summary.get('params_file')}, report {self.summary.get('report_dir')}"
            )
            self.done()
        except Exception as exc:  # noqa: BLE001 - report, keep the bag
            self.get_logger().error(traceback.format_exc())
            self.fail(f"identification failed: {exc}; the bag is kept at {self.bag_dir}")

    def done(self) -> None:
        self.state = "done"
        self.write_summary()
        self.publish_status()
        self.finished = self.exit_when_done

    def fail(self, message: str) -> None:
        self.error = message
        self.state = "error"
        self.exit_code = 1
        self.get_logger().error(message)
        self.write_summary()
        self.publish_status()
        self.finished = self.exit_when_done

    def write_summary(self) -> None:
        self.summary.update({"state": self.state, "error": self.error, "run_dir": str(self.run_dir),
                             "protocol": self.protocol.name, **self.counters()})
        try:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            (self.run_dir / "summary.json").write_text(json.dumps(self.summary, indent=2, default=str))
        except OSError as exc:
            self.get_logger().error(f"cannot write summary.json: {exc}")

    def on_abort(self, _req, resp):
        resp.success = self.abort("abort service")
        resp.message = f"aborted; bag kept at {self.bag_dir}" if resp.success else f"nothing to abort ({self.state})"
        return resp

    def abort(self, reason: str) -> bool:
        if self.state not in ("waiting", "running", "starting", "planning"):
            return False
        for _ in range(3):
            self.cmd_pub.publish(Float64(data=0.0))
        self.get_logger().warning(f"aborted ({reason}): 0 V commanded, closing the bag")
        self.finish_recording(aborted=True)
        if self.state == "error":  # closing the bag failed: reported as a recording fault
            return True
        self.error = f"aborted by {reason}"
        self.done()
        return True

    def status(self) -> dict:
        """The run's state: segment, simulated time since the protocol started (s), its duration (s)."""
        total = self.segments[-1].end_s if self.segments else 0.0
        elapsed = (self.now_ns() - self.t0_ns) * 1e-9 if (self.t0_ns and self.state == "running") else None
        return {"state": self.state, "pass": self.pass_number, "segment": self.segment_index + 1,
                "segments": len(self.segments), "elapsed_s": elapsed, "duration_s": total,
                "progress": min(1.0, elapsed / total) if elapsed is not None and total else None,
                "bag": str(self.bag_dir), "error": self.error, **self.counters()}

    def counters(self) -> dict:
        return {"outputs_behind_clock": self.outputs_behind_clock, "restarts": self.restarts}

    def publish_status(self) -> None:
        self.status_pub.publish(String(data=json.dumps(self.status())))

    def log_progress(self) -> None:
        """``progress_period_s``: the status and the current segment's kind and numbers as one log line."""
        status = self.status()
        if 0 <= self.segment_index < len(self.segments):
            seg = self.segments[self.segment_index]
            status.update(kind=seg.kind, **{k: v for k, v in seg.info.items() if isinstance(v, (int, float))})
        self.get_logger().info("progress " + json.dumps(status))

    def shutdown_safely(self) -> None:
        """SIGINT/SIGTERM: like the abort service (0 V, bag closed with everything so far)."""
        if not self.abort("shutdown"):
            self.finish_recording(aborted=self.state not in ("recorded", "identifying", "done"))


def main(args=None) -> None:
    """``ros2 run dea_ros identifier_node``; exits with the node's exit code (1 after an error)."""
    holder = {}

    def factory():
        holder["node"] = IdentifierNode()
        return holder["node"]

    run_nodes([factory], args=args if args is not None else sys.argv)
    node = holder.get("node")
    if node is not None:
        if node.state == "identifying":  # Ctrl-C during the offline fit: the voltage is already 0 V
            print("identifier_node: waiting for the identification to finish (Ctrl-C again to stop)")
            while node.state == "identifying":
                time.sleep(0.1)
        sys.exit(node.exit_code)


if __name__ == "__main__":
    main()
