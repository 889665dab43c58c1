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

import dataclasses
import io
import os
import struct
import zlib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Dict, List, Mapping, Optional, Sequence, Tuple, Union

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
        self._data_crc = 0  # CRC-32 of the data section so far (Data End record)
        self._write(MCAP_MAGIC)
        self._write_record(Header(profile=profile, library=library))

    @classmethod
    def _resume(cls, stream: BinaryIO, scan: "McapScan", offset: int, data_crc: int,
                rewrite_last_index: bool) -> "McapChunkedWriter":
        """A writer continuing an unfinished file (see :func:`finish_in_place`).

        ``stream`` is positioned at ``offset`` (the end of the valid prefix), ``data_crc`` is the
        CRC-32 of the bytes before it. With ``rewrite_last_index`` the last chunk's Message Index
        records are written first (they were cut off).
        """
        writer = cls.__new__(cls)
        writer._stream = stream
        writer._compression_name, writer._compress = _compressor("zstd", None)
        writer._chunk_size = 768 * 1024
        writer._offset = offset
        writer._schemas = dict(scan.schemas)
        writer._channels = dict(scan.channels)
        writer._chunk = bytearray()
        writer._chunk_index_entries = defaultdict(list)
        writer._chunk_start_time = writer._chunk_end_time = writer._chunk_messages = 0
        writer._metadata_indexes = [m for m in scan.metadata_indexes if m.offset + m.length <= offset]
        writer._metadata_count = len(writer._metadata_indexes)
        writer._message_count = scan.message_count
        writer._message_start_time = scan.message_start_time
        writer._message_end_time = scan.message_end_time
        writer._channel_counts = defaultdict(int, scan.channel_counts)
        writer._finished = False
        writer._data_crc = data_crc
        chunks = [c for c in scan.chunks if c.end <= offset]
        if rewrite_last_index and chunks:
            last = chunks[-1] = dataclasses.replace(chunks[-1])  # the scan stays as it was
            builder = RecordBuilder()
            last.index_offsets = {}
            for channel_id, entries in sorted(last.entries.items()):
                last.index_offsets[channel_id] = offset + builder.count
                MessageIndex(channel_id=channel_id, records=list(entries)).write(builder)
            last.index_length = builder.count
            writer._write(builder.end())
        writer._chunk_indexes = [c.chunk_index() for c in chunks]
        return writer

    # -- helpers ---------------------------------------------------------------------------
    def _write(self, data: Union[bytes, bytearray, memoryview]) -> None:
        if not self._finished:
            self._data_crc = zlib.crc32(data, self._data_crc)
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

    def finish(self, summary: bool = True) -> None:
        """Write Data End, the summary section, Footer and magic; flush the stream.

        ``summary=False`` writes no summary section (footer with summary start 0: readers then
        scan the data section linearly); only for a file that must be closed on a full disk.
        """
        if self._finished:
            return
        self.close_chunk()
        self._write_record(DataEnd(data_section_crc=self._data_crc))
        self._finished = True  # the data section is complete: no CRC over the summary
        if not summary:
            footer = Footer(summary_start=0, summary_offset_start=0, summary_crc=0)
            self._write_record(footer)
            self._write(MCAP_MAGIC)
            self._stream.flush()
            return
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
        summary_bytes = builder.end()
        crc = zlib.crc32(summary_bytes)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), crc)
        self._write(summary_bytes)
        self._write_record(Footer(summary_start=summary_start,
                           summary_offset_start=summary_offset_start, summary_crc=crc))
        self._write(MCAP_MAGIC)
        self._stream.flush()


#: Known MCAP opcodes (anything else in a ros2 bag is damage: rosbag2 never writes private records).
_KNOWN_OPCODES = frozenset(int(op) for op in Opcode)
#: Largest chunk we are willing to decompress (a flipped size field must not allocate terabytes).
MAX_CHUNK_UNCOMPRESSED_BYTES = 1 << 30


@dataclass
class ChunkInfo:
    """One complete Chunk record found by :func:`scan_mcap`, with what its index should say."""

    offset: int  #: file offset of the Chunk record
    record_length: int  #: bytes of the record (opcode + length + body)
    message_start_time: int
    message_end_time: int
    compression: str
    compressed_size: int
    uncompressed_size: int
    #: from the chunk content: channel id -> [(log_time, offset in the uncompressed chunk)]
    entries: Dict[int, List[Tuple[int, int]]] = field(default_factory=dict)
    #: Message Index records found right after the chunk: channel id -> file offset
    index_offsets: Dict[int, int] = field(default_factory=dict)
    index_length: int = 0

    @property
    def end(self) -> int:
        """File offset just past the Chunk record (where its Message Index records start)."""
        return self.offset + self.record_length

    @property
    def index_complete(self) -> bool:
        """Every channel of the chunk has its Message Index record after it."""
        return set(self.entries) <= set(self.index_offsets)

    def chunk_index(self) -> ChunkIndex:
        """The Chunk Index record of the summary section describing this chunk."""
        return ChunkIndex(
            message_start_time=self.message_start_time,
            message_end_time=self.message_end_time,
            chunk_start_offset=self.offset,
            chunk_length=self.record_length,
            message_index_offsets=dict(self.index_offsets),
            message_index_length=self.index_length,
            compression=self.compression,
            compressed_size=self.compressed_size,
            uncompressed_size=self.uncompressed_size,
        )


@dataclass
class McapScan:
    """Result of :func:`scan_mcap`: everything readable from the complete prefix of a file.

    ``problem`` says why reading stopped early (end of an unfinished file, or a damaged record);
    ``damage`` lists every sign of corruption found (damaged or unknown records, CRC mismatches,
    indexes or summary that disagree with the data). A file cut short by a killed writer has a
    ``problem`` but no ``damage``. ``data_lost`` tells damage to the data itself (records that
    cannot be read, a data-section CRC mismatch) from damage only to indexes and the summary,
    which can be rebuilt from the data without loss.
    """

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
    damage: List[str] = field(default_factory=list)  #: signs of corruption (see class docstring)
    chunks: List[ChunkInfo] = field(default_factory=list)
    metadata_indexes: List[MetadataIndex] = field(default_factory=list)
    #: file offset of the record holding each entry of ``messages`` (its Chunk, or itself)
    message_offsets: List[int] = field(default_factory=list)
    top_level_messages: int = 0  #: Message records outside chunks
    message_count: int = 0  #: messages found (also without ``load_messages``)
    channel_counts: Dict[int, int] = field(default_factory=dict)  #: channel id -> messages
    message_start_time: int = 0  #: smallest log time, ns (0 without messages)
    message_end_time: int = 0  #: largest log time, ns (0 without messages)
    data_end_offset: Optional[int] = None  #: offset of the Data End record, if seen
    data_lost: bool = False  #: damage to the data section itself (see class docstring)

    @property
    def truncated(self) -> bool:
        """True when the data section is incomplete (writer killed or file damaged)."""
        return not self.data_end_seen

    @property
    def damaged(self) -> bool:
        """True when corruption was found (not only an unfinished end)."""
        return bool(self.damage)

    def _count(self, channel_id: int, log_time: int) -> None:
        self._count_entries({channel_id: [(log_time, 0)]})

    def _count_entries(self, entries: Mapping[int, List[Tuple[int, int]]]) -> None:
        """Add the messages ``{channel: [(log_time, offset)]}`` to the counts and time range."""
        for channel_id, pairs in entries.items():
            if not pairs:
                continue
            times = [t for t, _ in pairs]
            low, high = min(times), max(times)
            if self.message_count == 0:
                self.message_start_time, self.message_end_time = low, high
            else:
                self.message_start_time = min(self.message_start_time, low)
                self.message_end_time = max(self.message_end_time, high)
            self.message_count += len(pairs)
            self.channel_counts[channel_id] = self.channel_counts.get(channel_id, 0) + len(pairs)


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


def _parse_message_index(body: bytes) -> MessageIndex:
    """A Message Index record (fast: one unpack for all entries)."""
    channel_id, length = struct.unpack_from("<HI", body, 0)
    if length % 16 or 6 + length > len(body):
        raise ValueError(f"Message Index entries of {length} bytes in a record of {len(body)}")
    return MessageIndex(channel_id, list(struct.iter_unpack("<QQ", body[6 : 6 + length])))


def _opcode_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.title().replace("_", " ")
    except ValueError:
        return f"opcode {opcode:#04x}"


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if size > MAX_CHUNK_UNCOMPRESSED_BYTES:
        raise ValueError(f"implausible uncompressed chunk size {size} bytes")
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    raise ValueError(f"unsupported chunk compression {compression!r}")


def _chunk_records(
    chunk: Chunk, load_messages: bool = True
) -> Tuple[List[Schema], List[Channel], List[Message], Dict[int, List[Tuple[int, int]]]]:
    """Decompress and CRC-check a chunk; its records and ``{channel: [(log_time, offset)]}``."""
    raw = _decompress(chunk.compression, chunk.data, chunk.uncompressed_size)
    if len(raw) != chunk.uncompressed_size:
        raise ValueError(f"chunk decompressed to {len(raw)} bytes, header says {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(raw) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    schemas: List[Schema] = []
    channels: List[Channel] = []
    messages: List[Message] = []
    entries: Dict[int, List[Tuple[int, int]]] = defaultdict(list)
    position = 0
    while position < len(raw):
        if position + 9 > len(raw):
            raise ValueError("chunk ends inside a record header")
        opcode, length = _RECORD_PREFIX.unpack_from(raw, position)
        body = raw[position + 9 : position + 9 + length]
        if len(body) != length:
            raise ValueError("chunk ends inside a record")
        if opcode == Opcode.MESSAGE:
            if length < 22:
                raise ValueError(f"Message record of {length} bytes inside the chunk (at least 22 expected)")
            channel_id, sequence, log_time, publish_time = struct.unpack_from("<HIQQ", body, 0)
            if load_messages:
                messages.append(Message(channel_id, log_time, body[22:], publish_time, sequence))
            entries[channel_id].append((log_time, position))
        elif opcode == Opcode.SCHEMA:
            schemas.append(_parse(Schema, body))
        elif opcode == Opcode.CHANNEL:
            channels.append(_parse(Channel, body))
        elif opcode not in _KNOWN_OPCODES:
            raise ValueError(f"unknown record opcode {opcode:#04x} inside the chunk")
        position += 9 + length
    if entries:
        times = [t for pairs in entries.values() for t, _ in pairs]
        if min(times) != chunk.message_start_time or max(times) != chunk.message_end_time:
            raise ValueError(
                f"chunk header says messages from {chunk.message_start_time} to {chunk.message_end_time} ns, "
                f"its messages span {min(times)} to {max(times)} ns"
            )
    return schemas, channels, messages, dict(entries)


def scan_mcap(
    path: Union[str, Path], *, load_messages: bool = True, verify: bool = False, salvage: bool = False
) -> McapScan:
    """Read an MCAP file record by record, tolerating a truncated or damaged tail.

    Every complete record before the first problem is returned; ``problem`` says what stopped the
    scan (e.g. "file ends inside a Chunk record at offset 123456"). Every chunk is decompressed and
    its CRC checked. Raises :class:`BagError` only when the file is not MCAP at all
    (missing/invalid magic or first record not a Header).

    :param verify: also check everything a reader relies on and list disagreements in
        ``damage``: the Message Index records after each chunk against the chunk content, the
        Data End CRC of the data section, and the whole summary section (footer CRC, schemas,
        channels, statistics, chunk and metadata indexes against the data).
    :param salvage: skip a damaged record (when its length leads to a plausible next record) and
        keep reading, instead of stopping at it; what was skipped is listed in ``damage``.
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
        _scan_records(handle, scan, load_messages, verify, salvage)
        scan.complete = scan.data_end_seen and has_valid_footer(path)
        if scan.data_end_seen and not scan.complete:
            if _ends_with_magic(handle, scan.file_size):  # an end is there, but not a valid footer
                scan.problem = "summary section or footer damaged after Data End"
                scan.damage.append(f"{path}: {scan.problem}")
            else:  # cut short after the data: the summary is simply missing (rebuilt by recover)
                scan.problem = f"file ends at offset {scan.file_size} inside the summary section (no footer)"
        elif not scan.data_end_seen and has_valid_footer(path):
            # The file has its end (footer + magic): stopping early is damage, not truncation.
            scan.data_lost = True
            if not scan.damage:
                scan.damage.append(f"{path}: {scan.problem}; the file has a footer, so it was not cut short")
        if verify and scan.complete and scan.data_end_offset is not None:
            _verify_summary(handle, scan)
    return scan


def _ends_with_magic(handle, file_size: int) -> bool:
    if file_size < 2 * len(MCAP_MAGIC):
        return False
    handle.seek(file_size - len(MCAP_MAGIC))
    return handle.read(len(MCAP_MAGIC)) == MCAP_MAGIC


def _plausible_record_at(handle, position: int, file_size: int) -> bool:
    if position == file_size:
        return True
    handle.seek(position)
    prefix = handle.read(9)
    if len(prefix) < 9:
        return False
    opcode, length = _RECORD_PREFIX.unpack(prefix)
    return opcode in _KNOWN_OPCODES and opcode != Opcode.HEADER and length <= file_size - position - 9


def _scan_records(handle, scan: McapScan, load_messages: bool, verify: bool, salvage: bool) -> None:
    path = scan.path
    position = len(MCAP_MAGIC)
    scan.valid_end = position
    crc = zlib.crc32(MCAP_MAGIC)
    index_target: Optional[ChunkInfo] = None  # chunk whose Message Index records may follow
    while True:
        handle.seek(position)
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
            scan.problem = f"file ends inside a {_opcode_name(opcode)} record at offset {position}"
            break
        body = handle.read(length)
        record_crc = zlib.crc32(body, zlib.crc32(prefix, crc))
        follows_chunk = index_target
        index_target = None
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
                if length < 22:
                    raise ValueError(f"Message record of {length} bytes (at least 22 expected)")
                scan.top_level_messages += 1
                channel_id, sequence, log_time, publish_time = struct.unpack_from("<HIQQ", body, 0)
                scan._count(channel_id, log_time)
                if load_messages:
                    scan.messages.append(Message(channel_id, log_time, body[22:], publish_time, sequence))
                    scan.message_offsets.append(position)
            elif opcode == Opcode.CHUNK:
                chunk = _parse(Chunk, body)
                schemas, channels, messages, entries = _chunk_records(chunk, load_messages)
                for schema in schemas:
                    scan.schemas[schema.id] = schema
                for channel in channels:
                    scan.channels[channel.id] = channel
                scan._count_entries(entries)
                if load_messages:
                    scan.messages.extend(messages)
                    scan.message_offsets.extend([position] * len(messages))
                info = ChunkInfo(
                    offset=position,
                    record_length=9 + length,
                    message_start_time=chunk.message_start_time,
                    message_end_time=chunk.message_end_time,
                    compression=chunk.compression,
                    compressed_size=len(chunk.data),
                    uncompressed_size=chunk.uncompressed_size,
                    entries=entries,
                )
                scan.chunks.append(info)
                index_target = info
            elif opcode == Opcode.MESSAGE_INDEX:
                index = _parse_message_index(body)
                if follows_chunk is not None:
                    if index.channel_id in follows_chunk.index_offsets:
                        raise ValueError(f"second Message Index for channel {index.channel_id}")
                    if verify and sorted(index.records) != sorted(follows_chunk.entries.get(index.channel_id, [])):
                        scan.damage.append(
                            f"{path}: Message Index record at offset {position} (channel {index.channel_id}) "
                            f"does not match the chunk at offset {follows_chunk.offset}"
                        )
                    follows_chunk.index_offsets[index.channel_id] = position
                    follows_chunk.index_length += 9 + length
                    index_target = follows_chunk
            elif opcode == Opcode.METADATA:
                scan.metadata.append(_parse(Metadata, body))
                scan.metadata_indexes.append(
                    MetadataIndex(offset=position, length=9 + length, name=scan.metadata[-1].name)
                )
            elif opcode == Opcode.DATA_END:
                data_end = _parse(DataEnd, body)
                if verify and data_end.data_section_crc and data_end.data_section_crc != crc:
                    scan.data_lost = True
                    scan.damage.append(
                        f"{path}: data section CRC mismatch (Data End record at offset {position} says "
                        f"{data_end.data_section_crc:#010x}, the bytes give {crc:#010x}): a schema, channel, "
                        "metadata or index record is damaged"
                    )
                scan.data_end_seen = True
                scan.data_end_offset = position
                scan.valid_end = position + 9 + length
                break
            elif opcode == Opcode.FOOTER:
                # Footer without Data End: unusual but complete.
                scan.data_end_seen = True
                scan.valid_end = position
                break
            elif opcode not in _KNOWN_OPCODES:
                raise ValueError("unknown record opcode (rosbag2 writes no such record)")
        except BagError:
            raise
        except Exception as exc:  # damaged record: keep the valid prefix
            reason = f"damaged record at offset {position} ({_opcode_name(opcode)}: {type(exc).__name__}: {exc})"
            scan.damage.append(f"{path}: {reason}")
            index_only = opcode == Opcode.MESSAGE_INDEX  # rebuilt from the chunk: nothing is lost
            if (salvage or index_only) and _plausible_record_at(handle, position + 9 + length, scan.file_size):
                scan.data_lost = scan.data_lost or not index_only
                crc = record_crc
                position += 9 + length
                continue
            scan.data_lost = True
            scan.problem = reason
            break
        crc = record_crc
        position += 9 + length
        scan.valid_end = position


def _verify_summary(handle, scan: McapScan) -> None:
    """Check the summary section and footer of a complete file against the scanned data."""
    path = scan.path
    problems: List[str] = []
    handle.seek(scan.file_size - _FOOTER_SIZE - len(MCAP_MAGIC))
    footer_bytes = handle.read(_FOOTER_SIZE)
    try:
        footer = _parse(Footer, footer_bytes[9:])
    except Exception as exc:  # noqa: BLE001
        scan.damage.append(f"{path}: footer unreadable ({type(exc).__name__}: {exc})")
        return
    footer_offset = scan.file_size - _FOOTER_SIZE - len(MCAP_MAGIC)
    start = footer.summary_start or footer_offset
    if not scan.valid_end <= start <= footer_offset:
        scan.damage.append(
            f"{path}: footer at offset {footer_offset} points to a summary at offset {footer.summary_start}, "
            f"outside {scan.valid_end}..{footer_offset}"
        )
        return
    handle.seek(scan.valid_end)
    between = handle.read(footer_offset - scan.valid_end)
    if not footer.summary_start:  # no summary section (allowed): readers scan the data section
        if between:
            scan.damage.append(f"{path}: {len(between)} unexplained bytes between Data End and the footer")
        return
    if footer.summary_start and start != scan.valid_end:
        problems.append(f"summary starts at offset {start}, not right after Data End ({scan.valid_end})")
    summary_bytes = between[start - scan.valid_end :]
    if footer.summary_crc:
        crc = zlib.crc32(footer_bytes[:-4], zlib.crc32(summary_bytes))
        if crc != footer.summary_crc:
            problems.append(
                f"summary CRC mismatch (footer says {footer.summary_crc:#010x}, the bytes give {crc:#010x})"
            )
    records: Dict[int, list] = defaultdict(list)
    groups: Dict[int, Tuple[int, int]] = {}
    position = 0
    try:
        while position < len(summary_bytes):
            opcode, length = _RECORD_PREFIX.unpack_from(summary_bytes, position)
            body = summary_bytes[position + 9 : position + 9 + length]
            if len(body) != length:
                raise ValueError(f"summary ends inside a {_opcode_name(opcode)} record")
            classes = {
                Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.STATISTICS: Statistics,
                Opcode.CHUNK_INDEX: ChunkIndex, Opcode.METADATA_INDEX: MetadataIndex,
                Opcode.SUMMARY_OFFSET: SummaryOffset,
            }
            if opcode in classes:
                records[opcode].append(_parse(classes[opcode], body))
            elif opcode != Opcode.ATTACHMENT_INDEX:
                raise ValueError(f"unexpected {_opcode_name(opcode)} record in the summary")
            if opcode != Opcode.SUMMARY_OFFSET:
                first, total = groups.get(opcode, (start + position, 0))
                groups[opcode] = (first, total + 9 + length)
            position += 9 + length
    except Exception as exc:  # noqa: BLE001
        scan.damage.append(f"{path}: summary record at offset {start + position} unreadable "
                           f"({type(exc).__name__}: {exc})")
        return
    # (a summary may list schemas and channels no message used, which are absent from the data)
    for schema in records[Opcode.SCHEMA]:
        if schema.id in scan.schemas and scan.schemas[schema.id] != schema:
            problems.append(f"summary schema {schema.id} ({schema.name}) differs from the data section")
    for channel in records[Opcode.CHANNEL]:
        if channel.id in scan.channels and scan.channels[channel.id] != channel:
            problems.append(f"summary channel {channel.id} ({channel.topic}) differs from the data section")
    counts = scan.channel_counts
    for stats in records[Opcode.STATISTICS]:
        # (not the time range: writers differ on a message logged at time 0; the CRC covers it)
        expected = {
            "message_count": scan.message_count,
            "chunk_count": len(scan.chunks),
            "metadata_count": len(scan.metadata),
        }
        for key, value in expected.items():
            if getattr(stats, key) != value:
                problems.append(f"summary statistics {key} is {getattr(stats, key)}, the data have {value}")
        nonzero = {k: v for k, v in stats.channel_message_counts.items() if v}
        if stats.channel_message_counts and nonzero != dict(counts):
            problems.append("summary statistics channel_message_counts differ from the data")
    chunk_indexes = records[Opcode.CHUNK_INDEX]
    if chunk_indexes or scan.chunks:
        expected_indexes = sorted((c.chunk_index() for c in scan.chunks), key=lambda c: c.chunk_start_offset)
        found = sorted(chunk_indexes, key=lambda c: c.chunk_start_offset)
        if len(found) != len(expected_indexes):
            problems.append(f"summary lists {len(found)} chunks, the data section has {len(expected_indexes)}")
        else:
            for got, want in zip(found, expected_indexes):
                if got != want:
                    problems.append(f"summary Chunk Index of the chunk at offset {want.chunk_start_offset} "
                                    "does not match the chunk")
                    break
    metadata_indexes = records[Opcode.METADATA_INDEX]
    if metadata_indexes and sorted((m.offset, m.length, m.name) for m in metadata_indexes) != sorted(
        (m.offset, m.length, m.name) for m in scan.metadata_indexes
    ):
        problems.append("summary Metadata Index records do not match the Metadata records")
    for offset in records[Opcode.SUMMARY_OFFSET]:
        if offset.group_length == 0 and offset.group_opcode not in groups:
            continue  # an empty group (mcap-python lists those too)
        if groups.get(offset.group_opcode) != (offset.group_start, offset.group_length):
            problems.append(f"summary offset of the {_opcode_name(offset.group_opcode)} group is wrong")
    scan.damage.extend(f"{path}: summary section at offset {start}: {problem}" for problem in problems)


def finish_in_place(
    path: Union[str, Path],
    scan: McapScan,
    extra_metadata: Sequence[Tuple[str, Mapping[str, str]]] = (),
    *,
    fsync: bool = True,
) -> int:
    """Complete an unfinished MCAP file where it lies: no second copy, so it works on a full disk.

    The file is cut back to the end of its last complete record (``scan.valid_end``; a last chunk
    whose Message Index records were cut gets them rewritten), then ``extra_metadata`` records,
    Data End, the summary section (schemas, channels, statistics, chunk and metadata indexes),
    Footer and magic are appended. If that does not fit (disk full), less is written: no
    summary (readers then scan the file linearly, which needs no index), then fewer extra
    metadata records, most important (first) kept longest, down to none (50 bytes). If even that fails
    the file is left cut back to its valid prefix and
    :class:`BagError` says so. Returns the bytes cut off.

    ``scan`` must come from :func:`scan_mcap` on this file, without damage.
    """
    path = Path(path)
    if scan.header is None or scan.damaged or scan.data_end_seen or scan.top_level_messages:
        raise BagError(f"{path}: only an unfinished, undamaged, chunked MCAP file can be finished in place")
    cut = scan.valid_end
    last = scan.chunks[-1] if scan.chunks else None
    rewrite_index = last is not None and not last.index_complete and cut <= last.end + last.index_length
    if rewrite_index:
        cut = last.end
    try:
        with open(path, "r+b", buffering=0) as handle:
            handle.truncate(cut)
            handle.seek(0)
            crc = 0
            remaining = cut
            while remaining:
                block = handle.read(min(remaining, 1 << 20))
                if not block:
                    raise BagError(f"{path} shrank while it was being finished")
                crc = zlib.crc32(block, crc)
                remaining -= len(block)
            # Most complete first; then without the summary (and the cut Message Index records,
            # which only a summary refers to), then with fewer of the extra records (the first
            # ones matter most), down to nothing but Data End, Footer and magic (50 bytes).
            extra = list(extra_metadata)
            attempts = [(rewrite_index, extra, True), (rewrite_index, extra, False)]
            attempts += [(False, extra[:count], False) for count in range(len(extra), -1, -1)]
            error: Optional[OSError] = None
            for index, metadata, with_summary in attempts:
                handle.seek(cut)
                try:
                    writer = McapChunkedWriter._resume(handle, scan, cut, crc, index)
                    for name, data in metadata:
                        writer.add_metadata(name, data)
                    writer.finish(summary=with_summary)
                    if fsync:
                        os.fsync(handle.fileno())
                    return scan.file_size - cut
                except OSError as exc:
                    error = exc
                    handle.truncate(cut)
            raise BagError(
                f"cannot finish {path}: {_os_reason(error)}; it is cut back to its {cut} valid bytes "
                f"({scan.message_count} messages), free some space and run 'dea-ros bag recover' on it"
            )
    except OSError as exc:
        raise BagError(f"cannot finish {path}: {_os_reason(exc)}") from exc


def _os_reason(exc: Optional[BaseException]) -> str:
    """An OSError as text, saying "disk full" for ENOSPC/EFBIG/EDQUOT."""
    import errno

    if exc is None:
        return "unknown error"
    code = getattr(exc, "errno", None)
    text = getattr(exc, "strerror", None) or str(exc)
    if code in (errno.ENOSPC, errno.EDQUOT):
        return f"disk full ({text})"
    if code == errno.EFBIG:
        return f"disk full: file size limit reached ({text})"
    return text
