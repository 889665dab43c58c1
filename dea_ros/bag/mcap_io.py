"""Low-level MCAP I/O: a chunked writer that can flush on demand and a truncation-tolerant scanner.

The writer produces the same record layout as the MCAP C++ writer used by
``rosbag2_storage_mcap`` (MCAP spec v0, https://mcap.dev/spec): magic, Header, Schema and Channel
records in the data section, Chunks (each followed by its Message Index records), Metadata
records, Data End, then a summary section (Schemas, Channels, Statistics, Chunk Indexes, Metadata
Indexes, Summary Offsets), Footer and closing magic. Schema and Channel records are written
outside chunks as soon as they are registered, so a file cut off at any point still contains
every schema and channel its complete chunks refer to.

:meth:`McapChunkedWriter.flush` closes the open chunk and hands it to the OS; with a periodic
flush, a process killed by SIGKILL leaves a file whose complete prefix holds every message older
than the flush period. :func:`scan_mcap` reads such a prefix (record by record, validating chunk
CRCs) and reports where and why it stopped.

Only ``mcap.records`` (record classes) and ``zstandard`` / ``lz4`` are used; no ROS.
"""

import io
import os
import struct
import zlib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Dict, List, Mapping, Optional, Tuple, Union

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from .errors import BagError

__all__ = [
    "MCAP_MAGIC",
    "COMPRESSIONS",
    "McapChunkedWriter",
    "McapScan",
    "scan_mcap",
    "has_valid_footer",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Chunk compressions accepted by :class:`McapChunkedWriter` (``"none"`` = uncompressed chunks).
COMPRESSIONS = ("zstd", "lz4", "none")
_MESSAGE_HEADER = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log, publish
_RECORD_PREFIX = struct.Struct("<BQ")
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, crc


def _compressor(compression: str, level: Optional[int]):
    """Return ``(name written in the chunk record, compress(bytes) -> bytes)``."""
    if compression == "zstd":
        try:
            import zstandard
        except ImportError:  # pragma: no cover - zstandard is a dependency of mcap
            raise BagError(
                "compression='zstd' needs the 'zstandard' package (pip install zstandard) "
                "or use compression='lz4' / 'none'"
            ) from None
        compressor = zstandard.ZstdCompressor(level=3 if level is None else level)
        return "zstd", compressor.compress
    if compression == "lz4":
        try:
            import lz4.frame
        except ImportError:  # pragma: no cover - lz4 is a dependency of mcap
            raise BagError(
                "compression='lz4' needs the 'lz4' package (pip install lz4) "
                "or use compression='zstd' / 'none'"
            ) from None
        if level is None:
            return "lz4", lz4.frame.compress
        return "lz4", lambda data: lz4.frame.compress(data, compression_level=level)
    if compression == "none":
        return "", bytes
    raise BagError(f"compression={compression!r} is not supported; use one of {COMPRESSIONS}")


class McapChunkedWriter:
    """Chunked MCAP writer with explicit :meth:`flush` (not thread-safe; callers serialize).

    :param stream: binary stream opened for writing at offset 0 (not closed by this class); an
        unbuffered ``open(path, "xb", buffering=0)`` makes every closed chunk reach the OS at once.
    :param profile: MCAP header profile (``"ros2"`` for rosbag2).
    :param library: MCAP header library string.
    :param compression: ``"zstd"``, ``"lz4"`` or ``"none"``.
    :param chunk_size_bytes: a chunk is closed once its uncompressed size reaches this.
    :param compression_level: codec level (``None`` = codec default).
    """

    def __init__(
        self,
        stream: BinaryIO,
        *,
        profile: str,
        library: str,
        compression: str = "zstd",
        chunk_size_bytes: int = 768 * 1024,
        compression_level: Optional[int] = None,
    ) -> None:
        if chunk_size_bytes <= 0:
            raise BagError(f"chunk_size_bytes={chunk_size_bytes} must be positive")
        self._stream = stream
        self._compression_name, self._compress = _compressor(compression, compression_level)
        self._chunk_size = int(chunk_size_bytes)
        self._offset = 0
        self._schemas: Dict[int, Schema] = {}
        self._channels: Dict[int, Channel] = {}
        self._chunk = bytearray()
        self._chunk_index_entries: Dict[int, List[int]] = defaultdict(list)
        self._chunk_start_time = 0
        self._chunk_end_time = 0
        self._chunk_messages = 0
        self._chunk_indexes: List[ChunkIndex] = []
        self._metadata_indexes: List[MetadataIndex] = []
        self._message_count = 0
        self._message_start_time = 0
        self._message_end_time = 0
        self._channel_counts: Dict[int, int] = defaultdict(int)
        self._metadata_count = 0
        self._finished = False
        self._write(MCAP_MAGIC)
        self._write_record(Header(profile=profile, library=library))

    # -- helpers ---------------------------------------------------------------------------
    def _write(self, data: Union[bytes, bytearray, memoryview]) -> None:
        view = memoryview(data)
        while view:
            written = self._stream.write(view)
            if written is None:  # pragma: no cover - non-blocking streams are not supported
                raise BagError("MCAP output stream is non-blocking; use a regular file")
            view = view[written:]
        self._offset += len(data)

    def _write_record(self, record) -> int:
        """Write one record outside any chunk; return its offset."""
        builder = RecordBuilder()
        record.write(builder)
        offset = self._offset
        self._write(builder.end())
        return offset

    @property
    def bytes_written(self) -> int:
        """Bytes handed to the stream so far (excluding the open chunk)."""
        return self._offset

    @property
    def message_count(self) -> int:
        """Messages added so far (including those in the open chunk)."""
        return self._message_count

    @property
    def message_start_time(self) -> int:
        """Smallest log time written, ns (0 before the first message)."""
        return self._message_start_time

    @property
    def message_end_time(self) -> int:
        """Largest log time written, ns (0 before the first message)."""
        return self._message_end_time

    @property
    def pending_messages(self) -> int:
        """Messages in the open chunk, not yet handed to the stream."""
        return self._chunk_messages

    # -- records ---------------------------------------------------------------------------
    def add_schema(self, name: str, encoding: str, data: bytes, schema_id: Optional[int] = None) -> int:
        """Write a Schema record; returns its id (1, 2, ... unless ``schema_id`` is given)."""
        if schema_id is None:
            schema_id = max(self._schemas, default=0) + 1
        if not 0 < schema_id <= 0xFFFF or schema_id in self._schemas:
            raise BagError(f"invalid or duplicate MCAP schema id {schema_id} for schema {name!r}")
        schema = Schema(id=schema_id, name=name, encoding=encoding, data=bytes(data))
        self._schemas[schema_id] = schema
        self._write_record(schema)
        return schema_id

    def add_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str],
        channel_id: Optional[int] = None,
    ) -> int:
        """Write a Channel record; returns its id (1, 2, ... unless ``channel_id`` is given)."""
        if schema_id != 0 and schema_id not in self._schemas:
            raise BagError(f"channel {topic!r} refers to unknown MCAP schema id {schema_id}")
        if channel_id is None:
            channel_id = max(self._channels, default=0) + 1
        if not 0 <= channel_id <= 0xFFFF or channel_id in self._channels:
            raise BagError(f"invalid or duplicate MCAP channel id {channel_id} for topic {topic!r}")
        channel = Channel(
            id=channel_id,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=dict(metadata),
        )
        self._channels[channel_id] = channel
        self._write_record(channel)
        return channel_id

    def add_message(
        self,
        channel_id: int,
        log_time: int,
        publish_time: int,
        data: Union[bytes, bytearray, memoryview],
        sequence: int = 0,
    ) -> None:
        """Append a Message record to the open chunk (closing it when full)."""
        chunk = self._chunk
        offset = len(chunk)
        chunk += _MESSAGE_HEADER.pack(
            0x05, 22 + len(data), channel_id, sequence & 0xFFFFFFFF, log_time, publish_time
        )
        chunk += data
        entries = self._chunk_index_entries[channel_id]
        entries.append(log_time)
        entries.append(offset)
        if self._chunk_messages == 0:
            self._chunk_start_time = self._chunk_end_time = log_time
        elif log_time < self._chunk_start_time:
            self._chunk_start_time = log_time
        elif log_time > self._chunk_end_time:
            self._chunk_end_time = log_time
        self._chunk_messages += 1
        if self._message_count == 0:
            self._message_start_time = self._message_end_time = log_time
        elif log_time < self._message_start_time:
            self._message_start_time = log_time
        elif log_time > self._message_end_time:
            self._message_end_time = log_time
        self._message_count += 1
        self._channel_counts[channel_id] += 1
        if offset >= self._chunk_size:
            self.close_chunk()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write a Metadata record (outside chunks) and remember its index entry."""
        builder = RecordBuilder()
        Metadata(name=name, metadata=dict(data)).write(builder)
        payload = builder.end()
        offset = self._offset
        self._write(payload)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(payload), name=name))
        self._metadata_count += 1

    def close_chunk(self) -> None:
        """Compress and write the open chunk and its message indexes (no-op when empty)."""
        if self._chunk_messages == 0:
            return
        raw = bytes(self._chunk)
        compressed = self._compress(raw)
        chunk = Chunk(
            compression=self._compression_name,
            data=compressed,
            message_start_time=self._chunk_start_time,
            message_end_time=self._chunk_end_time,
            uncompressed_crc=zlib.crc32(raw),
            uncompressed_size=len(raw),
        )
        builder = RecordBuilder()
        chunk.write(builder)
        chunk_bytes = builder.end()
        chunk_start = self._offset
        index_builder = RecordBuilder()
        index_offsets: Dict[int, int] = {}
        index_start = chunk_start + len(chunk_bytes)
        for channel_id, entries in self._chunk_index_entries.items():
            index_offsets[channel_id] = index_start + index_builder.count
            pairs = list(zip(entries[0::2], entries[1::2]))
            MessageIndex(channel_id=channel_id, records=pairs).write(index_builder)
        index_bytes = index_builder.end()
        # One write call for chunk + indexes keeps the on-disk prefix record-aligned in practice.
        self._write(chunk_bytes + index_bytes)
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=chunk.message_start_time,
                message_end_time=chunk.message_end_time,
                chunk_start_offset=chunk_start,
                chunk_length=len(chunk_bytes),
                message_index_offsets=index_offsets,
                message_index_length=len(index_bytes),
                compression=chunk.compression,
                compressed_size=len(compressed),
                uncompressed_size=len(raw),
            )
        )
        self._chunk = bytearray()
        self._chunk_index_entries = defaultdict(list)
        self._chunk_messages = 0

    def flush(self, fsync: bool = False) -> None:
        """Close the open chunk, flush the stream and optionally ``os.fsync`` it."""
        self.close_chunk()
        self._stream.flush()
        if fsync:
            os.fsync(self._stream.fileno())

    def finish(self) -> None:
        """Write Data End, the summary section, Footer and magic; flush the stream."""
        if self._finished:
            return
        self.close_chunk()
        self._write_record(DataEnd(data_section_crc=0))
        summary_start = self._offset
        builder = RecordBuilder()
        offsets: List[SummaryOffset] = []

        def group(opcode: Opcode, records) -> None:
            start = builder.count
            for record in records:
                record.write(builder)
            if builder.count > start:
                offsets.append(SummaryOffset(opcode, summary_start + start, builder.count - start))

        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        statistics = Statistics(
            message_count=self._message_count,
            schema_count=len(self._schemas),
            channel_count=len(self._channels),
            attachment_count=0,
            metadata_count=self._metadata_count,
            chunk_count=len(self._chunk_indexes),
            message_start_time=self._message_start_time,
            message_end_time=self._message_end_time,
            channel_message_counts=dict(sorted(self._channel_counts.items())),
        )
        group(Opcode.STATISTICS, [statistics])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + builder.count
        for offset in offsets:
            offset.write(builder)
        summary = builder.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), crc)
        self._write(summary)
        self._write_record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc))
        self._write(MCAP_MAGIC)
        self._stream.flush()
        self._finished = True


@dataclass
class McapScan:
    """Result of :func:`scan_mcap`: everything readable from the complete prefix of a file."""

    path: Path
    header: Optional[Header] = None
    schemas: Dict[int, Schema] = field(default_factory=dict)
    channels: Dict[int, Channel] = field(default_factory=dict)
    messages: List[Message] = field(default_factory=list)
    metadata: List[Metadata] = field(default_factory=list)
    file_size: int = 0
    valid_end: int = 0  #: offset just past the last complete, valid data record
    data_end_seen: bool = False  #: the Data End record was reached (data section complete)
    complete: bool = False  #: Footer and closing magic present
    problem: str = ""  #: why reading stopped early ("" when complete)

    @property
    def truncated(self) -> bool:
        """True when the data section is incomplete (writer killed or file damaged)."""
        return not self.data_end_seen


def has_valid_footer(path: Union[str, Path]) -> bool:
    """True if the file ends with a Footer record and the MCAP magic (cheap completeness test)."""
    try:
        with open(path, "rb") as handle:
            handle.seek(0, io.SEEK_END)
            size = handle.tell()
            if size < 2 * len(MCAP_MAGIC) + _FOOTER_SIZE:
                return False
            handle.seek(size - _FOOTER_SIZE - len(MCAP_MAGIC))
            tail = handle.read()
    except OSError:
        return False
    return tail[-8:] == MCAP_MAGIC and tail[0] == Opcode.FOOTER and tail[1:9] == struct.pack("<Q", 20)


def _parse(record_class, body: bytes):
    return record_class.read(ReadDataStream(io.BytesIO(body)))


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    raise ValueError(f"unsupported chunk compression {compression!r}")


def _chunk_records(chunk: Chunk) -> Tuple[List[Schema], List[Channel], List[Message]]:
    raw = _decompress(chunk.compression, chunk.data, chunk.uncompressed_size)
    if len(raw) != chunk.uncompressed_size:
        raise ValueError(f"chunk decompressed to {len(raw)} bytes, header says {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(raw) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    schemas: List[Schema] = []
    channels: List[Channel] = []
    messages: List[Message] = []
    position = 0
    while position < len(raw):
        if position + 9 > len(raw):
            raise ValueError("chunk ends inside a record header")
        opcode, length = _RECORD_PREFIX.unpack_from(raw, position)
        body = raw[position + 9 : position + 9 + length]
        if len(body) != length:
            raise ValueError("chunk ends inside a record")
        if opcode == Opcode.MESSAGE:
            channel_id, sequence, log_time, publish_time = struct.unpack_from("<HIQQ", body, 0)
            messages.append(Message(channel_id, log_time, body[22:], publish_time, sequence))
        elif opcode == Opcode.SCHEMA:
            schemas.append(_parse(Schema, body))
        elif opcode == Opcode.CHANNEL:
            channels.append(_parse(Channel, body))
        position += 9 + length
    return schemas, channels, messages


def scan_mcap(path: Union[str, Path], *, load_messages: bool = True) -> McapScan:
    """Read an MCAP file record by record, tolerating a truncated or damaged tail.

    Every complete record before the first problem is returned; ``problem`` says what stopped the
    scan (e.g. "file ends inside a Chunk record at offset 123456"). Raises :class:`BagError` only
    when the file is not MCAP at all (missing/invalid magic or first record not a Header).
    """
    path = Path(path)
    scan = McapScan(path=path)
    try:
        handle = open(path, "rb")
    except OSError as exc:
        raise BagError(f"cannot open MCAP file {path}: {exc.strerror or exc}") from exc
    with handle:
        handle.seek(0, io.SEEK_END)
        scan.file_size = handle.tell()
        handle.seek(0)
        magic = handle.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            what = "is empty" if not magic else "does not start with the MCAP magic"
            raise BagError(f"{path} is not an MCAP file: it {what}")
        position = len(MCAP_MAGIC)
        scan.valid_end = position
        while True:
            prefix = handle.read(9)
            if len(prefix) < 9:
                scan.problem = (
                    f"file ends at offset {scan.file_size} without a Data End record "
                    "(writer did not close the file)"
                    if not prefix
                    else f"file ends inside a record header at offset {position}"
                )
                break
            opcode, length = _RECORD_PREFIX.unpack(prefix)
            if length > scan.file_size - position - 9:
                try:
                    name = Opcode(opcode).name
                except ValueError:
                    name = f"opcode {opcode:#x}"
                scan.problem = f"file ends inside a {name} record at offset {position}"
                break
            body = handle.read(length)
            try:
                if scan.header is None:
                    if opcode != Opcode.HEADER:
                        raise BagError(f"{path} is not a valid MCAP file: first record is not a Header")
                    scan.header = _parse(Header, body)
                elif opcode == Opcode.SCHEMA:
                    schema = _parse(Schema, body)
                    scan.schemas[schema.id] = schema
                elif opcode == Opcode.CHANNEL:
                    channel = _parse(Channel, body)
                    scan.channels[channel.id] = channel
                elif opcode == Opcode.MESSAGE:
                    if load_messages:
                        channel_id, sequence, log_time, publish_time = struct.unpack_from("<HIQQ", body, 0)
                        scan.messages.append(Message(channel_id, log_time, body[22:], publish_time, sequence))
                elif opcode == Opcode.CHUNK:
                    chunk = _parse(Chunk, body)
                    schemas, channels, messages = _chunk_records(chunk)
                    for schema in schemas:
                        scan.schemas[schema.id] = schema
                    for channel in channels:
                        scan.channels[channel.id] = channel
                    if load_messages:
                        scan.messages.extend(messages)
                elif opcode == Opcode.METADATA:
                    scan.metadata.append(_parse(Metadata, body))
                elif opcode == Opcode.DATA_END:
                    scan.data_end_seen = True
                    scan.valid_end = position + 9 + length
                    break
                elif opcode == Opcode.FOOTER:
                    # Footer without Data End: unusual but complete.
                    scan.data_end_seen = True
                    scan.valid_end = position
                    break
            except BagError:
                raise
            except Exception as exc:  # damaged record: keep the valid prefix
                scan.problem = f"damaged record at offset {position} ({type(exc).__name__}: {exc})"
                break
            position += 9 + length
            scan.valid_end = position
        scan.complete = scan.data_end_seen and has_valid_footer(path)
        if scan.data_end_seen and not scan.complete:
            scan.problem = "summary section or footer missing/damaged after Data End"
    return scan
