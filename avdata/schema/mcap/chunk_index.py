"""The chunk index of the MCAP summary and the message indexes after each chunk.

What the writer packs (one ChunkIndex record per chunk, one MessageIndex record per channel in it) and the
reader's view of them.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

import numpy as np

from avdata.schema.mcap.records import CHUNK_HEADER, MESSAGE_INDEX_ENTRY, MESSAGE_INDEX_HEADER, RECORD_PREFIX, Opcode

_U64_FIELD: Final = struct.Struct("<Q")
_U16_U64_PAIR: Final = struct.Struct("<HQ")
_ONE_ENTRY_MESSAGE_INDEX: Final = struct.Struct("<BQHIQQ")
_CHUNK_INDEX_HEAD: Final = struct.Struct("<QQQQI")
_CHUNK_INDEX_SIZES: Final = struct.Struct("<QQ")
#: A one-message chunk's ChunkIndex record up to its compression field: prefix, start, end, chunk start, chunk
#: length, the map's byte length and its one (channel id, message index offset) pair, message index length.
_ONE_MESSAGE_CHUNK_INDEX: Final = struct.Struct("<BQQQQQIHQQ")

#: Per channel id, the (log time, record offset) of each of its messages in one chunk.
ChunkMessages = dict[int, list[tuple[int, int]]]


def message_index_records(index: ChunkMessages, position: int) -> tuple[bytes, bytes]:
    """The MessageIndex records of one chunk (channels in id order) written at file offset ``position``.

    Returns:
        (the records, the chunk index's (channel id, record offset) map field without its length).
    """
    offsets = bytearray()
    blobs: list[bytes] = []
    for channel_id in sorted(index):
        entries = index[channel_id]
        array_bytes = MESSAGE_INDEX_ENTRY.size * len(entries)
        if len(entries) == 1:
            blob = _ONE_ENTRY_MESSAGE_INDEX.pack(Opcode.MESSAGE_INDEX, 2 + 4 + array_bytes, channel_id,
                                                 array_bytes, *entries[0])
        else:
            flat = [value for entry in entries for value in entry]
            blob = (MESSAGE_INDEX_HEADER.pack(Opcode.MESSAGE_INDEX, 2 + 4 + array_bytes, channel_id, array_bytes)
                    + struct.pack(f"<{len(flat)}Q", *flat))
        offsets += _U16_U64_PAIR.pack(channel_id, position)
        blobs.append(blob)
        position += len(blob)
    return b"".join(blobs), bytes(offsets)


def chunk_index_record(*, start: int, end: int, chunk_start: int, chunk_length: int, offsets: bytes,
                       message_index_length: int, compression_field: bytes, payload_size: int,
                       uncompressed_size: int) -> bytes:
    """One ChunkIndex record (prefix included).

    The CHUNK_INDEX layout of :data:`~avdata.schema.mcap.records.RECORD_LAYOUTS`, packed directly: one per
    chunk, and the generic encoder cost more than the rest of the chunk's bookkeeping.
    """
    body = b"".join((
        _CHUNK_INDEX_HEAD.pack(start, end, chunk_start, chunk_length, len(offsets)), offsets,
        _U64_FIELD.pack(message_index_length), compression_field,
        _CHUNK_INDEX_SIZES.pack(payload_size, uncompressed_size)))
    return RECORD_PREFIX.pack(Opcode.CHUNK_INDEX, len(body)) + body


def one_message_indexes(*, channel_id: int, log_time: int, chunk_start: int, chunk_length: int, position: int,
                        compression_field: bytes, payload_size: int, uncompressed_size: int) -> tuple[bytes, bytes]:
    """(MessageIndex record, ChunkIndex record) of a chunk holding one message, its message index written at ``position``.

    The bytes :func:`message_index_records` and :func:`chunk_index_record` give for such a chunk, packed at once:
    every large message gets a chunk of its own, and the general forms' loops and joins were most of its cost.
    """
    message_index = _ONE_ENTRY_MESSAGE_INDEX.pack(Opcode.MESSAGE_INDEX, 2 + 4 + MESSAGE_INDEX_ENTRY.size, channel_id,
                                                  MESSAGE_INDEX_ENTRY.size, log_time, 0)
    chunk_index = (_ONE_MESSAGE_CHUNK_INDEX.pack(
        Opcode.CHUNK_INDEX, _ONE_MESSAGE_CHUNK_INDEX.size - RECORD_PREFIX.size + len(compression_field)
        + _CHUNK_INDEX_SIZES.size, log_time, log_time, chunk_start, chunk_length, _U16_U64_PAIR.size, channel_id,
        position, len(message_index)) + compression_field + _CHUNK_INDEX_SIZES.pack(payload_size, uncompressed_size))
    return message_index, chunk_index


@dataclass(frozen=True, slots=True, kw_only=True)
class ChunkInfo:
    """One chunk as the summary's chunk index describes it (offsets in bytes from the file start)."""

    start_ns: int
    end_ns: int
    offset: int
    length: int
    message_index_offsets: dict[int, int]
    message_index_length: int
    compression: str
    compressed_size: int
    uncompressed_size: int

    @property
    def records_offset(self) -> int:
        """File offset of the chunk's (possibly compressed) records."""
        return self.offset + CHUNK_HEADER.size + 4 + len(self.compression.encode()) + 8


@dataclass(frozen=True, slots=True, kw_only=True)
class MessageTable:
    """Where each message of one topic lies: arrays sorted by log time (length M).

    Attributes:
        log_time_ns: (M,) log times.
        chunk: (M,) the chunk (index into :attr:`McapReader.chunks`) holding each message.
        record_offset: (M,) offset of the message record inside its chunk's uncompressed records.
    """

    log_time_ns: np.ndarray
    chunk: np.ndarray
    record_offset: np.ndarray


@dataclass(frozen=True, slots=True, kw_only=True)
class ChannelInfo:
    """A channel and its schema."""

    id: int
    topic: str
    message_encoding: str
    schema_id: int
    schema_name: str
    schema_encoding: str
