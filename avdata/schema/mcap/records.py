"""The MCAP spec's record layouts, declared once.

Opcodes, the ``struct`` formats of the hot records, and :data:`RECORD_LAYOUTS` with the generic encoder and
decoder of every other record avdata writes or reads.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import Any, Final

from avdata.errors import one_line

#: Any C-contiguous buffer of bytes: what the writer takes as message parts and the reader hands out.
Buffer = bytes | bytearray | memoryview

MAGIC: Final = b"\x89MCAP0\r\n"


class Opcode:
    """Record opcodes of the MCAP spec."""

    HEADER: Final = 0x01
    FOOTER: Final = 0x02
    SCHEMA: Final = 0x03
    CHANNEL: Final = 0x04
    MESSAGE: Final = 0x05
    CHUNK: Final = 0x06
    MESSAGE_INDEX: Final = 0x07
    CHUNK_INDEX: Final = 0x08
    ATTACHMENT: Final = 0x09
    ATTACHMENT_INDEX: Final = 0x0A
    STATISTICS: Final = 0x0B
    METADATA: Final = 0x0C
    METADATA_INDEX: Final = 0x0D
    SUMMARY_OFFSET: Final = 0x0E
    DATA_END: Final = 0x0F


#: Every record starts with opcode (uint8) and body length (uint64).
RECORD_PREFIX: Final = struct.Struct("<BQ")
#: Message record up to its data: prefix, channel id, sequence, log time, publish time.
MESSAGE_HEADER: Final = struct.Struct("<BQHIQQ")
#: Chunk record up to its compression string: prefix, start, end, uncompressed size, uncompressed CRC.
CHUNK_HEADER: Final = struct.Struct("<BQQQQI")
#: Message index record up to its entries: prefix, channel id, byte length of the (time, offset) array.
MESSAGE_INDEX_HEADER: Final = struct.Struct("<BQHI")
MESSAGE_INDEX_ENTRY: Final = struct.Struct("<QQ")
#: Footer record: prefix, summary start, summary offset start, summary CRC.
FOOTER: Final = struct.Struct("<BQQQI")
#: DataEnd record: prefix, data-section CRC.
DATA_END: Final = struct.Struct("<BQI")

# Field kinds of the generic record layouts.
_U8, _U16, _U32, _U64 = "B", "H", "I", "Q"
_STR = "str"  # uint32 byte length + UTF-8
_BYTES = "bytes"  # uint32 byte length + bytes
_STR_MAP = "map<str,str>"  # uint32 byte length + (str, str) pairs
_U16_U64_MAP = "map<u16,u64>"  # uint32 byte length + (uint16, uint64) pairs

#: The layout of every record avdata writes or reads besides the hot ones above: field names and kinds.
RECORD_LAYOUTS: Final[dict[int, tuple[tuple[str, str], ...]]] = {
    Opcode.HEADER: (("profile", _STR), ("library", _STR)),
    Opcode.SCHEMA: (("id", _U16), ("name", _STR), ("encoding", _STR), ("data", _BYTES)),
    Opcode.CHANNEL: (("id", _U16), ("schema_id", _U16), ("topic", _STR), ("message_encoding", _STR),
                     ("metadata", _STR_MAP)),
    Opcode.CHUNK_INDEX: (("message_start_time", _U64), ("message_end_time", _U64), ("chunk_start_offset", _U64),
                         ("chunk_length", _U64), ("message_index_offsets", _U16_U64_MAP),
                         ("message_index_length", _U64), ("compression", _STR), ("compressed_size", _U64),
                         ("uncompressed_size", _U64)),
    Opcode.STATISTICS: (("message_count", _U64), ("schema_count", _U16), ("channel_count", _U32),
                        ("attachment_count", _U32), ("metadata_count", _U32), ("chunk_count", _U32),
                        ("message_start_time", _U64), ("message_end_time", _U64),
                        ("channel_message_counts", _U16_U64_MAP)),
    Opcode.METADATA: (("name", _STR), ("metadata", _STR_MAP)),
    Opcode.METADATA_INDEX: (("offset", _U64), ("length", _U64), ("name", _STR)),
    Opcode.SUMMARY_OFFSET: (("group_opcode", _U8), ("group_start", _U64), ("group_length", _U64)),
}

#: Chunk compressions this module writes and reads ("" = uncompressed).
COMPRESSIONS: Final = ("", "zstd", "lz4")


class RecordError(ValueError):
    """A record's bytes do not parse; turned into an InputError naming the file by the caller."""


def encode_record(opcode: int, values: Mapping[str, Any]) -> bytes:
    """The bytes of one record (prefix included) from its field values, per :data:`RECORD_LAYOUTS`."""
    body = bytearray()
    for name, kind in RECORD_LAYOUTS[opcode]:
        value = values[name]
        if kind in (_U8, _U16, _U32, _U64):
            body += struct.pack("<" + kind, value)
        elif kind == _STR:
            body += sized(value.encode())
        elif kind == _BYTES:
            body += sized(bytes(value))
        elif kind == _STR_MAP:
            body += sized(b"".join(sized(k.encode()) + sized(v.encode()) for k, v in value.items()))
        else:
            body += sized(b"".join(struct.pack("<HQ", k, v) for k, v in sorted(value.items())))
    return RECORD_PREFIX.pack(opcode, len(body)) + bytes(body)


def decode_record(opcode: int, body: Buffer) -> dict[str, Any]:
    """Field values of one record body (after the prefix), per :data:`RECORD_LAYOUTS`.

    Raises:
        RecordError: the body is shorter than its fields say, or a string is not UTF-8.
    """
    data = memoryview(body)
    values: dict[str, Any] = {}
    position = 0
    try:
        for name, kind in RECORD_LAYOUTS[opcode]:
            if kind in (_U8, _U16, _U32, _U64):
                (values[name],) = struct.unpack_from("<" + kind, data, position)
                position += struct.calcsize(kind)
                continue
            blob, position = _takesized(data, position)
            if kind == _STR:
                values[name] = str(blob, "utf-8")
            elif kind == _BYTES:
                values[name] = bytes(blob)
            elif kind == _STR_MAP:
                pairs: dict[str, str] = {}
                inner = 0
                while inner < len(blob):
                    key, inner = _takesized(blob, inner)
                    value, inner = _takesized(blob, inner)
                    pairs[str(key, "utf-8")] = str(value, "utf-8")
                values[name] = pairs
            else:
                if len(blob) % 10:
                    raise RecordError(f"map of {len(blob)} bytes is not a whole number of (uint16, uint64) pairs")
                values[name] = dict(struct.iter_unpack("<HQ", blob))
    except (struct.error, UnicodeDecodeError) as error:
        raise RecordError(f"malformed record 0x{opcode:02x} ({one_line(error)})") from error
    return values


def sized(data: bytes) -> bytes:
    """``data`` behind its uint32 little-endian byte length (MCAP's string and bytes fields)."""
    return struct.pack("<I", len(data)) + data


def _takesized(data: memoryview, position: int) -> tuple[memoryview, int]:
    (size,) = struct.unpack_from("<I", data, position)
    start = position + 4
    if start + size > len(data):
        raise RecordError(f"field of {size} bytes at byte {position} runs past the record's end ({len(data)} bytes)")
    return data[start : start + size], start + size

