"""Recorder process for test_crash_recovery: writes continuously until it is SIGKILLed.

Usage: python sigkill_writer_script.py <bag_dir> <flush_period_s>

Message i: /dea/range Range with header.stamp.nanosec = i, header.frame_id = "m<i>",
range = i * 0.25 (exact in float32); /dea/voltage Float64 with data = i * 0.5. Both are logged
at the same wall-clock time ``time.time_ns()``. Prints "ready" once the topics are registered.
"""

import sys
import time

from dea_ros.bag import BagWriter, sensor_data_qos


def main() -> None:
    bag_dir, flush_period_s = sys.argv[1], float(sys.argv[2])
    # Big chunks: only the time-based flush can put data on disk before the kill.
    writer = BagWriter(bag_dir, flush_period_s=flush_period_s, chunk_size_bytes=64 * 1024 * 1024)
    writer.add_topic("/dea/range", "sensor_msgs/msg/Range", sensor_data_qos())
    writer.add_topic("/dea/voltage", "std_msgs/msg/Float64")
    print("ready", flush=True)
    i = 0
    while True:
        now = time.time_ns()
        writer.write(
            "/dea/range",
            {"header": {"stamp": {"sec": 0, "nanosec": i}, "frame_id": f"m{i}"}, "range": i * 0.25},
            now,
        )
        writer.write("/dea/voltage", {"data": i * 0.5}, now)
        i += 1
        time.sleep(0.0005)


if __name__ == "__main__":
    main()
