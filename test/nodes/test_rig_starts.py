"""Issue 20: `dea-ros rig up` with staggered node starts delivers displacement (two fixed staggerings;
the 20-run measurement with random 0-30 s delays is bench/bench_rig_starts.py)."""
import importlib.util
import os
import socket
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from dea_ros.cli.rig import RigProcesses  # noqa: E402 - needs rclpy
from dea_ros.sim import free_udp_port  # noqa: E402

_SPEC = importlib.util.spec_from_file_location(
    "bench_rig_starts", Path(__file__).resolve().parents[2] / "bench" / "bench_rig_starts.py")
bench = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(bench)


@pytest.mark.parametrize("delays", [
    # the laser node 12 s after the emulator began streaming unread: its buffer was trimmed mid-frame
    {"mock_hardware_node": 0.0, "amplifier_node": 1.0, "model_node": 2.0, "laser_sensor_node": 12.0},
    # the laser node first, the sensor (mock) 6 s later: the node retries until the port exists
    {"laser_sensor_node": 0.0, "model_node": 1.0, "amplifier_node": 4.0, "mock_hardware_node": 6.0},
])
def test_staggered_rig_starts_deliver_displacement(delays):
    result = bench.staggered_start(delays, timeout_s=40.0)
    assert result["problem"] is None, result
    assert result["seconds_to_displacement"] is not None, result


@pytest.mark.parametrize("node, params, reason", [
    ("mock_hardware_node", {"params_file": "A2", "laser_output": "carrier_pigeon"},
     "mock_hardware_node: parameter 'laser_output': topic, emulator or both, got 'carrier_pigeon'"),
    ("mock_hardware_node", {"params_file": "/nonexistent/membrane.yaml"},
     "mock_hardware_node: parameter 'params_file': /nonexistent/membrane.yaml: no such parameters file"),
    ("model_node", {"params_file": "/nonexistent/membrane.yaml"},
     "model_node: parameter 'params_file': /nonexistent/membrane.yaml: no such parameters file"),
    ("laser_sensor_node", {"backend": "carrier_pigeon"},
     "laser_sensor_node: parameter 'backend': ild1320 or mock, got 'carrier_pigeon'"),
])
def test_a_refused_start_is_reported_with_its_reason_even_when_quiet(node, params, reason):
    """A rig node that refuses its parameters exits with its reason as the last line it prints (a node
    refused part-way must not end in an AttributeError from its own clean-up), and the rig's report
    names the node, its exit code and that line (`dea-ros rig up` and the demo keep node output off the
    screen)."""
    assert_refused(node, params, reason)


def test_a_mock_whose_amplifier_port_is_taken_names_the_parameter():
    """The start-up failure stop 35's CI may have met: the amplifier's port held by another socket (in
    simulated time, where the clock's lock exists only later). The mock names the parameter and the fix."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("127.0.0.1", free_udp_port()))
        port = holder.getsockname()[1]
        assert_refused("mock_hardware_node",
                       {"params_file": "A2", "amplifier_port": port, "publish_clock": True, "laser_output": "topic"},
                       f"mock_hardware_node: parameter 'amplifier_port': MockAmplifierReceiver: cannot bind UDP "
                       f"127.0.0.1:{port}")


def assert_refused(node: str, params: dict, reason: str) -> None:
    """``node`` started with ``params`` exits 1, the rig's report ends with ``reason``, no traceback."""
    rig = RigProcesses(namespace=f"/refused_{os.getpid()}", quiet=True)
    try:
        rig.start(node, params).wait(timeout=60.0)
        problem = rig.check_alive()
    finally:
        rig.stop()
    assert problem is not None and problem.startswith(f"{node} exited with code 1; its last lines:"), problem
    assert problem.splitlines()[-1].strip().startswith(reason), problem
    assert "Traceback" not in problem, problem
