"""Node benchmarks (each node in its own process, real rclpy over loopback DDS).

1. model_node latency: a publisher process sends sensor_msgs/BatteryState voltages at 1 kHz,
   stamped at send time; model_node (own process) answers each with displacement_predicted
   stamped like its input; this process receives the predictions and measures
   receive time - stamp (same host clock). Median and p99 over ``--latency-s`` seconds.
2. Sensor pipeline: mock_hardware_node serves the ILD1320 emulator at 2 kHz on a pty,
   laser_sensor_node reads and publishes ``displacement``; this process counts the samples over
   ``--pipeline-s`` seconds and the gaps in their acquisition stamps (a sample dropped anywhere
   in the pipeline leaves a 1 ms gap instead of 0.5 ms).

Run: python bench/bench_nodes.py [--latency-s 30] [--pipeline-s 60]  (writes bench/results/nodes.md)
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

RATE = float(os.environ.get("DEA_BENCH_MODEL_RATE", "1000.0"))

PUBLISHER = r"""
import sys, time, rclpy
from rclpy.node import Node
from sensor_msgs.msg import BatteryState
from dea_ros.nodes.common import SENSOR_QOS, make_voltage_state
rclpy.init(); n = Node('voltage_source'); pub = n.create_publisher(BatteryState, 'voltage', SENSOR_QOS)
duration = float(sys.argv[1])
# wait until the node under test is up (a loaded machine: 10+ s), then 1 s more
t_wait = time.monotonic() + 120.0
while pub.get_subscription_count() == 0 and time.monotonic() < t_wait: time.sleep(0.05)
time.sleep(1.0)
t_end = time.monotonic() + duration; k = 0; next_t = time.monotonic()
while time.monotonic() < t_end:
    u = 2200.0 if (k // 500) % 2 else 0.0
    pub.publish(make_voltage_state(u, n.get_clock().now().nanoseconds, True)); k += 1
    next_t += 0.001
    delay = next_t - time.monotonic()
    if delay > 0: time.sleep(delay)
print(k, flush=True)
"""


def bench_latency(seconds: float, env) -> dict:
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import Range

    from dea_ros.nodes.common import SENSOR_QOS

    model = subprocess.Popen([sys.executable, "-m", "dea_ros.nodes.model_node", "--ros-args", "-p", f"rate_hz:={RATE}"],
                             env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    source = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(seconds)], env=env, stdout=subprocess.PIPE,
                              text=True)
    rclpy.init()
    node = Node("latency_probe")
    lat = []

    def on_pred(msg):
        now = node.get_clock().now().nanoseconds
        lat.append((now - (msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)) * 1e-9)

    node.create_subscription(Range, "displacement_predicted", on_pred, SENSOR_QOS)
    t_end = time.monotonic() + seconds + 130.0
    while time.monotonic() < t_end and source.poll() is None:
        rclpy.spin_once(node, timeout_sec=0.01)
    sent = int(source.communicate(timeout=10)[0].strip() or 0)
    model.terminate()
    model.wait(timeout=10)
    node.destroy_node()
    rclpy.shutdown()
    lat = np.array(lat)
    lat = lat[(lat > 0) & (lat < 0.5)]  # predictions of the model's own timer (no input) are not responses
    return {"sent": sent, "received": int(lat.size), "median_ms": float(np.median(lat) * 1e3),
            "p99_ms": float(np.percentile(lat, 99) * 1e3), "max_ms": float(lat.max() * 1e3)}


def bench_pipeline(seconds: float, env) -> dict:
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import Range

    from dea_ros.nodes.common import SENSOR_QOS

    link = f"/tmp/dea_ros_bench_laser_{os.getpid()}"
    mock = subprocess.Popen([sys.executable, "-m", "dea_ros.nodes.mock_hardware_node", "--ros-args",
                             "-p", "laser_output:=emulator", "-p", f"laser_port:={link}", "-p", "amplifier_port:=0"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(2.0)
    laser = subprocess.Popen([sys.executable, "-m", "dea_ros.nodes.laser_sensor_node", "--ros-args",
                              "-p", f"port:={link}", "-p", "zero_offset_m:=0.002", "-p", "measuring_rate_hz:=2000.0"],
                             env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rclpy.init()
    node = Node("pipeline_probe")
    stamps = []
    node.create_subscription(Range, "displacement",
                             lambda m: stamps.append(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9), SENSOR_QOS)
    t_warm = time.monotonic() + 3.0
    while time.monotonic() < t_warm:
        rclpy.spin_once(node, timeout_sec=0.01)
    stamps.clear()
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        rclpy.spin_once(node, timeout_sec=0.01)
    for p in (laser, mock):
        p.terminate()
        p.wait(timeout=10)
    node.destroy_node()
    rclpy.shutdown()
    t = np.sort(np.array(stamps))
    dt = np.diff(t)
    expected = int(round((t[-1] - t[0]) * 2000)) + 1
    dropped = int(np.sum(np.maximum(np.round(dt / 0.5e-3) - 1, 0)))
    return {"received": int(t.size), "expected_from_stamps": expected, "dropped": dropped,
            "rate_Hz": float((t.size - 1) / (t[-1] - t[0])), "max_gap_ms": float(dt.max() * 1e3)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--latency-s", type=float, default=30.0)
    ap.add_argument("--pipeline-s", type=float, default=60.0)
    args = ap.parse_args()
    env = dict(os.environ)
    env.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
    os.environ.update(env)
    lat = bench_latency(args.latency_s, env)
    pipe = bench_pipeline(args.pipeline_s, env)
    text = "\n".join([
        f"Machine: {machine()}", "",
        f"### model_node latency, voltage message -> prediction, 1 kHz for {args.latency_s:g} s (separate processes)",
        "", "| sent | received | median [ms] | p99 [ms] | max [ms] |", "|---|---|---|---|---|",
        f"| {lat['sent']} | {lat['received']} | {lat['median_ms']:.3f} | {lat['p99_ms']:.3f} | {lat['max_ms']:.2f} |",
        "",
        f"### Sensor pipeline: ILD1320 emulator (2 kHz, pty) -> laser_sensor_node -> subscriber, {args.pipeline_s:g} s",
        "", "| received | expected (from stamps) | dropped | rate [Hz] | max gap [ms] |", "|---|---|---|---|---|",
        f"| {pipe['received']} | {pipe['expected_from_stamps']} | {pipe['dropped']} | {pipe['rate_Hz']:.1f} | "
        f"{pipe['max_gap_ms']:.2f} |", "",
    ])
    print(text)
    out = Path(__file__).with_name("results")
    out.mkdir(exist_ok=True)
    (out / "nodes.md").write_text(text + "\n")


if __name__ == "__main__":
    main()
