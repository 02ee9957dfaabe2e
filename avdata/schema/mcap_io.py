"""MCAP reading and writing for avdata scenes, over one set of record layouts.

Every record layout of the MCAP spec that avdata writes or reads is declared once here
(:data:`RECORD_LAYOUTS`, the ``struct`` formats of the hot records), and both :class:`McapWriter`
and :class:`McapReader` use them.

Integrity: every chunk carries the CRC-32 of its uncompressed records (also the large chunks
written straight from the caller's buffers), the DataEnd record carries the CRC-32 of the whole
data section and the Footer that of the summary, exactly as the MCAP spec defines them, so the
stock ``mcap`` reader with ``validate_crcs=True`` checks the same bytes :meth:`McapReader.verify`
does. Together they cover every byte of the file but the two magics, which are compared. The
writer computes each byte's CRC once, with libdeflate's CRC-32 (``deflate``, about 8x zlib's): a
chunk's CRC is chained into the data-section CRC with :func:`crc32_combine` (ISA-L's) instead of a
second pass. A large message's CRC is computed just before the ``writev`` that copies it to the
file, which then reads the payload (a few MB: a cloud, an image) from the CPU cache.

Reading: the file is memory-mapped; a message of an uncompressed chunk is a read-only zero-copy
view into the mapping, and a compressed chunk is decompressed only when a message in it is read.
Every failure caused by the file's bytes is an :class:`~avdata.errors.InputError` naming the file,
the record and the value.
"""

from __future__ import annotations

import ctypes
import mmap
import os
import struct
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, Final

import deflate
import numpy as np
from isal import isal_zlib

from avdata.errors import InputError, one_line

Buffer = bytes | bytearray | memoryview

# ---------------------------------------------------------------------------------------- layouts
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
            body += _sized(value.encode())
        elif kind == _BYTES:
            body += _sized(bytes(value))
        elif kind == _STR_MAP:
            body += _sized(b"".join(_sized(k.encode()) + _sized(v.encode()) for k, v in value.items()))
        else:
            body += _sized(b"".join(struct.pack("<HQ", k, v) for k, v in sorted(value.items())))
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
    return values


def _sized(data: bytes) -> bytes:
    return struct.pack("<I", len(data)) + data


def _take_sized(data: memoryview, position: int) -> tuple[memoryview, int]:
    (size,) = struct.unpack_from("<I", data, position)
    start = position + 4
    if start + size > len(data):
        raise RecordError(f"field of {size} bytes at byte {position} runs past the record's end ({len(data)} bytes)")
    return data[start : start + size], start + size


# ------------------------------------------------------------------------------------------ CRCs
# libdeflate's CRC-32 (the same polynomial as zlib's) ran at 21 GB/s on data in the CPU cache
# here, ISA-L's at 9-10 and zlib's at 2.5 (2026-11-23, README): it is what keeps checksummed writes
# and verified reads near plain file speed. libdeflate has no CRC combination; ISA-L's is used.


def crc32(data: Buffer, value: int = 0) -> int:
    """CRC-32 (zlib's polynomial) of ``data`` (a C-contiguous buffer), continuing from ``value``."""
    return deflate.crc32(data, value)


crc32_combine = isal_zlib.crc32_combine


# ---------------------------------------------------------------------------------- compression
def _compress(compression: str, data: bytes | bytearray) -> bytes | bytearray:
    if compression == "zstd":
        import zstandard

        return zstandard.compress(data)
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.compress(data))
    return data


def _decompress(compression: str, data: Buffer, uncompressed_size: int) -> bytes:
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


# ---------------------------------------------------------------------------------------- writer
class McapWriter:
    """Writes an indexed, fully checksummed MCAP file to an open binary file; a context manager.

    Large messages (at least ``large_message_bytes``) get a chunk of their own, written straight
    from the caller's buffers without a copy; small ones are batched into chunks of about
    ``chunk_size`` bytes, copied, except parts of 16 kB or more in memory nobody can change (bytes
    and views of bytes, such as a file's contents), which the chunk keeps by reference. The
    ``with`` block ends with :meth:`finish` (summary and footer) unless it raised.

    Writing goes straight to the file descriptor with ``os.writev``: the small records written
    since the last large message are queued and go out in the same system call as the next large
    chunk, so a large message costs one ``writev``; the stream's own buffer is never used.

    Args:
        stream: a writable binary file positioned at 0 with a ``fileno`` (written through its
            descriptor; nothing may be written to the stream itself until :meth:`finish`).
        library: the writing library's name and version, recorded in the header.
        compression: "" (none), "zstd" or "lz4" for every chunk.
        chunk_size: close a chunk of small messages once its records exceed this many bytes.
        large_message_bytes: messages at least this large get a chunk of their own.
        written: the tally of bytes written this file adds to (a dataset's scenes share one);
            past a tenth of memory the file's pages leave the page cache as written back.

    Raises:
        InputError: an unknown compression.
    """

    def __init__(self, stream: BinaryIO, *, library: str, compression: str = "", chunk_size: int = 1 << 20,
                 large_message_bytes: int = 256 << 10, written: WrittenBytes | None = None):
        if compression not in COMPRESSIONS:
            raise InputError(f"expected an MCAP chunk compression of {list(COMPRESSIONS)}, got {compression!r}")
        stream.flush()
        self._fd = stream.fileno()
        self._compression = compression
        self._compression_field = _sized(compression.encode())
        self._chunk_size = chunk_size
        self._large = large_message_bytes
        self._schema_records: list[bytes] = []
        self._channel_records: list[bytes] = []
        self._chunk_indexes: list[bytes] = []
        self._metadata_indexes: list[dict[str, Any]] = []
        self._message_counts: dict[int, int] = {}
        self._start_time: int | None = None
        self._end_time = 0
        # The open chunk's records: ``_segments`` (``_segments_bytes`` in all), then ``_records``.
        self._segments: list[Buffer] = []
        self._segments_bytes = 0
        self._records = bytearray()
        self._index: dict[int, list[tuple[int, int]]] = {}
        self._chunk_times: tuple[int, int] | None = None
        self._position = 0
        self._data_crc = 0
        self._pending: list[Buffer] = []
        self._pending_bytes = 0
        self._reservation = _Reservation(self._fd)
        self._cache_release = _CacheRelease(self._fd, written or WrittenBytes())
        self._finished = False
        #: Called once before the first chunk is written; the messages it adds go first in the file,
        #: ahead of those already buffered (avdata writes /tf_static there).
        self.before_first_chunk: Callable[[], None] | None = None
        self._write(MAGIC)
        self._write(encode_record(Opcode.HEADER, {"profile": "", "library": library}))

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.finish()
        else:
            self.abort()

    def abort(self) -> None:
        """Stops without writing the summary or the records still queued (the caller discards the file)."""
        self._finished = True
        self._pending = []
        self._pending_bytes = 0

    # ----------------------------------------------------------------- low level
    def _write(self, data: bytes | bytearray) -> None:
        """Queues ``data`` (bytes nobody changes later) for the next ``writev``, chaining its CRC."""
        self._queue([data], len(data), crc32(data, self._data_crc))

    def _queue(self, buffers: Sequence[Buffer], size: int, data_crc: int) -> None:
        """Queues ``buffers`` (``size`` bytes that nobody changes later) whose data-section CRC ends at ``data_crc``."""
        self._pending += buffers
        self._pending_bytes += size
        self._data_crc = data_crc
        self._position += size
        if self._pending_bytes >= _FLUSH_BYTES or len(self._pending) >= _MAX_QUEUED:
            self._flush()

    def _flush(self, large: Sequence[Buffer] = (), large_bytes: int = 0) -> None:
        """Writes the queued records, then ``large`` (``large_bytes`` in all), in one ``writev``."""
        self._reservation.ahead_of(self._pending_bytes + large_bytes)
        _write_all(self._fd, [*self._pending, *large] if large else self._pending, self._pending_bytes + large_bytes)
        self._cache_release.after_write(self._pending_bytes + large_bytes)
        self._pending = []
        self._pending_bytes = 0

    # ----------------------------------------------------------------- API
    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Adds a schema record; returns its id (1, 2, ...)."""
        schema_id = len(self._schema_records) + 1
        record = encode_record(Opcode.SCHEMA, {"id": schema_id, "name": name, "encoding": encoding, "data": data})
        self._schema_records.append(record)
        self._write(record)
        return schema_id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        """Adds a channel record; returns its id (0, 1, ...)."""
        channel_id = len(self._channel_records)
        record = encode_record(Opcode.CHANNEL, {"id": channel_id, "schema_id": schema_id, "topic": topic,
                                                "message_encoding": message_encoding, "metadata": {}})
        self._channel_records.append(record)
        self._write(record)
        return channel_id

    def add_message(self, channel_id: int, log_time: int, publish_time: int, sequence: int,
                    parts: Sequence[Buffer]) -> None:
        """Appends one message whose payload is the concatenation of ``parts`` (not copied when large)."""
        size = 0
        for part in parts:
            size += part.nbytes if isinstance(part, memoryview) else len(part)
        header = MESSAGE_HEADER.pack(Opcode.MESSAGE, MESSAGE_HEADER.size - RECORD_PREFIX.size + size, channel_id,
                                     sequence, log_time, publish_time)
        self._message_counts[channel_id] = self._message_counts.get(channel_id, 0) + 1
        if self._start_time is None or log_time < self._start_time:
            self._start_time = log_time
        if log_time > self._end_time:
            self._end_time = log_time
        if size >= self._large:
            self._start()
            self._finish_chunk()
            self._large_chunk(channel_id, log_time, header, parts, size)
            return
        self._index.setdefault(channel_id, []).append((log_time, self._segments_bytes + len(self._records)))
        self._records += header
        for part in parts:
            kept = _by_reference(part)
            if kept is None:
                self._records += part
            else:
                # A camera image or a scan read from its file: kept by reference until the chunk is written.
                # Copying it into the chunk cost 4% of a nuScenes conversion's CPU (README, Performance).
                self._segments += (self._records, kept)
                self._segments_bytes += len(self._records) + len(kept)
                self._records = bytearray()
        if self._chunk_times is None:
            self._chunk_times = (log_time, log_time)
        elif not self._chunk_times[0] <= log_time <= self._chunk_times[1]:
            self._chunk_times = (min(self._chunk_times[0], log_time), max(self._chunk_times[1], log_time))
        if self._segments_bytes + len(self._records) >= self._chunk_size:
            self._finish_chunk()

    @property
    def earliest_log_time(self) -> int | None:
        """The smallest log time of the messages added so far (None before the first)."""
        return self._start_time

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Adds a metadata record (indexed in the summary)."""
        self._finish_chunk()
        offset = self._position
        blob = encode_record(Opcode.METADATA, {"name": name, "metadata": dict(data)})
        self._write(blob)
        self._metadata_indexes.append({"offset": offset, "length": len(blob), "name": name})

    def finish(self) -> None:
        """Closes the last chunk and writes DataEnd (data-section CRC), the summary and the footer."""
        if self._finished:
            return
        self._finished = True
        self._finish_chunk()
        self._write(DATA_END.pack(Opcode.DATA_END, 4, self._data_crc))
        summary_start = self._position
        summary = bytearray()
        offsets: list[bytes] = []

        def group(opcode: int, records: Sequence[bytes]) -> None:
            if records:
                offsets.append(encode_record(Opcode.SUMMARY_OFFSET, {
                    "group_opcode": opcode, "group_start": summary_start + len(summary),
                    "group_length": sum(len(r) for r in records)}))
                summary.extend(b"".join(records))

        statistics = {
            "message_count": sum(self._message_counts.values()),
            "schema_count": len(self._schema_records),
            "channel_count": len(self._channel_records),
            "attachment_count": 0,
            "metadata_count": len(self._metadata_indexes),
            "chunk_count": len(self._chunk_indexes),
            "message_start_time": self._start_time or 0,
            "message_end_time": self._end_time,
            "channel_message_counts": dict(self._message_counts),
        }
        group(Opcode.SCHEMA, self._schema_records)
        group(Opcode.CHANNEL, self._channel_records)
        group(Opcode.STATISTICS, [encode_record(Opcode.STATISTICS, statistics)])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.METADATA_INDEX, [encode_record(Opcode.METADATA_INDEX, m) for m in self._metadata_indexes])
        summary_offset_start = summary_start + len(summary)
        summary.extend(b"".join(offsets))
        # The footer's CRC covers the summary and the footer up to the CRC field (MCAP spec).
        footer_head = FOOTER.pack(Opcode.FOOTER, FOOTER.size - RECORD_PREFIX.size, summary_start,
                                  summary_offset_start, 0)[:-4]
        summary_crc = crc32(footer_head, crc32(summary))
        tail = footer_head + struct.pack("<I", summary_crc) + MAGIC
        self._flush([summary, tail], len(summary) + len(tail))
        self._reservation.release()

    # ----------------------------------------------------------------- chunks
    def _start(self) -> None:
        """Runs ``before_first_chunk`` once, putting what it adds ahead of the buffered messages."""
        hook, self.before_first_chunk = self.before_first_chunk, None
        if hook is None:
            return
        segments, records, index, times = self._segments, self._records, self._index, self._chunk_times
        self._segments, self._segments_bytes, self._records, self._index, self._chunk_times = [], 0, bytearray(), {}, None
        hook()
        shift = self._segments_bytes + len(self._records)
        for channel_id, entries in index.items():
            self._index.setdefault(channel_id, []).extend((t, offset + shift) for t, offset in entries)
        if segments:
            self._segments += [self._records, *segments]
            self._segments_bytes = shift + sum(map(len, segments))  # bytes, bytearrays and byte views
            self._records = records
        else:
            self._records += records
        if times is not None:
            start, end = self._chunk_times or times
            self._chunk_times = (min(start, times[0]), max(end, times[1]))

    def _finish_chunk(self) -> None:
        self._start()
        if not self._records and not self._segments:
            return
        # The buffers themselves go to the file (a copy cost as much as filling them); the next
        # chunk gets new ones, so nothing changes these after they are queued.
        segments = [*self._segments, self._records] if self._records else self._segments
        size = self._segments_bytes + len(self._records)
        start, end = self._chunk_times or (0, 0)
        index = self._index
        self._segments, self._segments_bytes, self._records = [], 0, bytearray()
        self._index = {}
        self._chunk_times = None
        self._compressed_chunk(segments, size, start, end, index)

    def _compressed_chunk(self, segments: Sequence[Buffer], size: int, start: int, end: int,
                          index: dict[int, list[tuple[int, int]]]) -> None:
        """Writes one chunk whose records are the concatenation of ``segments`` (``size`` bytes)."""
        records_crc = 0
        for segment in segments:
            records_crc = crc32(segment, records_crc)
        if self._compression:
            compressed = _compress(self._compression, b"".join(segments))
            head = self._chunk_head(len(compressed), size, records_crc, start, end)
            chunk_start = self._position
            self._write(head)
            self._write(compressed)
            self._chunk_end(chunk_start, start, end, len(compressed), size, index)
            return
        head = self._chunk_head(size, size, records_crc, start, end)
        chunk_start = self._position
        self._write(head)
        # Uncompressed: the chunk's CRC is that of the bytes written; chained, not computed again.
        self._queue(segments, size, crc32_combine(self._data_crc, records_crc, size))
        self._chunk_end(chunk_start, start, end, size, size, index)

    def _chunk_head(self, payload_size: int, uncompressed_size: int, crc: int, start: int, end: int) -> bytes:
        body_size = CHUNK_HEADER.size - RECORD_PREFIX.size + len(self._compression_field) + 8 + payload_size
        return (CHUNK_HEADER.pack(Opcode.CHUNK, body_size, start, end, uncompressed_size, crc)
                + self._compression_field + _U64_FIELD.pack(payload_size))

    def _large_chunk(self, channel_id: int, log_time: int, header: bytes, parts: Sequence[Buffer], size: int) -> None:
        index = {channel_id: [(log_time, 0)]}
        if self._compression:
            self._compressed_chunk([b"".join([header, *(bytes(p) for p in parts)])], len(header) + size, log_time,
                                   log_time, index)
            return
        # Uncompressed: the payload goes from the caller's buffers to the file without a copy, in
        # the same writev as the records queued before it. Its CRC is computed first: that pass
        # also brings the payload into the CPU cache for the copy the writev makes, and the chunk
        # header goes out complete. (Computed after the writev instead, from the cache, the CRC
        # cost as much and its header field took one pwrite per message; README.) The
        # data-section CRC is chained from the chunk's CRC, so every byte is checksummed once.
        payload = [p if isinstance(p, (bytes, bytearray)) else memoryview(p).cast("B") for p in parts]
        records_size = len(header) + size
        chunk_crc = crc32(header)
        for part in payload:
            chunk_crc = crc32(part, chunk_crc)
        head = self._chunk_head(records_size, records_size, chunk_crc, log_time, log_time)
        chunk_start = self._position
        self._flush([head, header, *payload], len(head) + records_size)
        self._data_crc = crc32_combine(crc32(head, self._data_crc), chunk_crc, records_size)
        self._position += len(head) + records_size
        self._chunk_end(chunk_start, log_time, log_time, records_size, records_size, index)

    def _chunk_end(self, chunk_start: int, start: int, end: int, payload_size: int, uncompressed_size: int,
                   index: dict[int, list[tuple[int, int]]]) -> None:
        """Queues the chunk's message indexes and remembers its chunk index record."""
        chunk_length = self._position - chunk_start
        position = self._position
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
        message_index = b"".join(blobs)
        self._write(message_index)
        # The CHUNK_INDEX layout of RECORD_LAYOUTS, packed directly (one per chunk; the generic
        # encoder cost more than the rest of the chunk's bookkeeping).
        body = b"".join((
            _CHUNK_INDEX_HEAD.pack(start, end, chunk_start, chunk_length, len(offsets)), offsets,
            _U64_FIELD.pack(len(message_index)), self._compression_field,
            _CHUNK_INDEX_SIZES.pack(payload_size, uncompressed_size)))
        self._chunk_indexes.append(RECORD_PREFIX.pack(Opcode.CHUNK_INDEX, len(body)) + body)


#: A message part at least this large that nobody can change (:func:`_frozen`) joins its chunk by reference.
_BY_REFERENCE_BYTES: Final = 16 << 10
#: Queued small records are written once they reach this many bytes or this many buffers.
_FLUSH_BYTES: Final = 1 << 20
_MAX_QUEUED: Final = 256
_U64_FIELD: Final = struct.Struct("<Q")
_U16_U64_PAIR: Final = struct.Struct("<HQ")
_ONE_ENTRY_MESSAGE_INDEX: Final = struct.Struct("<BQHIQQ")
_CHUNK_INDEX_HEAD: Final = struct.Struct("<QQQQI")
_CHUNK_INDEX_SIZES: Final = struct.Struct("<QQ")
#: Buffers per writev call (the kernel's IOV_MAX is 1024).
_IOV_MAX: Final = 1024


def _by_reference(part: Buffer) -> bytes | memoryview | None:
    """``part`` as bytes to keep until its chunk is written, if large and :func:`_frozen`; else None (copy it)."""
    if isinstance(part, bytes):
        return part if len(part) >= _BY_REFERENCE_BYTES else None
    if not isinstance(part, memoryview) or part.nbytes < _BY_REFERENCE_BYTES or not part.c_contiguous:
        return None
    if not _frozen(part.obj):
        return None
    return part if part.format == "B" and part.ndim == 1 else part.cast("B")


def _frozen(owner: object) -> bool:
    """True if nobody can change the bytes ``owner`` exports: a bytes object, or a view (numpy arrays included) of one."""
    while True:
        if isinstance(owner, bytes):
            return True
        if isinstance(owner, memoryview):
            owner = owner.obj
        elif isinstance(owner, np.ndarray) and owner.base is not None:
            owner = owner.base
        else:
            return False


def _libc_fallocate() -> Callable[[int, int, int, int], int] | None:
    """Linux's ``fallocate(2)``, or None elsewhere.

    Not ``os.posix_fallocate``: where a filesystem lacks the call, glibc emulates it by writing
    zeros and growing the file, which would cost more than it saves.
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        function = ctypes.CDLL(None, use_errno=True).fallocate
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    function.restype = ctypes.c_int
    return function


_FALLOCATE: Final = _libc_fallocate()
_FALLOC_FL_KEEP_SIZE: Final = 1


class _Reservation:
    """Reserves a file's blocks ahead of its writes, without changing its size.

    Why: on ext4 (delayed allocation) every write that extends a file reserves its blocks page by
    page; with the extent reserved first, the same ``write`` calls into the page cache ran 1.5x as
    fast here (3.3 -> 5.0 GB/s, 2 MB writes; README, Performance). ``FALLOC_FL_KEEP_SIZE`` leaves
    the size at what was written, so nothing reading the file, or left by a crash, sees the
    reservation; :meth:`release` gives back what was not used. Where the call fails (unsupported,
    no space for the step), reserving stops and writes go on as they would have: a full disk is
    then reported by the write itself.
    """

    #: Reserve at least this much at a time, and at most this much: steps grow with the file.
    _MIN_STEP: Final = 4 << 20
    _MAX_STEP: Final = 64 << 20

    def __init__(self, fd: int):
        self._fd = fd
        self._written = 0
        self._reserved = 0
        self._enabled = _FALLOCATE is not None

    def ahead_of(self, size: int) -> None:
        """Makes sure the next ``size`` bytes written are reserved, then counts them as written."""
        end = self._written + size
        self._written = end
        if end <= self._reserved or not self._enabled:
            return
        step = max(end - self._reserved, min(max(self._reserved, self._MIN_STEP), self._MAX_STEP))
        assert _FALLOCATE is not None
        if _FALLOCATE(self._fd, _FALLOC_FL_KEEP_SIZE, self._reserved, step) != 0:
            self._enabled = False
            return
        self._reserved += step

    def release(self) -> None:
        """Frees the blocks reserved beyond what was written (truncating to the same size does)."""
        if self._reserved > self._written:
            os.ftruncate(self._fd, os.fstat(self._fd).st_size)
        self._reserved = 0


def _physical_memory_bytes() -> int:
    """The machine's memory (0 where the platform does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return 0


class WrittenBytes:
    """Bytes written so far by the writers that share this tally (one dataset's scenes in one process).

    Their files' pages leave the page cache once it passes :data:`DROP_WRITTEN_AFTER_BYTES`
    (see :class:`_CacheRelease`).
    """

    def __init__(self) -> None:
        self.total = 0


#: A tenth of the machine's memory: where Linux starts writing dirty pages back by itself
#: (``vm.dirty_background_ratio``'s default); 0 where the platform does not say.
DROP_WRITTEN_AFTER_BYTES = _physical_memory_bytes() // 10


class _CacheRelease:
    """Drops a file's pages from the page cache once written back, a step at a time as it grows.

    Only once the writers sharing its :class:`WrittenBytes` (a dataset's scenes) have written a
    tenth of the machine's memory. Why: nothing in avdata reads a file it is writing, and a
    large conversion writes far more than memory holds. Kept, its pages fill the page cache,
    push out what the machine had cached, and every new page must be found somewhere: 200
    nuScenes-sized scenes (16 GB) took 45-51 s of system time here kept, 8-12 s dropped (README,
    Performance). Below a tenth of memory a dataset's files sit in the page cache unwritten, and
    dropping them would add their write-back to the writes (a 563 MB scene: 0.78 of plain
    writes' CPU, against 0.94 kept; KITTI object, 1.4 GB: ~10% more CPU); above it they are being
    written back anyway. ``POSIX_FADV_DONTNEED`` starts the write-back of a range's dirty pages
    and drops its clean ones, so each call drops the step whose write-back the previous call
    started, and starts the new step's. Pages still being written back are left to the kernel,
    and so is a file's last step.
    """

    _STEP: Final = 8 << 20

    def __init__(self, fd: int, written: WrittenBytes):
        self._fd = fd
        self._tally = written
        self._written = 0
        self._started = 0  # write-back started up to here (dropped before the previous call's end)
        self._dropped = 0
        self._enabled = hasattr(os, "posix_fadvise")

    def after_write(self, size: int) -> None:
        """Counts ``size`` more bytes written at the end of the file; drops and starts a step when one is full."""
        self._written += size
        self._tally.total += size
        if (self._written - self._started < self._STEP or self._tally.total <= DROP_WRITTEN_AFTER_BYTES
                or not self._enabled):
            return
        try:
            os.posix_fadvise(self._fd, self._dropped, self._written - self._dropped, os.POSIX_FADV_DONTNEED)
        except OSError:  # a file system without it: the kernel keeps the pages, as it would have
            self._enabled = False
            return
        self._dropped, self._started = self._started, self._written


def _write_all(fd: int, buffers: list[Buffer], total: int) -> None:
    """Writes ``buffers`` (``total`` bytes) in order with ``os.writev``, continuing after short writes."""
    written = os.writev(fd, buffers[:_IOV_MAX])
    if written == total:
        return
    # More buffers than one call takes, or a short write (signals, > 2 GiB): go on from where it stopped.
    views = [memoryview(b).cast("B") for b in buffers]
    while True:
        done = 0
        while done < len(views) and written >= views[done].nbytes:
            written -= views[done].nbytes
            done += 1
        views = views[done:]
        if not views:
            return
        views[0] = views[0][written:]
        written = os.writev(fd, views[:_IOV_MAX])


# ---------------------------------------------------------------------------------------- reader
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


class McapReader:
    """Random access into an MCAP file written by :class:`McapWriter`, through its summary and indexes.

    Opening maps the file, checks both magics and the summary CRC, and parses the summary
    (schemas, channels, chunk indexes, metadata indexes). Message indexes are read on first use of
    :meth:`table`. Message payloads of uncompressed chunks are zero-copy read-only views into the
    mapping; views outlive :meth:`close` safely (the mapping is released when the last one goes).

    Args:
        path: the ``.mcap`` file.
        verify: check each chunk's CRC the first time one of its messages is read.

    Raises:
        InputError: the file is missing, truncated, damaged or has no summary.
    """

    def __init__(self, path: str | Path, *, verify: bool = False):
        self.path = Path(path)
        self.verify = verify
        self._map: mmap.mmap | None = None
        self._map_pid = 0
        self._fd = -1
        self._verified: set[int] = set()
        self._views: dict[int, memoryview] = {}  # checked uncompressed chunks' records
        self._chunk_cache: tuple[int, bytes] | None = None
        self._tables: dict[str, MessageTable] | None = None
        try:
            self._size = self.path.stat().st_size
        except OSError as error:
            raise InputError(f"{self.path}: cannot read the scene file ({error.strerror})") from error
        minimum = 2 * len(MAGIC) + FOOTER.size
        if self._size < minimum:
            with open(self.path, "rb") as stream:
                head = stream.read(len(MAGIC))
            what = "truncated MCAP file" if MAGIC.startswith(head) else "not an MCAP file (bad magic bytes at byte 0)"
            raise InputError(f"{self.path}: {what} ({self._size} bytes, expected at least {minimum})")
        data = self._data()
        if data[: len(MAGIC)] != MAGIC:
            raise InputError(f"{self.path}: not an MCAP file (bad magic bytes at byte 0)")
        if data[-len(MAGIC) :] != MAGIC:
            raise InputError(f"{self.path}: truncated MCAP file (no closing magic; an interrupted write?)")
        self.footer_offset = self._size - len(MAGIC) - FOOTER.size
        opcode, length, summary_start, summary_offset_start, summary_crc = FOOTER.unpack_from(data, self.footer_offset)
        if opcode != Opcode.FOOTER or length != FOOTER.size - RECORD_PREFIX.size:
            raise self.error(self.footer_offset, f"expected a Footer record, got opcode 0x{opcode:02x} length {length}")
        if not len(MAGIC) < summary_start <= summary_offset_start <= self.footer_offset:
            raise self.error(self.footer_offset, f"summary start {summary_start} / summary offset start "
                             f"{summary_offset_start} outside the file (footer at {self.footer_offset})")
        computed = crc32(data[summary_start : self.footer_offset + FOOTER.size - 4])
        if computed != summary_crc:
            raise self.error(self.footer_offset, f"summary CRC mismatch: footer says 0x{summary_crc:08x}, "
                             f"bytes {summary_start}..{self.footer_offset + FOOTER.size - 4} give 0x{computed:08x}")
        self.summary_start = summary_start
        self._parse_summary(summary_start, summary_offset_start)

    # ----------------------------------------------------------------- errors and mapping
    def error(self, offset: int, message: str) -> InputError:
        """An InputError naming this file, the byte offset and what is wrong there."""
        return InputError(f"{self.path}: byte {offset}: {message}")

    def _data(self) -> mmap.mmap:
        if self._map is None or self._map_pid != os.getpid():
            try:
                self._fd = os.open(self.path, os.O_RDONLY)
                self._map = mmap.mmap(self._fd, 0, access=mmap.ACCESS_READ)
            except (OSError, ValueError) as error:
                raise InputError(f"{self.path}: cannot map the scene file ({one_line(error)})") from error
            self._views = {}
            self._map_pid = os.getpid()
        return self._map

    def read_into(self, offset: int, target: memoryview) -> None:
        """Fills ``target`` with the file's bytes from ``offset`` on (one ``preadv``, no intermediate copy)."""
        self._data()
        read = os.preadv(self._fd, [target], offset)
        if read != target.nbytes:
            raise self.error(offset, f"read {read} of {target.nbytes} bytes: the file is shorter than its index says")

    def close(self) -> None:
        """Drops the mapping; numpy views handed out keep their pages until they are gone."""
        self._views = {}
        if self._map is not None and self._map_pid == os.getpid():
            try:
                self._map.close()
            except BufferError:
                pass  # views are alive: the mapping is released with the last of them
            os.close(self._fd)
        self._map = None
        self._chunk_cache = None

    def __getstate__(self) -> dict[str, Any]:
        state = {name: getattr(self, name) for name in self.__dict__}
        state.update(_map=None, _map_pid=0, _fd=-1, _chunk_cache=None, _views={})
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    # ----------------------------------------------------------------- summary
    def _records(self, start: int, end: int) -> Iterator[tuple[int, int, memoryview]]:
        """(offset, opcode, body) of each record between two file offsets."""
        data = memoryview(self._data())
        position = start
        while position < end:
            if position + RECORD_PREFIX.size > end:
                raise self.error(position, f"record prefix runs past byte {end}")
            opcode, length = RECORD_PREFIX.unpack_from(data, position)
            body_start = position + RECORD_PREFIX.size
            if length > end - body_start:
                raise self.error(position, f"record 0x{opcode:02x} of {length} bytes runs past byte {end}")
            yield position, opcode, data[body_start : body_start + length]
            position = body_start + length

    def _decode(self, offset: int, opcode: int, body: memoryview) -> dict[str, Any]:
        try:
            return decode_record(opcode, body)
        except RecordError as error:
            raise self.error(offset, str(error)) from error

    def _parse_summary(self, start: int, end: int) -> None:
        schemas: dict[int, dict[str, Any]] = {}
        channels: dict[int, dict[str, Any]] = {}
        self.chunks: list[ChunkInfo] = []
        self.metadata_offsets: dict[str, tuple[int, int]] = {}
        for offset, opcode, body in self._records(start, end):
            if opcode == Opcode.SCHEMA:
                schema = self._decode(offset, opcode, body)
                schemas[schema["id"]] = schema
            elif opcode == Opcode.CHANNEL:
                channel = self._decode(offset, opcode, body)
                channels[channel["id"]] = channel
            elif opcode == Opcode.CHUNK_INDEX:
                values = self._decode(offset, opcode, body)
                chunk = ChunkInfo(
                    start_ns=values["message_start_time"], end_ns=values["message_end_time"],
                    offset=values["chunk_start_offset"], length=values["chunk_length"],
                    message_index_offsets=values["message_index_offsets"],
                    message_index_length=values["message_index_length"], compression=values["compression"],
                    compressed_size=values["compressed_size"], uncompressed_size=values["uncompressed_size"])
                self._check_chunk_index(offset, chunk)
                self.chunks.append(chunk)
            elif opcode == Opcode.METADATA_INDEX:
                values = self._decode(offset, opcode, body)
                if not len(MAGIC) <= values["offset"] <= self.summary_start - values["length"]:
                    raise self.error(offset, f"metadata index points outside the data section: {values['offset']}")
                self.metadata_offsets[values["name"]] = (values["offset"], values["length"])
        self.chunks.sort(key=lambda c: c.offset)
        self.channels: dict[int, ChannelInfo] = {}
        for channel_id, channel in channels.items():
            if channel["schema_id"] not in schemas:
                raise InputError(f"{self.path}: channel {channel['topic']!r} refers to schema {channel['schema_id']}, "
                                 f"which the summary does not hold")
            self.channels[channel_id] = ChannelInfo(
                id=channel_id, topic=channel["topic"], message_encoding=channel["message_encoding"],
                schema_id=channel["schema_id"], schema_name=schemas[channel["schema_id"]]["name"],
                schema_encoding=schemas[channel["schema_id"]]["encoding"])
        self.schemas = schemas

    def _check_chunk_index(self, offset: int, chunk: ChunkInfo) -> None:
        if chunk.compression not in COMPRESSIONS:
            raise self.error(offset, f"chunk index: unsupported chunk compression {chunk.compression!r}")
        end = chunk.offset + chunk.length
        if not (len(MAGIC) <= chunk.offset and chunk.records_offset + chunk.compressed_size == end
                and end + chunk.message_index_length <= self.summary_start):
            raise self.error(offset, f"chunk index: chunk at byte {chunk.offset} of length {chunk.length} "
                             f"(records {chunk.compressed_size} bytes) does not fit the data section")
        if chunk.compression == "" and chunk.compressed_size != chunk.uncompressed_size:
            raise self.error(offset, f"chunk index: uncompressed chunk of {chunk.compressed_size} bytes says "
                             f"{chunk.uncompressed_size} bytes uncompressed")
        if chunk.start_ns > chunk.end_ns:
            raise self.error(offset, f"chunk index: start time {chunk.start_ns} after end time {chunk.end_ns}")

    def metadata(self, name: str) -> dict[str, str] | None:
        """The metadata record ``name`` (read through the summary's index alone), or None if absent."""
        location = self.metadata_offsets.get(name)
        if location is None:
            return None
        offset, length = location
        data = memoryview(self._data())
        opcode, body_length = RECORD_PREFIX.unpack_from(data, offset)
        if opcode != Opcode.METADATA or body_length != length - RECORD_PREFIX.size:
            raise self.error(offset, f"metadata index points at a record 0x{opcode:02x} of {body_length} bytes, "
                             f"expected a Metadata record of {length - RECORD_PREFIX.size}")
        values = self._decode(offset, opcode, data[offset + RECORD_PREFIX.size : offset + length])
        if values["name"] != name:
            raise self.error(offset, f"metadata record is named {values['name']!r}, its index says {name!r}")
        return dict(values["metadata"])

    # ----------------------------------------------------------------- message indexes
    def tables(self) -> dict[str, MessageTable]:
        """Topic -> positions of its messages, from the message indexes after each chunk (read once)."""
        if self._tables is None:
            self._tables = self._read_message_indexes()
        return self._tables

    def _read_message_indexes(self) -> dict[str, MessageTable]:
        # channel -> rows of (log_time, chunk number, record offset); plain tuples because most
        # chunks hold one large message and numpy's per-call cost would dominate opening a scene.
        per_channel: dict[int, list[tuple[int, int, int]]] = {}
        for chunk_i, chunk in enumerate(self.chunks):
            index_start = chunk.offset + chunk.length
            index_end = index_start + chunk.message_index_length
            for channel_id, offset in chunk.message_index_offsets.items():
                if channel_id not in self.channels or not index_start <= offset < index_end:
                    raise self.error(chunk.offset, f"chunk index: message index of channel {channel_id} at byte "
                                     f"{offset}, outside {index_start}..{index_end} or of an unknown channel")
            for offset, opcode, body in self._records(index_start, index_end):
                if opcode != Opcode.MESSAGE_INDEX or len(body) < 6:
                    raise self.error(offset, f"expected a MessageIndex record, got opcode 0x{opcode:02x}")
                channel_id, array_bytes = struct.unpack_from("<HI", body)
                if channel_id not in self.channels or array_bytes != len(body) - 6 or array_bytes % 16:
                    raise self.error(offset, f"message index of channel {channel_id} with {array_bytes} bytes "
                                     f"of entries in a {len(body)}-byte record")
                rows = per_channel.setdefault(channel_id, [])
                for log_time, record_offset in MESSAGE_INDEX_ENTRY.iter_unpack(body[6:]):
                    if record_offset + MESSAGE_HEADER.size > chunk.uncompressed_size:
                        raise self.error(offset, f"message index entry at record offset {record_offset}, past the "
                                         f"chunk's {chunk.uncompressed_size} bytes")
                    if not chunk.start_ns <= log_time <= chunk.end_ns:
                        raise self.error(offset, f"message index entry at {log_time} ns, outside the chunk's "
                                         f"{chunk.start_ns}..{chunk.end_ns} ns")
                    rows.append((log_time, chunk_i, record_offset))
        tables: dict[str, MessageTable] = {}
        for channel_id, channel_rows in per_channel.items():
            if not channel_rows:
                continue
            table = np.array(channel_rows, dtype=np.int64)
            table = table[np.lexsort((table[:, 2], table[:, 1], table[:, 0]))]
            tables[self.channels[channel_id].topic] = MessageTable(
                log_time_ns=table[:, 0].copy(), chunk=table[:, 1].copy(), record_offset=table[:, 2].copy())
        return tables

    def channel_of_topic(self, topic: str) -> ChannelInfo | None:
        """The channel of ``topic``, or None."""
        for channel in self.channels.values():
            if channel.topic == topic:
                return channel
        return None

    # ----------------------------------------------------------------- messages
    def chunk_records(self, chunk_i: int) -> memoryview:
        """The uncompressed records of chunk ``chunk_i``: a view into the mapping, or the decompressed bytes.

        The chunk record's header is checked against the chunk index once; with ``verify`` its
        CRC too (once per chunk).
        """
        view = self._views.get(chunk_i)
        if view is not None:
            return view
        if self._chunk_cache is not None and self._chunk_cache[0] == chunk_i:
            return memoryview(self._chunk_cache[1])
        chunk = self.chunks[chunk_i]
        data = memoryview(self._data())
        opcode, length, start, end, uncompressed_size, crc = CHUNK_HEADER.unpack_from(data, chunk.offset)
        (compression_length,) = struct.unpack_from("<I", data, chunk.offset + CHUNK_HEADER.size)
        compression = bytes(data[chunk.offset + CHUNK_HEADER.size + 4 : chunk.offset + CHUNK_HEADER.size + 4
                                 + compression_length])
        (records_length,) = struct.unpack_from("<Q", data, chunk.records_offset - 8)
        if (opcode != Opcode.CHUNK or length != chunk.length - RECORD_PREFIX.size
                or (start, end) != (chunk.start_ns, chunk.end_ns) or uncompressed_size != chunk.uncompressed_size
                or compression != chunk.compression.encode()
                or records_length != chunk.compressed_size):
            raise self.error(chunk.offset, "chunk record header disagrees with the summary's chunk index "
                             f"(opcode 0x{opcode:02x}, length {length}, times {start}..{end}, "
                             f"{records_length} -> {uncompressed_size} bytes, compression {compression!r})")
        raw = data[chunk.records_offset : chunk.records_offset + chunk.compressed_size]
        if chunk.compression:
            try:
                records = _decompress(chunk.compression, raw, chunk.uncompressed_size)
            except RecordError as error:
                raise self.error(chunk.offset, str(error)) from error
            view = memoryview(records)
        else:
            view = raw
        if self.verify and chunk_i not in self._verified:
            self._check_crc(chunk_i, crc, view)
            self._verified.add(chunk_i)
        if chunk.compression:
            # One decompressed chunk is kept: consecutive reads mostly hit the same one.
            self._chunk_cache = (chunk_i, records)
        else:
            self._views[chunk_i] = view
        return view

    def _check_crc(self, chunk_i: int, crc: int, records: memoryview) -> None:
        offset = self.chunks[chunk_i].offset
        if crc == 0:
            raise self.error(offset, "chunk has no CRC (0 = not computed: written by an avdata without checksums; "
                             "convert it again)")
        computed = crc32(records)
        if computed != crc:
            raise self.error(offset, f"chunk CRC mismatch: header says 0x{crc:08x}, records give 0x{computed:08x}")

    def read(self, table: MessageTable, i: int, channel_id: int) -> memoryview:
        """The payload of message ``i`` of ``table`` (a read-only view; zero-copy for uncompressed chunks)."""
        chunk_i = int(table.chunk[i])
        offset = int(table.record_offset[i])
        records = self.chunk_records(chunk_i)
        opcode, length, channel, _, log_time, _ = MESSAGE_HEADER.unpack_from(records, offset)
        end = offset + RECORD_PREFIX.size + length
        if (opcode != Opcode.MESSAGE or channel != channel_id or log_time != int(table.log_time_ns[i])
                or length < MESSAGE_HEADER.size - RECORD_PREFIX.size or end > len(records)):
            raise self.error(self.chunks[chunk_i].offset, f"message index entry at record offset {offset} points at "
                             f"opcode 0x{opcode:02x}, channel {channel}, time {log_time} ns, length {length}; "
                             f"expected a message of channel {channel_id} at {int(table.log_time_ns[i])} ns")
        return records[offset + MESSAGE_HEADER.size : end]

    def payload_file_offset(self, table: MessageTable, i: int) -> int | None:
        """The file offset of message ``i``'s payload when its chunk is uncompressed, else None."""
        chunk = self.chunks[int(table.chunk[i])]
        if chunk.compression:
            return None
        return chunk.records_offset + int(table.record_offset[i]) + MESSAGE_HEADER.size

    # ----------------------------------------------------------------- whole-file check
    def verify_file(self) -> list[str]:
        """Every integrity problem: data-section CRC, each chunk's CRC, and each chunk's decoding.

        The summary CRC was checked when the reader was opened. Returns one line per problem,
        each naming the file and the byte offset.
        """
        problems: list[str] = []
        data = memoryview(self._data())
        data_end = self.summary_start - DATA_END.size
        opcode, length, data_crc = DATA_END.unpack_from(data, data_end)
        if opcode != Opcode.DATA_END or length != 4:
            problems.append(str(self.error(data_end, f"expected a DataEnd record before the summary, got opcode "
                                           f"0x{opcode:02x} length {length}")))
        else:
            computed = crc32(data[:data_end])
            if data_crc == 0 or computed != data_crc:
                problems.append(str(self.error(data_end, f"data-section CRC mismatch: DataEnd says 0x{data_crc:08x}, "
                                               f"bytes 0..{data_end} give 0x{computed:08x}")))
        for chunk_i in range(len(self.chunks)):
            try:
                self.verify_chunk(chunk_i)
            except InputError as error:
                problems.append(str(error))
        return problems

    def verify_chunk(self, chunk_i: int) -> None:
        """Checks chunk ``chunk_i``'s header, decompression and CRC now (raises InputError)."""
        verify, self.verify = self.verify, True
        self._verified.discard(chunk_i)
        self._views.pop(chunk_i, None)
        if self._chunk_cache is not None and self._chunk_cache[0] == chunk_i:
            self._chunk_cache = None
        try:
            self.chunk_records(chunk_i)
        finally:
            self.verify = verify
