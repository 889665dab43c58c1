"""Issue 20: `dea-ros rig up` started with staggered node start delays delivers displacement, every time.

Each run starts the rig of `dea-ros rig up` (:func:`dea_ros.cli.rig.start_rig`: every node in its
own process, as ``ros2 run`` would) with random start delays (0-30 s) per node -- so the laser node
may come up long after the emulated ILD1320 began streaming unread, or before the sensor exists --
and waits until a finite displacement arrives on ``/<ns>/displacement``, counted from the start of
the last node. A run fails when none arrives within ``--timeout`` s.

    python bench/bench_rig_starts.py --runs 20 [--seed 20] [--max-delay 30] [--timeout 30]

Results: docs/benchmarks.md ("Issue 20 (session 8)"). test/nodes/test_rig_starts.py runs two
fixed staggerings with :func:`staggered_start`.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import statistics
import sys
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Range

from dea_ros.cli.rig import DEFAULT_START_DELAYS_S, RigProcesses, start_rig

NODES = tuple(DEFAULT_START_DELAYS_S)


def staggered_start(delays_s: dict[str, float], timeout_s: float = 30.0, membrane: str = "A2") -> dict:
    """Start the rig with ``delays_s``; the seconds from the last node's start to the first finite
    displacement (``None``: none within ``timeout_s``) and what failed."""
    namespace = f"/stagger_{os.getpid()}_{int(time.monotonic() * 1000) % 100000}"
    ctx = Context()
    rclpy.init(context=ctx)
    node = Node("stagger_probe", context=ctx)
    got: list[float] = []
    node.create_subscription(Range, f"{namespace}/displacement",
                             lambda m: got.append(m.range) if math.isfinite(m.range) else None,
                             qos_profile_sensor_data)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    rig = RigProcesses(namespace=namespace, quiet=True)
    result = {"delays_s": dict(delays_s), "seconds_to_displacement": None, "problem": None}
    try:
        start_rig(rig, membrane, sim_time=False, speed=1.0, laser_rate_hz=2000.0, update_rate_hz=1000.0,
                  start_delays_s=delays_s)
        t0 = time.monotonic()
        while time.monotonic() < t0 + timeout_s and not got:
            ex.spin_once(timeout_sec=0.05)
            problem = rig.check_alive()
            if problem:
                result["problem"] = problem
                break
        if got:
            result["seconds_to_displacement"] = time.monotonic() - t0
    finally:
        rig.stop()
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=20)
    ap.add_argument("--max-delay", type=float, default=30.0)
    ap.add_argument("--timeout", type=float, default=30.0)
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    results = []
    for i in range(args.runs):
        delays = {name: round(rng.uniform(0.0, args.max_delay), 1) for name in NODES}
        r = staggered_start(delays, args.timeout)
        results.append(r)
        print(json.dumps({"run": i + 1, **r}), flush=True)
    ok = [r["seconds_to_displacement"] for r in results if r["seconds_to_displacement"] is not None]
    print(f"{len(ok)} of {len(results)} runs delivered displacement; seconds after the last node's start: "
          f"median {statistics.median(ok) if ok else float('nan'):.2f}, max {max(ok) if ok else float('nan'):.2f}")
    return 0 if len(ok) == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
