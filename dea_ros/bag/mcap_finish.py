"""Finishing an unfinished MCAP file where it lies: no second copy, so it works on a full disk.

Used by ``dea-ros bag recover --in-place`` (:func:`~dea_ros.bag.recover_bag` with
``in_place=True``) and by the recorder after a write error.
"""
from __future__ import annotations

import os
import zlib
from pathlib import Path
from typing import BinaryIO, Mapping, Sequence

from ..errors import BagError
from .files import os_error_text
from .mcap_contents import McapScan
from .mcap_writer import McapChunkedWriter

__all__ = ["finish_in_place"]

#: One way of finishing: (rewrite the last chunk's Message Index records, extra Metadata, with summary).
_Attempt = tuple[bool, list[tuple[str, Mapping[str, str]]], bool]


def finish_in_place(
    path: str | Path,
    scan: McapScan,
    extra_metadata: Sequence[tuple[str, Mapping[str, str]]] = (),
    *,
    fsync: bool = True,
) -> int:
    """Complete an unfinished MCAP file where it lies; return the bytes cut off.

    The file is cut back to the end of its last complete record (``scan.valid_end``; a last chunk
    whose Message Index records were cut gets them rewritten), then ``extra_metadata`` records,
    Data End, the summary section (schemas, channels, statistics, chunk and metadata indexes),
    Footer and magic are appended. If that does not fit (disk full), less is written: no
    summary (readers then scan the file linearly, which needs no index), then fewer extra
    metadata records, most important (first) kept longest, down to none (50 bytes). If even
    that fails the file is left cut back to its valid prefix and
    :class:`~dea_ros.errors.BagError` says so.

    ``scan`` must come from :func:`~dea_ros.bag.mcap_scan.scan_mcap` on this file, without damage.
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
            crc = _prefix_crc(handle, cut, path)
            error: OSError | None = None
            for index, metadata, with_summary in _attempts(rewrite_index, list(extra_metadata)):
                handle.seek(cut)
                try:
                    writer = McapChunkedWriter.resume(handle, scan, cut, crc, index)
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
                f"cannot finish {path}: {os_error_text(error)}; it is cut back to its {cut} valid bytes "
                f"({scan.message_count} messages), free some space and run 'dea-ros bag recover' on it"
            )
    except OSError as exc:
        raise BagError(f"cannot finish {path}: {os_error_text(exc)}") from exc


def _prefix_crc(handle: BinaryIO, size: int, path: Path) -> int:
    """CRC-32 of the first ``size`` bytes of the open file (the data section so far)."""
    handle.seek(0)
    crc = 0
    remaining = size
    while remaining:
        block = handle.read(min(remaining, 1 << 20))
        if not block:
            raise BagError(f"{path} shrank while it was being finished")
        crc = zlib.crc32(block, crc)
        remaining -= len(block)
    return crc


def _attempts(rewrite_index: bool, extra: list[tuple[str, Mapping[str, str]]]) -> list[_Attempt]:
    """The ways of finishing the file, most complete first.

    Then without the summary (and the cut Message Index records, which only a summary refers
    to), then with fewer of the extra records (the first ones matter most), down to nothing but
    Data End, Footer and magic (50 bytes).
    """
    attempts = [(rewrite_index, extra, True), (rewrite_index, extra, False)]
    attempts += [(False, extra[:count], False) for count in range(len(extra), -1, -1)]
    return attempts
