"""A bag as identifier_node records it, written without ROS from sampled signals.

``write_rig_bag(path, tv, uv, td, d, records)``: the amplifier's applied voltage (``/dea/voltage``,
sensor_msgs/BatteryState, each value stamped when it was applied) and the laser's displacement
(``/dea/displacement``, sensor_msgs/Range, NaN for a sample flagged implausible), interleaved in time
order, with the identifier's metadata ``records`` [(name, {key: str})]. Times in s from ``t0_ns``.
"""
from dea_ros.bag import BagWriter, sensor_data_qos

#: the protocol's start in ns since the epoch (any fixed instant)
T0_NS = 1_700_000_000_000_000_000


def stamp(t_ns: int) -> dict:
    """builtin_interfaces/Time of an instant in ns."""
    return {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}


def write_rig_bag(path, tv, uv, td, d, records, t0_ns: int = T0_NS):
    """The bag at ``path`` (returned): voltages ``uv`` (V) at ``tv`` (s), displacements ``d`` (m) at ``td`` (s)."""
    with BagWriter(path) as bag:
        bag.add_topic("/dea/voltage", "sensor_msgs/msg/BatteryState", sensor_data_qos(50))
        bag.add_topic("/dea/displacement", "sensor_msgs/msg/Range", sensor_data_qos(50))
        for name, record in records:
            bag.add_metadata(name, record)
        events = sorted([(int(round(t * 1e9)), "v", u) for t, u in zip(tv, uv)] +
                        [(int(round(t * 1e9)), "d", x) for t, x in zip(td, d)])
        for t_ns, kind, value in events:
            t_abs = t0_ns + t_ns
            if kind == "v":
                bag.write("/dea/voltage", {"header": {"stamp": stamp(t_abs), "frame_id": "amp"},
                                           "voltage": value, "present": True}, t_abs)
            else:
                bag.write("/dea/displacement", {"header": {"stamp": stamp(t_abs), "frame_id": "laser"},
                                                "radiation_type": 1, "range": value}, t_abs)
    return path
