"""JPEG files checked whole without decoding them: the marker chain up to the scan, and the end marker.

A JPEG is SOI (``ff d8``), marker segments (``ff xx`` + a big-endian length that counts itself), a
frame header (SOFn: precision, height, width), one or more scans (SOS + entropy-coded data) and EOI
(``ff d9``) as its last two bytes. Walking the segment lengths up to the first scan finds a file cut
or damaged inside its headers, and the end marker finds a file cut anywhere after them (a truncated
download, the common damage). JPEG has no checksum, so a flipped bit inside the entropy-coded data
goes unseen; decoding would not find it reliably either (libjpeg fills what it cannot read and only
warns). Reading the headers touches a few hundred bytes; decoding would touch every pixel.

The JPEG counterpart of :mod:`avdata.sources.png`: the nuScenes, Argoverse 2, Waymo and DAIR-V2X readers check
their images here (every real JPEG in ../shared/realdata passes: 18 nuScenes, 5 Waymo v1).
"""

from __future__ import annotations

import struct

__all__ = ["jpeg_problem"]

_SOI = b"\xff\xd8"
_EOI = b"\xff\xd9"
_SOS = 0xDA
#: SOF0..SOF15 are frame headers except DHT (c4), JPG (c8) and DAC (cc), which share the range.
_FRAME_HEADERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: Markers without a length: TEM and the restart markers RST0..RST7.
_STANDALONE = frozenset({0x01, *range(0xD0, 0xD8)})
_LENGTH = struct.Struct(">H")


def jpeg_problem(data: bytes | bytearray | memoryview) -> tuple[str | None, tuple[int, int]]:
    """Why ``data`` is not a whole JPEG (None if it is), and its (width, height) from the frame header.

    Returns:
        (a one-line reason naming the marker and its byte offset, or None; (width, height), (0, 0)
        when no frame header was read).
    """
    view = memoryview(data).cast("B")
    if bytes(view[:2]) != _SOI:
        return f"expected a JPEG file (bytes ff d8), got {bytes(view[:8]).hex(' ') or 'an empty file'}", (0, 0)
    size = (0, 0)
    offset = 2
    while True:
        if offset + 2 > len(view):
            return f"marker at byte {offset}: the file ends before it (truncated file?)", size
        prefix, marker = view[offset], view[offset + 1]
        if prefix != 0xFF:
            return f"expected a marker (ff xx) at byte {offset}, got {prefix:02x} (damaged bytes)", size
        if marker == 0xFF:  # a fill byte before the marker
            offset += 1
            continue
        if marker in _STANDALONE:
            offset += 2
            continue
        if marker == _EOI[1]:
            return f"end marker ff d9 at byte {offset} before any scan (no image data)", size
        if offset + 4 > len(view):
            return f"segment ff {marker:02x} at byte {offset}: the file ends inside its length (truncated file?)", size
        (length,) = _LENGTH.unpack_from(view, offset + 2)
        end = offset + 2 + length
        if length < 2:
            return f"segment ff {marker:02x} at byte {offset}: expected a length of at least 2, got {length}", size
        if end > len(view):
            return (f"segment ff {marker:02x} at byte {offset}: length {length} runs past the end of the "
                    f"{len(view)}-byte file (truncated file?)"), size
        if marker in _FRAME_HEADERS:
            if length < 8:
                return f"frame header ff {marker:02x} at byte {offset}: expected at least 8 bytes, got {length}", size
            height, width = struct.unpack_from(">HH", view, offset + 5)
            size = (width, height)
        if marker == _SOS:
            break
        offset = end
    if 0 in size:
        return f"expected a frame header (SOF) with a width and height before the scan, got {size[0]} x {size[1]}", size
    if bytes(view[-2:]) != _EOI:
        return f"expected the file to end with the EOI marker ff d9, got {bytes(view[-2:]).hex(' ')} (truncated file?)", size
    return None, size
