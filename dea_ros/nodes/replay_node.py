"""The replay node of ``dea-ros replay BAG``: a bag's topics republished with the original timing.

Messages are republished as recorded (raw CDR, no decoding) with the recorded offered QoS, at
``--rate`` times the original speed, optionally in a loop, for a subset of topics
(``--topics``), from ``--start-offset`` seconds into the bag. With ``--clock`` the bag time is
published on ``/clock`` so that nodes with ``use_sim_time`` (e.g. model_node) run on the log's time.

The bag side is not ROS: :func:`open_playback` checks the bag and the topics and finds the first
log time, :func:`playback_schedule` yields each message with the time it is due (pauses longer
than ``--max-gap`` cut out). This module only creates the node, its publishers and their QoS, and
sleeps until each message is due. rclpy is imported when a replay starts (an optional dependency
of the command line: without ROS 2 the command says how to get it).
"""
from __future__ import annotations

import importlib
import math
import time
from dataclasses import dataclass
from typing import Callable, Iterator

from ..bag import BagReader

__all__ = ["register", "replay", "cmd_replay", "message_class", "playback_qos", "BagPlayback", "open_playback",
           "playback_schedule"]


def message_class(type_name: str):
    """``pkg/msg/Type`` -> the rclpy message class."""
    try:
        pkg, kind, name = type_name.split("/")
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ValueError, ImportError, AttributeError):
        raise ValueError(f"message type {type_name!r} is not installed (source its ROS package)") from None


def playback_qos(profiles):
    """The offer for playback, as rosbag2's ``Rosbag2QoS::adapt_offer_to_recorded_offers``.

    History is always keep_last 10 (recorded profiles of discovered publishers say ``unknown``/0);
    reliability and durability are the recorded ones when every recorded publisher agreed,
    else rosbag2's default offer (reliable, volatile).
    """
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    if not profiles or len({(p.reliability, p.durability) for p in profiles}) != 1:
        return QoSProfile(depth=10)
    p = profiles[0]
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=10,
        reliability=ReliabilityPolicy.BEST_EFFORT if p.reliability == "best_effort" else ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if p.durability == "transient_local" else DurabilityPolicy.VOLATILE,
    )


# ---------------------------------------------------------------------------- the bag's schedule (no ROS)
@dataclass(frozen=True)
class BagPlayback:
    """What a replay plays: the bag, its topics (name -> topic info), the topics replayed and the
    first real log time, ns."""

    path: object
    topics: dict
    wanted: list
    first_log_time_ns: int


def open_playback(bag_path, topics=None) -> BagPlayback:
    """Check the bag and the topics (default: all); a ValueError names the topics it lacks."""
    with BagReader(bag_path) as bag:
        info = bag.topics()
        wanted = list(info) if not topics else list(topics)
        missing = [t for t in wanted if t not in info]
        if missing:
            raise ValueError(f"{bag_path}: topics {missing} are not in the bag (it has {sorted(info)})")
        # the first real log time (a message logged with time 0, e.g. before a simulated clock
        # started, would otherwise make the replay wait decades)
        t_first = next((m.log_time_ns for m in bag.raw_messages(wanted) if m.log_time_ns > 0), 0)
    return BagPlayback(bag_path, info, wanted, t_first)


def playback_schedule(playback: BagPlayback, start_offset_s: float = 0.0, max_gap_s: float = 10.0,
                      on_gap: Callable[[int], None] | None = None) -> Iterator[tuple[int, object]]:
    """One pass over the bag: (ns after the start of the pass at rate 1, raw message) in log-time order.

    Messages before ``start_offset_s`` (s after the first log time) are left out; a pause in the
    log longer than ``max_gap_s`` is cut out (``on_gap(pause_ns)`` is called for each).
    """
    offset_ns = int(start_offset_s * 1e9)
    skipped_ns = 0
    previous_ns = None
    with BagReader(playback.path) as bag:
        for msg in bag.raw_messages(playback.wanted):
            rel = msg.log_time_ns - playback.first_log_time_ns - offset_ns
            if rel < 0:
                continue
            if previous_ns is not None and msg.log_time_ns - previous_ns > max_gap_s * 1e9:
                skipped_ns += msg.log_time_ns - previous_ns  # a long pause in the log: do not wait it out
                if on_gap is not None:
                    on_gap(msg.log_time_ns - previous_ns)
            previous_ns = msg.log_time_ns
            yield rel - skipped_ns, msg


# ---------------------------------------------------------------------------- the node
class _Publishers:
    """The replay node's publishers: one per replayed topic with its recorded QoS, and /clock."""

    def __init__(self, node, playback: BagPlayback, publish_clock: bool):
        self.pubs = {t: node.create_publisher(message_class(playback.topics[t].type), t,
                                              playback_qos(playback.topics[t].qos_profiles))
                     for t in playback.wanted}
        self.clock_class = message_class("rosgraph_msgs/msg/Clock") if publish_clock else None
        self.clock_pub = node.create_publisher(self.clock_class, "/clock", 10) if publish_clock else None
        self.published = 0

    def publish(self, msg) -> None:
        """The raw message on its topic (after the bag time on /clock, with ``--clock``); counted."""
        if self.clock_pub is not None:
            c = self.clock_class()
            c.clock.sec, c.clock.nanosec = divmod(msg.log_time_ns, 1_000_000_000)
            self.clock_pub.publish(c)
        self.pubs[msg.topic].publish(msg.data)
        self.published += 1


def _play_once(playback: BagPlayback, publishers: _Publishers, rate: float, start_offset_s: float,
               max_gap_s: float, quiet: bool) -> None:
    """One pass over the bag in real time / ``rate``."""
    def on_gap(pause_ns: int) -> None:
        if not quiet:
            print(f"replay: skipping a gap of {pause_ns * 1e-9:.1f} s")

    start_wall = time.monotonic()
    for due_ns, msg in playback_schedule(playback, start_offset_s, max_gap_s, on_gap):
        delay = start_wall + due_ns * 1e-9 / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        publishers.publish(msg)


def replay(bag_path, rate: float = 1.0, loop: bool = False, topics=None, start_offset_s: float = 0.0,
           publish_clock: bool = False, quiet: bool = False, max_loops: int | None = None,
           max_gap_s: float = 10.0, delay_s: float = 0.5) -> int:
    """Republish; returns the number of messages published (the bag and options are checked first)."""
    if not rate > 0:
        raise ValueError(f"--rate: must be > 0, got {rate}")
    playback = open_playback(bag_path, topics)
    try:
        import rclpy
        from rclpy.node import Node
    except ImportError as exc:  # a valid bag, but no ROS 2 in this environment: a set-up error (exit 2)
        raise ValueError(f"replay publishes on ROS 2 and needs rclpy ({exc}): source /opt/ros/<distro>/setup.bash "
                         "(or use the venv of scripts/setup_env.sh, which has the ROS 2 wheels)") from None
    rclpy.init()
    node = Node("dea_ros_replay")
    publishers = None
    loops = 0
    try:
        publishers = _Publishers(node, playback, publish_clock)
        time.sleep(max(0.0, delay_s))  # let subscribers discover the publishers first
        while True:
            _play_once(playback, publishers, rate, start_offset_s, max_gap_s, quiet)
            loops += 1
            if not loop or (max_loops is not None and loops >= max_loops):
                break
            if not quiet:
                print(f"replay: loop {loops} done ({publishers.published} messages)", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.shutdown()
    return publishers.published if publishers is not None else 0


# ---------------------------------------------------------------------------- the command
def cmd_replay(args) -> int:
    """``dea-ros replay``: check the options, replay, report the count."""
    for option, value, low, high in (("--rate", args.rate, 1e-3, 1e3), ("--start-offset", args.start_offset, 0.0, 1e7),
                                     ("--delay", args.delay, 0.0, 3600.0), ("--max-gap", args.max_gap, 1e-3, 1e7)):
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"{option}: must be from {low:g} to {high:g}, got {value:g}")
    n = replay(args.bag, rate=args.rate, loop=args.loop, topics=args.topics, start_offset_s=args.start_offset,
               publish_clock=args.clock, max_gap_s=args.max_gap, delay_s=args.delay)
    print(f"replayed {n} messages from {args.bag}")
    return 0


def register(subparsers) -> None:
    """Add the ``replay`` subcommand."""
    p = subparsers.add_parser("replay", help="republish a bag's topics with the original timing (ROS 2)")
    p.add_argument("bag", help="bag directory or .mcap file")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (2: twice as fast)")
    p.add_argument("--loop", action="store_true", help="start again at the end")
    p.add_argument("--topics", nargs="+", help="only these topics (default: all)")
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S", help="skip the first S seconds")
    p.add_argument("--clock", action="store_true", help="publish the bag time on /clock (use_sim_time)")
    p.add_argument("--delay", type=float, default=0.5, metavar="S",
                   help="wait before the first message so that subscribers are discovered")
    p.add_argument("--max-gap", type=float, default=10.0, metavar="S",
                   help="pauses in the log longer than this are skipped, not waited out")
    p.set_defaults(func=cmd_replay)
