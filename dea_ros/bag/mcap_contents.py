"""What a scan found in an MCAP file: :class:`McapScan` and its :class:`ChunkInfo` entries.

Filled by :func:`dea_ros.bag.mcap_scan.scan_mcap`, checked against the summary section by
:func:`dea_ros.bag.mcap_summary_check.verify_summary`, completed by
:func:`dea_ros.bag.mcap_finish.finish_in_place` and rewritten by :func:`dea_ros.bag.recover_bag`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from mcap.records import Channel, ChunkIndex, Header, Message, Metadata, MetadataIndex, Schema

__all__ = ["ChunkInfo", "McapScan"]


@dataclass
class ChunkInfo:
    """One complete Chunk record found by a scan, with what its index should say."""

    offset: int  #: file offset of the Chunk record
    record_length: int  #: bytes of the record (opcode + length + body)
    message_start_time: int
    message_end_time: int
    compression: str
    compressed_size: int
    uncompressed_size: int
    #: from the chunk content: channel id -> [(log_time, offset in the uncompressed chunk)]
    entries: dict[int, list[tuple[int, int]]] = field(default_factory=dict)
    #: Message Index records found right after the chunk: channel id -> file offset
    index_offsets: dict[int, int] = field(default_factory=dict)
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
    """Everything readable from the complete prefix of a file (:func:`~dea_ros.bag.mcap_scan.scan_mcap`).

    ``problem`` says why reading stopped early (end of an unfinished file, or a damaged record);
    ``damage`` lists every sign of corruption found (damaged or unknown records, CRC mismatches,
    indexes or summary that disagree with the data). A file cut short by a killed writer has a
    ``problem`` but no ``damage``. ``data_lost`` tells damage to the data itself (records that
    cannot be read, a data-section CRC mismatch) from damage only to indexes and the summary,
    which can be rebuilt from the data without loss. Times are log times in ns since the epoch.
    """

    path: Path
    header: Header | None = None
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    file_size: int = 0
    valid_end: int = 0  #: offset just past the last complete, valid data record
    data_end_seen: bool = False  #: the Data End record was reached (data section complete)
    complete: bool = False  #: Footer and closing magic present
    problem: str = ""  #: why reading stopped early ("" when complete)
    damage: list[str] = field(default_factory=list)  #: signs of corruption (see class docstring)
    chunks: list[ChunkInfo] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)
    #: file offset of the record holding each entry of ``messages`` (its Chunk, or itself)
    message_offsets: list[int] = field(default_factory=list)
    top_level_messages: int = 0  #: Message records outside chunks
    message_count: int = 0  #: messages found (also without ``load_messages``)
    channel_counts: dict[int, int] = field(default_factory=dict)  #: channel id -> messages
    message_start_time: int = 0  #: smallest log time, ns (0 without messages)
    message_end_time: int = 0  #: largest log time, ns (0 without messages)
    data_end_offset: int | None = None  #: offset of the Data End record, if seen
    data_lost: bool = False  #: damage to the data section itself (see class docstring)

    @property
    def truncated(self) -> bool:
        """True when the data section is incomplete (writer killed or file damaged)."""
        return not self.data_end_seen

    @property
    def damaged(self) -> bool:
        """True when corruption was found (not only an unfinished end)."""
        return bool(self.damage)

    def count_message(self, channel_id: int, log_time: int) -> None:
        """Add one message to the counts and time range."""
        self.count_entries({channel_id: [(log_time, 0)]})

    def count_entries(self, entries: Mapping[int, list[tuple[int, int]]]) -> None:
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
