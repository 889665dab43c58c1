"""``dea-ros bag info BAG``, ``dea-ros bag recover BAG``, ``dea-ros bag convert BAG --to FORMAT`` (no ROS needed).

``bag info`` verifies what it reports (chunk CRCs, decompression, indexes, summary, and that
every message decodes with its schema) and exits 2 naming the file and record when the bag is
corrupt. ``bag recover`` refuses damaged data unless ``--salvage`` and says when the disk is full.
``bag convert`` rewrites a bag in the Humble or the Jazzy rosbag2 format.
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from typing import Any

from ..bag.convert import convert_bag
from ..bag.reader import BagReader
from ..bag.recover import recover_bag

__all__ = ["register"]


def cmd_bag_info(args: argparse.Namespace) -> int:
    """``dea-ros bag info BAG [--json] [--no-verify]``: what the bag holds, and its corruption."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        bag = BagReader(args.bag)
    for warning in caught:
        print(f"dea-ros bag info: warning: {warning.message}", file=sys.stderr)
    with bag:
        out = _bag_information(bag)
        corruption = [] if args.no_verify else bag.verify()
        out["corruption"] = corruption
    if args.json:
        print(json.dumps(out, indent=2))
        return _report_corruption(args.bag, corruption)
    print(f"bag {out['path']}: {out['messages']} messages, {out['duration_s']:.3f} s"
          f"{' (TRUNCATED: run dea-ros bag recover)' if out['truncated'] else ''}")
    for name, t in out["topics"].items():
        print(f"  {name:<40} {t['type']:<32} {t['messages']:>8}  {', '.join(t['qos'])}")
    if out["metadata"]:
        print(f"  metadata records: {', '.join(out['metadata'])}")
    return _report_corruption(args.bag, corruption)


def _bag_information(bag: BagReader) -> dict[str, Any]:
    """What ``bag info`` reports (its JSON, without the corruption list)."""
    topics = bag.topics()
    meta = bag.metadata()
    return {
        "path": str(bag.path),
        "files": [str(f) for f in bag.files],
        "messages": bag.message_count,
        "start_time_ns": bag.start_time_ns,
        "end_time_ns": bag.end_time_ns,
        "duration_s": (bag.end_time_ns - bag.start_time_ns) * 1e-9 if bag.message_count else 0.0,
        "truncated": bag.truncated,
        "topics": {name: {"type": t.type, "messages": t.message_count,
                          "qos": [q.reliability + "/" + q.durability + f"/depth {q.depth}" for q in t.qos_profiles]}
                   for name, t in topics.items()},
        "metadata": sorted(meta),
    }


def _report_corruption(bag: str, corruption: list[str]) -> int:
    """Print the corruption found (if any) to stderr; the exit status (2 when corrupt)."""
    if not corruption:
        return 0
    print(f"dea-ros bag info: error: bag {bag} is CORRUPT ({len(corruption)} problem(s)):", file=sys.stderr)
    for problem in corruption:
        print(f"  {problem}", file=sys.stderr)
    print(f"  'dea-ros bag recover --salvage {bag}' keeps the readable records", file=sys.stderr)
    return 2


def cmd_bag_recover(args: argparse.Namespace) -> int:
    """``dea-ros bag recover BAG [--salvage] [--in-place]``: print what the recovery did."""
    report = recover_bag(args.bag, salvage=args.salvage, in_place=args.in_place)
    print(report.summary())
    return 0


def cmd_bag_convert(args: argparse.Namespace) -> int:
    """``dea-ros bag convert BAG --to FORMAT [--out DIR]``: print where the converted bag is."""
    target = convert_bag(args.bag, args.to, args.out)
    print(f"{target}: {args.bag} in the {args.to} rosbag2 format")
    return 0


def register(subparsers: Any) -> None:
    """Add the ``bag`` command group to the ``dea-ros`` parser's subparsers."""
    p = subparsers.add_parser("bag", help="inspect, recover or convert an MCAP bag")
    sub = p.add_subparsers(dest="bag_command", metavar="ACTION")
    sub.required = True
    info = sub.add_parser("info", help="topics, counts, QoS, duration")
    info.add_argument("bag")
    info.add_argument("--json", action="store_true")
    info.add_argument("--no-verify", action="store_true",
                      help="skip reading and decoding every record (faster; corruption goes unnoticed)")
    info.set_defaults(func=cmd_bag_info)
    rec = sub.add_parser("recover", help="make a bag readable after the recorder was killed")
    rec.add_argument("bag")
    rec.add_argument("--salvage", action="store_true",
                     help="keep what is readable of a damaged file, skipping damaged records")
    rec.add_argument("--in-place", action="store_true",
                     help="finish an unfinished file where it lies (no copy: works on a full disk)")
    rec.set_defaults(func=cmd_bag_recover)
    conv = sub.add_parser("convert", help="rewrite a bag in the Humble or the Jazzy rosbag2 format",
                          description="Humble's ros2 bag reads only the humble format (metadata version 5); "
                                      "Jazzy and newer read both. Messages, schemas, QoS and metadata are kept.")
    conv.add_argument("bag", help="bag directory")
    conv.add_argument("--to", required=True, choices=("humble", "jazzy"), help="target format")
    conv.add_argument("--out", help="new bag directory (default: BAG_<format> beside BAG)")
    conv.set_defaults(func=cmd_bag_convert)
