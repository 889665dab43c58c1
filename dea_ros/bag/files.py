"""Durable file-system steps shared by the bag writer and the recovery: atomic text, fsync, disk full.

Nothing is left half-written: :func:`write_text_atomic` writes a temporary file and renames it;
:func:`fsync_directory` makes such a rename survive a power cut. :func:`os_error_text` and
:func:`is_disk_full` turn an ``OSError`` into what the user needs to read.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path

from ..errors import BagError

__all__ = ["DISK_FULL_ERRNOS", "write_text_atomic", "fsync_directory", "is_disk_full", "os_error_text"]

#: errno values that mean "no room left": device full, quota exceeded, file size limit.
DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def write_text_atomic(path: Path, text: str, fsync: bool) -> None:
    """Write ``text`` (UTF-8) to ``path`` through ``<path>.tmp`` and a rename; ``fsync`` before it.

    On failure the temporary file is removed, ``path`` is unchanged and
    :class:`~dea_ros.errors.BagError` names it.
    """
    temporary = path.with_name(path.name + ".tmp")
    try:
        with open(temporary, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            if fsync:
                os.fsync(handle.fileno())
        os.replace(temporary, path)
    except OSError as exc:
        try:
            temporary.unlink()  # never leave a partial or empty file behind
        except OSError:
            pass
        raise BagError(f"cannot write {path}: {exc.strerror or exc}") from exc


def fsync_directory(directory: Path) -> None:
    """Make a rename durable (best effort: not every platform can open a directory)."""
    try:
        handle = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(handle)
    except OSError:
        pass
    finally:
        os.close(handle)


def is_disk_full(exc: BaseException | None) -> bool:
    """True for an ``OSError`` that means the disk (or quota, or file size limit) is full."""
    return getattr(exc, "errno", None) in DISK_FULL_ERRNOS


def os_error_text(exc: BaseException | None) -> str:
    """An OSError as text, saying "disk full" for ENOSPC/EFBIG/EDQUOT."""
    if exc is None:
        return "unknown error"
    code = getattr(exc, "errno", None)
    text = getattr(exc, "strerror", None) or str(exc)
    if code in (errno.ENOSPC, errno.EDQUOT):
        return f"disk full ({text})"
    if code == errno.EFBIG:
        return f"disk full: file size limit reached ({text})"
    return text
