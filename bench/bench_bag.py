"""Recorder throughput of dea_ros.bag.BagWriter (messages/second, no loss), as a markdown table.

Measures sustained writing of ``sensor_msgs/msg/Range``-sized messages (CDR, ~50 bytes) into a
rosbag2 MCAP bag, from the first write to ``close()`` (summary + metadata.yaml included):

* ``write_serialized`` with pre-serialized CDR bytes (what a node does with
  ``rclpy.serialization.serialize_message``), for zstd / lz4 / uncompressed chunks;
* ``write`` with a Python dict per message (mcap_ros2 dynamic CDR serialization).

Every run is read back with :class:`dea_ros.bag.BagReader` and must contain exactly the messages
written (no loss). Reported numbers are medians over ``--repeats`` runs (min-max in brackets).

Usage: ``python bench/bench_bag.py [--messages 200000] [--dict-messages 20000] [--repeats 5]``
"""

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from importlib.metadata import version
from pathlib import Path
from typing import Callable, List

from dea_ros.bag import BagReader, BagWriter, MessageDefinitionStore, sensor_data_qos
from dea_ros.bag.message_codec import message_encoder

TOPIC = "/dea/range"
TYPE = "sensor_msgs/msg/Range"


def range_dict(i: int) -> dict:
    """A Range message as the rig publishes it (frame 'dea_laser', range in metres)."""
    return {
        "header": {"stamp": {"sec": 1_700_000_000 + i // 1000, "nanosec": (i % 1000) * 1_000_000},
                   "frame_id": "dea_laser"},
        "radiation_type": 1,
        "field_of_view": 0.05,
        "min_range": 0.001,
        "max_range": 0.05,
        "range": 0.01 + 1e-6 * (i % 1000),
        "variance": 1e-10,
    }


def serialized_ranges(count: int) -> List[bytes]:
    """``count`` distinct CDR-encoded Range messages (same encoder the bag's write() uses)."""
    definition = MessageDefinitionStore().full_definition(TYPE)
    encode = message_encoder(TYPE, definition.text)
    return [encode(range_dict(i)) for i in range(count)]


def run_once(directory: Path, messages: int, compression: str, write: Callable) -> float:
    """Write ``messages`` messages; return messages per second (first write to close)."""
    bag = directory / f"bench_{compression}_{time.monotonic_ns()}"
    writer = BagWriter(bag, compression=compression, flush_period_s=1.0)
    writer.add_topic(TOPIC, TYPE, sensor_data_qos())
    t0_ns = time.time_ns()
    start = time.perf_counter()
    write(writer, messages, t0_ns)
    writer.close()
    elapsed = time.perf_counter() - start
    with BagReader(bag) as reader:
        stored = reader.topics()[TOPIC].message_count
        if stored != messages or reader.message_count != messages:
            raise RuntimeError(f"message loss: wrote {messages}, bag {bag} holds {stored}")
    for path in bag.iterdir():
        path.unlink()
    bag.rmdir()
    return messages / elapsed


def cpu_model() -> str:
    """The CPU model name (``/proc/cpuinfo``), else what ``platform`` says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def nproc() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=200_000, help="messages per write_serialized run")
    parser.add_argument("--dict-messages", type=int, default=20_000, help="messages per write() run")
    parser.add_argument("--repeats", type=int, default=5, help="runs per case (median reported)")
    parser.add_argument("--dir", type=Path, default=None, help="directory for the bags (default: temp)")
    args = parser.parse_args()

    payloads = serialized_ranges(1000)
    payload_size = statistics.mean(len(p) for p in payloads)

    def write_serialized(writer: BagWriter, count: int, t0_ns: int) -> None:
        ws = writer.write_serialized
        n_payloads = len(payloads)
        for i in range(count):
            ws(TOPIC, payloads[i % n_payloads], t0_ns + i * 1000)

    def write_dicts(writer: BagWriter, count: int, t0_ns: int) -> None:
        dicts = [range_dict(i) for i in range(1000)]
        for i in range(count):
            writer.write(TOPIC, dicts[i % 1000], t0_ns + i * 1000)

    cases = [
        ("write_serialized (CDR bytes)", "zstd", args.messages, write_serialized),
        ("write_serialized (CDR bytes)", "lz4", args.messages, write_serialized),
        ("write_serialized (CDR bytes)", "none", args.messages, write_serialized),
        ("write (dict -> CDR, mcap_ros2)", "zstd", args.dict_messages, write_dicts),
    ]
    with tempfile.TemporaryDirectory(dir=args.dir) as temporary:
        directory = Path(temporary)
        rows = []
        for label, compression, count, function in cases:
            rates = [run_once(directory, count, compression, function) for _ in range(args.repeats)]
            rows.append((label, compression, count, statistics.median(rates), min(rates), max(rates)))

    print("### dea_ros.bag recorder throughput\n")
    print(f"- machine: {nproc()} CPUs (nproc), {cpu_model()}, {platform.system()} {platform.release()}")
    print(f"- Python {platform.python_version()} ({sys.executable}); mcap {version('mcap')}, "
          f"mcap-ros2-support {version('mcap-ros2-support')}")
    print(f"- message: {TYPE}, {payload_size:.0f} bytes CDR; flush_period_s=1.0; median of {args.repeats} runs; "
          "time from first write to close(); every run read back, no loss\n")
    print("| API | compression | messages/run | median msg/s | min-max msg/s | median MB/s (payload) |")
    print("|---|---|---:|---:|---:|---:|")
    for label, compression, count, median, low, high in rows:
        print(
            f"| {label} | {compression} | {count:,} | {median:,.0f} | {low:,.0f}-{high:,.0f} | "
            f"{median * payload_size / 1e6:.1f} |"
        )


if __name__ == "__main__":
    main()
