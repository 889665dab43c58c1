"""``dea-ros replay BAG``: republish a bag's topics with their original timing (ROS 2).

The options are checked here; the node (:mod:`dea_ros.nodes.replay_node`) is loaded when the
command runs, so the command line works without ROS 2 and ``replay`` then says how to get it.
"""
from __future__ import annotations

import math

__all__ = ["register", "cmd_replay"]


def cmd_replay(args) -> int:
    """``dea-ros replay``: check the options, replay, report the count."""
    for option, value, low, high in (("--rate", args.rate, 1e-3, 1e3), ("--start-offset", args.start_offset, 0.0, 1e7),
                                     ("--delay", args.delay, 0.0, 3600.0), ("--max-gap", args.max_gap, 1e-3, 1e7)):
        if not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"{option}: must be from {low:g} to {high:g}, got {value:g}")
    from ..nodes.replay_node import replay

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
