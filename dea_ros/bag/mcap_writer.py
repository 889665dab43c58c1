"""A chunked MCAP writer that can flush on demand, and continue an unfinished file.

The writer produces the same record layout as the MCAP C++ writer used by
``rosbag2_storage_mcap`` (MCAP spec v0, https://mcap.dev/spec): magic, Header, Schema and Channel
records in the data section, Chunks (each followed by its Message Index records), Metadata
records, Data End, then a summary section (Schemas, Channels, Statistics, Chunk Indexes, Metadata
Indexes, Summary Offsets), Footer and closing magic. Schema and Channel records are written
outside chunks as soon as they are registered, so a file cut off at any point still contains
every schema and channel its complete chunks refer to.

:meth:`McapChunkedWriter.flush` closes the open chunk and hands it to the OS; with a periodic
flush, a process killed by SIGKILL leaves a file whose complete prefix holds every message older
than the flush period (read back by :func:`~dea_ros.bag.mcap_scan.scan_mcap`).
:meth:`McapChunkedWriter.resume` continues such a prefix (:func:`~dea_ros.bag.mcap_finish.finish_in_place`).
Only ``mcap.records`` (record classes) and the chunk codecs are used; no ROS.
"""
from __future__ import annotations

import dataclasses
import os
import struct
import zlib
from collections import defaultdict
from typing import BinaryIO, Mapping

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from ..errors import BagError
from .mcap_compression import chunk_compressor
from .mcap_contents import McapScan
from .mcap_records import MCAP_MAGIC, MESSAGE_HEADER

__all__ = ["McapChunkedWriter", "DEFAULT_CHUNK_SIZE_BYTES"]

#: Uncompressed size that closes a chunk (768 KiB, as libmcap).
DEFAULT_CHUNK_SIZE_BYTES = 768 * 1024


class McapChunkedWriter:
    """Chunked MCAP writer with explicit :meth:`flush` (not thread-safe; callers serialize).

    * ``stream``: binary stream opened for writing at offset 0 (not closed by this class); an
      unbuffered ``open(path, "xb", buffering=0)`` makes every closed chunk reach the OS at once.
    * ``profile``: MCAP header profile (``"ros2"`` for rosbag2); ``library``: MCAP header library
      string; ``compression``: ``"zstd"``, ``"lz4"`` or ``"none"``; a chunk is closed once its
      uncompressed size reaches ``chunk_size_bytes``; ``compression_level``: codec level (``None``
      = codec default).
    """

    def __init__(
        self,
        stream: BinaryIO,
        *,
        profile: str,
        library: str,
        compression: str = "zstd",
        chunk_size_bytes: int = DEFAULT_CHUNK_SIZE_BYTES,
        compression_level: int | None = None,
    ) -> None:
        if chunk_size_bytes <= 0:
            raise BagError(f"chunk_size_bytes={chunk_size_bytes} must be positive")
        self._start(stream, compression, compression_level, chunk_size_bytes)
        self._write(MCAP_MAGIC)
        self._write_record(Header(profile=profile, library=library))

    def _start(self, stream: BinaryIO, compression: str, compression_level: int | None,
               chunk_size_bytes: int) -> None:
        """The state of a writer at the start of a file (nothing written yet)."""
        self._stream = stream
        self._compression_name, self._compress = chunk_compressor(compression, compression_level)
        self._chunk_size = int(chunk_size_bytes)
        self._offset = 0
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk = bytearray()
        self._chunk_index_entries: dict[int, list[int]] = defaultdict(list)
        self._chunk_start_time = 0
        self._chunk_end_time = 0
        self._chunk_messages = 0
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._message_count = 0
        self._message_start_time = 0
        self._message_end_time = 0
        self._channel_counts: dict[int, int] = defaultdict(int)
        self._metadata_count = 0
        self._finished = False
        self._data_crc = 0  # CRC-32 of the data section so far (Data End record)

    @classmethod
    def resume(cls, stream: BinaryIO, scan: McapScan, offset: int, data_crc: int,
               rewrite_last_index: bool) -> McapChunkedWriter:
        """A writer continuing an unfinished file (zstd chunks) after its valid prefix.

        ``stream`` is positioned at ``offset`` (the end of the valid prefix, ``scan`` of that
        file), ``data_crc`` is the CRC-32 of the bytes before it. With ``rewrite_last_index`` the
        last chunk's Message Index records are written first (they were cut off).
        """
        writer = cls.__new__(cls)
        writer._start(stream, "zstd", None, DEFAULT_CHUNK_SIZE_BYTES)
        writer._offset = offset
        writer._schemas = dict(scan.schemas)
        writer._channels = dict(scan.channels)
        writer._metadata_indexes = [m for m in scan.metadata_indexes if m.offset + m.length <= offset]
        writer._metadata_count = len(writer._metadata_indexes)
        writer._message_count = scan.message_count
        writer._message_start_time = scan.message_start_time
        writer._message_end_time = scan.message_end_time
        writer._channel_counts = defaultdict(int, scan.channel_counts)
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
    def _write(self, data: bytes | bytearray | memoryview) -> None:
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
    def add_schema(self, name: str, encoding: str, data: bytes, schema_id: int | None = None) -> int:
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
        channel_id: int | None = None,
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
        data: bytes | bytearray | memoryview,
        sequence: int = 0,
    ) -> None:
        """Append a Message record to the open chunk (closing it when full)."""
        chunk = self._chunk
        offset = len(chunk)
        chunk += MESSAGE_HEADER.pack(
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
        index_offsets: dict[int, int] = {}
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
        self._write_summary()
        self._write(MCAP_MAGIC)
        self._stream.flush()

    def _write_summary(self) -> None:
        """Write the summary section and the Footer pointing to it (after Data End)."""
        summary_start = self._offset
        builder = RecordBuilder()
        offsets: list[SummaryOffset] = []

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
