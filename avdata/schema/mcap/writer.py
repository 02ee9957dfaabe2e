"""The MCAP writer: chunks of small messages, a chunk of its own per large one, every byte checksummed once."""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence
from types import TracebackType
from typing import BinaryIO, Final

from avdata.errors import InputError
from avdata.schema.mcap.checksum import crc32, crc32_combine
from avdata.schema.mcap.chunk_index import (
    ChunkMessages,
    chunk_index_record,
    message_index_records,
    one_message_indexes,
)
from avdata.schema.mcap.compression import compress
from avdata.schema.mcap.fileio import CacheRelease, Reservation, WrittenBytes, by_reference, immutable, write_all
from avdata.schema.mcap.records import (
    CHUNK_HEADER,
    COMPRESSIONS,
    DATA_END,
    FOOTER,
    MAGIC,
    MESSAGE_HEADER,
    RECORD_PREFIX,
    Buffer,
    ChannelRecord,
    HeaderRecord,
    MetadataIndexRecord,
    MetadataRecord,
    Opcode,
    SchemaRecord,
    StatisticsRecord,
    SummaryOffsetRecord,
    encode_record,
    sized,
)

#: Queued small records are written once they reach this many bytes or this many buffers.
_FLUSH_BYTES: Final = 1 << 20
_MAX_QUEUED: Final = 256


class McapWriter:
    """Writes an indexed, fully checksummed MCAP file to an open binary file; a context manager.

    Large messages (at least ``large_message_bytes``) get a chunk of their own, written straight
    from the caller's buffers without a copy; small ones are batched into chunks of about
    ``chunk_size`` bytes, copied, except parts of 16 kB or more in memory nobody can change (bytes
    and views of bytes, such as a file's contents), which the chunk keeps by reference. The
    ``with`` block ends with :meth:`finish` (summary and footer) unless it raised.

    Writing goes straight to the file descriptor with ``os.writev``: the small records written
    since the last large message are queued and go out in the same system call as the next large
    chunk, so a large message costs one ``writev``; one in bytes nobody can change (an image read
    from its file) waits in the queue too, up to 1 MB queued. The stream's own buffer is never used.

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
        self._compression_field = sized(compression.encode())
        # A Chunk record up to its records: CHUNK_HEADER's fields, the compression field, the records' byte length.
        self._chunk_head_layout = struct.Struct(f"{CHUNK_HEADER.format}{len(self._compression_field)}sQ")
        self._chunk_size = chunk_size
        self._large = large_message_bytes
        self._schema_records: list[bytes] = []
        self._channel_records: list[bytes] = []
        self._chunk_indexes: list[bytes] = []
        self._metadata_indexes: list[MetadataIndexRecord] = []
        self._message_counts: dict[int, int] = {}
        self._start_time: int | None = None
        self._end_time = 0
        # The open chunk's records: ``_segments`` (``_segments_bytes`` in all), then ``_records``.
        self._segments: list[Buffer] = []
        self._segments_bytes = 0
        self._records = bytearray()
        self._index: ChunkMessages = {}
        self._chunk_times: tuple[int, int] | None = None
        self._position = 0
        self._data_crc = 0
        self._pending: list[Buffer] = []
        self._pending_bytes = 0
        self._reservation = Reservation(self._fd)
        self._cache_release = CacheRelease(self._fd, written or WrittenBytes())
        self._finished = False
        #: Called once before the first chunk is written; the messages it adds go first in the file,
        #: ahead of those already buffered (avdata writes /tf_static there).
        self.before_first_chunk: Callable[[], None] | None = None
        self._write(MAGIC)
        self._write(encode_record(HeaderRecord(profile="", library=library)))

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
        write_all(self._fd, [*self._pending, *large] if large else self._pending, self._pending_bytes + large_bytes)
        self._cache_release.after_write(self._pending_bytes + large_bytes)
        self._pending = []
        self._pending_bytes = 0

    # ----------------------------------------------------------------- API
    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Adds a schema record; returns its id (1, 2, ...)."""
        schema_id = len(self._schema_records) + 1
        record = encode_record(SchemaRecord(id=schema_id, name=name, encoding=encoding, data=data))
        self._schema_records.append(record)
        self._write(record)
        return schema_id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int) -> int:
        """Adds a channel record; returns its id (0, 1, ...)."""
        channel_id = len(self._channel_records)
        record = encode_record(ChannelRecord(id=channel_id, schema_id=schema_id, topic=topic,
                                             message_encoding=message_encoding, metadata={}))
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
            self._finish_chunk()
            self._large_chunk(channel_id, log_time, header, parts, size)
            return
        self._index.setdefault(channel_id, []).append((log_time, self._segments_bytes + len(self._records)))
        self._records += header
        for part in parts:
            kept = by_reference(part)
            if kept is None:
                self._records += part
            else:
                # A camera image or a scan read from its file: kept by reference until the chunk is written.
                # Copying it into the chunk would be a second pass over every image and scan's bytes.
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
        blob = encode_record(MetadataRecord(name=name, metadata=dict(data)))
        self._write(blob)
        self._metadata_indexes.append(MetadataIndexRecord(offset=offset, length=len(blob), name=name))

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
                offsets.append(encode_record(SummaryOffsetRecord(
                    group_opcode=opcode, group_start=summary_start + len(summary),
                    group_length=sum(len(r) for r in records))))
                summary.extend(b"".join(records))

        statistics = StatisticsRecord(
            message_count=sum(self._message_counts.values()),
            schema_count=len(self._schema_records),
            channel_count=len(self._channel_records),
            attachment_count=0,
            metadata_count=len(self._metadata_indexes),
            chunk_count=len(self._chunk_indexes),
            message_start_time=self._start_time or 0,
            message_end_time=self._end_time,
            channel_message_counts=dict(self._message_counts),
        )
        group(Opcode.SCHEMA, self._schema_records)
        group(Opcode.CHANNEL, self._channel_records)
        group(Opcode.STATISTICS, [encode_record(statistics)])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.METADATA_INDEX, [encode_record(m) for m in self._metadata_indexes])
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
                          index: ChunkMessages) -> None:
        """Writes one chunk whose records are the concatenation of ``segments`` (``size`` bytes)."""
        records_crc = 0
        for segment in segments:
            records_crc = crc32(segment, records_crc)
        if self._compression:
            compressed = compress(self._compression, b"".join(segments))
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
        layout = self._chunk_head_layout
        return layout.pack(Opcode.CHUNK, layout.size - RECORD_PREFIX.size + payload_size, start, end, uncompressed_size,
                           crc, self._compression_field, payload_size)

    def _large_chunk(self, channel_id: int, log_time: int, header: bytes, parts: Sequence[Buffer], size: int) -> None:
        if self._compression:
            self._compressed_chunk([b"".join([header, *(bytes(p) for p in parts)])], len(header) + size, log_time,
                                   log_time, {channel_id: [(log_time, 0)]})
            return
        # Uncompressed: the payload goes from the caller's buffers to the file without a copy, in
        # the same writev as the records queued before it. Its CRC is computed first: that pass
        # also brings the payload into the CPU cache for the copy the writev makes, and the chunk
        # header goes out complete. Computed after the writev instead, the CRC costs as much and its
        # header field one pwrite per message; in L2-sized pieces, each checksummed just before its
        # own write, the extra system calls cost more than the cache saves. The data-section CRC is
        # chained from the chunk's CRC, so every byte is checksummed once.
        payload = [p if isinstance(p, (bytes, bytearray)) else memoryview(p).cast("B") for p in parts]
        records_size = len(header) + size
        chunk_crc = crc32(header)
        for part in payload:
            chunk_crc = crc32(part, chunk_crc)
        head = self._chunk_head(records_size, records_size, chunk_crc, log_time, log_time)
        chunk_start = self._position
        chunk_length = len(head) + records_size
        data_crc = crc32_combine(crc32(head, self._data_crc), chunk_crc, records_size)
        if all(map(immutable, parts)):
            # Bytes nobody can change (an image read from its file): queued, they go out in the next
            # writev, with the next large message (one writev per frame of a cloud and an image).
            self._queue([head, header, *payload], chunk_length, data_crc)
        else:
            self._flush([head, header, *payload], chunk_length)
            self._data_crc = data_crc
            self._position += chunk_length
        message_index, chunk_index = one_message_indexes(
            channel_id=channel_id, log_time=log_time, chunk_start=chunk_start, chunk_length=chunk_length,
            position=self._position, compression_field=self._compression_field, payload_size=records_size,
            uncompressed_size=records_size)
        self._write(message_index)
        self._chunk_indexes.append(chunk_index)

    def _chunk_end(self, chunk_start: int, start: int, end: int, payload_size: int, uncompressed_size: int,
                   index: ChunkMessages) -> None:
        """Queues the chunk's message indexes and remembers its chunk index record."""
        chunk_length = self._position - chunk_start
        message_index, offsets = message_index_records(index, self._position)
        self._write(message_index)
        self._chunk_indexes.append(chunk_index_record(
            start=start, end=end, chunk_start=chunk_start, chunk_length=chunk_length, offsets=offsets,
            message_index_length=len(message_index), compression_field=self._compression_field,
            payload_size=payload_size, uncompressed_size=uncompressed_size))
