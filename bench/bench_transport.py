"""The lockstep's floor: one ROS 2 message hop between two processes, as the rig's nodes pass a tick on.

Two processes (this one and an echo node started as a subprocess, both rclpy with the Python
SingleThreadedExecutor, std_msgs/Header, reliable depth 10 as the lockstep's acknowledgements) play
ping-pong ``--n`` times: a round trip is two hops, each a DDS delivery, an executor wake-up and a
Python callback. Prints the median and 90th percentile round trip, and the CPU per hop of each process.
A lockstep tick of ``dea-ros rig demo`` needs four such hops in series (mock -> amplifier -> identifier
-> amplifier -> mock) plus the amplifier's timer on the new clock: at 250 ticks per simulated second
and 2.5x real time a tick may take 1.6 ms of wall time.

Run: python bench/bench_transport.py [--n 2000]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import machine  # noqa: E402

ECHO = """
import rclpy, sys
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Header
rclpy.init()
node = rclpy.create_node("transport_echo")
pub = node.create_publisher(Header, sys.argv[1] + "/pong", 10)
node.create_subscription(Header, sys.argv[1] + "/ping", pub.publish, 10)
ex = SingleThreadedExecutor()
ex.add_node(node)
try:
    ex.spin()
except BaseException:
    pass
"""


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Header

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000)
    args = ap.parse_args()
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    ns = f"/transport{os.getpid()}"
    echo = subprocess.Popen([sys.executable, "-c", ECHO, ns])
    rclpy.init()
    node = rclpy.create_node("transport_ping")
    got = []
    node.create_subscription(Header, ns + "/pong", lambda m: got.append(time.perf_counter()), 10)
    pub = node.create_publisher(Header, ns + "/ping", 10)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    load0 = os.getloadavg()
    try:
        t_end = time.monotonic() + 30.0
        while not got and time.monotonic() < t_end:  # discovery
            pub.publish(Header())
            ex.spin_once(timeout_sec=0.1)
        got.clear()
        rtt = []
        cpu0 = (cpu_s(os.getpid()), cpu_s(echo.pid))
        for _ in range(args.n):
            t0 = time.perf_counter()
            pub.publish(Header())
            while not got:
                ex.spin_once(timeout_sec=1.0)
            rtt.append(got.pop() - t0)
        cpu1 = (cpu_s(os.getpid()), cpu_s(echo.pid))
    finally:
        echo.terminate()
        echo.wait()
        node.destroy_node()
        rclpy.shutdown()
    rtt_ms = 1e3 * np.array(rtt)
    print(f"machine: {machine()}; load {load0[0]:.1f} -> {os.getloadavg()[0]:.1f}")
    print(f"{args.n} round trips: median {np.median(rtt_ms):.2f} ms, p90 {np.percentile(rtt_ms, 90):.2f} ms "
          f"(one hop ~{np.median(rtt_ms) / 2:.2f} ms); CPU per round trip: pinger "
          f"{1e3 * (cpu1[0] - cpu0[0]) / args.n:.2f} ms, echo {1e3 * (cpu1[1] - cpu0[1]) / args.n:.2f} ms")


if __name__ == "__main__":
    main()
