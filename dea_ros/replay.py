"""``dea-ros replay BAG``: republish a bag's topics on their original names with the original timing.

Messages are republished as recorded (raw CDR, no decoding) with the recorded offered QoS, at
``--rate`` times the original speed, optionally in a loop, for a subset of topics
(``--topics``), from ``--start-offset`` seconds into the bag. With ``--clock`` the bag time is
published on ``/clock`` so that nodes with ``use_sim_time`` (e.g. model_node) run on the log's time.
"""
from __future__ import annotations

import importlib
import time

__all__ = ["register", "replay", "message_class", "playback_qos"]


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


def replay(bag_path, rate: float = 1.0, loop: bool = False, topics=None, start_offset_s: float = 0.0,
           publish_clock: bool = False, quiet: bool = False, max_loops: int | None = None,
           max_gap_s: float = 10.0, delay_s: float = 0.5) -> int:
    """Republish; returns the number of messages published (the bag and options are checked first)."""
    from .bag import BagReader

    if not rate > 0:
        raise ValueError(f"--rate: must be > 0, got {rate}")
    with BagReader(bag_path) as bag:
        info = bag.topics()
        wanted = list(info) if not topics else list(topics)
        missing = [t for t in wanted if t not in info]
        if missing:
            raise ValueError(f"{bag_path}: topics {missing} are not in the bag (it has {sorted(info)})")
        # the first real log time (a message logged with time 0, e.g. before a simulated clock
        # started, would otherwise make the replay wait decades)
        t_first = next((m.log_time_ns for m in bag.raw_messages(wanted) if m.log_time_ns > 0), 0)
    try:
        import rclpy
        from rclpy.node import Node
        from rosgraph_msgs.msg import Clock
    except ImportError as exc:  # a valid bag, but no ROS 2 in this environment: a set-up error (exit 2)
        raise ValueError(f"replay publishes on ROS 2 and needs rclpy ({exc}): source /opt/ros/<distro>/setup.bash "
                         "(or use the venv of scripts/setup_env.sh, which has the ROS 2 wheels)") from None
    rclpy.init()
    node = Node("dea_ros_replay")
    pubs = {t: node.create_publisher(message_class(info[t].type), t, playback_qos(info[t].qos_profiles))
            for t in wanted}
    clock_pub = node.create_publisher(Clock, "/clock", 10) if publish_clock else None
    published = 0
    loops = 0
    try:
        time.sleep(max(0.0, delay_s))  # let subscribers discover the publishers first
        while True:
            start_wall = time.monotonic()
            offset_ns = int(start_offset_s * 1e9)
            skipped_ns = 0
            previous_ns = None
            with BagReader(bag_path) as bag:
                for msg in bag.raw_messages(wanted):
                    rel = msg.log_time_ns - t_first - offset_ns
                    if rel < 0:
                        continue
                    if previous_ns is not None and msg.log_time_ns - previous_ns > max_gap_s * 1e9:
                        skipped_ns += msg.log_time_ns - previous_ns  # a long pause in the log: do not wait it out
                        if not quiet:
                            print(f"replay: skipping a gap of {(msg.log_time_ns - previous_ns) * 1e-9:.1f} s")
                    previous_ns = msg.log_time_ns
                    delay = start_wall + (rel - skipped_ns) * 1e-9 / rate - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                    if clock_pub is not None:
                        c = Clock()
                        c.clock.sec, c.clock.nanosec = divmod(msg.log_time_ns, 1_000_000_000)
                        clock_pub.publish(c)
                    pubs[msg.topic].publish(msg.data)
                    published += 1
            loops += 1
            if not loop or (max_loops is not None and loops >= max_loops):
                break
            if not quiet:
                print(f"replay: loop {loops} done ({published} messages)", flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.shutdown()
    return published


def cmd_replay(args) -> int:
    import math

    for option, value, low, high in (("--rate", args.rate, 1e-3, 1e3), ("--start-offset", args.start_offset, 0.0, 1e7),
                                     ("--delay", args.delay, 0.0, 3600.0), ("--max-gap", args.max_gap, 1e-3, 1e7)):
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"{option}: must be from {low:g} to {high:g}, got {value:g}")
    n = replay(args.bag, rate=args.rate, loop=args.loop, topics=args.topics, start_offset_s=args.start_offset,
               publish_clock=args.clock, max_gap_s=args.max_gap, delay_s=args.delay)
    print(f"replayed {n} messages from {args.bag}")
    return 0


def register(subparsers) -> None:
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
