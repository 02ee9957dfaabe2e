"""Chunk compression: zstd and lz4, imported only when a compressed chunk is written or read."""

from __future__ import annotations

from avdata.errors import one_line
from avdata.schema.mcap.records import Buffer, RecordError


def compress(compression: str, data: bytes | bytearray) -> bytes | bytearray:
    """``data`` compressed with ``compression`` ("zstd", "lz4"; anything else: unchanged)."""
    if compression == "zstd":
        import zstandard

        return zstandard.compress(data)
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.compress(data))
    return data


def decompress(compression: str, data: Buffer, uncompressed_size: int) -> bytes:
    """Decompressed chunk records; raises RecordError for anything the codec refuses."""
    try:
        if compression == "zstd":
            import zstandard

            out = zstandard.ZstdDecompressor().decompress(data, max_output_size=uncompressed_size)
        elif compression == "lz4":
            import lz4.frame

            out = lz4.frame.decompress(data)
        else:
            raise RecordError(f"unsupported chunk compression {compression!r}")
    except RecordError:
        raise
    except Exception as error:  # noqa: BLE001 - each codec has its own error types; all mean "bad bytes"
        raise RecordError(f"{compression} decompression failed ({type(error).__name__}: {one_line(error)})") from error
    if len(out) != uncompressed_size:
        raise RecordError(f"expected {uncompressed_size} bytes after {compression} decompression, got {len(out)}")
    return bytes(out)
