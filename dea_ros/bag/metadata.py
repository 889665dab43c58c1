"""rosbag2 ``metadata.yaml`` (``rosbag2_bagfile_information``): build, dump, load, validate.

Field sets per metadata version, as encoded by ``YAML::convert<rosbag2_storage::BagMetadata>``
(``rosbag2_storage/include/rosbag2_storage/yaml.hpp``) and read by ``rosbags.rosbag2.Reader``:

* version 9 (``rosbag2_format="jazzy"``: Jazzy, Kilted, Rolling): ``version``,
  ``storage_identifier``, ``duration.nanoseconds``, ``starting_time.nanoseconds_since_epoch``,
  ``message_count``, ``topics_with_message_count[].{topic_metadata.{name, type,
  serialization_format, offered_qos_profiles (YAML list), type_description_hash}, message_count}``,
  ``compression_format``, ``compression_mode``, ``relative_file_paths``, ``files[].{path,
  starting_time, duration, message_count}``, ``custom_data`` (map or ``~``), ``ros_distro``.
* version 5 (``rosbag2_format="humble"``): the same without ``type_description_hash``,
  ``custom_data`` and ``ros_distro``; ``offered_qos_profiles`` is a YAML *string* with integer
  enums. (Humble's reader rejects version 9 files: it parses ``offered_qos_profiles`` as a string.)

The same mapping (without the ``rosbag2_bagfile_information`` key) is stored in the MCAP
Metadata record named ``rosbag2`` under ``serialized_metadata``, as ``rosbag2_storage_mcap``'s
``update_metadata`` does on open and on close (Iron+); ``MCAPStorage::read_metadata`` takes the
metadata version from it to decode the channels' ``offered_qos_profiles``.
An empty bag has ``starting_time`` = ``INT64_MAX`` and ``duration`` = 0, as rosbag2's
``SequentialWriter::init_metadata`` leaves it.

Which format: :func:`default_rosbag2_format`: ``"humble"`` (metadata version 5), which every supported
distro reads, unless the user asks for ``"jazzy"`` (version 9); ``ros_distro`` is never written
empty (:func:`ros_distro_for_format`: ``$ROS_DISTRO``, else the format's distro name). What each
distro's rosbag2 requires of these files is described in ``docs/rosbag2_formats.md``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import yaml

from ..errors import BagError
from .qos import QosProfile, parse_qos_profiles, qos_to_dict, serialize_qos_profiles

__all__ = [
    "ROSBAG2_FORMAT_VERSIONS",
    "METADATA_FILENAME",
    "EMPTY_BAG_STARTING_TIME_NS",
    "ROSBAG2_METADATA_RECORD",
    "CUSTOM_DATA_RECORD",
    "TopicSummary",
    "FileSummary",
    "build_bag_metadata",
    "dump_metadata_yaml",
    "dump_serialized_metadata",
    "load_metadata_yaml",
    "parse_bag_metadata",
    "metadata_version_for_format",
    "format_for_metadata_version",
    "default_rosbag2_format",
    "resolve_rosbag2_format",
    "ros_distro_for_format",
]

#: rosbag2 format name -> ``metadata.yaml`` version written.
ROSBAG2_FORMAT_VERSIONS = {"jazzy": 9, "humble": 5}
METADATA_FILENAME = "metadata.yaml"
#: ``std::chrono::nanoseconds::max()``: rosbag2's starting time of a bag without messages.
EMPTY_BAG_STARTING_TIME_NS = 2**63 - 1
#: Name of the MCAP Metadata record holding the serialized ``metadata.yaml`` (rosbag2 convention).
ROSBAG2_METADATA_RECORD = "rosbag2"
#: MCAP Metadata record keeping ``custom_data`` in Humble-format bags (metadata version 5 has no
#: ``custom_data`` field); :func:`dea_ros.bag.convert_bag` restores it when converting to Jazzy.
CUSTOM_DATA_RECORD = "rosbag2.custom_data"


def metadata_version_for_format(rosbag2_format: str) -> int:
    """``"jazzy"`` -> 9, ``"humble"`` -> 5; ``BagError`` for anything else."""
    try:
        return ROSBAG2_FORMAT_VERSIONS[rosbag2_format]
    except KeyError:
        raise BagError(
            f"rosbag2_format={rosbag2_format!r} is not supported; use 'jazzy' (metadata version 9, "
            "Jazzy/Kilted/Rolling), 'humble' (metadata version 5, Humble and newer) or 'auto' "
            "(from $ROS_DISTRO)"
        ) from None


def format_for_metadata_version(version: int) -> str:
    """``9`` -> ``"jazzy"``; any version below 9 -> ``"humble"`` (Humble's rosbag2 reads up to 8)."""
    return "jazzy" if version >= ROSBAG2_FORMAT_VERSIONS["jazzy"] else "humble"


def default_rosbag2_format() -> str:
    """``"humble"``: the format every supported distro's ``ros2 bag`` reads (Humble, Iron, Jazzy, Kilted,
    Rolling), whatever ``$ROS_DISTRO`` says or whether ROS is sourced at all.

    A bag is read on other machines than the one that recorded it (lab PCs run Humble and Jazzy),
    so the recorder's distro says nothing about the reader's. The Humble format (metadata version
    5) loses nothing a Jazzy bag carries: ``custom_data`` and the type hashes are kept in MCAP
    records and channel metadata (``dea-ros bag convert --to jazzy`` restores a version 9 bag);
    ``rosbag2_format="jazzy"`` writes version 9 directly (Jazzy and newer only).
    """
    return "humble"


def resolve_rosbag2_format(rosbag2_format: str | None) -> str:
    """``None``/``""``/``"auto"`` -> :func:`default_rosbag2_format`; a format name is checked."""
    if rosbag2_format is None or str(rosbag2_format).strip().lower() in ("", "auto"):
        return default_rosbag2_format()
    name = str(rosbag2_format).strip().lower()
    metadata_version_for_format(name)  # raises BagError naming the valid values
    return name


def ros_distro_for_format(rosbag2_format: str, ros_distro: str | None = None) -> str:
    """The ``ros_distro`` to record: ``ros_distro``, else ``$ROS_DISTRO``, else the format's name."""
    distro = os.environ.get("ROS_DISTRO", "") if ros_distro is None else ros_distro
    return distro.strip() or rosbag2_format


@dataclass
class TopicSummary:
    """One entry of ``topics_with_message_count``."""

    name: str
    type: str
    message_count: int = 0
    offered_qos_profiles: list[QosProfile] = field(default_factory=list)
    type_description_hash: str = ""
    serialization_format: str = "cdr"


@dataclass
class FileSummary:
    """One entry of ``files`` (one storage file of the bag)."""

    path: str
    starting_time_ns: int
    duration_ns: int
    message_count: int


def build_bag_metadata(
    *,
    version: int,
    files: Sequence[FileSummary],
    topics: Sequence[TopicSummary],
    custom_data: Mapping[str, str] | None = None,
    ros_distro: str = "",
    storage_identifier: str = "mcap",
) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping for ``version`` (see module docstring)."""
    message_count = sum(f.message_count for f in files)
    with_messages = [f for f in files if f.message_count > 0]
    if with_messages:
        start = min(f.starting_time_ns for f in with_messages)
        end = max(f.starting_time_ns + f.duration_ns for f in with_messages)
    else:
        start, end = EMPTY_BAG_STARTING_TIME_NS, EMPTY_BAG_STARTING_TIME_NS
    topic_entries = []
    for topic in topics:
        topic_metadata: dict[str, Any] = {
            "name": topic.name,
            "type": topic.type,
            "serialization_format": topic.serialization_format,
        }
        if version >= 9:
            topic_metadata["offered_qos_profiles"] = [
                qos_to_dict(p, version) for p in topic.offered_qos_profiles
            ]
        else:
            topic_metadata["offered_qos_profiles"] = serialize_qos_profiles(
                topic.offered_qos_profiles, version
            )
        if version >= 7:
            topic_metadata["type_description_hash"] = topic.type_description_hash
        topic_entries.append({"topic_metadata": topic_metadata, "message_count": int(topic.message_count)})
    info: dict[str, Any] = {
        "version": int(version),
        "storage_identifier": storage_identifier,
        "duration": {"nanoseconds": int(end - start)},
        "starting_time": {"nanoseconds_since_epoch": int(start)},
        "message_count": int(message_count),
        "topics_with_message_count": topic_entries,
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [f.path for f in files],
        "files": [
            {
                "path": f.path,
                "starting_time": {"nanoseconds_since_epoch": int(f.starting_time_ns)},
                "duration": {"nanoseconds": int(f.duration_ns)},
                "message_count": int(f.message_count),
            }
            for f in files
        ],
    }
    if version >= 6:
        info["custom_data"] = {str(k): str(v) for k, v in custom_data.items()} if custom_data else None
    if version >= 8:
        # rosbag2 writes $ROS_DISTRO; never leave it empty (unset with the PyPI wheels).
        info["ros_distro"] = ros_distro or format_for_metadata_version(version)
    return info


class _YamlCppStyleDumper(yaml.SafeDumper):
    """Indent block sequences inside mappings, as yaml-cpp does (cosmetic only)."""

    def increase_indent(self, flow: bool = False, indentless: bool = False):  # noqa: D401
        return super().increase_indent(flow, False)


def _dump(data: Any) -> str:
    return yaml.dump(
        data, Dumper=_YamlCppStyleDumper, default_flow_style=False, sort_keys=False, allow_unicode=True
    )


def dump_metadata_yaml(info: Mapping[str, Any]) -> str:
    """Text of ``metadata.yaml`` for a ``rosbag2_bagfile_information`` mapping."""
    return _dump({"rosbag2_bagfile_information": dict(info)})


def dump_serialized_metadata(info: Mapping[str, Any]) -> str:
    """Value of ``serialized_metadata`` in the MCAP ``rosbag2`` Metadata record."""
    return _dump(dict(info)).rstrip("\n")


def _require(mapping: Mapping[str, Any], key: str, kind, where: str, source: str):
    if key not in mapping:
        raise BagError(f"{source}: field '{where}{key}' is missing")
    value = mapping[key]
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        expected = kind.__name__ if isinstance(kind, type) else "/".join(k.__name__ for k in kind)
        raise BagError(f"{source}: field '{where}{key}' must be {expected}, got {value!r}")
    return value


def parse_bag_metadata(info: Any, source: str) -> dict[str, Any]:
    """Validate a ``rosbag2_bagfile_information`` mapping and normalize it.

    Returns a dict with ``version``, ``storage_identifier``, ``relative_file_paths``,
    ``message_count``, ``starting_time_ns``, ``duration_ns``, ``ros_distro``, ``custom_data`` and
    ``topics`` (``{name: TopicSummary}``). ``source`` names the file in error messages.
    """
    if not isinstance(info, Mapping):
        raise BagError(f"{source}: 'rosbag2_bagfile_information' must be a mapping")
    version = _require(info, "version", int, "", source)
    storage = _require(info, "storage_identifier", str, "", source)
    paths = _require(info, "relative_file_paths", list, "", source)
    if not all(isinstance(p, str) and p for p in paths):
        raise BagError(f"{source}: 'relative_file_paths' must be a list of file names, got {paths!r}")
    message_count = _require(info, "message_count", int, "", source)
    starting = _require(info, "starting_time", Mapping, "", source)
    duration = _require(info, "duration", Mapping, "", source)
    starting_ns = _require(starting, "nanoseconds_since_epoch", int, "starting_time.", source)
    duration_ns = _require(duration, "nanoseconds", int, "duration.", source)
    entries = _require(info, "topics_with_message_count", (list, type(None)), "", source) or []
    topics: dict[str, TopicSummary] = {}
    for index, entry in enumerate(entries):
        where = f"topics_with_message_count[{index}]."
        if not isinstance(entry, Mapping):
            raise BagError(f"{source}: '{where[:-1]}' must be a mapping")
        topic_metadata = _require(entry, "topic_metadata", Mapping, where, source)
        where_topic = where + "topic_metadata."
        name = _require(topic_metadata, "name", str, where_topic, source)
        type_name = _require(topic_metadata, "type", str, where_topic, source)
        serialization = _require(topic_metadata, "serialization_format", str, where_topic, source)
        try:
            qos = parse_qos_profiles(topic_metadata.get("offered_qos_profiles"))
        except ValueError as exc:
            raise BagError(f"{source}: '{where_topic}offered_qos_profiles' of {name}: {exc}") from None
        count = _require(entry, "message_count", int, where, source)
        type_hash = topic_metadata.get("type_description_hash") or ""
        topics[name] = TopicSummary(name, type_name, count, qos, str(type_hash), serialization)
    custom_data = info.get("custom_data") or {}
    return {
        "version": version,
        "storage_identifier": storage,
        "relative_file_paths": list(paths),
        "message_count": message_count,
        "starting_time_ns": starting_ns,
        "duration_ns": duration_ns,
        "ros_distro": str(info.get("ros_distro") or ""),
        "custom_data": {str(k): str(v) for k, v in custom_data.items()} if isinstance(custom_data, Mapping) else {},
        "topics": topics,
    }


def load_metadata_yaml(path: str | Path) -> dict[str, Any]:
    """Read and validate a bag's ``metadata.yaml`` (see :func:`parse_bag_metadata`)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise BagError(f"cannot read {path}: {exc.strerror or exc}") from exc
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        reason = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise BagError(
            f"{path} is not valid YAML ({reason}{where}); if the .mcap file is intact, delete it "
            "and run dea_ros.bag.recover_bag() to regenerate it"
        ) from None
    if not isinstance(document, Mapping) or "rosbag2_bagfile_information" not in document:
        raise BagError(
            f"{path} is not a rosbag2 metadata file: top-level key 'rosbag2_bagfile_information' missing"
        )
    return parse_bag_metadata(document["rosbag2_bagfile_information"], str(path))
