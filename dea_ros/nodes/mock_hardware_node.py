"""mock_hardware_node: the simulated rig (amplifier output stage, membrane with its mass, laser head).

The node is a thin rclpy adapter around :mod:`dea_ros.sim` (parameters, topics, timers, ``/clock``):
the physics is :class:`~dea_ros.sim.rig_simulator.RigSimulator`, the amplifier's output stage
:class:`~dea_ros.sim.amplifier_receiver.MockAmplifierReceiver`, the serial laser
:class:`~dea_ros.sim.ild1320_emulator.ILD1320Emulator`.

The membrane is integrated with the core's fixed-step RK4 (``physics_dt_s``) with its own
"true" parameters (``params_file``). It receives the amplifier's output from the ``mock``
amplifier backend over UDP (``amplifier_port``), and measures the displacement like the
laser: Gaussian noise (``noise_m``), quantisation (``quantisation_m``) and a sensor latency
(``sensor_latency_s``). The measurement leaves the mock in one or both ways
(``laser_output``):

* ``emulator``: an ILD1320 emulator on a pseudo-terminal (symlink ``laser_port``), read
  by laser_sensor_node exactly like the real sensor over its USB-RS422 adapter (real time);
* ``topic``: the mock publishes ``displacement`` (sensor_msgs/Range) itself at
  ``sample_rate_hz``, stamped with the acquisition time.

Time: with ``publish_clock: false`` the mock follows the wall clock (real time). With
``publish_clock: true`` it is the clock master: it advances simulated time at
``real_time_factor`` times the wall clock in ticks of 1/``clock_rate_hz`` (simulated),
publishes ``/clock`` (rosgraph_msgs/Clock) and the other nodes run with
``use_sim_time: true``; the laser output must then be ``topic``. With ``lockstep`` (default) the
simulation never runs ahead of the amplifier and of the nodes listed in ``lockstep_topics``. A tick
k (time t_k) runs in a fixed order:

1. the membrane is integrated up to t_k and ``/clock`` t_k is published;
2. the mock waits for the amplifier's output for t_k (its UDP datagram, stamped with the simulated
   clock), which holds from t_k on; only then
3. the laser samples acquired up to t_k are published (they depend on the voltages before t_k only);
4. the mock waits until every active participant of ``lockstep_topics`` acknowledged t_k
   (std_msgs/Header stamped >= t_k: identifier_node's ``~/tick_done``, position_controller_node's
   ``~/tick_done``, amplifier_node's ``~/command_received``), then tick k + 1 begins.

With ``max_ticks_per_clock`` > 1 (``dea-ros rig demo``: 50) one ``/clock`` message advances every tick that
the acknowledgements already cover (amplifier_node acknowledges a batch of K commands once, for its K
updates): the membrane is integrated to the first of them, amplifier_node runs one update per tick and
sends each output stamped with its tick, the mock applies each from that time, and the laser samples of
those ticks go out after the last output. The physics and the samples are those of one tick per ``/clock``
(test_command_batch_rig); one ``/clock`` per batch instead of per tick, so the amplifier's and the identifier's
executor rounds for it go too (docs/benchmarks.md, issue 22 session 16: x1.85 -> x6.8). A participant that
acknowledges each tick (a controller) keeps one tick per ``/clock``.

A participant is active while it acknowledged within ``lockstep_timeout_s`` of wall time; a wait
longer than that continues anyway (counted in ``lockstep_timeouts``). ``real_time_factor`` is an
upper bound. With amplifier_node's ``~/command_received`` in ``lockstep_topics`` the clock does
not advance before the command a controller computed from the sample of t_k has *reached* the
amplifier (the acknowledgement is stamped with the amplifier's clock at receipt, which is t_k
because the sample went out after the amplifier's update for t_k): the amplifier applies it at its
update for t_{k+1}, so a sample-driven controller sees a fixed delay of exactly one tick from
acquisition to applied voltage (position_controller_node's ``loop_delay_s`` at 1 kHz).

The node sleeps between events: a thread blocks on the amplifier's UDP socket and, when a datagram
arrives, runs the tick itself (publishing from that thread: no executor round per tick, the largest part
of the mock's CPU per tick, issue 22); acknowledgements arrive as messages on the executor, and the
pacing timer runs only while the clock is ahead of ``real_time_factor``. Both paths hold one lock. With
``pause_when_idle`` (``dea-ros rig demo``) the clock stands once the lockstep participants that
acknowledged fall silent for ``lockstep_timeout_s`` (the protocol ended) until one acknowledges again. A
paused rig costs no CPU: the nodes' timers on the simulated clock do not fire, nothing polls (issue 22).
Before the first acknowledgement the clock runs (the nodes starting need it; amplifier_node ramps to 0 V
when its clock stalls for 2 s while it is active, so a paused clock must not wait for a slow start).

The simulated amplifier has its own dead-man interlock: when no datagram arrived for
``amplifier_deadman_s`` of wall time (the amplifier node was killed, hangs, or its host lost
power), its output drops to 0 V by itself, as a real rig's interlock would.
"""
from __future__ import annotations

import math
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock as RclClock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Range
from std_msgs.msg import Header

from ..errors import AmplifierBackendError
from ..hardware.amplifier.udp import DEFAULT_MOCK_PORT
from ..model import MembraneParameters, ParameterError, load_parameters
from ..sim.amplifier_receiver import MockAmplifierReceiver
from ..sim.ild1320_emulator import ILD1320Emulator
from ..sim.plant import LASER_QUANTISATION_M
from ..sim.rig_simulator import LaserSampler, RigSimulator
from .common import (
    SENSOR_QOS,
    TOPIC_DISPLACEMENT,
    declare_bool,
    declare_float,
    declare_int,
    declare_str,
    make_range,
    publish_diagnostic,
)
from .runner import run_node

__all__ = ["MockHardwareNode", "main"]


class MockHardwareNode(Node):
    """The simulated rig as a node: parameters, topics, timers and ``/clock`` around :mod:`dea_ros.sim`."""

    # what shutdown_safely releases, None until created: rclpy's context also destroys a node whose
    # start-up was refused part-way, and the refusal must stay the last thing the user reads
    receiver: MockAmplifierReceiver | None = None
    emulator: ILD1320Emulator | None = None
    tick_lock: threading.Lock | None = None   # simulated time only

    def __init__(self, **kwargs):
        super().__init__("mock_hardware_node", **kwargs)
        self._declare_parameters()
        params = self._membrane()
        try:
            self.receiver = MockAmplifierReceiver(port=self.amplifier_port, deadman_timeout_s=self.amplifier_deadman_s)
        except AmplifierBackendError as exc:   # e.g. the port is in use: say which parameter, not a traceback
            raise SystemExit(f"mock_hardware_node: parameter 'amplifier_port': {exc}") from None
        self.tick_index = 0                      # /clock ticks published (simulated time)
        self.amp_time_s: float | None = None     # simulated send time of the latest amplifier datagram
        self.clock_time_s: float | None = None   # last /clock published
        self.tick_wall_s = time.monotonic()      # wall time at which the current lockstep wait began
        self.samples_out = True                  # the laser samples of the current tick are published
        self.lockstep_timeouts = 0
        self.ack_times: dict = {}
        self.acks_received = 0                   # lockstep acknowledgements (all participants)
        self.paused = False                      # pause_when_idle: no participant active, the clock stands
        self.clock_jumps = 0                     # /clock messages that advanced more than one tick
        if self.publish_clock and self.lockstep:
            for topic in self.lockstep_topics:
                self.create_subscription(Header, topic, self.on_ack(topic), 10)
        # simulated time starts at the wall-clock date (plausible bag stamps); real time runs on monotonic
        t0 = time.time() if self.publish_clock else time.monotonic()
        self.sim = RigSimulator(params, self.physics_dt_s, t0, self.noise_m, self.quantisation_m,
                                self.sensor_latency_s, self.seed)
        self.sim_t0 = t0
        self.sampler = LaserSampler(self.sim, self.sample_rate_hz, t0)
        self._create_laser_outputs()
        self._create_clock_and_timers()
        self.published = 0
        if self.publish_clock:
            self.waiter.start()  # last: it runs ticks, which need every attribute above
        self.get_logger().info(
            f"mock rig: membrane {params.name}, noise {self.noise_m * 1e6:g} um, amplifier UDP port "
            f"{self.receiver.port}, laser output {self.laser_output}"
            + (f" ({self.emulator.port_path} -> {self.laser_port})" if self.emulator else "")
            + (f", simulated time x{self.real_time_factor:g}" if self.publish_clock else ", real time")
        )

    def _declare_parameters(self) -> None:
        """Declare every parameter (fixed at start-up) and keep its value as an attribute of the same name."""
        self.params_file = declare_str(self, "params_file", "A2", "true membrane of the simulated rig (preset or YAML)")
        self.noise_m = declare_float(self, "noise_m", 1e-6, "laser noise, standard deviation, m", 0.0, 1e-3)
        self.quantisation_m = declare_float(self, "quantisation_m", LASER_QUANTISATION_M,
                                            "laser resolution, m (ILD1320-10: 0.156 um)",
                                            0.0, 1e-4)
        self.sensor_latency_s = declare_float(self, "sensor_latency_s", 0.0, "laser latency, s", 0.0, 0.1)
        self.physics_dt_s = declare_float(self, "physics_dt_s", 0.5e-3, "RK4 step of the membrane, s",
                                          1e-5, 5e-3)
        self.sample_rate_hz = declare_float(self, "sample_rate_hz", 1000.0,
                                            "laser rate for laser_output topic, Hz", 1.0, 20000.0)
        self.laser_output = declare_str(self, "laser_output", "topic", "topic, emulator or both")
        self.laser_port = declare_str(self, "laser_port", "/tmp/dea_ros_mock_laser",
                                      "symlink of the emulated sensor's serial port")
        self.laser_standoff_m = declare_float(self, "laser_standoff_m", 2e-3,
                                              "distance reading of the flat membrane (tare value), m", 0.0, 0.01)
        self.amplifier_port = declare_int(self, "amplifier_port", DEFAULT_MOCK_PORT,
                                          "UDP port for the amplifier mock backend (0: any free port)", 0, 65535)
        self.publish_clock = declare_bool(self, "publish_clock", False,
                                          "be the clock master: publish /clock (simulated time)")
        self.real_time_factor = declare_float(self, "real_time_factor", 1.0,
                                              "simulated seconds per wall second (publish_clock)", 0.01, 100.0)
        self.clock_rate_hz = declare_float(self, "clock_rate_hz", 500.0, "/clock ticks per simulated second",
                                           10.0, 10000.0)
        self.lockstep = declare_bool(self, "lockstep", True,
                                     "simulated time: never advance before the amplifier and the lockstep_topics "
                                     "acted on the last tick")
        self.lockstep_timeout_s = declare_float(self, "lockstep_timeout_s", 0.5,
                                                "wall-clock wait for the amplifier per tick, s", 0.001, 10.0)
        self.amplifier_deadman_s = declare_float(self, "amplifier_deadman_s", 0.5,
                                                 "the simulated amplifier drops to 0 V when no datagram came for "
                                                 "this long (wall clock), s", 0.01, 10.0)
        self.pause_when_idle = declare_bool(
            self, "pause_when_idle", False,
            "simulated time with lockstep: once a participant acknowledged, the clock stands (and the node "
            "sleeps) while none acknowledged within lockstep_timeout_s, e.g. after a protocol ended")
        self.lockstep_topics = self.declare_parameter(
            "lockstep_topics", ["identifier_node/tick_done"],
            ParameterDescriptor(description="std_msgs/Header topics of nodes that must finish a tick before the "
                                            "simulated clock advances (lockstep), e.g. identifier_node/tick_done, "
                                            "amplifier_node/command_received")).value
        self.seed = declare_int(self, "seed", 0, "noise seed", 0, 2**31 - 1)
        self.max_ticks_per_clock = declare_int(
            self, "max_ticks_per_clock", 1,
            "lockstep: at most this many ticks per /clock message, taken only while every active participant's "
            "acknowledgement covers them (a batch of commands); 1: one /clock per tick", 1, 1000)

    def _membrane(self) -> MembraneParameters:
        """The true membrane (``params_file``), once the laser output and the clock are a valid combination."""
        if self.laser_output not in ("topic", "emulator", "both"):
            raise SystemExit(f"mock_hardware_node: parameter 'laser_output': topic, emulator or both, "
                             f"got {self.laser_output!r}")
        if self.publish_clock and self.laser_output != "topic":
            raise SystemExit("mock_hardware_node: with publish_clock (simulated time) laser_output must be "
                             "'topic' (the serial emulator streams in wall-clock time)")
        try:
            return load_parameters(self.params_file)
        except (ParameterError, FileNotFoundError) as exc:
            raise SystemExit(f"mock_hardware_node: parameter 'params_file': {exc}") from None

    def _create_laser_outputs(self) -> None:
        """The ``displacement`` publisher (topic) and the serial emulator (emulator), as ``laser_output`` asks."""
        self.range_pub = None
        if self.laser_output in ("topic", "both"):
            self.range_pub = self.create_publisher(Range, TOPIC_DISPLACEMENT, SENSOR_QOS)
        self.emulator = None
        if self.laser_output in ("emulator", "both"):
            standoff = self.laser_standoff_m
            self.emulator = ILD1320Emulator(
                lambda t: standoff + self.sim.measure(t), measuring_rate_hz=2000.0, symlink=self.laser_port,
            ).start()

    def _create_clock_and_timers(self) -> None:
        """``/clock`` and the tick timer (simulated time), or the real-time timer; the diagnostics."""
        self.clock_pub = None
        if self.publish_clock:
            self.clock_pub = self.create_publisher(Clock, "/clock", 10)
            self.wall_t0 = time.monotonic()
            # event driven: a tick advances when the amplifier's datagram arrives (a thread sleeps on the
            # UDP socket and runs the tick itself: no executor round per tick, issue 22) and when an
            # acknowledgement arrives; the pacing timer runs only while the clock is ahead of
            # real_time_factor x the wall clock, a slow one catches the lockstep timeouts. A paused or
            # waiting rig costs no CPU. Every path into the tick holds tick_lock.
            self.tick_lock = threading.Lock()
            period = min(1.0 / (self.clock_rate_hz * self.real_time_factor), 0.0005)  # catches up when late
            self.timer = self.create_timer(period, self.on_sim_tick, clock=_wall_clock())
            self.timer.cancel()
            self.watch_timer = self.create_timer(min(0.05, self.lockstep_timeout_s / 4), self.on_sim_tick,
                                                 clock=_wall_clock())
            # the waiter thread re-armed the pacing timer: the executor must wait on it again
            self.timer_rearmed = self.create_guard_condition(lambda: None)
            self.waiter = threading.Thread(target=self._wait_for_amplifier, daemon=True)  # started by __init__
        else:
            self.timer = self.create_timer(0.002, self.on_realtime_tick)
        self.mono_to_ros = self.get_clock().now().nanoseconds * 1e-9 - time.monotonic()
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(1.0, self.publish_diagnostics, clock=_wall_clock())

    # ------------------------------------------------------------------ time
    def _wait_for_amplifier(self) -> None:
        """Thread: sleep on the amplifier's UDP socket; advance the tick when a datagram is pending."""
        while self.receiver.is_open:
            if self.receiver.wait_readable(0.2):
                try:
                    self.on_sim_tick()
                except Exception as exc:  # noqa: BLE001 - e.g. the socket closed at shutdown; the executor goes on
                    if self.receiver.is_open:
                        self.get_logger().error(f"lockstep tick failed: {exc!r}")
                        time.sleep(0.01)

    def poll_amplifier(self) -> None:
        """Apply the amplifier's outputs received since the last poll, each from its send time.

        In real time the datagram carries the amplifier's monotonic send time (same host, same
        clock; a time in the future applies now); in simulated time it is stamped with the
        simulated clock (use_sim_time). The simulator integrates up to that instant with the
        previous voltage first, so executor and transport delays do not shift the physics.
        """
        received_all = self.receiver.poll_all()
        for received in received_all:
            if self.publish_clock:
                self.amp_time_s = max(self.amp_time_s or received.sent_s, received.sent_s)
                self.sim.apply_voltage(received.voltage_V, from_s=received.sent_s)
            else:
                sent_s = received.sent_s if received.sent_s <= time.monotonic() else None
                self.sim.apply_voltage(received.voltage_V, from_s=sent_s)
        if self.receiver.applied_voltage_V() == 0.0 and self.sim.voltage_V != 0.0:
            self.sim.apply_voltage(0.0)  # the dead-man expired: the amplifier's output is off

    def emit_samples(self, t_end: float, to_ros_offset: float) -> None:
        """Publish laser samples acquired up to t_end (simulation time axis)."""
        if self.range_pub is None:
            return
        for t_acq, d in self.sampler.samples_until(t_end):
            t_ros_ns = int(round((t_acq + to_ros_offset) * 1e9))
            self.range_pub.publish(make_range(d, t_ros_ns, "dea_laser"))
            self.published += 1

    def on_realtime_tick(self) -> None:
        self.poll_amplifier()
        now = time.monotonic()
        self.sim.advance_to(now)
        self.emit_samples(now, self.mono_to_ros)

    def _tick_start_s(self) -> float:
        """Earliest stamp that acknowledges the current tick: half a tick before it. Stamps travel as
        integer ns and come back as float seconds since the epoch, where one rounding step is ~0.2 us:
        an exact comparison would miss acknowledgements and wait for the timeout."""
        return self.clock_time_s - 0.5 / self.clock_rate_hz

    def amplifier_behind(self) -> bool:
        """True while the amplifier's output for the current tick has not arrived."""
        return self.amp_time_s is not None and self.amp_time_s < self._tick_start_s()

    def participants_behind(self) -> str | None:
        """The first active lockstep participant that has not acknowledged the current tick, or None."""
        t = self._tick_start_s()
        now = time.monotonic()
        for topic, (stamp_s, wall_s) in self.ack_times.items():
            if stamp_s < t and now - wall_s < self.lockstep_timeout_s:
                return topic  # an active participant (acked within the timeout) is behind
        return None

    def _pause_if_idle(self) -> bool:
        """``pause_when_idle``: True (the clock stands) while no participant acknowledged within the timeout,
        once one has (before, the clock runs: the nodes starting need it, and amplifier_node ramps to 0 V
        when its clock stalls for 2 s while it is active)."""
        if not self.ack_times:
            return False
        now = time.monotonic()
        # a participant is not idle while its last acknowledgement covers the current tick (a batch of
        # commands acknowledged once for several ticks, issue 22), however long those ticks take
        tick_start = self._tick_start_s()
        idle = not any(now - wall_s < self.lockstep_timeout_s or stamp_s >= tick_start
                       for stamp_s, wall_s in self.ack_times.values())
        if idle != self.paused:
            self.paused = idle
            if idle:
                self.watch_timer.cancel()  # nothing to time out: an acknowledgement resumes the clock
            else:
                self.watch_timer.reset()
            self.wall_t0 = now - self.tick_index / (self.clock_rate_hz * self.real_time_factor)  # no catch-up burst
            self.get_logger().info(f"simulated clock {'paused' if idle else 'resumed'} at t = "
                                   f"{self.clock_time_s - self.sim_t0:.3f} s (simulated)")
        return idle

    def on_ack(self, topic: str):
        def record(msg: Header) -> None:
            if topic not in self.ack_times:
                self.get_logger().info(f"lockstep: {topic} acknowledges ticks; the simulated clock waits for it")
            with self.tick_lock:  # (subscribed with publish_clock only)
                if not self.ack_times:   # from here on real_time_factor paces (before: real time), no burst
                    self.wall_t0 = time.monotonic() - self.tick_index / (self.clock_rate_hz * self.real_time_factor)
                self.ack_times[topic] = (msg.stamp.sec + msg.stamp.nanosec * 1e-9, time.monotonic())
                self.acks_received += 1
                self._advance()  # the last acknowledgement starts the next tick without waiting for the timer
        return record

    def _waited_too_long(self, what: str) -> bool:
        """Lockstep wait: False while within ``lockstep_timeout_s`` (keep waiting); True (counted) after it."""
        waited = time.monotonic() - self.tick_wall_s
        if waited < self.lockstep_timeout_s:
            return False
        self.lockstep_timeouts += 1
        if self.lockstep_timeouts <= 10 or self.lockstep_timeouts in (100, 1000) or self.lockstep_timeouts % 10000 == 0:
            self.get_logger().warning(
                f"{what} silent for {waited:.2f} s (wall) at simulated t = {self.clock_time_s:.3f} s: "
                f"continuing ({self.lockstep_timeouts} timeouts)")
        return True

    def release_samples(self) -> bool:
        """Publish the current tick's laser samples once the amplifier's output for it arrived (lockstep).

        The amplifier applies its voltage for t_k first; the samples up to t_k go out after it, so that
        every command computed from them reaches the amplifier within tick k (its update at t_k+1 applies
        it). Returns False while still waiting.
        """
        if self.lockstep and self.amplifier_behind() and not self._waited_too_long("amplifier"):
            return False
        self.emit_samples(self.clock_time_s, 0.0)
        self.samples_out = True
        self.tick_wall_s = time.monotonic()
        return True

    def on_sim_tick(self) -> None:
        """Advance the lockstep tick as far as possible (module docstring: clock, amplifier, samples, acks).
        Called by the executor's timers and by the thread that waits on the amplifier's socket."""
        with self.tick_lock:
            self._advance()

    def _rearm_timer(self) -> None:
        """Start the pacing timer; from the socket's thread, wake the executor to wait on it."""
        self.timer.reset()
        if threading.current_thread() is self.waiter:
            self.timer_rearmed.trigger()

    def _advance(self) -> None:
        """on_sim_tick's work, ``tick_lock`` held."""
        self.poll_amplifier()
        if not self.samples_out and not self.release_samples():
            return
        if self.tick_index / self.clock_rate_hz > (time.monotonic() - self.wall_t0) * self._pace():
            if self.timer.is_canceled():
                self._rearm_timer()
            return  # ahead of the requested speed: the pacing timer calls again
        if not self.timer.is_canceled():
            self.timer.cancel()
        if self.lockstep and self.clock_time_s is not None:
            if self.pause_when_idle and self._pause_if_idle():
                return
            behind = self.participants_behind()
            if behind is not None and not self._waited_too_long(behind):
                return
        n_ticks = self._ticks_covered()
        self.tick_index += n_ticks
        if n_ticks > 1:
            self.clock_jumps += 1
            if self.clock_jumps == 1:
                self.get_logger().info(f"lockstep: /clock advances up to {self.max_ticks_per_clock} ticks at once "
                                       f"while the acknowledgements cover them (first: {n_ticks})")
        t_new = self.sim.t0_s + self.tick_index / self.clock_rate_hz
        # up to the first of the ticks only: the amplifier's outputs for the others are applied, each from its
        # own update time, when they arrive (RigSimulator.apply_voltage integrates up to it first)
        self.sim.advance_to(self.sim.t0_s + (self.tick_index - n_ticks + 1) / self.clock_rate_hz)
        self.clock_time_s = t_new
        self.samples_out = False
        self.tick_wall_s = time.monotonic()
        self.publish_clock_time()
        self.release_samples()  # at once when the amplifier is not waited for
        if not (self.lockstep and (self.amp_time_s is not None or self.ack_times)) and self.timer.is_canceled():
            self._rearm_timer()  # nothing will wake the node (no amplifier yet, no lockstep): the timer paces

    def _pace(self) -> float:
        """Simulated s per wall s at most: ``real_time_factor``, but at most real time while the lockstep has not
        engaged (no acknowledgement yet: nothing waits for the nodes, which are starting; at the demo's x10 a
        tick would last 0.4 ms of wall time)."""
        if self.lockstep and not self.ack_times:
            return min(1.0, self.real_time_factor)
        return self.real_time_factor

    def _ticks_covered(self) -> int:
        """How many ticks the next ``/clock`` advances (``max_ticks_per_clock``): 1, or while every active
        participant has acknowledged ahead (amplifier_node acknowledges a batch of K commands once, stamped
        with the update before its last sample's) the ticks that acknowledgement covers, within the pace of
        ``real_time_factor``. The physics is the same as tick by tick: the amplifier runs one update per tick
        (each sample through its limits) and its outputs hold from their own update times; the laser samples
        of those ticks go out after the last output, as after each output with one tick per /clock. A
        participant that acknowledges each tick (a controller's ``tick_done``, a single ``voltage_cmd``)
        keeps one tick per /clock: the fixed sample-to-voltage delay does not change."""
        if self.max_ticks_per_clock <= 1 or not self.lockstep or self.clock_time_s is None:
            return 1
        now = time.monotonic()
        stamps = [stamp_s for stamp_s, wall_s in self.ack_times.values() if now - wall_s < self.lockstep_timeout_s]
        if not stamps:
            return 1
        period_s = 1.0 / self.clock_rate_hz
        # tick k + i may start once every participant acknowledged tick k + i - 1 (half a tick of rounding)
        covered = math.floor((min(stamps) - self.clock_time_s + 0.5 * period_s) / period_s) + 1
        paced = math.floor((now - self.wall_t0) * self._pace() * self.clock_rate_hz - self.tick_index) + 1
        return max(1, min(covered, paced, self.max_ticks_per_clock))

    def publish_clock_time(self) -> None:
        """Publish ``/clock`` = the current tick's time."""
        msg = Clock()
        sec = math.floor(self.clock_time_s)
        msg.clock.sec = int(sec)
        msg.clock.nanosec = min(int(round((self.clock_time_s - sec) * 1e9)), 999_999_999)
        self.clock_pub.publish(msg)

    def publish_diagnostics(self) -> None:
        lag = (time.monotonic() - self.wall_t0) * self.real_time_factor - (self.sim.t_s - self.sim_t0) \
            if self.publish_clock else 0.0
        publish_diagnostic(
            self, self.diag_pub, f"{self.get_name()}: simulated rig", self.sim.params.name,
            DiagnosticStatus.OK, "running",
            [("voltage_V", f"{self.sim.voltage_V:.1f}"),
             ("displacement_m", f"{self.sim.displacement_m:.9f}"),
             ("physics_steps", self.sim.steps), ("samples_published", self.published),
             ("amplifier_datagrams", self.receiver.received_count), ("sim_lag_s", f"{lag:.3f}"),
             ("amplifier_deadman_trips", self.receiver.deadman_trip_count),
             ("lockstep_timeouts", self.lockstep_timeouts), ("lockstep", self.lockstep_state()),
             ("lockstep_acks", self.acks_received), ("clock_ticks", self.tick_index),
             ("clock_messages_of_several_ticks", self.clock_jumps)],
        )

    def lockstep_state(self) -> str:
        """'real time', 'free-running' (no participant acknowledged yet), 'paused' or 'lockstep'."""
        if not self.publish_clock:
            return "real time"
        if not (self.lockstep and self.ack_times):
            return "free-running"
        return "paused" if self.paused else "lockstep"

    def shutdown_safely(self) -> None:
        """Stop the serial emulator (removes its symlink) and release the UDP port; idempotent, and safe on
        a node whose start-up was refused part-way."""
        if self.emulator is not None:
            self.emulator.stop()
            self.emulator = None
        if self.receiver is not None and self.receiver.is_open:
            if self.tick_lock is not None:
                with self.tick_lock:  # not in the middle of the socket thread's tick
                    self.receiver.close()
            else:
                self.receiver.close()

    def destroy_node(self):
        self.shutdown_safely()
        return super().destroy_node()


def _wall_clock() -> RclClock:
    """The steady clock: timers that must not follow a simulated /clock."""
    return RclClock(clock_type=ClockType.STEADY_TIME)


def main(args=None) -> None:
    run_node(MockHardwareNode, args)


if __name__ == "__main__":
    main()
