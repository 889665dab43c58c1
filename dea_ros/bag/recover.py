""":func:`recover_bag`: repair a bag whose recorder was killed (SIGKILL, power cut, crash).

An unfinished bag directory has a ``<name>_0.mcap`` without summary/footer (possibly ending
inside a chunk) and no ``metadata.yaml``. ``ros2 bag info/play``, Foxglove and rosbags need the
footer. :func:`recover_bag` keeps every complete record of the valid prefix (all chunks that were
flushed, i.e. all messages older than the writer's ``flush_period_s``), rewrites them into a
complete MCAP file with summary and indexes, keeps the damaged original next to it as
``<name>_0.mcap.truncated`` (unless ``keep_original=False``) and regenerates ``metadata.yaml``
from the MCAP channels and the ``rosbag2`` Metadata record. Complete files are left untouched, so
running it on a healthy bag only rewrites ``metadata.yaml``.

It is the equivalent of ``ros2 bag reindex`` plus MCAP's ``mcap recover``, without ROS.
"""

import os
from pathlib import Path
from typing import Any, Dict, List, NamedTuple, Optional, Union

import yaml

from .errors import BagError
from .mcap_io import McapChunkedWriter, has_valid_footer, scan_mcap
from .metadata import (
    EMPTY_BAG_STARTING_TIME_NS,
    METADATA_FILENAME,
    FileSummary,
    TopicSummary,
    build_bag_metadata,
    dump_metadata_yaml,
    dump_serialized_metadata,
    load_metadata_yaml,
    metadata_version_for_format,
)
from .qos import parse_qos_profiles
from .reader import _McapFile
from .writer import ROSBAG2_METADATA_RECORD, _write_text_atomic

__all__ = ["recover_bag", "RecoveryReport"]

_BACKUP_SUFFIX = ".truncated"


class RecoveryReport(NamedTuple):
    """What :func:`recover_bag` did."""

    bag_dir: Path
    files: List[Path]  #: storage files of the bag (after recovery)
    rewritten: List[Path]  #: files that were truncated/unfinished and rewritten
    message_count: int  #: messages in the recovered bag
    topic_message_counts: Dict[str, int]
    dropped_bytes: int  #: bytes of incomplete records discarded
    problems: List[str]  #: what was wrong, per file


def _storage_files(path: Path) -> List[Path]:
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise BagError(f"cannot recover {path}: no such bag directory or .mcap file")
    metadata_path = path / METADATA_FILENAME
    files: List[Path] = []
    if metadata_path.is_file():
        try:
            info = load_metadata_yaml(metadata_path)
            files = [path / Path(p).name for p in info["relative_file_paths"] if (path / Path(p).name).is_file()]
        except BagError:
            files = []  # regenerated below
    for candidate in sorted(path.glob("*.mcap")):
        if candidate not in files:
            files.append(candidate)
    if not files:
        raise BagError(f"cannot recover {path}: it contains no .mcap file")
    return files


def _rosbag2_record(records) -> Optional[Dict[str, Any]]:
    """The last parseable ``rosbag2`` ``serialized_metadata`` mapping, if any."""
    found = None
    for name, data in records:
        if name != ROSBAG2_METADATA_RECORD or "serialized_metadata" not in data:
            continue
        try:
            parsed = yaml.safe_load(data["serialized_metadata"])
        except yaml.YAMLError:
            continue
        if isinstance(parsed, dict):
            found = parsed
    return found


def _qos_uses_integers(text: str) -> bool:
    """True for ``offered_qos_profiles`` written with integer enums (metadata version <= 8)."""
    try:
        items = yaml.safe_load(text) if text else None
    except yaml.YAMLError:
        return False
    return isinstance(items, list) and any(
        isinstance(item, dict) and isinstance(item.get("reliability"), int) for item in items
    )


def recover_bag(
    path: Union[str, Path],
    *,
    keep_original: bool = True,
    rosbag2_format: Optional[str] = None,
) -> RecoveryReport:
    """Make an unfinished/truncated bag readable by every tool; regenerate ``metadata.yaml``.

    :param path: bag directory, or a single ``.mcap`` file (then only that file is repaired and
        the ``metadata.yaml`` written next to it describes only that file).
    :param keep_original: keep each rewritten original as ``<file>.truncated``.
    :param rosbag2_format: ``"jazzy"`` or ``"humble"`` metadata; default: the version recorded in
        the bag's ``rosbag2`` MCAP Metadata record, else ``"humble"`` when the channels carry
        integer QoS enums (Humble writes no such record), else ``"jazzy"``.
    :raises BagError: when the path holds no MCAP file or a file is not MCAP at all.
    """
    path = Path(path).expanduser()
    bag_dir = path.parent if path.is_file() else path
    files = _storage_files(path)
    problems: List[str] = []
    dropped = 0
    scans = {}
    infos = {}
    for file_path in files:
        if has_valid_footer(file_path):
            infos[file_path] = _McapFile(file_path)
            infos[file_path].close()
            if infos[file_path].problem:
                problems.append(f"{file_path}: {infos[file_path].problem}")
            continue
        scan = scan_mcap(file_path)
        if scan.header is None:
            raise BagError(f"cannot recover {file_path}: it ends before the MCAP Header record")
        scans[file_path] = scan
        dropped += scan.file_size - scan.valid_end
        problems.append(f"{file_path}: {scan.problem or 'no footer'}")

    # Bag-level information: topics, counts, times, rosbag2 record.
    all_records = []
    qos_texts: List[str] = []
    topics: Dict[str, TopicSummary] = {}
    file_summaries: List[FileSummary] = []
    for file_path in files:
        if file_path in scans:
            scan = scans[file_path]
            channels, schemas, records = scan.channels, scan.schemas, [(m.name, dict(m.metadata)) for m in scan.metadata]
            counts: Dict[int, int] = {}
            for message in scan.messages:
                counts[message.channel_id] = counts.get(message.channel_id, 0) + 1
            times = [m.log_time for m in scan.messages]
            start, end, count = min(times, default=0), max(times, default=0), len(times)
        else:
            info = infos[file_path]
            channels, schemas, records = info.channels, info.schemas, info.metadata
            counts, start, end, count = info.counts, info.start_time, info.end_time, info.message_count
        all_records.extend(records)
        for channel_id, channel in channels.items():
            qos_texts.append(channel.metadata.get("offered_qos_profiles", ""))
            schema = schemas.get(channel.schema_id)
            type_name = schema.name if schema is not None else ""
            summary = topics.get(channel.topic)
            if summary is None:
                try:
                    qos = parse_qos_profiles(channel.metadata.get("offered_qos_profiles", ""))
                except ValueError as exc:
                    problems.append(f"{file_path}: channel {channel.topic}: {exc}")
                    qos = []
                summary = TopicSummary(
                    channel.topic,
                    type_name,
                    0,
                    qos,
                    channel.metadata.get("topic_type_hash", ""),
                    channel.message_encoding,
                )
                topics[channel.topic] = summary
            summary.message_count += counts.get(channel_id, 0)
        if count:
            file_summaries.append(FileSummary(file_path.name, start, end - start, count))
        else:
            file_summaries.append(FileSummary(file_path.name, EMPTY_BAG_STARTING_TIME_NS, 0, 0))

    recorded = _rosbag2_record(all_records) or {}
    if rosbag2_format is not None:
        version = metadata_version_for_format(rosbag2_format)
    elif isinstance(recorded.get("version"), int):
        version = recorded["version"]
    elif any(_qos_uses_integers(text) for text in qos_texts):
        version = metadata_version_for_format("humble")  # Humble writes no rosbag2 record
    else:
        version = metadata_version_for_format("jazzy")
    custom_data = recorded.get("custom_data") if isinstance(recorded.get("custom_data"), dict) else None
    ros_distro = recorded.get("ros_distro") if isinstance(recorded.get("ros_distro"), str) else ""
    bag_info = build_bag_metadata(
        version=version,
        files=file_summaries,
        topics=list(topics.values()),
        custom_data=custom_data,
        ros_distro=ros_distro,
    )

    rewritten: List[Path] = []
    for file_path, scan in scans.items():
        temporary = file_path.with_name(file_path.name + ".recovering")
        if temporary.exists():
            temporary.unlink()
        with open(temporary, "xb", buffering=0) as handle:
            writer = McapChunkedWriter(
                handle,
                profile=scan.header.profile,
                library=f"{scan.header.library} (recovered by dea_ros.bag.recover_bag)",
                compression="zstd",
            )
            for schema in scan.schemas.values():
                writer.add_schema(schema.name, schema.encoding, schema.data, schema_id=schema.id)
            for channel in scan.channels.values():
                schema_id = channel.schema_id if channel.schema_id in scan.schemas else 0
                writer.add_channel(
                    channel.topic, channel.message_encoding, schema_id, channel.metadata, channel_id=channel.id
                )
            for name, data in ((m.name, m.metadata) for m in scan.metadata):
                if name != ROSBAG2_METADATA_RECORD:
                    writer.add_metadata(name, data)
            known = set(scan.channels)
            for message in scan.messages:
                if message.channel_id in known:
                    writer.add_message(
                        message.channel_id, message.log_time, message.publish_time, message.data, message.sequence
                    )
            if version >= 8:
                writer.add_metadata(ROSBAG2_METADATA_RECORD, {"serialized_metadata": dump_serialized_metadata(bag_info)})
            writer.finish()
            os.fsync(handle.fileno())
        if keep_original:
            os.replace(file_path, file_path.with_name(file_path.name + _BACKUP_SUFFIX))
        os.replace(temporary, file_path)
        rewritten.append(file_path)

    _write_text_atomic(bag_dir / METADATA_FILENAME, dump_metadata_yaml(bag_info), fsync=True)
    return RecoveryReport(
        bag_dir=bag_dir,
        files=files,
        rewritten=rewritten,
        message_count=sum(f.message_count for f in file_summaries),
        topic_message_counts={name: t.message_count for name, t in topics.items()},
        dropped_bytes=dropped,
        problems=problems,
    )
