"""Issue 20: `dea-ros rig up` with staggered node starts delivers displacement (two fixed staggerings;
the 20-run measurement with random 0-30 s delays is bench/bench_rig_starts.py)."""
import importlib.util
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

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
