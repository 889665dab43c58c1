"""What Humble's and Jazzy's rosbag2 require of a bag, re-stated for the tests (no ROS needed).

rosbag2 reads ``metadata.yaml`` and the MCAP metadata with yaml-cpp: every field is fetched with
``node["field"].as<T>()``, which throws (and ``ros2 bag info``/``play`` fail with "Exception on
parsing info file") when the field is missing or its YAML node cannot convert to ``T``. This
module applies the same conversions to the YAML *nodes* (``yaml.compose``: scalar text, plain or
quoted, sequence, mapping), so a quoted ``'5'`` is accepted where yaml-cpp accepts it and a list
is rejected where yaml-cpp wants a string. The field lists and types are read from ros2/rosbag2
(and ros2/rmw for the enum ranges) on these branches:

humble (rosbag2 0.15.x):
  * ``rosbag2_storage/src/rosbag2_storage/metadata_io.cpp``: ``convert<BagMetadata>::decode``,
    ``convert<TopicMetadata>::decode`` (``offered_qos_profiles.as<std::string>()`` from version 4),
    ``convert<FileInformation>``, ``convert<std::chrono::nanoseconds>`` (``uint64``).
  * ``rosbag2_transport/src/rosbag2_transport/player.cpp`` (``YAML::Load`` of that string,
    ``.as<std::vector<Rosbag2QoS>>()``) and ``rosbag2_transport/src/rosbag2_transport/qos.cpp``
    (``convert<Rosbag2QoS>::decode``: the four policies ``as<int>``, ``depth`` ``as<int>``,
    durations ``{sec, nsec}`` ``as<uint64_t>``, ``avoid_ros_namespace_conventions`` ``as<bool>``).
  * ``rosbag2_storage_mcap/src/mcap_storage.cpp`` (``get_metadata``): the channel metadata
    ``offered_qos_profiles`` string is taken verbatim (then parsed as above by the player);
    Metadata records are not read.
  * rmw ``rmw/include/rmw/types.h`` (humble): history 0-3, reliability 0-3, durability 0-3,
    liveliness 0-4 (no ``best_available``).

jazzy (rosbag2 0.26.x):
  * ``rosbag2_storage/include/rosbag2_storage/yaml.hpp``: as Humble plus ``custom_data``
    (version >= 6, ``as<unordered_map<string, string>>``: null or a map of scalars),
    ``type_description_hash`` (version >= 7, string), ``ros_distro`` (version >= 8, string);
    ``offered_qos_profiles`` is a sequence from version 9, a string before.
  * ``rosbag2_storage/src/rosbag2_storage/qos.cpp`` (``convert<rclcpp::QoS>::decode``): history
    read as an int in [0, 3] selects integer policies, else the four policies are strings
    (``rmw_qos_*_policy_from_str``); ``depth`` only for ``keep_last``; ``to_rclcpp_qos_vector``
    accepts an empty string.
  * ``rosbag2_storage_mcap/src/mcap_storage.cpp`` (``read_metadata``): a Metadata record
    ``rosbag2`` with ``serialized_metadata`` is decoded with ``convert<BagMetadata>::decode`` (same
    rules, no ``rosbag2_bagfile_information`` wrapper) and gives the version used for the channels'
    ``offered_qos_profiles``; without it the version is 8. ``ROS_DISTRO`` of that record is read.
  * rmw ``rmw/src/qos_string_conversions.c`` (jazzy): the policy names.
"""

import re
from pathlib import Path
from typing import Dict, List

import yaml
from yaml.nodes import MappingNode, ScalarNode, SequenceNode

DISTROS = ("humble", "jazzy")

#: Integer enum values each distro's rmw defines (rmw/include/rmw/types.h of that branch).
_ENUM_RANGES = {
    "humble": {"history": 3, "reliability": 3, "durability": 3, "liveliness": 4},
    "jazzy": {"history": 3, "reliability": 4, "durability": 4, "liveliness": 5},
}
#: rmw_qos_*_policy_from_str names (jazzy); anything else decodes to UNKNOWN. rosbag2 writes
#: "unknown" for UNKNOWN (qos.cpp encode), which decodes back to UNKNOWN.
_POLICY_NAMES = {
    "history": {"system_default": 0, "keep_last": 1, "keep_all": 2, "unknown": 3},
    "reliability": {"system_default": 0, "reliable": 1, "best_effort": 2, "unknown": 3, "best_available": 4},
    "durability": {"system_default": 0, "transient_local": 1, "volatile": 2, "unknown": 3, "best_available": 4},
    "liveliness": {"system_default": 0, "automatic": 1, "manual_by_topic": 3, "unknown": 4, "best_available": 5},
}
_POLICY_BY_NUMBER = {field: {v: k for k, v in names.items()} for field, names in _POLICY_NAMES.items()}
_POLICY_BY_NUMBER["liveliness"][2] = "manual_by_node"
_DURATIONS = ("deadline", "lifespan", "liveliness_lease_duration")
_YAML_CPP_NULL = {"~", "null", "Null", "NULL", ""}
_YAML_CPP_TRUE = {"y", "yes", "true", "on"}
_YAML_CPP_FALSE = {"n", "no", "false", "off"}


class RuleError(AssertionError):
    """The distro's rosbag2 would throw on this field."""


# -- yaml-cpp conversions (yaml-cpp/node/convert.h) ------------------------------------------------
def _is_null(node) -> bool:
    return isinstance(node, ScalarNode) and node.style is None and node.value in _YAML_CPP_NULL


def _field(node, key: str, where: str):
    """``node[key]`` of a map; missing -> yaml-cpp ``InvalidNode`` on ``as<T>()``."""
    if not isinstance(node, MappingNode):
        raise RuleError(f"{where}: expected a map, got {type(node).__name__}")
    for key_node, value in node.value:
        if isinstance(key_node, ScalarNode) and key_node.value == key:
            return value
    raise RuleError(f"{where}.{key}: missing (yaml-cpp InvalidNode)")


def as_string(node, where: str) -> str:
    if not isinstance(node, ScalarNode) or _is_null(node):
        raise RuleError(f"{where}: as<std::string>() needs a scalar, got {_describe(node)}")
    return node.value


def as_int(node, where: str, unsigned: bool = False) -> int:
    text = as_string(node, where).strip()
    pattern = r"\+?[0-9]+" if unsigned else r"[-+]?[0-9]+"
    if not re.fullmatch(pattern, text):
        kind = "uint64_t" if unsigned else "int"
        raise RuleError(f"{where}: as<{kind}>() cannot convert {text!r}")
    value = int(text)
    limit = 2**64 - 1 if unsigned else 2**31 - 1
    if value > limit or value < (0 if unsigned else -(2**31)):
        raise RuleError(f"{where}: {value} out of range")
    return value


def as_uint64(node, where: str) -> int:
    return as_int(node, where, unsigned=True)


def as_bool(node, where: str) -> bool:
    text = as_string(node, where)
    if text in (text.lower(), text.upper(), text.capitalize()):  # yaml-cpp IsFlexibleCase
        if text.lower() in _YAML_CPP_TRUE:
            return True
        if text.lower() in _YAML_CPP_FALSE:
            return False
    raise RuleError(f"{where}: as<bool>() cannot convert {text!r}")


def as_sequence(node, where: str) -> list:
    if not isinstance(node, SequenceNode):
        raise RuleError(f"{where}: a sequence is required, got {_describe(node)}")
    return node.value


def _describe(node) -> str:
    if isinstance(node, ScalarNode):
        return "null" if _is_null(node) else f"scalar {node.value!r}"
    return "a sequence" if isinstance(node, SequenceNode) else "a map"


# -- QoS ------------------------------------------------------------------------------------------
def _duration(node, where: str) -> tuple:
    return (as_uint64(_field(node, "sec", where), where + ".sec"),
            as_uint64(_field(node, "nsec", where), where + ".nsec"))


def _policy_int(node, field: str, distro: str, where: str) -> str:
    value = as_int(node, where)
    if not 0 <= value <= _ENUM_RANGES[distro][field]:
        raise RuleError(f"{where}: {value} is not an rmw {field} policy on {distro}")
    return _POLICY_BY_NUMBER[field].get(value, "best_available")


def decode_qos(node, distro: str, where: str) -> dict:
    """One profile as the distro's rosbag2 decodes it (policy names normalized to rmw names)."""
    result: Dict[str, object] = {}
    if distro == "humble":  # rosbag2_transport/src/rosbag2_transport/qos.cpp (humble)
        for field in ("history", "reliability", "durability", "liveliness"):
            result[field] = _policy_int(_field(node, field, where), field, distro, f"{where}.{field}")
        result["depth"] = as_int(_field(node, "depth", where), where + ".depth")
    else:  # rosbag2_storage/src/rosbag2_storage/qos.cpp (jazzy): auto-detect int or string policies
        history = _field(node, "history", where)
        try:
            integer_mode = 0 <= as_int(history, where) <= 3
        except RuleError:
            integer_mode = False
        for field in ("history", "reliability", "durability", "liveliness"):
            value_node = _field(node, field, where)
            if integer_mode:
                result[field] = _policy_int(value_node, field, distro, f"{where}.{field}")
            else:
                name = as_string(value_node, f"{where}.{field}")
                if name not in _POLICY_NAMES[field]:
                    raise RuleError(f"{where}.{field}: {name!r} is not an rmw policy name (decodes to UNKNOWN)")
                result[field] = name
        if result["history"] == "keep_last":
            result["depth"] = as_int(_field(node, "depth", where), where + ".depth")
        else:
            result["depth"] = 0
    for field in _DURATIONS:
        result[field] = _duration(_field(node, field, where), f"{where}.{field}")
    result["avoid_ros_namespace_conventions"] = as_bool(
        _field(node, "avoid_ros_namespace_conventions", where), where + ".avoid_ros_namespace_conventions")
    return result


def decode_qos_text(text: str, distro: str, where: str) -> List[dict]:
    """``offered_qos_profiles`` as a string (metadata < 9, and every MCAP channel)."""
    if text == "":  # humble player.cpp: offered_qos_profiles.empty(); jazzy to_rclcpp_qos_vector
        return []
    try:
        node = yaml.compose(text)
    except yaml.YAMLError as exc:
        raise RuleError(f"{where}: not YAML ({exc})") from None
    return [decode_qos(item, distro, f"{where}[{i}]") for i, item in enumerate(as_sequence(node, where))]


# -- metadata ----------------------------------------------------------------------------------------
def decode_bag_metadata(node, distro: str, where: str = "rosbag2_bagfile_information") -> dict:
    """``convert<BagMetadata>::decode`` of the distro; returns what it reads (QoS decoded)."""
    version = as_int(_field(node, "version", where), where + ".version")
    info = {"version": version,
            "storage_identifier": as_string(_field(node, "storage_identifier", where), where + ".storage_identifier"),
            "duration_ns": as_uint64(_field(_field(node, "duration", where), "nanoseconds", where + ".duration"),
                                     where + ".duration.nanoseconds"),
            "starting_time_ns": as_uint64(
                _field(_field(node, "starting_time", where), "nanoseconds_since_epoch", where + ".starting_time"),
                where + ".starting_time.nanoseconds_since_epoch"),
            "message_count": as_uint64(_field(node, "message_count", where), where + ".message_count"),
            "topics": {}}
    topics_where = where + ".topics_with_message_count"
    for index, entry in enumerate(as_sequence(_field(node, "topics_with_message_count", where), topics_where)):
        entry_where = f"{topics_where}[{index}]"
        meta = _field(entry, "topic_metadata", entry_where)
        meta_where = entry_where + ".topic_metadata"
        name = as_string(_field(meta, "name", meta_where), meta_where + ".name")
        topic = {"type": as_string(_field(meta, "type", meta_where), meta_where + ".type"),
                 "serialization_format": as_string(_field(meta, "serialization_format", meta_where),
                                                   meta_where + ".serialization_format"),
                 "qos": [], "type_description_hash": "",
                 "message_count": as_uint64(_field(entry, "message_count", entry_where),
                                            entry_where + ".message_count")}
        qos_node_where = meta_where + ".offered_qos_profiles"
        if distro == "jazzy" and version >= 9:
            items = as_sequence(_field(meta, "offered_qos_profiles", meta_where), qos_node_where)
            topic["qos"] = [decode_qos(item, distro, f"{qos_node_where}[{i}]") for i, item in enumerate(items)]
        elif version >= 4:
            text = as_string(_field(meta, "offered_qos_profiles", meta_where), qos_node_where)
            topic["qos"] = decode_qos_text(text, distro, qos_node_where)
        if distro == "jazzy" and version >= 7:
            topic["type_description_hash"] = as_string(_field(meta, "type_description_hash", meta_where),
                                                       meta_where + ".type_description_hash")
        info["topics"][name] = topic
    paths_where = where + ".relative_file_paths"
    info["relative_file_paths"] = [as_string(p, paths_where)
                                   for p in as_sequence(_field(node, "relative_file_paths", where), paths_where)]
    if version >= 3:
        for key in ("compression_format", "compression_mode"):
            info[key] = as_string(_field(node, key, where), f"{where}.{key}")
    if version >= 5:
        files_where = where + ".files"
        info["files"] = []
        for index, item in enumerate(as_sequence(_field(node, "files", where), files_where)):
            item_where = f"{files_where}[{index}]"
            info["files"].append({
                "path": as_string(_field(item, "path", item_where), item_where + ".path"),
                "starting_time_ns": as_uint64(_field(_field(item, "starting_time", item_where),
                                                     "nanoseconds_since_epoch", item_where), item_where),
                "duration_ns": as_uint64(_field(_field(item, "duration", item_where), "nanoseconds", item_where),
                                         item_where),
                "message_count": as_uint64(_field(item, "message_count", item_where), item_where + ".message_count"),
            })
    if distro == "jazzy" and version >= 6:
        custom = _field(node, "custom_data", where)
        info["custom_data"] = {}
        if not _is_null(custom):
            if not isinstance(custom, MappingNode):
                raise RuleError(f"{where}.custom_data: a map (or ~) is required, got {_describe(custom)}")
            for key_node, value_node in custom.value:
                key = as_string(key_node, where + ".custom_data key")
                info["custom_data"][key] = as_string(value_node, f"{where}.custom_data.{key}")
    if distro == "jazzy" and version >= 8:
        info["ros_distro"] = as_string(_field(node, "ros_distro", where), where + ".ros_distro")
    return info


def check_metadata_yaml(text: str, distro: str) -> dict:
    """``MetadataIo::read_metadata`` of the distro on the text of a ``metadata.yaml``."""
    assert distro in DISTROS
    root = yaml.compose(text)
    return decode_bag_metadata(_field(root, "rosbag2_bagfile_information", "metadata.yaml"), distro)


def check_mcap(path: Path, distro: str) -> dict:
    """What the distro's ``rosbag2_storage_mcap`` reads from the file: ``{topic: [qos]}``, version, distro."""
    from mcap.reader import make_reader

    with open(path, "rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        records = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    result = {"version": None, "ros_distro": None, "topics": {}}
    version = 8  # jazzy mcap_storage.cpp: no serialized_metadata -> 8
    if distro == "jazzy":
        for name, data in records:
            if name != "rosbag2":
                continue
            serialized = data.get("serialized_metadata", "")
            if serialized:
                decoded = decode_bag_metadata(yaml.compose(serialized), distro, f"{path.name}: rosbag2 record")
                version = decoded["version"]
                result["ros_distro"] = decoded.get("ros_distro")
            if "ROS_DISTRO" in data:
                result["ros_distro"] = data["ROS_DISTRO"]
        result["version"] = version
    for channel in summary.channels.values():
        text = channel.metadata.get("offered_qos_profiles")
        if text is None:
            result["topics"][channel.topic] = []
            continue
        # humble: verbatim string, parsed by the player; jazzy: to_rclcpp_qos_vector(text, version)
        result["topics"][channel.topic] = decode_qos_text(text, distro, f"{path.name}: channel {channel.topic}")
    return result


def check_bag(bag_dir: Path, distro: str) -> dict:
    """Both places the distro reads: ``metadata.yaml`` and every storage file; returns the first."""
    bag_dir = Path(bag_dir)
    info = check_metadata_yaml((bag_dir / "metadata.yaml").read_text(encoding="utf-8"), distro)
    info["mcap"] = {}
    for name in info["relative_file_paths"]:
        info["mcap"][name] = check_mcap(bag_dir / name, distro)
    return info


def same_qos(decoded: dict, profile) -> bool:
    """A decoded profile equals a :class:`dea_ros.bag.QosProfile` (depth ignored when not keep_last)."""
    expected = {
        "history": profile.history, "reliability": profile.reliability, "durability": profile.durability,
        "liveliness": profile.liveliness, "depth": profile.depth if profile.history == "keep_last" else None,
        "deadline": tuple(profile.deadline), "lifespan": tuple(profile.lifespan),
        "liveliness_lease_duration": tuple(profile.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": profile.avoid_ros_namespace_conventions,
    }
    got = dict(decoded)
    if expected["depth"] is None:
        expected.pop("depth")
        got.pop("depth")
    return got == expected
