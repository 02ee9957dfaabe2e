"""The MCAP spec's record layouts, declared once.

Opcodes, the ``struct`` formats of the hot records (messages, chunks, indexes, footer), and one typed class
per other record avdata writes or reads (``SchemaRecord``, ``ChannelRecord`` ...), whose fields carry their MCAP
kinds: :data:`RECORD_LAYOUTS` is read off those classes, and :func:`encode_record` / :func:`decode_record` turn
a record into bytes and back by it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Final, TypeVar

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

def _field(kind: str) -> dict[str, str]:
    """A record field's dataclass metadata: its MCAP kind (one of the ``_U8`` ... ``_U16_U64_MAP`` above)."""
    return {"kind": kind}


@dataclass(frozen=True, slots=True, kw_only=True)
class HeaderRecord:
    """The Header record (first after the magic)."""

    OPCODE: ClassVar[int] = Opcode.HEADER
    profile: str = field(metadata=_field(_STR))
    library: str = field(metadata=_field(_STR))


@dataclass(frozen=True, slots=True, kw_only=True)
class SchemaRecord:
    """A Schema record: id (1, 2, ...), name, encoding and the schema itself."""

    OPCODE: ClassVar[int] = Opcode.SCHEMA
    id: int = field(metadata=_field(_U16))
    name: str = field(metadata=_field(_STR))
    encoding: str = field(metadata=_field(_STR))
    data: bytes = field(metadata=_field(_BYTES))


@dataclass(frozen=True, slots=True, kw_only=True)
class ChannelRecord:
    """A Channel record: id (0, 1, ...), its schema, topic and message encoding."""

    OPCODE: ClassVar[int] = Opcode.CHANNEL
    id: int = field(metadata=_field(_U16))
    schema_id: int = field(metadata=_field(_U16))
    topic: str = field(metadata=_field(_STR))
    message_encoding: str = field(metadata=_field(_STR))
    metadata: dict[str, str] = field(metadata=_field(_STR_MAP))


@dataclass(frozen=True, slots=True, kw_only=True)
class ChunkIndexRecord:
    """A ChunkIndex record of the summary (the writer packs its hot form in ``chunk_index``)."""

    OPCODE: ClassVar[int] = Opcode.CHUNK_INDEX
    message_start_time: int = field(metadata=_field(_U64))
    message_end_time: int = field(metadata=_field(_U64))
    chunk_start_offset: int = field(metadata=_field(_U64))
    chunk_length: int = field(metadata=_field(_U64))
    message_index_offsets: dict[int, int] = field(metadata=_field(_U16_U64_MAP))
    message_index_length: int = field(metadata=_field(_U64))
    compression: str = field(metadata=_field(_STR))
    compressed_size: int = field(metadata=_field(_U64))
    uncompressed_size: int = field(metadata=_field(_U64))


@dataclass(frozen=True, slots=True, kw_only=True)
class StatisticsRecord:
    """The Statistics record of the summary."""

    OPCODE: ClassVar[int] = Opcode.STATISTICS
    message_count: int = field(metadata=_field(_U64))
    schema_count: int = field(metadata=_field(_U16))
    channel_count: int = field(metadata=_field(_U32))
    attachment_count: int = field(metadata=_field(_U32))
    metadata_count: int = field(metadata=_field(_U32))
    chunk_count: int = field(metadata=_field(_U32))
    message_start_time: int = field(metadata=_field(_U64))
    message_end_time: int = field(metadata=_field(_U64))
    channel_message_counts: dict[int, int] = field(metadata=_field(_U16_U64_MAP))


@dataclass(frozen=True, slots=True, kw_only=True)
class MetadataRecord:
    """A Metadata record: a name and string pairs."""

    OPCODE: ClassVar[int] = Opcode.METADATA
    name: str = field(metadata=_field(_STR))
    metadata: dict[str, str] = field(metadata=_field(_STR_MAP))


@dataclass(frozen=True, slots=True, kw_only=True)
class MetadataIndexRecord:
    """A MetadataIndex record of the summary: where a Metadata record lies."""

    OPCODE: ClassVar[int] = Opcode.METADATA_INDEX
    offset: int = field(metadata=_field(_U64))
    length: int = field(metadata=_field(_U64))
    name: str = field(metadata=_field(_STR))


@dataclass(frozen=True, slots=True, kw_only=True)
class SummaryOffsetRecord:
    """A SummaryOffset record: where the summary's group of one opcode lies."""

    OPCODE: ClassVar[int] = Opcode.SUMMARY_OFFSET
    group_opcode: int = field(metadata=_field(_U8))
    group_start: int = field(metadata=_field(_U64))
    group_length: int = field(metadata=_field(_U64))


#: Every record type avdata writes or reads besides the hot ones above.
Record = (HeaderRecord | SchemaRecord | ChannelRecord | ChunkIndexRecord | StatisticsRecord | MetadataRecord
          | MetadataIndexRecord | SummaryOffsetRecord)
#: Any one record type, for the typed decoder.
RecordT = TypeVar("RecordT", HeaderRecord, SchemaRecord, ChannelRecord, ChunkIndexRecord, StatisticsRecord,
                   MetadataRecord, MetadataIndexRecord, SummaryOffsetRecord)

#: The one layout table: opcode -> (field name, kind) of each field in order, read off the record classes.
RECORD_LAYOUTS: Final[dict[int, tuple[tuple[str, str], ...]]] = {
    record_type.OPCODE: tuple((f.name, str(f.metadata["kind"])) for f in fields(record_type))
    for record_type in (HeaderRecord, SchemaRecord, ChannelRecord, ChunkIndexRecord, StatisticsRecord,
                        MetadataRecord, MetadataIndexRecord, SummaryOffsetRecord)
}

#: Chunk compressions this module writes and reads ("" = uncompressed).
COMPRESSIONS: Final = ("", "zstd", "lz4")


class RecordError(ValueError):
    """A record's bytes do not parse; turned into an InputError naming the file by the caller."""


def encode_record(record: Record) -> bytes:
    """The bytes of one record (prefix included), per :data:`RECORD_LAYOUTS`."""
    body = bytearray()
    opcode = record.OPCODE
    for name, kind in RECORD_LAYOUTS[opcode]:
        value = getattr(record, name)
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


def decode_record(record_type: type[RecordT], body: Buffer) -> RecordT:
    """The record of type ``record_type`` whose body (after the prefix) is ``body``, per :data:`RECORD_LAYOUTS`.

    Raises:
        RecordError: the body is shorter than its fields say, or a string is not UTF-8.
    """
    data = memoryview(body)
    values: dict[str, Any] = {}
    position = 0
    opcode = record_type.OPCODE
    try:
        for name, kind in RECORD_LAYOUTS[opcode]:
            if kind in (_U8, _U16, _U32, _U64):
                (values[name],) = struct.unpack_from("<" + kind, data, position)
                position += struct.calcsize(kind)
                continue
            blob, position = _take_sized(data, position)
            if kind == _STR:
                values[name] = str(blob, "utf-8")
            elif kind == _BYTES:
                values[name] = bytes(blob)
            elif kind == _STR_MAP:
                pairs: dict[str, str] = {}
                inner = 0
                while inner < len(blob):
                    key, inner = _take_sized(blob, inner)
                    value, inner = _take_sized(blob, inner)
                    pairs[str(key, "utf-8")] = str(value, "utf-8")
                values[name] = pairs
            else:
                if len(blob) % 10:
                    raise RecordError(f"map of {len(blob)} bytes is not a whole number of (uint16, uint64) pairs")
                values[name] = dict(struct.iter_unpack("<HQ", blob))
    except (struct.error, UnicodeDecodeError) as error:
        raise RecordError(f"malformed record 0x{opcode:02x} ({one_line(error)})") from error
    return record_type(**values)


def sized(data: bytes) -> bytes:
    """``data`` behind its uint32 little-endian byte length (MCAP's string and bytes fields)."""
    return struct.pack("<I", len(data)) + data


def _take_sized(data: memoryview, position: int) -> tuple[memoryview, int]:
    (size,) = struct.unpack_from("<I", data, position)
    start = position + 4
    if start + size > len(data):
        raise RecordError(f"field of {size} bytes at byte {position} runs past the record's end ({len(data)} bytes)")
    return data[start : start + size], start + size

