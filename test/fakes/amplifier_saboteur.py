"""Helper process: amplifier_node and a saboteur node run by the package's runner (as ``ros2 run``
would), the saboteur drives the amplifier to 2 kV, then breaks the process:

* ``raise``: an uncaught exception in the saboteur's callback escapes the executor;
* ``shutdown``: rclpy is shut down from another thread (executor shutdown).

Usage: amplifier_saboteur.py MODE UDP_PORT NAMESPACE
"""
import sys
import threading
import time

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

from dea_ros.nodes.amplifier_node import AmplifierNode
from dea_ros.nodes.runner import run_nodes


def main():
    mode, port, namespace = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    nodes = {}

    def amplifier():
        node = AmplifierNode(namespace=namespace, parameter_overrides=[
            Parameter("backend", value="mock"), Parameter("mock_port", value=port),
            Parameter("params_file", value="A2"), Parameter("update_rate_hz", value=250.0),
            Parameter("slew_rate_V_per_s", value=20000.0), Parameter("ramp_down_rate_V_per_s", value=10000.0),
            Parameter("watchdog_timeout_s", value=2.0)])
        node.trigger_configure()
        node.trigger_activate()
        nodes["amp"] = node
        return node

    class Saboteur(Node):
        def __init__(self):
            super().__init__("saboteur", namespace=namespace)
            self.pub = self.create_publisher(Float64, "voltage_cmd", 10)
            self.create_timer(0.01, self.tick)
            self.done = False

        def tick(self):
            self.pub.publish(Float64(data=2000.0))
            amp = nodes["amp"]
            if self.done or amp.controller is None or amp.controller.output_V < 2000.0:
                return
            self.done = True
            print("at 2 kV", flush=True)
            if mode == "raise":
                raise RuntimeError("saboteur: an uncaught exception in a callback")
            threading.Thread(target=lambda: (time.sleep(0.05), rclpy.shutdown()), daemon=True).start()

    run_nodes([amplifier, Saboteur], args=sys.argv[:1])


if __name__ == "__main__":
    main()
