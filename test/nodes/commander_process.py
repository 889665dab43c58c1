"""Helper process for the amplifier tests: publishes a fuzzed voltage_cmd stream, then stays silent."""
import math
import random
import sys
import time

import rclpy
from rclpy.node import Node
from std_msgs.msg import Float64

from dea_ros.nodes.common import COMMAND_QOS


def main():
    seed, duration = int(sys.argv[1]), float(sys.argv[2])
    rng = random.Random(seed)
    rclpy.init()
    node = Node("fuzz_commander")
    pub = node.create_publisher(Float64, "voltage_cmd", COMMAND_QOS)
    specials = [math.nan, math.inf, -math.inf, -1.0, 1e5, 2430.0, 2431.0, 0.0]
    t_match = time.monotonic() + 20.0
    while pub.get_subscription_count() == 0 and time.monotonic() < t_match:
        time.sleep(0.01)  # discovery: a command published before the match is lost
    print("ready", flush=True)
    t_end = time.monotonic() + duration  # the whole stream after the match (discovery is slow under load)
    for value in specials:  # every special at least once (the random stream may miss some)
        pub.publish(Float64(data=value))
    while time.monotonic() < t_end:
        kind = rng.random()
        if kind < 0.1:
            burst = [rng.uniform(-3000, 5000) for _ in range(rng.randint(5, 50))]
        elif kind < 0.2:
            burst = [rng.choice(specials)]
        else:
            burst = [rng.uniform(0, 2400)]
        for value in burst:
            pub.publish(Float64(data=value))
        rclpy.spin_once(node, timeout_sec=0.0)
        time.sleep(rng.choice([0.001, 0.005, 0.02, 0.05]))
    print("silent", flush=True)
    while True:  # silence until killed
        time.sleep(1.0)


if __name__ == "__main__":
    main()
