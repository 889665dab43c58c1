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

from pathlib import Path
from typing import Dict, List, Optional, Union

from .errors import BagError
from .metadata import METADATA_FILENAME, load_metadata_yaml, metadata_version_for_format
from .qos import parse_qos_profiles
from .reader import BagReader
from .writer import CUSTOM_DATA_RECORD, ROSBAG2_METADATA_RECORD, BagWriter

__all__ = ["convert_bag"]


def _storage_files(bag_dir: Path) -> List[Path]:
    metadata_file = bag_dir / METADATA_FILENAME
    if metadata_file.is_file():
        return [bag_dir / name for name in load_metadata_yaml(metadata_file)["relative_file_paths"]]
    return sorted(bag_dir.glob("*.mcap"))


def convert_bag(
    source: Union[str, Path],
    rosbag2_format: str,
    out: Optional[Union[str, Path]] = None,
) -> Path:
    """Write ``source`` as a new bag in ``rosbag2_format`` (``"humble"`` or ``"jazzy"``).

    :param source: bag directory (complete: run :func:`~dea_ros.bag.recover_bag` on a killed one).
    :param rosbag2_format: target format.
    :param out: new bag directory (must not exist or be empty); default ``<source>_<format>``.
    :returns: the new bag directory.
    :raises BagError: unknown format, unreadable or truncated source, existing output.
    """
    from mcap.reader import make_reader

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

    custom_data: Dict[str, str] = dict(bag_info.get("custom_data") or {})
    ros_distro = bag_info.get("ros_distro") or ""
    for name, data in records:
        if name == ROSBAG2_METADATA_RECORD and data.get("ROS_DISTRO") and not ros_distro:
            ros_distro = data["ROS_DISTRO"]
        elif name == CUSTOM_DATA_RECORD and not custom_data:
            custom_data = dict(data)
    yaml_topics = bag_info.get("topics", {})

    with BagWriter(
        target,
        rosbag2_format=rosbag2_format,
        ros_distro=ros_distro or None,
        custom_data=custom_data,
        min_free_bytes=0,
    ) as writer:
        for file_path in _storage_files(source):
            with open(file_path, "rb") as handle:
                mcap_reader = make_reader(handle)
                summary = mcap_reader.get_summary()
                channels = summary.channels if summary is not None else {}
                schemas = summary.schemas if summary is not None else {}
                registered = set(writer.topic_message_counts())
                for channel in sorted(channels.values(), key=lambda c: c.id):
                    if channel.topic in registered:
                        continue
                    schema = schemas.get(channel.schema_id)
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
                    writer.add_topic(channel.topic, schema.name, qos, type_hash=type_hash,
                                     schema_text=schema.data.decode("utf-8"))
                for record in mcap_reader.iter_metadata():
                    if record.name not in (ROSBAG2_METADATA_RECORD, CUSTOM_DATA_RECORD):
                        writer.add_metadata(record.name, dict(record.metadata))
                for _schema, channel, message in mcap_reader.iter_messages(log_time_order=False):
                    writer.write_serialized(channel.topic, message.data, message.log_time, message.publish_time)
    return target
