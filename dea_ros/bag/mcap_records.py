"""The MCAP record format (spec v0, https://mcap.dev/spec): constants and parsing of single records.

A record is an opcode byte, a little-endian uint64 body length and the body. This module reads
one record body (:func:`parse_record`, :func:`parse_message_index`), the content of a Chunk
(:func:`chunk_content`: decompressed, CRC-checked, split into records) and probes the end of a
file (:func:`has_valid_footer`, :func:`ends_with_magic`). Parsing errors are plain exceptions
(``ValueError`` and whatever ``mcap.records`` raises): the scanner turns them into damage reports.
Only ``mcap.records`` (record classes) is used; no ROS.
"""
from __future__ import annotations

import io
import struct
import zlib
from collections import defaultdict
from pathlib import Path
from typing import BinaryIO, NamedTuple

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, MessageIndex, Schema

from .mcap_compression import decompress_chunk

__all__ = [
    "MCAP_MAGIC",
    "FOOTER_SIZE",
    "RECORD_PREFIX",
    "RECORD_PREFIX_SIZE",
    "MESSAGE_HEADER",
    "MESSAGE_PREFIX_SIZE",
    "KNOWN_OPCODES",
    "ChunkContent",
    "parse_record",
    "parse_message_index",
    "parse_message",
    "opcode_name",
    "chunk_content",
    "has_valid_footer",
    "ends_with_magic",
    "plausible_record_at",
]

#: Leading and trailing magic bytes of every MCAP file.
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Bytes of a Footer record: opcode, length, summary_start, summary_offset_start, summary_crc.
FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
#: Opcode and body length in front of every record.
RECORD_PREFIX = struct.Struct("<BQ")
RECORD_PREFIX_SIZE = RECORD_PREFIX.size
#: A whole Message record header: opcode, record length, channel, sequence, log time, publish time.
MESSAGE_HEADER = struct.Struct("<BQHIQQ")
#: Bytes of a Message record body before the message data: channel, sequence, log and publish time.
MESSAGE_PREFIX_SIZE = 22
#: Known MCAP opcodes (anything else in a ros2 bag is damage: rosbag2 never writes private records).
KNOWN_OPCODES = frozenset(int(op) for op in Opcode)

_MESSAGE_PREFIX = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time


class ChunkContent(NamedTuple):
    """The records of one chunk (:func:`chunk_content`)."""

    schemas: list[Schema]
    channels: list[Channel]
    messages: list[Message]  #: empty unless ``load_messages``
    #: channel id -> [(log_time, offset in the uncompressed chunk)], for every message
    entries: dict[int, list[tuple[int, int]]]


def parse_record(record_class, body: bytes):
    """The ``mcap.records`` object of class ``record_class`` encoded in ``body``."""
    return record_class.read(ReadDataStream(io.BytesIO(body)))


def parse_message_index(body: bytes) -> MessageIndex:
    """A Message Index record (fast: one unpack for all entries)."""
    channel_id, length = struct.unpack_from("<HI", body, 0)
    if length % 16 or 6 + length > len(body):
        raise ValueError(f"Message Index entries of {length} bytes in a record of {len(body)}")
    return MessageIndex(channel_id, list(struct.iter_unpack("<QQ", body[6 : 6 + length])))


def parse_message(body: bytes) -> Message:
    """A Message record body (at least :data:`MESSAGE_PREFIX_SIZE` bytes, checked by the caller)."""
    channel_id, sequence, log_time, publish_time = _MESSAGE_PREFIX.unpack_from(body, 0)
    return Message(channel_id, log_time, body[MESSAGE_PREFIX_SIZE:], publish_time, sequence)


def opcode_name(opcode: int) -> str:
    """A record kind for messages, e.g. ``"Message Index"`` (``"opcode 0x42"`` when unknown)."""
    try:
        return Opcode(opcode).name.title().replace("_", " ")
    except ValueError:
        return f"opcode {opcode:#04x}"


def chunk_content(chunk: Chunk, load_messages: bool = True) -> ChunkContent:
    """Decompress and CRC-check a chunk; its records and ``{channel: [(log_time, offset)]}``."""
    raw = decompress_chunk(chunk.compression, chunk.data, chunk.uncompressed_size)
    if len(raw) != chunk.uncompressed_size:
        raise ValueError(f"chunk decompressed to {len(raw)} bytes, header says {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(raw) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    content = ChunkContent([], [], [], defaultdict(list))
    position = 0
    while position < len(raw):
        if position + RECORD_PREFIX_SIZE > len(raw):
            raise ValueError("chunk ends inside a record header")
        opcode, length = RECORD_PREFIX.unpack_from(raw, position)
        body = raw[position + RECORD_PREFIX_SIZE : position + RECORD_PREFIX_SIZE + length]
        if len(body) != length:
            raise ValueError("chunk ends inside a record")
        _add_chunk_record(content, opcode, body, position, load_messages)
        position += RECORD_PREFIX_SIZE + length
    _check_chunk_times(chunk, content.entries)
    return content._replace(entries=dict(content.entries))


def _add_chunk_record(content: ChunkContent, opcode: int, body: bytes, position: int, load_messages: bool) -> None:
    """Add one record found at ``position`` of a chunk's uncompressed data to ``content``."""
    if opcode == Opcode.MESSAGE:
        if len(body) < MESSAGE_PREFIX_SIZE:
            raise ValueError(f"Message record of {len(body)} bytes inside the chunk (at least 22 expected)")
        channel_id, sequence, log_time, publish_time = _MESSAGE_PREFIX.unpack_from(body, 0)
        if load_messages:
            content.messages.append(Message(channel_id, log_time, body[MESSAGE_PREFIX_SIZE:], publish_time, sequence))
        content.entries[channel_id].append((log_time, position))
    elif opcode == Opcode.SCHEMA:
        content.schemas.append(parse_record(Schema, body))
    elif opcode == Opcode.CHANNEL:
        content.channels.append(parse_record(Channel, body))
    elif opcode not in KNOWN_OPCODES:
        raise ValueError(f"unknown record opcode {opcode:#04x} inside the chunk")


def _check_chunk_times(chunk: Chunk, entries: dict[int, list[tuple[int, int]]]) -> None:
    """The chunk header's time range must be that of its messages."""
    if not entries:
        return
    times = [t for pairs in entries.values() for t, _ in pairs]
    if min(times) != chunk.message_start_time or max(times) != chunk.message_end_time:
        raise ValueError(
            f"chunk header says messages from {chunk.message_start_time} to {chunk.message_end_time} ns, "
            f"its messages span {min(times)} to {max(times)} ns"
        )


def has_valid_footer(path: str | Path) -> bool:
    """True if the file ends with a Footer record and the MCAP magic (cheap completeness test)."""
    try:
        with open(path, "rb") as handle:
            handle.seek(0, io.SEEK_END)
            size = handle.tell()
            if size < 2 * len(MCAP_MAGIC) + FOOTER_SIZE:
                return False
            handle.seek(size - FOOTER_SIZE - len(MCAP_MAGIC))
            tail = handle.read()
    except OSError:
        return False
    return tail[-8:] == MCAP_MAGIC and tail[0] == Opcode.FOOTER and tail[1:9] == struct.pack("<Q", 20)


def ends_with_magic(handle: BinaryIO, file_size: int) -> bool:
    """True if the open file of ``file_size`` bytes ends with the MCAP magic (after its header magic)."""
    if file_size < 2 * len(MCAP_MAGIC):
        return False
    handle.seek(file_size - len(MCAP_MAGIC))
    return handle.read(len(MCAP_MAGIC)) == MCAP_MAGIC


def plausible_record_at(handle: BinaryIO, position: int, file_size: int) -> bool:
    """True if a known, non-Header record that fits in the file starts at ``position`` (or it is the end)."""
    if position == file_size:
        return True
    handle.seek(position)
    prefix = handle.read(RECORD_PREFIX_SIZE)
    if len(prefix) < RECORD_PREFIX_SIZE:
        return False
    opcode, length = RECORD_PREFIX.unpack(prefix)
    return opcode in KNOWN_OPCODES and opcode != Opcode.HEADER and length <= file_size - position - RECORD_PREFIX_SIZE
