"""The replay node of ``dea-ros replay BAG``: a bag's topics republished with the original timing.

Messages are republished as recorded (raw CDR, no decoding) with the recorded offered QoS, at
``--rate`` times the original speed, optionally in a loop, for a subset of topics
(``--topics``), from ``--start-offset`` seconds into the bag. With ``--clock`` the bag time is
published on ``/clock`` so that nodes with ``use_sim_time`` (e.g. model_node) run on the log's time.

The bag side is not ROS (:mod:`dea_ros.bag.playback`): ``open_playback`` checks the bag and the
topics and finds the first log time, ``playback_schedule`` yields each message with the time it is
due (pauses longer than ``--max-gap`` cut out). This module only creates the node, its publishers and their QoS, and
sleeps until each message is due. rclpy is imported when a replay starts (an optional dependency
of the command line: without ROS 2 the command says how to get it).
"""
from __future__ import annotations

import importlib
import time

from ..bag.playback import BagPlayback, open_playback, playback_schedule

__all__ = ["replay", "message_class", "playback_qos"]


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
