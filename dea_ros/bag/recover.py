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

Every file is verified first (chunk CRCs, decompression, data-section CRC, indexes, summary).
Damage limited to indexes or the summary is rebuilt from the data without loss. Damage to the
data itself (a record that cannot be read) stops the recovery with :class:`BagError` naming the
file and record, before anything is changed, unless ``salvage=True``: then every readable record
is kept and the damaged ones are skipped.

Nothing is ever left half-written: a rewritten file goes to ``<file>.recovering``, is fsynced and
renamed over the original (the temporary file is removed on any failure), and a full disk is
reported as such, naming the path. ``in_place=True`` (used by the recorder after a write error,
and ``dea-ros bag recover --in-place`` on a full disk) finishes an unfinished file where it lies
instead: it is cut back to its last complete record and its summary appended, which needs no
second copy of the data.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Mapping, NamedTuple, Sequence

import yaml
from mcap.records import Channel, Schema

from ..errors import BagError
from .definitions import MessageDefinitionStore
from .files import fsync_directory, is_disk_full, write_text_atomic
from .mcap_contents import McapScan
from .mcap_finish import finish_in_place
from .mcap_scan import scan_mcap
from .mcap_writer import McapChunkedWriter
from .message_codec import message_decoder
from .metadata import (
    EMPTY_BAG_STARTING_TIME_NS,
    METADATA_FILENAME,
    ROSBAG2_METADATA_RECORD,
    FileSummary,
    TopicSummary,
    build_bag_metadata,
    dump_metadata_yaml,
    dump_serialized_metadata,
    load_metadata_yaml,
    metadata_version_for_format,
)
from .qos import QosProfile, parse_qos_profiles, serialize_qos_profiles

__all__ = ["recover_bag", "RecoveryReport"]

_BACKUP_SUFFIX = ".truncated"
_DAMAGED_SUFFIX = ".damaged"
#: An MCAP Metadata record: (name, {key: value}).
_Record = tuple[str, Mapping[str, str]]


class RecoveryReport(NamedTuple):
    """What :func:`recover_bag` did."""

    bag_dir: Path
    files: list[Path]  #: storage files of the bag (after recovery)
    rewritten: list[Path]  #: files that were truncated/unfinished and rewritten
    message_count: int  #: messages in the recovered bag
    topic_message_counts: dict[str, int]
    dropped_bytes: int  #: bytes of incomplete records discarded
    problems: list[str]  #: what was wrong, per file
    damage: list[str] = []  #: corruption found (with ``salvage``: what was skipped)
    in_place: list[Path] = []  #: files finished in place (no copy)

    def summary(self) -> str:
        """A few lines for a person: what was done, how many messages, what was lost."""
        lines = [f"bag {self.bag_dir}: {self.message_count} messages in {len(self.files)} file(s)"]
        for file_path in self.rewritten:
            how = "finished in place" if file_path in self.in_place else "rewritten"
            lines.append(f"  {how}: {file_path}")
        if not self.rewritten:
            lines.append("  storage files intact: only metadata.yaml regenerated")
        if self.dropped_bytes:
            lines.append(f"  {self.dropped_bytes} bytes of incomplete or damaged records dropped")
        for topic, count in sorted(self.topic_message_counts.items()):
            lines.append(f"  {topic:<40} {count:>8}")
        for problem in self.damage:
            lines.append(f"  damage: {problem}")
        return "\n".join(lines)


def recover_bag(
    path: str | Path,
    *,
    keep_original: bool = True,
    rosbag2_format: str | None = None,
    salvage: bool = False,
    in_place: bool = False,
    extra_metadata: Sequence[_Record] = (),
) -> RecoveryReport:
    """Make an unfinished/truncated bag readable by every tool; regenerate ``metadata.yaml``.

    * ``path``: bag directory, or a single ``.mcap`` file (then only that file is repaired and
      the ``metadata.yaml`` written next to it describes only that file).
    * ``keep_original``: keep each rewritten original as ``<file>.truncated`` (``<file>.damaged``
      when records were skipped).
    * ``rosbag2_format``: ``"jazzy"`` or ``"humble"`` metadata; default: the version recorded in
      the bag's ``rosbag2`` MCAP Metadata record, else ``"humble"`` when the channels carry
      integer QoS enums (Humble writes no such record), else ``"jazzy"``.
    * ``salvage``: keep what is readable of files whose data are damaged (skipping the damaged
      records) instead of raising :class:`~dea_ros.errors.BagError`.
    * ``in_place``: finish unfinished, undamaged files where they lie (no copy: works on a full
      disk; no backup of the original is kept).
    * ``extra_metadata``: MCAP Metadata records ``(name, {key: value})`` to add to each
      rewritten file (e.g. an experiment marked aborted).

    Raises :class:`~dea_ros.errors.BagError` when the path holds no MCAP file, a file is not
    MCAP at all, its data are damaged (without ``salvage``), or the disk is full; the message
    names the file.
    """
    path = Path(path).expanduser()
    bag_dir = path.parent if path.is_file() else path
    files = _storage_files(path)
    scans = _scan_files(files, bag_dir, salvage)
    contents = _bag_contents(files, scans)
    bag_info, version = _bag_information(contents, rosbag2_format)
    rosbag2_record = (ROSBAG2_METADATA_RECORD, {"serialized_metadata": dump_serialized_metadata(bag_info)})
    finishing = list(extra_metadata) + ([rosbag2_record] if version >= 8 else [])
    finished_in_place = _finish_files(scans.to_repair, finishing, keep_original, in_place)
    write_text_atomic(bag_dir / METADATA_FILENAME, dump_metadata_yaml(bag_info), fsync=True)
    return RecoveryReport(
        bag_dir=bag_dir,
        files=files,
        rewritten=list(scans.to_repair),
        message_count=sum(f.message_count for f in contents.files),
        topic_message_counts={name: t.message_count for name, t in contents.topics.items()},
        dropped_bytes=scans.dropped_bytes,
        problems=scans.problems + contents.problems,
        damage=scans.damage,
        in_place=finished_in_place,
    )


def _storage_files(path: Path) -> list[Path]:
    """The storage files of a bag: those metadata.yaml lists (if readable), then every other .mcap."""
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise BagError(f"cannot recover {path}: no such bag directory or .mcap file")
    metadata_path = path / METADATA_FILENAME
    files: list[Path] = []
    if metadata_path.is_file():
        try:
            info = load_metadata_yaml(metadata_path)
            files = [path / Path(p).name for p in info["relative_file_paths"] if (path / Path(p).name).is_file()]
        except (BagError, RecursionError, UnicodeDecodeError):
            files = []  # damaged: regenerated below
    for candidate in sorted(path.glob("*.mcap")):
        if candidate not in files:
            files.append(candidate)
    if not files:
        raise BagError(f"cannot recover {path}: it contains no .mcap file")
    return files


@dataclass
class _FileScans:
    """The verifying scans of a bag's storage files and what they found."""

    all: dict[Path, McapScan] = field(default_factory=dict)
    to_repair: dict[Path, McapScan] = field(default_factory=dict)  #: files to rewrite or finish
    problems: list[str] = field(default_factory=list)  #: what was wrong, per repaired file
    damage: list[str] = field(default_factory=list)  #: corruption found, and what the repair did
    dropped_bytes: int = 0  #: bytes after the valid prefix of unfinished files


def _scan_files(files: list[Path], bag_dir: Path, salvage: bool) -> _FileScans:
    """Scan and verify every file; refuse damaged data unless ``salvage``; repair definitions.

    Nothing is changed on disk here: a refusal leaves the bag as it was.
    """
    scans = _FileScans()
    for file_path in files:
        scan = scans.all[file_path] = scan_mcap(file_path, verify=True, salvage=salvage)
        if scan.header is None:
            raise BagError(f"cannot recover {file_path}: it ends before the MCAP Header record")
        scans.damage.extend(scan.damage)
        if scan.data_lost and not salvage:
            listing = "; ".join(scan.damage[:5]) + \
                (f" (and {len(scan.damage) - 5} more)" if len(scan.damage) > 5 else "")
            raise BagError(
                f"cannot recover {file_path}: its data are damaged, not only cut short: {listing}. Nothing was "
                f"changed. Rerun with --salvage (salvage=True) to keep the {scan.message_count} readable "
                "messages and skip the damaged records"
            )
        if scan.complete and not scan.damage:
            continue  # intact: left untouched
        scans.damage.extend(_repair_definitions(scan, _recorded_qos(bag_dir)))
        scans.to_repair[file_path] = scan
        scans.dropped_bytes += scan.file_size - scan.valid_end if not scan.complete else 0
        scans.problems.append(f"{file_path}: {scan.problem or 'index or summary damaged'}")
    return scans


@dataclass
class _BagContents:
    """Bag-level information gathered from the scans: topics, files, Metadata records."""

    topics: dict[str, TopicSummary] = field(default_factory=dict)
    files: list[FileSummary] = field(default_factory=list)
    records: list[_Record] = field(default_factory=list)  #: every MCAP Metadata record
    qos_texts: list[str] = field(default_factory=list)  #: every channel's ``offered_qos_profiles``
    problems: list[str] = field(default_factory=list)  #: channels whose QoS cannot be read


def _bag_contents(files: list[Path], scans: _FileScans) -> _BagContents:
    """Topics (with message counts), file summaries and Metadata records of the recovered bag.

    A repaired file counts only the messages of the channels it keeps.
    """
    contents = _BagContents()
    for file_path in files:
        scan = scans.all[file_path]
        known = set(scan.channels)
        counts = {cid: n for cid, n in scan.channel_counts.items() if cid in known}
        contents.records.extend((m.name, dict(m.metadata)) for m in scan.metadata)
        _add_topics(contents, file_path, scan, counts)
        if file_path in scans.to_repair:
            times = [m.log_time for m in scan.messages if m.channel_id in known]
            start, end, count = min(times, default=0), max(times, default=0), len(times)
        else:
            start, end, count = scan.message_start_time, scan.message_end_time, scan.message_count
        if count:
            contents.files.append(FileSummary(file_path.name, start, end - start, count))
        else:
            contents.files.append(FileSummary(file_path.name, EMPTY_BAG_STARTING_TIME_NS, 0, 0))
    return contents


def _add_topics(contents: _BagContents, file_path: Path, scan: McapScan, counts: Mapping[int, int]) -> None:
    """Add a file's channels to the bag's topics (a topic's first channel gives its type and QoS)."""
    for channel_id, channel in scan.channels.items():
        contents.qos_texts.append(channel.metadata.get("offered_qos_profiles", ""))
        summary = contents.topics.get(channel.topic)
        if summary is None:
            schema = scan.schemas.get(channel.schema_id)
            try:
                qos = parse_qos_profiles(channel.metadata.get("offered_qos_profiles", ""))
            except ValueError as exc:
                contents.problems.append(f"{file_path}: channel {channel.topic}: {exc}")
                qos = []
            summary = TopicSummary(
                channel.topic,
                schema.name if schema is not None else "",
                0,
                qos,
                channel.metadata.get("topic_type_hash", ""),
                channel.message_encoding,
            )
            contents.topics[channel.topic] = summary
        summary.message_count += counts.get(channel_id, 0)


def _bag_information(contents: _BagContents, rosbag2_format: str | None) -> tuple[dict[str, Any], int]:
    """The ``metadata.yaml`` mapping of the recovered bag and its metadata version.

    The version is ``rosbag2_format``'s, else the one the bag's ``rosbag2`` record says, else
    Humble's when the channels carry integer QoS enums (Humble writes no such record), else Jazzy's.
    """
    recorded = _rosbag2_record(contents.records) or {}
    if rosbag2_format is not None:
        version = metadata_version_for_format(rosbag2_format)
    elif isinstance(recorded.get("version"), int):
        version = recorded["version"]
    elif any(_qos_uses_integers(text) for text in contents.qos_texts):
        version = metadata_version_for_format("humble")
    else:
        version = metadata_version_for_format("jazzy")
    custom_data = recorded.get("custom_data") if isinstance(recorded.get("custom_data"), dict) else None
    ros_distro = recorded.get("ros_distro") if isinstance(recorded.get("ros_distro"), str) else ""
    bag_info = build_bag_metadata(
        version=version,
        files=contents.files,
        topics=list(contents.topics.values()),
        custom_data=custom_data,
        ros_distro=ros_distro,
    )
    return bag_info, version


def _rosbag2_record(records: Sequence[_Record]) -> dict[str, Any] | None:
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


def _finish_files(to_repair: Mapping[Path, McapScan], finishing: list[_Record], keep_original: bool,
                  in_place: bool) -> list[Path]:
    """Rewrite (or, ``in_place``, finish where they lie) the files to repair; those finished in place."""
    finished_in_place: list[Path] = []
    for file_path, scan in to_repair.items():
        if in_place and not scan.damage and not scan.data_end_seen and not scan.top_level_messages:
            finish_in_place(file_path, scan, finishing)
            finished_in_place.append(file_path)
        else:
            _rewrite(file_path, scan, finishing, keep_original)
    return finished_in_place


def _recorded_qos(bag_dir: Path) -> dict[str, list[QosProfile]]:
    """``{topic: [QosProfile]}`` from the bag's metadata.yaml, if it is readable."""
    try:
        info = load_metadata_yaml(bag_dir / METADATA_FILENAME)
    except (BagError, RecursionError, UnicodeDecodeError, OSError):
        return {}
    return {name: list(t.offered_qos_profiles) for name, t in info["topics"].items() if t.offered_qos_profiles}


def _repair_definitions(scan: McapScan, recorded_qos: Mapping[str, list[QosProfile]]) -> list[str]:
    """Make a damaged file's schemas and channels usable by every reader; what was done, as text.

    A schema text that no longer parses is replaced by the installed/vendored definition of its
    type (if known), else its channels and their messages are dropped; a channel whose
    ``offered_qos_profiles`` no longer parses gets the topic's QoS from metadata.yaml, else none.
    """
    unusable, notes = _repair_schemas(scan)
    return notes + _repair_channels(scan, recorded_qos, unusable)


def _repair_schemas(scan: McapScan) -> tuple[set[int], list[str]]:
    """Replace damaged ``ros2msg`` schema texts by the known definitions; the unusable schema ids, notes."""
    notes: list[str] = []
    store = None
    unusable: set[int] = set()
    for schema_id, schema in list(scan.schemas.items()):
        if schema.encoding != "ros2msg":
            continue
        try:
            message_decoder(schema.name, schema.data)
            continue
        except Exception:  # noqa: BLE001 - damaged text
            pass
        try:
            store = store or MessageDefinitionStore()
            definition = store.full_definition(schema.name)
            message_decoder(schema.name, definition.text.encode("utf-8"))
        except Exception:  # noqa: BLE001 - unknown or damaged type name too
            unusable.add(schema_id)
            notes.append(f"{scan.path}: schema {schema_id} ({schema.name!r}) is damaged and its type unknown: "
                         "its topics are dropped")
            continue
        scan.schemas[schema_id] = Schema(id=schema_id, name=schema.name, encoding=schema.encoding,
                                         data=definition.text.encode("utf-8"))
        notes.append(f"{scan.path}: schema {schema_id} ({schema.name}) was damaged: replaced by the "
                     "installed definition")
    return unusable, notes


def _repair_channels(scan: McapScan, recorded_qos: Mapping[str, list[QosProfile]], unusable: set[int]) -> list[str]:
    """Drop the channels of unusable schemas; give damaged QoS texts the recorded ones; notes."""
    notes: list[str] = []
    for channel_id, channel in list(scan.channels.items()):
        if channel.schema_id in unusable:
            del scan.channels[channel_id]
            continue
        text = channel.metadata.get("offered_qos_profiles", "")
        try:
            parse_qos_profiles(text)
            continue
        except ValueError:
            pass
        metadata = {k: v for k, v in channel.metadata.items() if k != "offered_qos_profiles"}
        profiles = recorded_qos.get(channel.topic)
        if profiles:
            version = 5 if _qos_uses_integers(text) else 9
            metadata["offered_qos_profiles"] = serialize_qos_profiles(profiles, version)
        scan.channels[channel_id] = Channel(id=channel_id, topic=channel.topic,
                                            message_encoding=channel.message_encoding,
                                            schema_id=channel.schema_id, metadata=metadata)
        notes.append(f"{scan.path}: channel {channel_id} ({channel.topic}): offered_qos_profiles damaged, "
                     + ("taken from metadata.yaml" if profiles else "dropped"))
    return notes


def _rewrite(file_path: Path, scan: McapScan, finishing: list[_Record], keep_original: bool) -> None:
    """Write the scanned records to a complete ``<file>.recovering``, fsync, rename over ``file_path``."""
    temporary = file_path.with_name(file_path.name + ".recovering")
    _check_room_for_copy(file_path, scan)
    try:
        if temporary.exists():
            temporary.unlink()
        with open(temporary, "xb", buffering=0) as handle:
            _write_complete_file(handle, scan, finishing)
            os.fsync(handle.fileno())
        if keep_original:
            suffix = _DAMAGED_SUFFIX if scan.data_lost else _BACKUP_SUFFIX
            os.replace(file_path, file_path.with_name(file_path.name + suffix))
        os.replace(temporary, file_path)
        fsync_directory(file_path.parent)
    except OSError as exc:
        try:
            temporary.unlink()
        except OSError:
            pass
        raise BagError(
            f"cannot recover {file_path}: "
            + (f"disk full while writing {temporary} ({exc.strerror}); the temporary file was removed and "
               f"{file_path} is unchanged. Free some space, or finish it where it lies with "
               "'dea-ros bag recover --in-place'" if is_disk_full(exc)
               else f"writing {temporary} failed: {exc.strerror or exc}")
        ) from None


def _check_room_for_copy(file_path: Path, scan: McapScan) -> None:
    """Refuse before writing anything when the disk cannot hold a recovered copy of the file."""
    needed = scan.valid_end + 64 * 1024
    free = shutil.disk_usage(file_path.parent).free
    if free < needed:
        raise BagError(
            f"cannot recover {file_path}: disk full ({free / 2**20:.1f} MiB free on the file system of "
            f"{file_path.parent}, a recovered copy needs about {needed / 2**20:.1f} MiB). Nothing was "
            "changed. Free some space, or finish the file where it lies with 'dea-ros bag recover --in-place'"
            + (" (possible: it is only cut short)" if not scan.damage and not scan.data_end_seen else "")
        )


def _write_complete_file(handle: BinaryIO, scan: McapScan, finishing: list[_Record]) -> None:
    """Write a complete MCAP file: the scan's records and messages, then the ``finishing`` records.

    The old ``rosbag2`` record is left out (``finishing`` holds the new one); messages of dropped
    channels are left out.
    """
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
    for name, data in finishing:
        writer.add_metadata(name, data)
    writer.finish()
