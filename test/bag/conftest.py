"""Shared fixtures for the dea_ros.bag tests: deterministic messages of every rig type."""

import math
from pathlib import Path

import numpy as np
import pytest

from dea_ros.bag import MessageDefinitionStore, command_qos, sensor_data_qos

F32 = np.float32


def _f32(value: float) -> float:
    """A float exactly representable in float32 (so round trips compare with ==)."""
    return float(F32(value))


def _time(i: int) -> dict:
    return {"sec": 1_700_000_000 + i, "nanosec": (i * 7919) % 1_000_000_000}


def _header(i: int) -> dict:
    return {"stamp": _time(i), "frame_id": f"dea_frame_{i % 3}"}


def _range(i: int) -> dict:
    return {
        "header": _header(i),
        "radiation_type": i % 2,
        "field_of_view": _f32(0.05),
        "min_range": _f32(0.001),
        "max_range": _f32(0.05),
        "range": _f32(0.01 + 1e-5 * i),
        # no "variance": Humble's sensor_msgs/Range has no such field (added in sensor_msgs 5.0, Iron+)
    }


def _battery(i: int) -> dict:
    return {
        "header": _header(i),
        "voltage": _f32(12.0 - 0.01 * i),
        "temperature": _f32(25.0 + 0.1 * i),
        "current": _f32(-0.5 - 0.001 * i),
        "charge": _f32(math.nan) if i % 5 == 0 else _f32(1.5),
        "capacity": _f32(2.0),
        "design_capacity": _f32(2.2),
        "percentage": _f32(1.0 - 0.005 * i),
        "power_supply_status": i % 5,
        "power_supply_health": i % 9,
        "power_supply_technology": i % 9,
        "present": bool(i % 2),
        "cell_voltage": [_f32(3.7 + 0.01 * k) for k in range(i % 4)],
        "cell_temperature": [_f32(20.0 + k) for k in range((i + 1) % 3)],
        "location": f"slot {i % 2}",
        "serial_number": f"SN-{i:05d}",
    }


def _diagnostics(i: int) -> dict:
    return {
        "header": _header(i),
        "status": [
            {
                "level": (i + k) % 4,
                "name": f"dea/amplifier_{k}",
                "message": "OK" if (i + k) % 4 == 0 else f"warning {i}",
                "hardware_id": f"hv-amp-{k}",
                "values": [{"key": f"key{j}", "value": f"{i * j}"} for j in range((i + k) % 3)],
            }
            for k in range(i % 3)
        ],
    }


#: topic -> (type, qos, number of messages, generator(i) -> dict)
TOPICS = {
    "/dea/range": ("sensor_msgs/msg/Range", sensor_data_qos(), 120, _range),
    "/dea/voltage_cmd": ("std_msgs/msg/Float64", command_qos(), 120, lambda i: {"data": 1500.0 * math.sin(0.1 * i)}),
    "/dea/battery": ("sensor_msgs/msg/BatteryState", sensor_data_qos(depth=3), 60, _battery),
    "/diagnostics": ("diagnostic_msgs/msg/DiagnosticArray", command_qos(), 40, _diagnostics),
    "/clock": ("rosgraph_msgs/msg/Clock", sensor_data_qos(depth=1), 40, lambda i: {"clock": _time(i)}),
    "/dea/state": ("std_msgs/msg/String", command_qos(depth=20), 40, lambda i: {"data": f"state {i} ünïcödé"}),
    "/dea/header": ("std_msgs/msg/Header", command_qos(), 30, _header),
    "/dea/stamp": ("builtin_interfaces/msg/Time", command_qos(), 30, _time),
}


def build_schedule(t0_ns: int = 1_700_000_000_000_000_000):
    """``[(topic, log_time_ns, message_dict)]`` interleaving all topics, increasing log time."""
    schedule = []
    for index, (topic, (_type, _qos, count, make)) in enumerate(TOPICS.items()):
        period_ns = 1_000_000_000 // count
        offset = 1_000 * index  # distinct, deterministic per topic
        for i in range(count):
            schedule.append((topic, t0_ns + i * period_ns + offset, make(i)))
    schedule.sort(key=lambda item: item[1])
    return schedule


def assert_fields_equal(expected, actual, where="msg"):
    """Compare a message dict with a decoded message (rosbags dataclass / mcap_ros2 object)."""
    if isinstance(expected, dict):
        for key, value in expected.items():
            assert hasattr(actual, key), f"{where}.{key} missing in {actual!r}"
            assert_fields_equal(value, getattr(actual, key), f"{where}.{key}")
    elif isinstance(expected, list):
        actual_list = list(actual)
        assert len(actual_list) == len(expected), f"{where}: length {len(actual_list)} != {len(expected)}"
        for index, (e, a) in enumerate(zip(expected, actual_list)):
            assert_fields_equal(e, a, f"{where}[{index}]")
    elif isinstance(expected, float):
        actual_float = float(actual)
        if math.isnan(expected):
            assert math.isnan(actual_float), f"{where}: {actual_float} is not NaN"
        else:
            assert actual_float == expected, f"{where}: {actual_float!r} != {expected!r}"
    elif isinstance(expected, bool):
        assert bool(actual) is expected and not isinstance(actual, (str, bytes)), f"{where}: {actual!r} != {expected!r}"
    else:
        assert actual == expected, f"{where}: {actual!r} != {expected!r}"


def distro_has_type_hashes(type_name: str) -> bool:
    """True when the installed definition of ``type_name`` comes with a type description.

    rosidl generates ``<Type>.json`` (with the RIHS01 hash) next to the ``.msg`` from Iron on;
    Humble installs none, and without ROS the vendored texts carry no hash either. Tests check
    the hash where the distro under test has one and check its absence elsewhere.
    """
    _text, source = MessageDefinitionStore().msg_text(type_name)
    return source not in ("vendored", "extra_definitions") and Path(source).with_suffix(".json").is_file()


def installed_msg_text(type_name: str):
    """The ``.msg`` text installed for the distro under test (``None`` without ROS messages)."""
    text, source = MessageDefinitionStore().msg_text(type_name)
    return None if source in ("vendored", "extra_definitions") else text


@pytest.fixture
def topics_spec():
    return TOPICS


@pytest.fixture
def schedule():
    return build_schedule()


@pytest.fixture
def fields_equal():
    return assert_fields_equal


@pytest.fixture
def has_type_hash():
    """``has_type_hash(type_name) -> bool`` (see :func:`distro_has_type_hashes`)."""
    return distro_has_type_hashes
