"""Convert a bag between the Humble and the Jazzy rosbag2 formats (``dea-ros bag convert``).

The formats differ in ``metadata.yaml`` (version 5 vs 9: QoS as a YAML string with integer enums
vs a YAML list with policy names; no ``type_description_hash``/``custom_data``/``ros_distro``
in version 5) and in the MCAP file (channel ``offered_qos_profiles`` text; the ``rosbag2``
Metadata record: ``ROS_DISTRO`` for Humble, ``serialized_metadata`` for Jazzy). So both files are
rewritten: every message is copied byte for byte with its log and publish times, every schema
text, type hash, QoS profile and user Metadata record is kept, and ``custom_data`` travels in the
``rosbag2.custom_data`` record of a Humble bag. Converting there and back gives the original
``metadata.yaml``, channels, schemas, records and messages.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from mcap.reader import make_reader
from mcap.records import Channel, Schema

from ..errors import BagError
from .metadata import CUSTOM_DATA_RECORD, ROSBAG2_METADATA_RECORD, TopicSummary, metadata_version_for_format
from .qos import parse_qos_profiles
from .reader import BagReader
from .writer import BagWriter

__all__ = ["convert_bag"]


def convert_bag(
    source: str | Path,
    rosbag2_format: str,
    out: str | Path | None = None,
) -> Path:
    """Write ``source`` as a new bag in ``rosbag2_format`` (``"humble"`` or ``"jazzy"``).

    * ``source``: bag directory (complete: run :func:`~dea_ros.bag.recover_bag` on a killed one).
    * ``rosbag2_format``: target format.
    * ``out``: new bag directory (must not exist or be empty); default ``<source>_<format>``.

    Returns the new bag directory. Raises :class:`~dea_ros.errors.BagError` for an unknown
    format, an unreadable or truncated source, an existing output.
    """
    metadata_version_for_format(rosbag2_format)  # a clear error for a bad --to first
    source = Path(source).expanduser()
    if not source.is_dir():
        raise BagError(f"{source} is not a bag directory (give the folder holding metadata.yaml and the .mcap)")
    target = Path(out).expanduser() if out is not None else source.with_name(f"{source.name}_{rosbag2_format}")
    if target.resolve() == source.resolve():
        raise BagError(f"--out {target} is the source bag; rosbag2 never overwrites a bag: choose a new directory")
    with BagReader(source, warn=False) as reader:
        if reader.truncated:
            raise BagError(f"{source} is truncated (the recorder was killed); run `dea-ros bag recover {source}` first")
        bag_info = reader.bag_metadata or {}
        records = reader.metadata_records()
        storage_files = reader.files
    ros_distro, custom_data = _distro_and_custom_data(bag_info, records)
    with BagWriter(
        target,
        rosbag2_format=rosbag2_format,
        ros_distro=ros_distro or None,
        custom_data=custom_data,
        min_free_bytes=0,
    ) as writer:
        for file_path in storage_files:
            _copy_file(file_path, writer, bag_info.get("topics", {}))
    return target


def _distro_and_custom_data(bag_info: Mapping[str, Any], records: list[tuple[str, dict[str, str]]],
                            ) -> tuple[str, dict[str, str]]:
    """The recorded ROS distro and ``custom_data``: from metadata.yaml, else from the MCAP records."""
    custom_data: dict[str, str] = dict(bag_info.get("custom_data") or {})
    ros_distro = bag_info.get("ros_distro") or ""
    for name, data in records:
        if name == ROSBAG2_METADATA_RECORD and data.get("ROS_DISTRO") and not ros_distro:
            ros_distro = data["ROS_DISTRO"]
        elif name == CUSTOM_DATA_RECORD and not custom_data:
            custom_data = dict(data)
    return ros_distro, custom_data


def _copy_file(file_path: Path, writer: BagWriter, yaml_topics: Mapping[str, TopicSummary]) -> None:
    """Copy one storage file: its topics, user Metadata records and every message byte for byte."""
    with open(file_path, "rb") as handle:
        mcap_reader = make_reader(handle)
        summary = mcap_reader.get_summary()
        channels = summary.channels if summary is not None else {}
        schemas = summary.schemas if summary is not None else {}
        registered = set(writer.topic_message_counts())
        for channel in sorted(channels.values(), key=lambda c: c.id):
            if channel.topic not in registered:
                _add_topic(writer, file_path, channel, schemas.get(channel.schema_id), yaml_topics)
        for record in mcap_reader.iter_metadata():
            if record.name not in (ROSBAG2_METADATA_RECORD, CUSTOM_DATA_RECORD):
                writer.add_metadata(record.name, dict(record.metadata))
        for _schema, channel, message in mcap_reader.iter_messages(log_time_order=False):
            writer.write_serialized(channel.topic, message.data, message.log_time, message.publish_time)


def _add_topic(writer: BagWriter, file_path: Path, channel: Channel, schema: Schema | None,
               yaml_topics: Mapping[str, TopicSummary]) -> None:
    """Register a channel's topic with its schema text, QoS and type hash (metadata.yaml's if the channel has none)."""
    if schema is None or schema.encoding != "ros2msg" or channel.message_encoding != "cdr":
        raise BagError(
            f"cannot convert topic {channel.topic} of {file_path}: only cdr messages with "
            "ros2msg schemas are rosbag2 bags"
        )
    try:
        qos = parse_qos_profiles(channel.metadata.get("offered_qos_profiles", ""))
    except ValueError as exc:
        raise BagError(f"{file_path}: channel {channel.topic}: {exc}") from None
    type_hash = channel.metadata.get("topic_type_hash", "")
    if not type_hash and channel.topic in yaml_topics:
        type_hash = yaml_topics[channel.topic].type_description_hash
    writer.add_topic(channel.topic, schema.name, qos, type_hash=type_hash, schema_text=schema.data.decode("utf-8"))
