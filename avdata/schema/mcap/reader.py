"""The MCAP reader: random access through the summary and the message indexes, over a memory mapping."""

from __future__ import annotations

import mmap
import os
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from avdata.errors import InputError, one_line
from avdata.schema.mcap.checksum import crc32
from avdata.schema.mcap.chunk_index import ChannelInfo, ChunkInfo, MessageTable
from avdata.schema.mcap.compression import decompress
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
        data = memoryview(self._data())
        opcode, body_length = RECORD_PREFIX.unpack_from(data, offset)
        if opcode != Opcode.METADATA or body_length != length - RECORD_PREFIX.size:
            raise self.error(offset, f"metadata index points at a record 0x{opcode:02x} of {body_length} bytes, "
                             f"expected a Metadata record of {length - RECORD_PREFIX.size}")
        record = self._decode(offset, MetadataRecord, data[offset + RECORD_PREFIX.size : offset + length])
        if record.name != name:
            raise self.error(offset, f"metadata record is named {record.name!r}, its index says {name!r}")
        return dict(record.metadata)

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
