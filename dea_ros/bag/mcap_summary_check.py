"""Checking the summary section and footer of a complete MCAP file against its data section.

Readers such as ``ros2 bag``, Foxglove and ``mcap.reader.SeekingReader`` trust the summary
(schemas, channels, statistics, chunk and metadata indexes, summary offsets) instead of reading
the data. :func:`verify_summary` compares each part with what a scan of the data found and lists
every disagreement in ``scan.damage``; all of it can be rebuilt from the data without loss.
"""
from __future__ import annotations

import zlib
from collections import defaultdict
from typing import BinaryIO, NamedTuple

from mcap.opcode import Opcode
from mcap.records import Channel, ChunkIndex, Footer, MetadataIndex, Schema, Statistics, SummaryOffset

from .mcap_contents import McapScan
from .mcap_records import FOOTER_SIZE, MCAP_MAGIC, RECORD_PREFIX, RECORD_PREFIX_SIZE, opcode_name, parse_record

__all__ = ["verify_summary"]

#: Record classes allowed in a summary section (Attachment Index records are allowed and skipped).
_SUMMARY_RECORDS = {
    Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.STATISTICS: Statistics,
    Opcode.CHUNK_INDEX: ChunkIndex, Opcode.METADATA_INDEX: MetadataIndex,
    Opcode.SUMMARY_OFFSET: SummaryOffset,
}


class _Summary(NamedTuple):
    """The records of a summary section by opcode, and where each group lies (start, length)."""

    records: dict[int, list]
    groups: dict[int, tuple[int, int]]


def verify_summary(handle: BinaryIO, scan: McapScan) -> None:
    """Check the summary section and footer of a complete file against the scanned data."""
    path = scan.path
    footer_offset = scan.file_size - FOOTER_SIZE - len(MCAP_MAGIC)
    handle.seek(footer_offset)
    footer_bytes = handle.read(FOOTER_SIZE)
    try:
        footer = parse_record(Footer, footer_bytes[RECORD_PREFIX_SIZE:])
    except Exception as exc:  # noqa: BLE001
        scan.damage.append(f"{path}: footer unreadable ({type(exc).__name__}: {exc})")
        return
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
    problems: list[str] = []
    if start != scan.valid_end:
        problems.append(f"summary starts at offset {start}, not right after Data End ({scan.valid_end})")
    summary_bytes = between[start - scan.valid_end :]
    problems += _crc_problems(footer, footer_bytes, summary_bytes)
    summary = _parse_summary(scan, summary_bytes, start)
    if summary is None:
        return
    problems += _definition_problems(summary, scan)
    problems += _statistics_problems(summary, scan)
    problems += _index_problems(summary, scan)
    problems += _offset_problems(summary)
    scan.damage.extend(f"{path}: summary section at offset {start}: {problem}" for problem in problems)


def _crc_problems(footer: Footer, footer_bytes: bytes, summary_bytes: bytes) -> list[str]:
    """The footer's summary CRC (over the summary and the footer up to the CRC) against the bytes."""
    if not footer.summary_crc:
        return []
    crc = zlib.crc32(footer_bytes[:-4], zlib.crc32(summary_bytes))
    if crc == footer.summary_crc:
        return []
    return [f"summary CRC mismatch (footer says {footer.summary_crc:#010x}, the bytes give {crc:#010x})"]


def _parse_summary(scan: McapScan, summary_bytes: bytes, start: int) -> _Summary | None:
    """The summary's records; ``None`` (and the damage noted) when a record cannot be read."""
    summary = _Summary(defaultdict(list), {})
    position = 0
    try:
        while position < len(summary_bytes):
            opcode, length = RECORD_PREFIX.unpack_from(summary_bytes, position)
            body = summary_bytes[position + RECORD_PREFIX_SIZE : position + RECORD_PREFIX_SIZE + length]
            if len(body) != length:
                raise ValueError(f"summary ends inside a {opcode_name(opcode)} record")
            if opcode in _SUMMARY_RECORDS:
                summary.records[opcode].append(parse_record(_SUMMARY_RECORDS[opcode], body))
            elif opcode != Opcode.ATTACHMENT_INDEX:
                raise ValueError(f"unexpected {opcode_name(opcode)} record in the summary")
            if opcode != Opcode.SUMMARY_OFFSET:
                first, total = summary.groups.get(opcode, (start + position, 0))
                summary.groups[opcode] = (first, total + RECORD_PREFIX_SIZE + length)
            position += RECORD_PREFIX_SIZE + length
    except Exception as exc:  # noqa: BLE001
        scan.damage.append(f"{scan.path}: summary record at offset {start + position} unreadable "
                           f"({type(exc).__name__}: {exc})")
        return None
    return summary


def _definition_problems(summary: _Summary, scan: McapScan) -> list[str]:
    """Schemas and channels that differ from the data section's.

    A summary may list schemas and channels no message used, which are absent from the data.
    """
    problems = []
    for schema in summary.records[Opcode.SCHEMA]:
        if schema.id in scan.schemas and scan.schemas[schema.id] != schema:
            problems.append(f"summary schema {schema.id} ({schema.name}) differs from the data section")
    for channel in summary.records[Opcode.CHANNEL]:
        if channel.id in scan.channels and scan.channels[channel.id] != channel:
            problems.append(f"summary channel {channel.id} ({channel.topic}) differs from the data section")
    return problems


def _statistics_problems(summary: _Summary, scan: McapScan) -> list[str]:
    """Statistics counts that differ from the data.

    Not the time range: writers differ on a message logged at time 0; the CRC covers it.
    """
    problems = []
    expected = {
        "message_count": scan.message_count,
        "chunk_count": len(scan.chunks),
        "metadata_count": len(scan.metadata),
    }
    for stats in summary.records[Opcode.STATISTICS]:
        for key, value in expected.items():
            if getattr(stats, key) != value:
                problems.append(f"summary statistics {key} is {getattr(stats, key)}, the data have {value}")
        nonzero = {k: v for k, v in stats.channel_message_counts.items() if v}
        if stats.channel_message_counts and nonzero != dict(scan.channel_counts):
            problems.append("summary statistics channel_message_counts differ from the data")
    return problems


def _index_problems(summary: _Summary, scan: McapScan) -> list[str]:
    """Chunk Index and Metadata Index records that do not describe the data section's records."""
    problems = []
    chunk_indexes = summary.records[Opcode.CHUNK_INDEX]
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
    metadata_indexes = summary.records[Opcode.METADATA_INDEX]
    if metadata_indexes and sorted((m.offset, m.length, m.name) for m in metadata_indexes) != sorted(
        (m.offset, m.length, m.name) for m in scan.metadata_indexes
    ):
        problems.append("summary Metadata Index records do not match the Metadata records")
    return problems


def _offset_problems(summary: _Summary) -> list[str]:
    """Summary Offset records that do not point at their group of records."""
    problems = []
    for offset in summary.records[Opcode.SUMMARY_OFFSET]:
        if offset.group_length == 0 and offset.group_opcode not in summary.groups:
            continue  # an empty group (mcap-python lists those too)
        if summary.groups.get(offset.group_opcode) != (offset.group_start, offset.group_length):
            problems.append(f"summary offset of the {opcode_name(offset.group_opcode)} group is wrong")
    return problems
