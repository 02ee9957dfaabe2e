"""PNG files checked whole without decoding them: every chunk's CRC-32, in one pass over the bytes.

A PNG is a signature and a chain of chunks (length, type, data, CRC-32 of type and data), IHDR first
and IEND last. Every byte of the file is covered: a flipped bit in a length breaks the chain, anywhere
else it breaks a CRC. Checking the CRCs (libdeflate's CRC-32, one pass over bytes already read) costs
far less than decoding (inflating and unfiltering every row) and finds every damaged byte, where libpng lets damaged
ancillary chunks and a damaged IEND through. The KITTI and OPV2V readers check their images here.
"""

from __future__ import annotations

import struct

import deflate

__all__ = ["PNG_IEND", "PNG_SIGNATURE", "png_problem"]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: The IEND chunk every whole PNG ends with (no data, so always these 12 bytes).
PNG_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"
_CHUNK_HEAD = struct.Struct(">I4s")


def png_problem(data: bytes | bytearray | memoryview) -> tuple[str | None, tuple[int, int]]:
    """Why ``data`` is not a whole, undamaged PNG (None if it is), and its (width, height) from IHDR.

    Returns:
        (a one-line reason naming the chunk and its byte offset, or None; (width, height), (0, 0)
        when there is no readable IHDR).
    """
    view = memoryview(data).cast("B")
    if len(view) < 8 + 25 or bytes(view[:8]) != PNG_SIGNATURE or bytes(view[12:16]) != b"IHDR":
        return f"expected a PNG file (signature and IHDR chunk), got {bytes(view[:16])!r}", (0, 0)
    size = struct.unpack(">II", view[16:24])
    offset = 8
    while True:
        if offset + 12 > len(view):
            return f"chunk at byte {offset}: the file ends inside it (truncated file?)", size
        length, kind = _CHUNK_HEAD.unpack_from(view, offset)
        end = offset + 12 + length
        if end > len(view):
            return f"chunk {kind!r} at byte {offset}: its {length} bytes run past the end (truncated file?)", size
        stored = int.from_bytes(view[end - 4:end], "big")
        if deflate.crc32(view[offset + 4:end - 4]) != stored:
            return f"chunk {kind!r} at byte {offset}: CRC-32 does not match (damaged bytes)", size
        if kind == b"IEND":
            if end != len(view):
                return f"{len(view) - end} bytes after the IEND chunk", size
            return None, size
        offset = end
