""":class:`BagReader`: read rosbag2 MCAP bags (directory or single ``.mcap``) without ROS.

Complete files are read through their summary and chunk indexes (``mcap.reader.SeekingReader``);
unfinished or truncated files (recorder killed) are read record by record up to the last
complete chunk (:func:`dea_ros.bag.mcap_scan.scan_mcap`), with a :class:`BagTruncatedWarning` and
``reader.truncated == True``. Messages are decoded with mcap_ros2's dynamic CDR decoder from the
``ros2msg`` schema stored in the bag, so no ROS message packages are needed; decoded messages
have attribute access (``msg.header.stamp.sec``, ``msg.range``).

Corruption (flipped bytes, a damaged chunk, a summary that disagrees with the data) never
escapes as a decoder's KeyError or zstd error: reading raises :class:`BagError` naming the file
and the damaged record. :meth:`BagReader.verify` checks a whole bag up front (chunk CRCs,
decompression, the data-section and summary CRCs, indexes against the data, and that every
message decodes with its schema), as ``dea-ros bag info`` does.
"""

from __future__ import annotations

import heapq
import warnings
from pathlib import Path
from typing import Any, BinaryIO, Callable, Iterable, Iterator, Mapping, NamedTuple

from mcap.reader import SeekingReader

from ..errors import BagError, BagTruncatedWarning, BagWarning, McapSummaryMissing
from .definitions import normalize_type_name
from .mcap_contents import McapScan
from .mcap_records import has_valid_footer
from .mcap_scan import scan_mcap
from .message_codec import message_decoder
from .metadata import METADATA_FILENAME, load_metadata_yaml
from .qos import QosProfile, parse_qos_profiles

__all__ = ["BagReader", "TopicInfo", "BagMessage", "RawBagMessage"]


class TopicInfo(NamedTuple):
    """What :meth:`BagReader.topics` reports per topic."""

    type: str  #: ``pkg/msg/Type``
    message_count: int
    qos_profiles: list[QosProfile]


class BagMessage(NamedTuple):
    """A decoded message: ``for topic, log_time_ns, msg in reader.messages(): ...``."""

    topic: str
    log_time_ns: int
    message: Any


class RawBagMessage(NamedTuple):
    """A message as stored: CDR bytes plus both timestamps (ns)."""

    topic: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes


class _McapFile:
    """One storage file: summary-based when complete, scan-based when truncated."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.truncated = False
        self.damaged = False
        self.problem = ""
        self._scan: McapScan | None = None
        self._handle: BinaryIO | None = None
        self._reader: SeekingReader | None = None
        if has_valid_footer(path) and self._open_indexed():
            return
        self._open_scanned()

    def _open_indexed(self) -> bool:
        """Read a complete file through its summary; False (file closed) when it must be scanned instead."""
        try:
            self._handle = open(self.path, "rb")
            self._reader = SeekingReader(self._handle, validate_crcs=True)
            header = self._reader.get_header()
            summary = self._reader.get_summary()
            if summary is None:  # no summary section (allowed by MCAP): read linearly
                raise McapSummaryMissing()
            if summary.statistics is None:
                raise ValueError("no summary statistics")
            self.profile = header.profile
            self.schemas = dict(summary.schemas)
            self.channels = dict(summary.channels)
            self.counts = dict(summary.statistics.channel_message_counts)
            self.start_time = summary.statistics.message_start_time
            self.end_time = summary.statistics.message_end_time
            self.message_count = summary.statistics.message_count
            self.metadata = [(m.name, dict(m.metadata)) for m in self._reader.iter_metadata()]
            self._check_profile()
            return True
        except BagError:
            self.close()
            raise
        except McapSummaryMissing:
            self.close()
        except Exception as exc:  # damaged summary: fall back to a linear scan
            self.close()
            self.problem = f"summary unreadable ({type(exc).__name__}: {exc}); scanned linearly"
        return False

    def _open_scanned(self) -> None:
        """Read the complete prefix of a file record by record (unfinished, damaged or without summary)."""
        path = self.path
        scan = scan_mcap(path)
        if scan.header is None:
            raise BagError(
                f"{path} ends before its MCAP Header record is complete ({scan.file_size} bytes); "
                "it holds no recoverable data"
            )
        self._scan = scan
        self.truncated = scan.truncated
        self.damaged = scan.damaged or bool(self.problem)
        details = [scan.problem] if scan.problem else []
        details += [d.replace(f"{path}: ", "", 1) for d in scan.damage if scan.problem not in d]
        if details:
            self.problem = "; ".join(([self.problem] if self.problem else []) + details)
        self.profile = scan.header.profile
        self.schemas = dict(scan.schemas)
        self.channels = dict(scan.channels)
        self.counts: dict[int, int] = {}
        for message in scan.messages:
            self.counts[message.channel_id] = self.counts.get(message.channel_id, 0) + 1
        times = [m.log_time for m in scan.messages]
        self.start_time = min(times, default=0)
        self.end_time = max(times, default=0)
        self.message_count = len(scan.messages)
        self.metadata = [(m.name, dict(m.metadata)) for m in scan.metadata]
        self._check_profile()

    def _check_profile(self) -> None:
        if self.profile != "ros2":
            raise BagError(
                f"{self.path} is an MCAP file with profile {self.profile!r}, not a ROS 2 bag "
                "(rosbag2 writes profile 'ros2'); open it with a generic MCAP reader instead"
            )

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
        self._handle = None
        self._reader = None

    def iter_raw(self, topics: set[str] | None) -> Iterator[tuple[int, int, Any, Any]]:
        """Yield ``(log_time, publish_time, channel, data)`` in log-time order."""
        if self._scan is not None:
            wanted = {cid for cid, ch in self.channels.items() if topics is None or ch.topic in topics}
            messages = [m for m in self._scan.messages if m.channel_id in wanted]
            messages.sort(key=lambda m: m.log_time)  # stable: file order among equal times
            for message in messages:
                yield message.log_time, message.publish_time, self.channels[message.channel_id], message.data
            return
        if self._reader is None:
            raise BagError(f"{self.path} is closed")
        try:
            for _schema, channel, message in self._reader.iter_messages(
                topics=sorted(topics) if topics is not None else None, log_time_order=True
            ):
                yield message.log_time, message.publish_time, channel, message.data
        except BagError:
            raise
        except Exception as exc:  # a damaged chunk or index: name the record
            raise BagError(self.damage_report(f"{type(exc).__name__}: {exc}")) from None

    def damage_report(self, error: str) -> str:
        """A message for a read failure: the damaged record found by a verifying scan."""
        try:
            damage = scan_mcap(self.path, load_messages=False, verify=True).damage
        except BagError as exc:
            damage = [str(exc)]
        where = damage[0] if damage else f"{self.path}: damaged"
        return (
            f"bag file {self.path} is corrupt, reading failed ({error}): {where}. Run "
            f"'dea-ros bag info {self.path}' for every problem, 'dea-ros bag recover --salvage' to keep "
            "the readable records"
        )


class BagReader:
    """Read a rosbag2 MCAP bag: a bag directory (with or without ``metadata.yaml``) or one ``.mcap``.

    * ``path``: bag directory or ``.mcap`` file.
    * ``warn``: emit :class:`BagWarning` / :class:`BagTruncatedWarning` for recoverable problems
      (they are always listed in :attr:`problems`).

    Raises :class:`BagError` (naming the file and the problem) for a path that is not a bag, an
    unsupported storage (e.g. sqlite3), a malformed ``metadata.yaml``, a missing storage file or
    a non-ROS-2 MCAP file.
    """

    def __init__(self, path: str | Path, *, warn: bool = True) -> None:
        self._path = Path(path).expanduser()
        self._warn = warn
        self.problems: list[str] = []
        self.bag_metadata: dict[str, Any] | None = None
        self._files: list[_McapFile] = []
        self._decoders: dict[tuple[int, int], Callable[[bytes], Any]] = {}
        self._metadata_problems: list[str] = []
        try:
            for file_path in self._resolve_files():
                self._files.append(_McapFile(file_path))
        except BaseException:
            self.close()
            raise
        for mcap_file in self._files:
            if mcap_file.problem:
                message = f"{mcap_file.path}: {mcap_file.problem}"
                self.problems.append(message)
                if self._warn:
                    category = BagTruncatedWarning if mcap_file.truncated else BagWarning
                    hint = (
                        f"; read the complete prefix ({mcap_file.message_count} messages). Run "
                        f"dea_ros.bag.recover_bag({str(self._bag_dir)!r}) to repair the bag for other tools"
                        if mcap_file.truncated
                        else ""
                    )
                    warnings.warn(message + hint, category, stacklevel=2)
        self._check_metadata_consistency()

    # -- opening -------------------------------------------------------------------------------
    def _resolve_files(self) -> list[Path]:
        path = self._path
        if not path.exists():
            raise BagError(f"bag {path} does not exist")
        if path.is_file():
            self._bag_dir = path.parent
            return [path]
        if not path.is_dir():
            raise BagError(f"bag {path} is neither a directory nor a file")
        self._bag_dir = path
        metadata_path = path / METADATA_FILENAME
        if metadata_path.is_file():
            info = _load_metadata(metadata_path)
            if info["storage_identifier"] != "mcap":
                raise BagError(
                    f"{metadata_path}: storage_identifier is {info['storage_identifier']!r}; only "
                    "'mcap' bags are supported (convert with: ros2 bag convert -i <bag> -o out.yaml, "
                    "storage_id: mcap)"
                )
            if not info["relative_file_paths"]:
                raise BagError(f"{metadata_path}: relative_file_paths is empty; the bag lists no storage file")
            self.bag_metadata = info
            files = []
            for relative in info["relative_file_paths"]:
                candidate = path / Path(relative).name
                if not candidate.is_file() and (path.parent / relative).is_file():
                    candidate = path.parent / relative  # metadata versions < 4 include the dir name
                if not candidate.is_file():
                    raise BagError(
                        f"{metadata_path} lists storage file {relative!r}, but {candidate} does not exist"
                    )
                files.append(candidate)
            return files
        candidates = sorted(path.glob("*.mcap"))
        if not candidates:
            others = sorted(p.name for p in path.iterdir())[:5]
            raise BagError(
                f"{path} is not a rosbag2 bag: it has no {METADATA_FILENAME} and no .mcap file "
                f"(contains {others or 'nothing'})"
            )
        message = (
            f"{metadata_path} is missing; reading {', '.join(c.name for c in candidates)} directly. "
            f"Run dea_ros.bag.recover_bag({str(path)!r}) to regenerate it"
        )
        self.problems.append(message)
        if self._warn:
            warnings.warn(message, BagWarning, stacklevel=3)
        return candidates

    def _check_metadata_consistency(self) -> None:
        if self.bag_metadata is None:
            return
        actual = {name: info.message_count for name, info in self.topics().items()}
        for name, summary in self.bag_metadata["topics"].items():
            if name not in actual:
                problem = f"{self._bag_dir / METADATA_FILENAME} lists topic {name}, which the MCAP file lacks"
            elif summary.message_count != actual[name] and not self.truncated:
                problem = (
                    f"{self._bag_dir / METADATA_FILENAME} says {summary.message_count} messages on "
                    f"{name}, the MCAP file has {actual[name]}; metadata.yaml is stale"
                )
            else:
                continue
            self.problems.append(problem)
            self._metadata_problems.append(problem)
            if self._warn:
                warnings.warn(problem, BagWarning, stacklevel=3)

    # -- information ----------------------------------------------------------------------------
    @property
    def path(self) -> Path:
        """The path given (bag directory or ``.mcap`` file)."""
        return self._path

    @property
    def files(self) -> list[Path]:
        """The ``.mcap`` storage files read."""
        return [f.path for f in self._files]

    @property
    def damaged(self) -> bool:
        """True when opening found corruption (a damaged record or summary); see :meth:`verify`."""
        return any(f.damaged for f in self._files)

    @property
    def truncated(self) -> bool:
        """True when a storage file was unfinished/truncated (only its complete prefix is read)."""
        return any(f.truncated for f in self._files)

    @property
    def message_count(self) -> int:
        """Total number of readable messages."""
        return sum(f.message_count for f in self._files)

    @property
    def start_time_ns(self) -> int:
        """Earliest log time (ns), 0 for an empty bag."""
        times = [f.start_time for f in self._files if f.message_count]
        return min(times, default=0)

    @property
    def end_time_ns(self) -> int:
        """Latest log time (ns), 0 for an empty bag."""
        times = [f.end_time for f in self._files if f.message_count]
        return max(times, default=0)

    def topics(self) -> dict[str, TopicInfo]:
        """``{topic: TopicInfo(type, message_count, qos_profiles)}`` from the MCAP channels."""
        result: dict[str, TopicInfo] = {}
        for mcap_file in self._files:
            for channel_id, channel in mcap_file.channels.items():
                schema = mcap_file.schemas.get(channel.schema_id)
                type_name = schema.name if schema is not None else ""
                count = mcap_file.counts.get(channel_id, 0)
                previous = result.get(channel.topic)
                if previous is not None:
                    if previous.type != type_name:
                        raise BagError(
                            f"topic {channel.topic} has type {previous.type} and {type_name} in bag "
                            f"{self._path}; a topic must keep one type"
                        )
                    result[channel.topic] = previous._replace(message_count=previous.message_count + count)
                    continue
                result[channel.topic] = TopicInfo(type_name, count, self._qos_of(mcap_file, channel))
        return result

    def _qos_of(self, mcap_file: _McapFile, channel) -> list[QosProfile]:
        text = channel.metadata.get("offered_qos_profiles", "")
        try:
            return parse_qos_profiles(text)
        except ValueError as exc:
            problem = f"{mcap_file.path}: channel {channel.topic}: {exc}"
            if problem not in self.problems:
                self.problems.append(problem)
            if self.bag_metadata and channel.topic in self.bag_metadata["topics"]:
                return list(self.bag_metadata["topics"][channel.topic].offered_qos_profiles)
            return []

    def metadata(self) -> dict[str, dict[str, str]]:
        """MCAP Metadata records as ``{name: {key: value}}`` (a repeated name keeps its last record).

        Includes the ``rosbag2`` record (``serialized_metadata``) that rosbag2 and
        :class:`~dea_ros.bag.BagWriter` store.
        """
        return {name: data for name, data in self.metadata_records()}

    def metadata_records(self) -> list[tuple[str, dict[str, str]]]:
        """All MCAP Metadata records ``(name, {key: value})`` in file order."""
        return [record for mcap_file in self._files for record in mcap_file.metadata]

    def require_topics(self, expected: Mapping[str, str]) -> None:
        """Raise :class:`BagError` unless every ``{topic: "pkg/msg/Type"}`` is present with that type."""
        available = self.topics()
        missing = []
        wrong = []
        for topic, type_name in expected.items():
            canonical = normalize_type_name(type_name)
            if topic not in available:
                missing.append(f"{topic} ({canonical})")
            elif normalize_type_name(available[topic].type) != canonical:
                wrong.append(f"{topic} is {available[topic].type}, expected {canonical}")
        if missing or wrong:
            parts = []
            if missing:
                parts.append("missing topics: " + ", ".join(missing))
            if wrong:
                parts.append("wrong types: " + "; ".join(wrong))
            listing = ", ".join(f"{t} ({i.type})" for t, i in sorted(available.items())) or "none"
            raise BagError(f"bag {self._path} does not match: {'; '.join(parts)}. Topics in the bag: {listing}")

    # -- messages -------------------------------------------------------------------------------
    def _topic_filter(self, topics: str | Iterable[str] | None) -> set[str] | None:
        if topics is None:
            return None
        wanted = {topics} if isinstance(topics, str) else set(topics)
        available = self.topics()
        unknown = sorted(wanted - set(available))
        if unknown:
            raise BagError(
                f"topic(s) {unknown} not in bag {self._path}; available: {sorted(available) or 'none'}"
            )
        return wanted

    def _iter_merged(self, topics: set[str] | None) -> Iterator[tuple[int, int, int, Any, Any]]:
        streams = [
            ((log, index, pub, channel, data) for log, pub, channel, data in mcap_file.iter_raw(topics))
            for index, mcap_file in enumerate(self._files)
        ]
        if len(streams) == 1:
            return streams[0]
        return heapq.merge(*streams, key=lambda item: (item[0], item[1]))

    def raw_messages(self, topics: str | Iterable[str] | None = None) -> Iterator[RawBagMessage]:
        """Yield :class:`RawBagMessage` (CDR bytes) in log-time order, optionally only ``topics``."""
        wanted = self._topic_filter(topics)
        for log_time, _index, publish_time, channel, data in self._iter_merged(wanted):
            yield RawBagMessage(channel.topic, log_time, publish_time, bytes(data))

    def messages(self, topics: str | Iterable[str] | None = None) -> Iterator[BagMessage]:
        """Yield :class:`BagMessage` ``(topic, log_time_ns, decoded message)`` in log-time order.

        * ``topics``: a topic or topics to read (all when ``None``); an unknown topic raises
            :class:`BagError` listing the available ones.
        """
        wanted = self._topic_filter(topics)
        for log_time, index, _publish_time, channel, data in self._iter_merged(wanted):
            decoder = self._decoder(index, channel)
            try:
                decoded = decoder(data)
            except Exception as exc:
                raise BagError(
                    f"cannot decode message on {channel.topic} at log time {log_time} ns in "
                    f"{self._files[index].path}: {type(exc).__name__}: {exc}"
                ) from exc
            yield BagMessage(channel.topic, log_time, decoded)

    def _decoder(self, file_index: int, channel) -> Callable[[bytes], Any]:
        key = (file_index, channel.id)
        decoder = self._decoders.get(key)
        if decoder is not None:
            return decoder
        mcap_file = self._files[file_index]
        schema = mcap_file.schemas.get(channel.schema_id)
        if channel.message_encoding != "cdr" or schema is None or schema.encoding != "ros2msg":
            raise BagError(
                f"cannot decode topic {channel.topic} in {mcap_file.path}: message encoding "
                f"{channel.message_encoding!r}, schema encoding {getattr(schema, 'encoding', None)!r}; "
                "only 'cdr' messages with 'ros2msg' schemas are supported (use raw_messages())"
            )
        try:
            decoder = message_decoder(schema.name, schema.data)
        except Exception as exc:
            raise BagError(
                f"cannot parse the message definition of {schema.name} (topic {channel.topic}) in "
                f"{mcap_file.path}: {type(exc).__name__}: {exc}"
            ) from exc
        self._decoders[key] = decoder
        return decoder

    # -- verification ---------------------------------------------------------------------------
    def verify(self, decode: bool = True, max_decode_errors: int = 5) -> list[str]:
        """Check the whole bag; return the corruption found (empty list: intact).

        Reads every record of every storage file (:func:`~dea_ros.bag.mcap_scan.scan_mcap` with
        ``verify=True``): chunk CRCs and decompression, the Message Index records against the
        chunks, the data-section CRC, the summary section and footer against the data. With
        ``decode``, every message is decoded with the schema stored for its channel. Also lists a
        ``metadata.yaml`` that disagrees with the storage files. Each entry names the file and the
        record (offset, topic, log time). An unfinished file (recorder killed) is not corruption:
        see :attr:`truncated`.
        """
        problems: list[str] = []
        for mcap_file in self._files:
            try:
                scan = scan_mcap(mcap_file.path, load_messages=decode, verify=True)
            except BagError as exc:
                problems.append(str(exc))
                continue
            problems.extend(scan.damage)
            for channel in scan.channels.values():
                try:
                    parse_qos_profiles(channel.metadata.get("offered_qos_profiles", ""))
                except ValueError as exc:
                    problems.append(f"{mcap_file.path}: channel {channel.id} ({channel.topic}): "
                                    f"offered_qos_profiles unreadable ({exc})")
            if decode:
                problems.extend(_decode_problems(scan, max_decode_errors))
        problems.extend(self._metadata_problems)
        return problems

    # -- lifetime -------------------------------------------------------------------------------
    def close(self) -> None:
        """Release the open files."""
        for mcap_file in self._files:
            mcap_file.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        self.close()


def _load_metadata(path: Path) -> dict[str, Any]:
    """:func:`load_metadata_yaml`, with every way a damaged file can fail as :class:`BagError`."""
    try:
        return load_metadata_yaml(path)
    except RecursionError:
        raise BagError(f"{path} is nested too deeply to be a rosbag2 metadata file; if the .mcap file is "
                       "intact, delete it and run 'dea-ros bag recover' to regenerate it") from None
    except UnicodeDecodeError:
        raise BagError(f"{path} is not text (damaged); if the .mcap file is intact, delete it and run "
                       "'dea-ros bag recover' to regenerate it") from None


def _decode_problems(scan: McapScan, max_errors: int) -> list[str]:
    """Decode every message of a scan with its channel's schema; the failures, as text."""
    decoders: dict[int, Callable[[bytes], Any] | None] = {}
    problems: list[str] = []
    failures = 0
    for number, (message, offset) in enumerate(zip(scan.messages, scan.message_offsets)):
        channel = scan.channels.get(message.channel_id)
        where = f"{scan.path}: message {number} (record at offset {offset}, log time {message.log_time} ns)"
        if channel is None:
            failures += 1
            if failures <= max_errors:
                problems.append(f"{where} refers to channel {message.channel_id}, which the file does not define")
            continue
        if message.channel_id not in decoders:
            schema = scan.schemas.get(channel.schema_id)
            decoder = None
            if channel.message_encoding == "cdr" and schema is not None and schema.encoding == "ros2msg":
                try:
                    decoder = message_decoder(schema.name, schema.data)
                except Exception:  # noqa: BLE001
                    # not necessarily damage (e.g. service event schemas the decoder does not parse);
                    # damage to a schema's bytes is caught by the data-section CRC
                    decoder = None
            decoders[message.channel_id] = decoder
        decoder = decoders[message.channel_id]
        if decoder is None:
            continue  # not CDR/ros2msg, or a schema the decoder cannot parse: not checked
        try:
            decoder(message.data)
        except Exception as exc:  # noqa: BLE001 - any decoder failure is corruption
            failures += 1
            if failures <= max_errors:
                type_name = scan.schemas[channel.schema_id].name
                problems.append(f"{where} on {channel.topic} does not decode as {type_name}: "
                                f"{type(exc).__name__}: {exc}")
    if failures > max_errors:
        problems.append(f"{scan.path}: {failures - max_errors} more messages fail to decode")
    return problems
