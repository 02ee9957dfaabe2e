"""The MCAP reader: random access through the summary and the message indexes, over a memory mapping."""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from avdata.errors import InputError
from avdata.schema.mcap.checksum import crc32
from avdata.schema.mcap.chunk_index import ChannelInfo, ChunkInfo, MessageTable
from avdata.schema.mcap.compression import decompress
from avdata.schema.mcap.fileio import ByteSource, MappedFile
from avdata.schema.mcap.records import (
    CHUNK_HEADER,
    COMPRESSIONS,
    DATA_END,
    FOOTER,
    MAGIC,
    MESSAGE_HEADER,
    MESSAGE_INDEX_ENTRY,
    RECORD_PREFIX,
    ChannelRecord,
    ChunkIndexRecord,
    MetadataIndexRecord,
    MetadataRecord,
    Opcode,
    RecordError,
    RecordT,
    SchemaRecord,
    decode_record,
)

#: Bytes read from the end of a file when opening it: the footer, and the summary of most scenes.
_TAIL_BYTES: Final = 64 << 10
#: The first chunk read, if it starts this close to the file start, is fetched from byte 0 (the first magic).
_HEAD_WITH_CHUNK_BYTES: Final = 64 << 10
#: Chunks up to this size (the writer's chunks of small messages) are fetched whole when their index is needed.
_SMALL_CHUNK_BYTES: Final = 2 << 20
#: The data-section CRC is computed over blocks of this size (an object is not fetched whole).
_CRC_BLOCK_BYTES: Final = 64 << 20


class McapReader:
    """Random access into an MCAP file written by :class:`McapWriter`, through its summary and indexes.

    Opening checks both magics and the summary CRC, and parses the summary (schemas, channels, chunk
    indexes, metadata indexes). Message indexes are read on first use of :meth:`tables` / :meth:`table`,
    or chunk by chunk by :meth:`find`. A local file is mapped: message payloads of uncompressed chunks are
    zero-copy read-only views into the mapping, and views outlive :meth:`close` safely (the mapping is
    released when the last one goes). An object in a store (a :class:`~avdata.schema.mcap.fileio.RangedFile`)
    is read by ranged requests: the end of the file (footer and summary) when opening, then each chunk
    together with its message index in one request when a message in it is first read; its first magic is
    compared when the first chunk is read, with that chunk's request.

    Args:
        path: the ``.mcap`` file, or the source of its bytes.
        verify: check each chunk's CRC the first time one of its messages is read.

    Raises:
        InputError: the file is missing, truncated, damaged or has no summary.
    """

    def __init__(self, path: str | Path | ByteSource, *, verify: bool = False):
        self._source: ByteSource = MappedFile(Path(path)) if isinstance(path, str | Path) else path
        self.path: str | Path = self._source.path if isinstance(self._source, MappedFile) else self._source.name
        self.verify = verify
        self._verified: set[int] = set()
        self._views: dict[int, memoryview] = {}  # checked uncompressed chunks' records (local files)
        self._views_pid = os.getpid()
        self._chunk_cache: tuple[int, bytes] | None = None
        self._tables: dict[str, MessageTable] | None = None
        self._topic_tables: dict[str, MessageTable] = {}
        self._located: dict[str, dict[int, tuple[int, int]]] = {}  # topic -> time -> (chunk, record offset)
        self._chunk_messages: dict[int, dict[int, list[tuple[int, int]]]] = {}
        self._size = self._source.size
        minimum = 2 * len(MAGIC) + FOOTER.size
        if self._size < minimum:
            head = self._source.head(len(MAGIC)) if isinstance(self._source, MappedFile) else \
                bytes(self._source.view(0, min(self._size, len(MAGIC))))
            what = "truncated MCAP file" if MAGIC.startswith(head) else "not an MCAP file (bad magic bytes at byte 0)"
            raise InputError(f"{self.path}: {what} ({self._size} bytes, expected at least {minimum})")
        # An object's first magic costs a request of its own here: it is compared with the first chunk read.
        self._head_checked = False
        if self._source.local:
            self._check_head()
        tail_start = max(0, self._size - _TAIL_BYTES)
        self._source.hold([(tail_start, self._size - tail_start)])
        if bytes(self._source.view(self._size - len(MAGIC), len(MAGIC))) != MAGIC:
            raise InputError(f"{self.path}: truncated MCAP file (no closing magic; an interrupted write?)")
        self.footer_offset = self._size - len(MAGIC) - FOOTER.size
        opcode, length, summary_start, summary_offset_start, summary_crc = FOOTER.unpack_from(
            self._source.view(self.footer_offset, FOOTER.size))
        if opcode != Opcode.FOOTER or length != FOOTER.size - RECORD_PREFIX.size:
            raise self.error(self.footer_offset, f"expected a Footer record, got opcode 0x{opcode:02x} length {length}")
        if not len(MAGIC) < summary_start <= summary_offset_start <= self.footer_offset:
            raise self.error(self.footer_offset, f"summary start {summary_start} / summary offset start "
                             f"{summary_offset_start} outside the file (footer at {self.footer_offset})")
        if summary_start < tail_start:
            # The metadata records are written just before the summary: fetch them with it.
            start = max(0, summary_start - _TAIL_BYTES)
            self._source.hold([(start, self._size - start)])
        computed = crc32(self._source.view(summary_start, self.footer_offset + FOOTER.size - 4 - summary_start))
        if computed != summary_crc:
            raise self.error(self.footer_offset, f"summary CRC mismatch: footer says 0x{summary_crc:08x}, "
                             f"bytes {summary_start}..{self.footer_offset + FOOTER.size - 4} give 0x{computed:08x}")
        self.summary_start = summary_start
        self._parse_summary(summary_start, summary_offset_start)

    # ----------------------------------------------------------------- errors and bytes
    def error(self, offset: int, message: str) -> InputError:
        """An InputError naming this file, the byte offset and what is wrong there."""
        return InputError(f"{self.path}: byte {offset}: {message}")

    @property
    def local(self) -> bool:
        """True for a local file (mapped), False for an object read by ranged requests."""
        return self._source.local

    def _check_head(self) -> None:
        if bytes(self._source.view(0, len(MAGIC))) != MAGIC:
            raise InputError(f"{self.path}: not an MCAP file (bad magic bytes at byte 0)")
        self._head_checked = True

    def read_into(self, offset: int, target: memoryview) -> None:
        """Fills ``target`` with the file's bytes from ``offset`` on (one ``preadv`` for a local file, no intermediate copy)."""
        self._source.read_into(offset, target)

    def close(self) -> None:
        """Drops the mapping (or the fetched ranges); numpy views handed out keep their bytes until they are gone."""
        self._views = {}
        self._source.close()
        self._chunk_cache = None

    def __getstate__(self) -> dict[str, Any]:
        state = {name: getattr(self, name) for name in self.__dict__}
        state.update(_chunk_cache=None, _views={})
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    # ----------------------------------------------------------------- summary
    def _records(self, start: int, end: int) -> Iterator[tuple[int, int, memoryview]]:
        """(offset, opcode, body) of each record between two file offsets."""
        data = self._source.view(start, end - start)
        position = start
        while position < end:
            if position + RECORD_PREFIX.size > end:
                raise self.error(position, f"record prefix runs past byte {end}")
            opcode, length = RECORD_PREFIX.unpack_from(data, position - start)
            body_start = position + RECORD_PREFIX.size
            if length > end - body_start:
                raise self.error(position, f"record 0x{opcode:02x} of {length} bytes runs past byte {end}")
            yield position, opcode, data[body_start - start : body_start - start + length]
            position = body_start + length

    def _decode(self, offset: int, record_type: type[RecordT], body: memoryview) -> RecordT:
        try:
            return decode_record(record_type, body)
        except RecordError as error:
            raise self.error(offset, str(error)) from error

    def _parse_summary(self, start: int, end: int) -> None:
        schemas: dict[int, SchemaRecord] = {}
        channels: dict[int, ChannelRecord] = {}
        self.chunks: list[ChunkInfo] = []
        self.metadata_offsets: dict[str, tuple[int, int]] = {}
        for offset, opcode, body in self._records(start, end):
            if opcode == Opcode.SCHEMA:
                schema = self._decode(offset, SchemaRecord, body)
                schemas[schema.id] = schema
            elif opcode == Opcode.CHANNEL:
                channel = self._decode(offset, ChannelRecord, body)
                channels[channel.id] = channel
            elif opcode == Opcode.CHUNK_INDEX:
                index = self._decode(offset, ChunkIndexRecord, body)
                chunk = ChunkInfo(
                    start_ns=index.message_start_time, end_ns=index.message_end_time,
                    offset=index.chunk_start_offset, length=index.chunk_length,
                    message_index_offsets=index.message_index_offsets,
                    message_index_length=index.message_index_length, compression=index.compression,
                    compressed_size=index.compressed_size, uncompressed_size=index.uncompressed_size)
                self._check_chunk_index(offset, chunk)
                self.chunks.append(chunk)
            elif opcode == Opcode.METADATA_INDEX:
                located = self._decode(offset, MetadataIndexRecord, body)
                if not len(MAGIC) <= located.offset <= self.summary_start - located.length:
                    raise self.error(offset, f"metadata index points outside the data section: {located.offset}")
                self.metadata_offsets[located.name] = (located.offset, located.length)
        self.chunks.sort(key=lambda c: c.offset)
        self.channels: dict[int, ChannelInfo] = {}
        for channel_id, channel in channels.items():
            if channel.schema_id not in schemas:
                raise InputError(f"{self.path}: channel {channel.topic!r} refers to schema {channel.schema_id}, "
                                 f"which the summary does not hold")
            self.channels[channel_id] = ChannelInfo(
                id=channel_id, topic=channel.topic, message_encoding=channel.message_encoding,
                schema_id=channel.schema_id, schema_name=schemas[channel.schema_id].name,
                schema_encoding=schemas[channel.schema_id].encoding)
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
        if length < RECORD_PREFIX.size:
            raise self.error(offset, f"metadata index gives a record of {length} bytes, shorter than a record prefix")
        data = self._source.view(offset, length)
        opcode, body_length = RECORD_PREFIX.unpack_from(data)
        if opcode != Opcode.METADATA or body_length != length - RECORD_PREFIX.size:
            raise self.error(offset, f"metadata index points at a record 0x{opcode:02x} of {body_length} bytes, "
                             f"expected a Metadata record of {length - RECORD_PREFIX.size}")
        record = self._decode(offset, MetadataRecord, data[RECORD_PREFIX.size :])
        if record.name != name:
            raise self.error(offset, f"metadata record is named {record.name!r}, its index says {name!r}")
        return dict(record.metadata)

    # ----------------------------------------------------------------- message indexes
    def tables(self) -> dict[str, MessageTable]:
        """Topic -> positions of its messages, from the message indexes after each chunk (read once).

        An object in a store fetches every chunk's message index for this (in parallel requests): readers of
        single messages use :meth:`find` and :meth:`table` instead.
        """
        if self._tables is None:
            self._tables = self._message_tables(range(len(self.chunks)))
        return self._tables

    def table(self, topic: str) -> MessageTable | None:
        """Positions of the messages on ``topic`` (None if it has none), read from the chunks that hold the topic."""
        if self._tables is not None or self._source.local:
            return self.tables().get(topic)
        if topic not in self._topic_tables:
            channel = self.channel_of_topic(topic)
            chunks = [] if channel is None else self._chunks_of_channel(channel.id)
            table = self._message_tables(chunks, only=channel.id if channel is not None else None).get(topic)
            if table is None:
                return None
            self._topic_tables[topic] = table
        return self._topic_tables[topic]

    def topics(self) -> list[str]:
        """Every topic with at least one message, sorted (from the summary alone for an object in a store)."""
        if self._tables is not None or self._source.local:
            return sorted(self.tables())
        self._check_index_channels(range(len(self.chunks)))
        return sorted({self.channels[channel_id].topic for chunk in self.chunks
                       for channel_id in chunk.message_index_offsets})

    def find(self, topic: str, time_ns: int) -> tuple[int, int] | None:
        """(chunk, record offset) of the first message on ``topic`` logged at ``time_ns``, or None.

        Through the tables when they are read; else (an object in a store) through the chunk index: only the
        chunks whose time range holds ``time_ns`` are read, each with its message index in one request.
        """
        located = self._located.get(topic)
        if located is None and (self._tables is not None or self._source.local):
            table = self.tables().get(topic)
            # time -> first message with it; built reversed so the first of equal times wins.
            located = self._located[topic] = {} if table is None else {
                time: (chunk_i, offset) for time, chunk_i, offset in zip(
                    table.log_time_ns[::-1].tolist(), table.chunk[::-1].tolist(), table.record_offset[::-1].tolist(),
                    strict=True)}
        if located is not None:
            return located.get(time_ns)
        channel = self.channel_of_topic(topic)
        if channel is None:
            return None
        for chunk_i in self._chunks_of_channel(channel.id, time_ns):
            self._hold_chunk(chunk_i)
            offsets = [offset for log_time, offset in self._messages_of_chunk(chunk_i).get(channel.id, [])
                       if log_time == time_ns]
            if offsets:
                return chunk_i, min(offsets)
        return None

    def prefetch(self, wanted: Iterable[tuple[str, int]]) -> None:
        """Fetches the chunks holding the messages on these (topic, time) in parallel requests (an object in a store).

        What :meth:`find` would fetch one chunk after another; a local file needs nothing.
        """
        if self._source.local:
            return
        ranges: list[tuple[int, int]] = []
        for topic, time_ns in wanted:
            channel = self.channel_of_topic(topic)
            if channel is not None:
                ranges.extend(self._chunk_range(i) for i in self._chunks_of_channel(channel.id, time_ns))
        self._source.hold(ranges)

    def _chunks_of_channel(self, channel_id: int, time_ns: int | None = None) -> list[int]:
        """The chunks holding messages of a channel (whose time range holds ``time_ns``, if given), in file order."""
        return [i for i, chunk in enumerate(self.chunks) if channel_id in chunk.message_index_offsets
                and (time_ns is None or chunk.start_ns <= time_ns <= chunk.end_ns)]

    def _check_index_channels(self, chunks: Iterable[int]) -> None:
        for chunk_i in chunks:
            chunk = self.chunks[chunk_i]
            index_start = chunk.offset + chunk.length
            index_end = index_start + chunk.message_index_length
            for channel_id, offset in chunk.message_index_offsets.items():
                if channel_id not in self.channels or not index_start <= offset < index_end:
                    raise self.error(chunk.offset, f"chunk index: message index of channel {channel_id} at byte "
                                     f"{offset}, outside {index_start}..{index_end} or of an unknown channel")

    def _message_tables(self, chunks: Sequence[int] | range, only: int | None = None) -> dict[str, MessageTable]:
        """Topic -> its message table, from the message indexes of ``chunks`` (of channel ``only``, if given)."""
        if not self._source.local:
            # A chunk of small messages comes whole with its index (its messages are read next, and the next
            # frames' are in it), a chunk of one large message only its index.
            self._source.hold([self._chunk_range(i) if self.chunks[i].length <= _SMALL_CHUNK_BYTES
                               else (self.chunks[i].offset + self.chunks[i].length, self.chunks[i].message_index_length)
                               for i in chunks if i not in self._chunk_messages], keep=True)
        # channel -> rows of (log_time, chunk number, record offset); plain tuples because most
        # chunks hold one large message and numpy's per-call cost would dominate opening a scene.
        per_channel: dict[int, list[tuple[int, int, int]]] = {}
        for chunk_i in chunks:
            # A local file's tables are built once: its chunks' parsed indexes need not stay in memory as well.
            for channel_id, entries in self._messages_of_chunk(chunk_i, keep=not self._source.local).items():
                if only is None or channel_id == only:
                    per_channel.setdefault(channel_id, []).extend(
                        (log_time, chunk_i, offset) for log_time, offset in entries)
        tables: dict[str, MessageTable] = {}
        for channel_id, channel_rows in per_channel.items():
            if not channel_rows:
                continue
            table = np.array(channel_rows, dtype=np.int64)
            table = table[np.lexsort((table[:, 2], table[:, 1], table[:, 0]))]
            tables[self.channels[channel_id].topic] = MessageTable(
                log_time_ns=table[:, 0].copy(), chunk=table[:, 1].copy(), record_offset=table[:, 2].copy())
        return tables

    def _messages_of_chunk(self, chunk_i: int, keep: bool = True) -> dict[int, list[tuple[int, int]]]:
        """Channel -> (log time, record offset) of each of its messages in chunk ``chunk_i``, from its message index (checked).

        ``keep``: remember them (an object's chunks are looked up again by :meth:`find` and :meth:`table`).
        """
        messages = self._chunk_messages.get(chunk_i)
        if messages is not None:
            return messages
        chunk = self.chunks[chunk_i]
        self._check_index_channels([chunk_i])
        index_start = chunk.offset + chunk.length
        messages = {}
        for offset, opcode, body in self._records(index_start, index_start + chunk.message_index_length):
            if opcode != Opcode.MESSAGE_INDEX or len(body) < 6:
                raise self.error(offset, f"expected a MessageIndex record, got opcode 0x{opcode:02x}")
            channel_id, array_bytes = struct.unpack_from("<HI", body)
            if channel_id not in self.channels or array_bytes != len(body) - 6 or array_bytes % 16:
                raise self.error(offset, f"message index of channel {channel_id} with {array_bytes} bytes "
                                 f"of entries in a {len(body)}-byte record")
            rows = messages.setdefault(channel_id, [])
            for entry in MESSAGE_INDEX_ENTRY.iter_unpack(body[6:]):
                log_time, record_offset = entry
                if record_offset + MESSAGE_HEADER.size > chunk.uncompressed_size:
                    raise self.error(offset, f"message index entry at record offset {record_offset}, past the "
                                     f"chunk's {chunk.uncompressed_size} bytes")
                if not chunk.start_ns <= log_time <= chunk.end_ns:
                    raise self.error(offset, f"message index entry at {log_time} ns, outside the chunk's "
                                     f"{chunk.start_ns}..{chunk.end_ns} ns")
                rows.append(entry)
        if keep:
            self._chunk_messages[chunk_i] = messages
        return messages

    def channel_of_topic(self, topic: str) -> ChannelInfo | None:
        """The channel of ``topic``, or None."""
        for channel in self.channels.values():
            if channel.topic == topic:
                return channel
        return None

    # ----------------------------------------------------------------- messages
    def _hold_chunk(self, chunk_i: int) -> None:
        """Fetches chunk ``chunk_i`` with its message index in one request (an object in a store; else nothing).

        The first chunk read also fetches the bytes before it, to compare the first magic without a request
        of its own.
        """
        if not self._source.local:
            self._source.hold([self._chunk_range(chunk_i)])

    def _chunk_range(self, chunk_i: int) -> tuple[int, int]:
        """(offset, length) of chunk ``chunk_i`` and its message index, from byte 0 while the first magic is unchecked."""
        chunk = self.chunks[chunk_i]
        start = 0 if not self._head_checked and chunk.offset <= _HEAD_WITH_CHUNK_BYTES else chunk.offset
        return start, chunk.offset + chunk.length + chunk.message_index_length - start

    def chunk_records(self, chunk_i: int) -> memoryview:
        """The uncompressed records of chunk ``chunk_i``: a view of the file's bytes, or the decompressed bytes.

        The chunk record's header is checked against the chunk index once; with ``verify`` its
        CRC too (once per chunk).
        """
        if self._views_pid != os.getpid():  # a forked copy: views of the parent's mapping are not this process's
            self._views, self._views_pid = {}, os.getpid()
        view = self._views.get(chunk_i)
        if view is not None:
            return view
        if self._chunk_cache is not None and self._chunk_cache[0] == chunk_i:
            return memoryview(self._chunk_cache[1])
        chunk = self.chunks[chunk_i]
        self._hold_chunk(chunk_i)
        if not self._head_checked:
            self._check_head()
        data = self._source.view(chunk.offset, chunk.length)
        opcode, length, start, end, uncompressed_size, crc = CHUNK_HEADER.unpack_from(data)
        (compression_length,) = struct.unpack_from("<I", data, CHUNK_HEADER.size)
        compression = bytes(data[CHUNK_HEADER.size + 4 : CHUNK_HEADER.size + 4 + compression_length])
        records_at = chunk.records_offset - chunk.offset
        (records_length,) = struct.unpack_from("<Q", data, records_at - 8)
        if (opcode != Opcode.CHUNK or length != chunk.length - RECORD_PREFIX.size
                or (start, end) != (chunk.start_ns, chunk.end_ns) or uncompressed_size != chunk.uncompressed_size
                or compression != chunk.compression.encode()
                or records_length != chunk.compressed_size):
            raise self.error(chunk.offset, "chunk record header disagrees with the summary's chunk index "
                             f"(opcode 0x{opcode:02x}, length {length}, times {start}..{end}, "
                             f"{records_length} -> {uncompressed_size} bytes, compression {compression!r})")
        raw = data[records_at : records_at + chunk.compressed_size]
        if chunk.compression:
            try:
                records = decompress(chunk.compression, raw, chunk.uncompressed_size)
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
        elif self._source.local:
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
        return self.read_message(int(table.chunk[i]), int(table.record_offset[i]), channel_id,
                                 int(table.log_time_ns[i]))

    def read_message(self, chunk_i: int, offset: int, channel_id: int, log_time_ns: int) -> memoryview:
        """The payload of the message at record ``offset`` of chunk ``chunk_i``, checked to be of the channel and time."""
        records = self.chunk_records(chunk_i)
        opcode, length, channel, _, log_time, _ = MESSAGE_HEADER.unpack_from(records, offset)
        end = offset + RECORD_PREFIX.size + length
        if (opcode != Opcode.MESSAGE or channel != channel_id or log_time != log_time_ns
                or length < MESSAGE_HEADER.size - RECORD_PREFIX.size or end > len(records)):
            raise self.error(self.chunks[chunk_i].offset, f"message index entry at record offset {offset} points at "
                             f"opcode 0x{opcode:02x}, channel {channel}, time {log_time} ns, length {length}; "
                             f"expected a message of channel {channel_id} at {log_time_ns} ns")
        return records[offset + MESSAGE_HEADER.size : end]

    def payload_file_offset(self, chunk_i: int, record_offset: int) -> int | None:
        """The file offset of the payload of the message at ``record_offset`` of an uncompressed chunk, else None."""
        chunk = self.chunks[chunk_i]
        if chunk.compression:
            return None
        return chunk.records_offset + record_offset + MESSAGE_HEADER.size

    # ----------------------------------------------------------------- whole-file check
    def verify_file(self) -> list[str]:
        """Every integrity problem: data-section CRC, each chunk's CRC, and each chunk's decoding.

        The summary CRC was checked when the reader was opened. Returns one line per problem,
        each naming the file and the byte offset. An object in a store is read once for the
        data-section CRC, a block at a time, and once more chunk by chunk.
        """
        problems: list[str] = []
        if not self._head_checked:
            try:
                self._check_head()
            except InputError as error:
                problems.append(str(error))
        data_end = self.summary_start - DATA_END.size
        opcode, length, data_crc = DATA_END.unpack_from(self._source.view(data_end, DATA_END.size))
        if opcode != Opcode.DATA_END or length != 4:
            problems.append(str(self.error(data_end, f"expected a DataEnd record before the summary, got opcode "
                                           f"0x{opcode:02x} length {length}")))
        else:
            computed = 0
            for block_start in range(0, data_end, _CRC_BLOCK_BYTES):
                block_length = min(_CRC_BLOCK_BYTES, data_end - block_start)
                computed = crc32(self._source.view(block_start, block_length), computed)
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
