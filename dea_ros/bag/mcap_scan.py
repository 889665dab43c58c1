"""Scanning an MCAP file record by record: what a truncated or damaged file still holds.

:func:`scan_mcap` reads the data section from the start (every chunk decompressed and its CRC
checked) up to the Data End record or the first problem, and reports where and why it stopped in
an :class:`~dea_ros.bag.mcap_contents.McapScan`. A writer killed by SIGKILL leaves a file whose
complete prefix holds every message older than its flush period; this is how that prefix is
read back (:class:`~dea_ros.bag.BagReader`) and rewritten (:func:`~dea_ros.bag.recover_bag`).
With ``verify`` it also checks what a reader relies on (Message Index records, the data-section
CRC, the summary section: :func:`~dea_ros.bag.mcap_summary_check.verify_summary`).
"""
from __future__ import annotations

import io
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Header, Metadata, MetadataIndex, Schema

from ..errors import BagError
from .mcap_contents import ChunkInfo, McapScan
from .mcap_records import (
    KNOWN_OPCODES,
    MCAP_MAGIC,
    MESSAGE_PREFIX_SIZE,
    RECORD_PREFIX,
    RECORD_PREFIX_SIZE,
    chunk_content,
    ends_with_magic,
    has_valid_footer,
    opcode_name,
    parse_message,
    parse_message_index,
    parse_record,
    plausible_record_at,
)
from .mcap_summary_check import verify_summary

__all__ = ["scan_mcap"]


def scan_mcap(path: str | Path, *, load_messages: bool = True, verify: bool = False, salvage: bool = False) -> McapScan:
    """Read an MCAP file record by record, tolerating a truncated or damaged tail.

    Every complete record before the first problem is returned; ``problem`` says what stopped the
    scan (e.g. "file ends inside a Chunk record at offset 123456"). Every chunk is decompressed and
    its CRC checked. Raises :class:`~dea_ros.errors.BagError` only when the file is not MCAP at
    all (missing/invalid magic or first record not a Header).

    ``load_messages=False`` counts the messages without keeping them. ``verify`` also checks
    everything a reader relies on and lists disagreements in ``damage``: the Message Index
    records after each chunk against the chunk content, the Data End CRC of the data section,
    and the whole summary section (footer CRC, schemas, channels, statistics, chunk and metadata
    indexes against the data). ``salvage`` skips a damaged record (when its length leads to a
    plausible next record) and keeps reading, instead of stopping at it; what was skipped is
    listed in ``damage``.
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
        _RecordWalk(handle, scan, load_messages, verify, salvage).run()
        _classify_end(handle, scan)
        if verify and scan.complete and scan.data_end_offset is not None:
            verify_summary(handle, scan)
    return scan


def _classify_end(handle: BinaryIO, scan: McapScan) -> None:
    """Set ``complete`` and tell a file cut short (truncation) from one damaged before its end."""
    path = scan.path
    scan.complete = scan.data_end_seen and has_valid_footer(path)
    if scan.data_end_seen and not scan.complete:
        if ends_with_magic(handle, scan.file_size):  # an end is there, but not a valid footer
            scan.problem = "summary section or footer damaged after Data End"
            scan.damage.append(f"{path}: {scan.problem}")
        else:  # cut short after the data: the summary is simply missing (rebuilt by recover)
            scan.problem = f"file ends at offset {scan.file_size} inside the summary section (no footer)"
    elif not scan.data_end_seen and has_valid_footer(path):
        # The file has its end (footer + magic): stopping early is damage, not truncation.
        scan.data_lost = True
        if not scan.damage:
            scan.damage.append(f"{path}: {scan.problem}; the file has a footer, so it was not cut short")


@dataclass
class _RecordWalk:
    """The walk through the data section, record by record, filling ``scan``."""

    handle: BinaryIO
    scan: McapScan
    load_messages: bool
    verify: bool
    salvage: bool
    position: int = len(MCAP_MAGIC)  #: offset of the record being read
    crc: int = zlib.crc32(MCAP_MAGIC)  #: CRC-32 of the data section before ``position``
    index_target: ChunkInfo | None = None  #: the chunk whose Message Index records may follow

    def run(self) -> None:
        """Read records until the Data End record, the end of the file or the first damage."""
        scan = self.scan
        scan.valid_end = self.position
        while True:
            record = self._read_record()
            if record is None:
                break
            opcode, length, body, record_crc = record
            follows_chunk, self.index_target = self.index_target, None
            try:
                if self._take(opcode, body, follows_chunk):
                    break  # Data End (or Footer): the data section is complete
            except BagError:
                raise
            except Exception as exc:  # damaged record: keep the valid prefix
                if not self._skip_damaged(opcode, length, exc):
                    break
                self.crc = record_crc
                self.position += RECORD_PREFIX_SIZE + length
                continue
            self.crc = record_crc
            self.position += RECORD_PREFIX_SIZE + length
            scan.valid_end = self.position

    def _read_record(self) -> tuple[int, int, bytes, int] | None:
        """``(opcode, length, body, CRC through it)`` of the next record; ``None`` at a cut-off end."""
        scan, position = self.scan, self.position
        self.handle.seek(position)
        prefix = self.handle.read(RECORD_PREFIX_SIZE)
        if len(prefix) < RECORD_PREFIX_SIZE:
            scan.problem = (
                f"file ends at offset {scan.file_size} without a Data End record "
                "(writer did not close the file)"
                if not prefix
                else f"file ends inside a record header at offset {position}"
            )
            return None
        opcode, length = RECORD_PREFIX.unpack(prefix)
        if length > scan.file_size - position - RECORD_PREFIX_SIZE:
            scan.problem = f"file ends inside a {opcode_name(opcode)} record at offset {position}"
            return None
        body = self.handle.read(length)
        return opcode, length, body, zlib.crc32(body, zlib.crc32(prefix, self.crc))

    def _take(self, opcode: int, body: bytes, follows_chunk: ChunkInfo | None) -> bool:
        """Add one record to the scan; True when it ends the data section. Raises on damage."""
        scan = self.scan
        if scan.header is None:
            if opcode != Opcode.HEADER:
                raise BagError(f"{scan.path} is not a valid MCAP file: first record is not a Header")
            scan.header = parse_record(Header, body)
        elif opcode == Opcode.SCHEMA:
            schema = parse_record(Schema, body)
            scan.schemas[schema.id] = schema
        elif opcode == Opcode.CHANNEL:
            channel = parse_record(Channel, body)
            scan.channels[channel.id] = channel
        elif opcode == Opcode.MESSAGE:
            self._take_message(body)
        elif opcode == Opcode.CHUNK:
            self._take_chunk(body)
        elif opcode == Opcode.MESSAGE_INDEX:
            self._take_message_index(body, follows_chunk)
        elif opcode == Opcode.METADATA:
            scan.metadata.append(parse_record(Metadata, body))
            scan.metadata_indexes.append(
                MetadataIndex(offset=self.position, length=RECORD_PREFIX_SIZE + len(body), name=scan.metadata[-1].name)
            )
        elif opcode == Opcode.DATA_END:
            self._take_data_end(body)
            return True
        elif opcode == Opcode.FOOTER:
            # Footer without Data End: unusual but complete.
            scan.data_end_seen = True
            scan.valid_end = self.position
            return True
        elif opcode not in KNOWN_OPCODES:
            raise ValueError("unknown record opcode (rosbag2 writes no such record)")
        return False

    def _take_message(self, body: bytes) -> None:
        """A Message record outside any chunk."""
        if len(body) < MESSAGE_PREFIX_SIZE:
            raise ValueError(f"Message record of {len(body)} bytes (at least 22 expected)")
        scan = self.scan
        scan.top_level_messages += 1
        message = parse_message(body)
        scan.count_message(message.channel_id, message.log_time)
        if self.load_messages:
            scan.messages.append(message)
            scan.message_offsets.append(self.position)

    def _take_chunk(self, body: bytes) -> None:
        """A Chunk record: its schemas, channels and messages; the chunk is then indexable."""
        scan = self.scan
        chunk = parse_record(Chunk, body)
        content = chunk_content(chunk, self.load_messages)
        for schema in content.schemas:
            scan.schemas[schema.id] = schema
        for channel in content.channels:
            scan.channels[channel.id] = channel
        scan.count_entries(content.entries)
        if self.load_messages:
            scan.messages.extend(content.messages)
            scan.message_offsets.extend([self.position] * len(content.messages))
        info = ChunkInfo(
            offset=self.position,
            record_length=RECORD_PREFIX_SIZE + len(body),
            message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time,
            compression=chunk.compression,
            compressed_size=len(chunk.data),
            uncompressed_size=chunk.uncompressed_size,
            entries=content.entries,
        )
        scan.chunks.append(info)
        self.index_target = info

    def _take_message_index(self, body: bytes, follows_chunk: ChunkInfo | None) -> None:
        """A Message Index record: belongs to the chunk right before it (checked with ``verify``)."""
        index = parse_message_index(body)
        if follows_chunk is None:
            return
        if index.channel_id in follows_chunk.index_offsets:
            raise ValueError(f"second Message Index for channel {index.channel_id}")
        if self.verify and sorted(index.records) != sorted(follows_chunk.entries.get(index.channel_id, [])):
            self.scan.damage.append(
                f"{self.scan.path}: Message Index record at offset {self.position} (channel {index.channel_id}) "
                f"does not match the chunk at offset {follows_chunk.offset}"
            )
        follows_chunk.index_offsets[index.channel_id] = self.position
        follows_chunk.index_length += RECORD_PREFIX_SIZE + len(body)
        self.index_target = follows_chunk

    def _take_data_end(self, body: bytes) -> None:
        """The Data End record: the data section is complete (its CRC checked with ``verify``)."""
        scan, crc = self.scan, self.crc
        data_end = parse_record(DataEnd, body)
        if self.verify and data_end.data_section_crc and data_end.data_section_crc != crc:
            scan.data_lost = True
            scan.damage.append(
                f"{scan.path}: data section CRC mismatch (Data End record at offset {self.position} says "
                f"{data_end.data_section_crc:#010x}, the bytes give {crc:#010x}): a schema, channel, "
                "metadata or index record is damaged"
            )
        scan.data_end_seen = True
        scan.data_end_offset = self.position
        scan.valid_end = self.position + RECORD_PREFIX_SIZE + len(body)

    def _skip_damaged(self, opcode: int, length: int, exc: Exception) -> bool:
        """Record a damaged record; True when the walk goes on after it (salvage, or only an index)."""
        scan, position = self.scan, self.position
        reason = f"damaged record at offset {position} ({opcode_name(opcode)}: {type(exc).__name__}: {exc})"
        scan.damage.append(f"{scan.path}: {reason}")
        index_only = opcode == Opcode.MESSAGE_INDEX  # rebuilt from the chunk: nothing is lost
        next_record = position + RECORD_PREFIX_SIZE + length
        if (self.salvage or index_only) and plausible_record_at(self.handle, next_record, scan.file_size):
            scan.data_lost = scan.data_lost or not index_only
            return True
        scan.data_lost = True
        scan.problem = reason
        return False
