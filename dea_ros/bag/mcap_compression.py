"""Chunk compression of MCAP files: ``zstd``, ``lz4`` or none, both directions.

The codecs are the optional ``zstandard`` and ``lz4`` packages (both dependencies of ``mcap``),
imported when a chunk first needs them.
"""
from __future__ import annotations

from typing import Callable

from ..errors import BagError

__all__ = ["COMPRESSIONS", "MAX_CHUNK_UNCOMPRESSED_BYTES", "chunk_compressor", "decompress_chunk"]

#: Chunk compressions a writer accepts (``"none"`` = uncompressed chunks).
COMPRESSIONS = ("zstd", "lz4", "none")
#: Largest chunk we are willing to decompress (a flipped size field must not allocate terabytes).
MAX_CHUNK_UNCOMPRESSED_BYTES = 1 << 30


def chunk_compressor(compression: str, level: int | None) -> tuple[str, Callable[[bytes], bytes]]:
    """``(name written in the chunk record, compress(bytes) -> bytes)`` for ``compression``.

    ``level`` is the codec's level (``None``: zstd level 3, lz4's default). Raises
    :class:`~dea_ros.errors.BagError` for an unknown compression or a missing codec package.
    """
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


def decompress_chunk(compression: str, data: bytes, size: int) -> bytes:
    """The uncompressed bytes of a chunk whose record says ``compression`` and ``size`` bytes.

    Raises ``ValueError`` for an implausible size or an unknown compression (damage, to the scanner).
    """
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
