"""Random access into one scene's MCAP file through its summary and message indexes.

Opening a scene reads only the MCAP summary (schemas, channels, chunk indexes, metadata index)
and the message-index records after each chunk; that gives every message's log time and byte
position. A message is then one ``pread`` (uncompressed chunks) or one chunk decompression
(zstd/lz4), never a scan of the file. Reads are positional, so one reader can be shared by threads;
each process (e.g. a DataLoader worker) opens its own file handle on first use.
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Metadata
from mcap.stream_reader import StreamReader

from avdata.errors import AvdataError, InputError
from avdata.frames import FrameGraph, Transform
from avdata.schema import topics
from avdata.schema.mcap_file import split_bytes_field
from avdata.schema.protos import ObjectLabelsMsg, VisibilityLabelsMsg
from avdata.schema.records import FrameInfo, ObjectLabels, VisibilityLabels, decode_object_labels, decode_visibility
from avdata.schema.scene_writer import NUMERIC_TYPES

_MAGIC = b"\x89MCAP0\r\n"
_OPCODE_MESSAGE_INDEX = 0x07
#: Message record: opcode(1) length(8) channel(2) sequence(4) log_time(8) publish_time(8) data.
_MESSAGE_DATA_SKIP = 1 + 8 + 2 + 4 + 8 + 8
_POINTS_DATA_FIELD = PointCloud.DESCRIPTOR.fields_by_name["data"].number
_NUMPY_OF_FOXGLOVE = {code: dtype for dtype, code in NUMERIC_TYPES.items()}


@dataclass(frozen=True, slots=True, kw_only=True)
class MessageTable:
    """Where each message of one topic lies: arrays sorted by log time (length M).

    ``data_offset`` is the absolute file offset of the message payload for uncompressed chunks; for
    compressed chunks it is the offset inside the decompressed chunk records, and
    ``chunk_index`` says which chunk to decompress.
    """

    log_time_ns: np.ndarray
    data_offset: np.ndarray
    data_length: np.ndarray
    chunk_index: np.ndarray


class SceneReader:
    """Reads one scene file: metadata, frame graph, sensor messages and labels.

    Args:
        path: the scene's ``.mcap`` file.

    Raises:
        InputError: the file is missing, truncated, corrupted or not an avdata scene.
        FormatVersionError: the scene was written by a newer major format version.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(f"{self.path}: scene file does not exist")
        self._fd_pid: tuple[int, int] | None = None
        try:
            with open(self.path, "rb") as stream:
                if stream.read(8) != _MAGIC:
                    raise InputError(f"{self.path}: not an MCAP file (bad magic bytes)")
                stream.seek(-8, os.SEEK_END)
                if stream.read(8) != _MAGIC:
                    raise InputError(f"{self.path}: truncated MCAP file (no footer magic; was the write interrupted?)")
                stream.seek(0)
                reader = SeekingReader(stream)
                summary = reader.get_summary()
                if summary is None:
                    raise InputError(f"{self.path}: MCAP file has no summary section (not written by avdata?)")
                # The summary's metadata index points at the record; reader.iter_metadata() would parse
                # the whole summary a second time.
                metadata = []
                for index in summary.metadata_indexes:
                    stream.seek(index.offset)
                    record = next(StreamReader(stream, skip_magic=True).records)
                    if not isinstance(record, Metadata):
                        raise InputError(f"{self.path}: metadata index points at a {type(record).__name__} record")
                    metadata.append(record)
        except (McapError, struct.error, ValueError, OSError, EOFError) as error:
            raise InputError(f"{self.path}: corrupted MCAP file ({error})") from error
        self._summary = summary
        scene_meta = [m for m in metadata if m.name == topics.SCENE_METADATA]
        if not scene_meta:
            raise InputError(f"{self.path}: missing '{topics.SCENE_METADATA}' metadata record (not an avdata scene)")
        self.metadata: dict[str, Any] = json.loads(scene_meta[0].metadata["json"])
        topics.check_version(self.metadata.get("format_version", "0"), str(self.path))
        self.name: str = self.metadata["name"]
        self._chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        self._chunk_cache: tuple[int, bytes] | None = None
        self._tables = self._read_message_indexes()
        self._graph: FrameGraph | None = None
        self._visibility_rows: dict[str, dict[int, int]] = {}

    # ----------------------------------------------------------------- low level
    @property
    def topics(self) -> list[str]:
        """Every topic with at least one message, sorted."""
        return sorted(self._tables)

    def message_table(self, topic: str) -> MessageTable:
        """Positions of every message on ``topic``."""
        table = self._tables.get(topic)
        if table is None:
            raise AvdataError(f"scene {self.name!r}: no topic {topic}; topics: {', '.join(self.topics)}")
        return table

    def times(self, topic: str) -> np.ndarray:
        """(M,) log times of the messages on ``topic``, sorted."""
        return self.message_table(topic).log_time_ns

    def read_raw(self, topic: str, time_ns: int) -> bytes:
        """The serialized message on ``topic`` logged at exactly ``time_ns``."""
        table = self.message_table(topic)
        i = int(np.searchsorted(table.log_time_ns, time_ns))
        if i >= len(table.log_time_ns) or table.log_time_ns[i] != time_ns:
            raise AvdataError(
                f"scene {self.name!r}: no message on {topic} at {time_ns} ns "
                f"(has {len(table.log_time_ns)} from {table.log_time_ns[0]} to {table.log_time_ns[-1]} ns)"
            )
        return self._read_at(table, i)

    def iter_raw(self, topic: str) -> list[tuple[int, bytes]]:
        """Every (log_time_ns, serialized message) on ``topic`` in time order."""
        table = self.message_table(topic)
        return [(int(table.log_time_ns[i]), self._read_at(table, i)) for i in range(len(table.log_time_ns))]

    def _fd(self) -> int:
        pid = os.getpid()
        if self._fd_pid is None or self._fd_pid[1] != pid:
            self._fd_pid = (os.open(self.path, os.O_RDONLY), pid)
        return self._fd_pid[0]

    def close(self) -> None:
        """Closes this process's file handle (reopened on the next read)."""
        if self._fd_pid is not None and self._fd_pid[1] == os.getpid():
            os.close(self._fd_pid[0])
        self._fd_pid = None

    def __getstate__(self) -> dict[str, Any]:
        state = {slot: getattr(self, slot) for slot in self.__dict__}
        state["_fd_pid"] = None
        state["_chunk_cache"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def _read_at(self, table: MessageTable, i: int) -> bytes:
        chunk_i = int(table.chunk_index[i])
        offset, length = int(table.data_offset[i]), int(table.data_length[i])
        chunk = self._chunks[chunk_i]
        if chunk.compression == "":
            data = os.pread(self._fd(), length, offset)
            if len(data) != length:
                raise InputError(f"{self.path}: truncated message at byte {offset}")
            return data
        records = self._decompressed(chunk_i)
        return records[offset : offset + length]

    def _decompressed(self, chunk_i: int) -> bytes:
        if self._chunk_cache is None or self._chunk_cache[0] != chunk_i:
            self._chunk_cache = (chunk_i, self._decompress(self._fd(), chunk_i))
        return self._chunk_cache[1]

    def _decompress(self, fd: int, chunk_i: int) -> bytes:
        chunk = self._chunks[chunk_i]
        compressed = os.pread(fd, chunk.chunk_length, chunk.chunk_start_offset)[_records_start(chunk.compression) :]
        if chunk.compression == "zstd":
            import zstandard

            return zstandard.ZstdDecompressor().decompress(compressed, max_output_size=chunk.uncompressed_size)
        if chunk.compression == "lz4":
            import lz4.frame

            return lz4.frame.decompress(compressed)
        raise InputError(f"{self.path}: unsupported chunk compression {chunk.compression!r}")

    def _read_message_indexes(self) -> dict[str, MessageTable]:
        channel_topic = {cid: ch.topic for cid, ch in self._summary.channels.items()}
        # channel -> rows of (log_time, record offset, chunk number, record length); plain Python
        # tuples here because most chunks hold one large message and numpy's per-call cost would
        # dominate opening a scene.
        per_channel: dict[int, list[tuple[int, int, int, int]]] = {}
        fd = os.open(self.path, os.O_RDONLY)
        try:
            for chunk_i, chunk in enumerate(self._chunks):
                if not chunk.message_index_length:
                    raise InputError(f"{self.path}: chunk at byte {chunk.chunk_start_offset} has no message index")
                blob = os.pread(fd, chunk.message_index_length, chunk.chunk_start_offset + chunk.chunk_length)
                records = None if chunk.compression == "" else self._decompress(fd, chunk_i)
                base = chunk.chunk_start_offset + _records_start(chunk.compression) if records is None else 0
                position = 0
                while position < len(blob):
                    (length,) = struct.unpack_from("<Q", blob, position + 1)
                    if blob[position] == _OPCODE_MESSAGE_INDEX:
                        channel_id, array_bytes = struct.unpack_from("<HI", blob, position + 9)
                        rows = per_channel.setdefault(channel_id, [])
                        for log_time, offset in struct.iter_unpack("<QQ", blob[position + 15 : position + 15 + array_bytes]):
                            record = offset + base
                            header = os.pread(fd, 9, record) if records is None else records[offset : offset + 9]
                            rows.append((log_time, record, chunk_i, struct.unpack_from("<Q", header, 1)[0]))
                    position += 9 + length
        finally:
            os.close(fd)
        tables: dict[str, MessageTable] = {}
        for channel_id, channel_rows in per_channel.items():
            if not channel_rows:
                continue
            table = np.array(channel_rows, dtype=np.int64)
            table = table[np.lexsort((table[:, 1], table[:, 2], table[:, 0]))]
            tables[channel_topic[channel_id]] = MessageTable(
                log_time_ns=table[:, 0].copy(),
                data_offset=table[:, 1] + _MESSAGE_DATA_SKIP,
                data_length=table[:, 3] - (_MESSAGE_DATA_SKIP - 9),
                chunk_index=table[:, 2].copy(),
            )
        return tables

    # ----------------------------------------------------------------- decoded access
    @property
    def graph(self) -> FrameGraph:
        """The scene's frame tree from ``/tf_static`` and ``/tf`` (built on first use)."""
        if self._graph is None:
            self._graph = self._build_graph()
        return self._graph

    def _build_graph(self) -> FrameGraph:
        graph = FrameGraph()
        graph.add_frame("world")
        if topics.TF_STATIC in self._tables:
            for _, raw in self.iter_raw(topics.TF_STATIC):
                for tf in FrameTransforms.FromString(raw).transforms:
                    graph.add_static(tf.parent_frame_id, tf.child_frame_id, _transform_of(tf))
        if topics.TF in self._tables:
            # (parent, child) -> rows of (time_ns, qw, qx, qy, qz, tx, ty, tz), converted in one batch.
            samples: dict[tuple[str, str], list[tuple[float, ...]]] = {}
            for _, raw in self.iter_raw(topics.TF):
                for tf in FrameTransforms.FromString(raw).transforms:
                    q, t = tf.rotation, tf.translation
                    samples.setdefault((tf.parent_frame_id, tf.child_frame_id), []).append(
                        (tf.timestamp.seconds * 1_000_000_000 + tf.timestamp.nanos, q.w, q.x, q.y, q.z, t.x, t.y, t.z))
            for (parent, child), rows in samples.items():
                times = np.array([row[0] for row in rows], dtype=np.int64)
                values = np.array([row[1:] for row in rows], dtype=np.float64)
                graph.add_stamped(parent, child, times, Transform.from_quat_wxyz(values[:, :4], values[:, 4:]))
        return graph

    def points(self, sensor_frame: str, time_ns: int) -> np.ndarray:
        """The point cloud of ``sensor_frame`` at ``time_ns`` as a structured array (N,) in the sensor frame."""
        raw = self.read_raw(topics.sensor_topic(sensor_frame, topics.POINTS_SUFFIX), time_ns)
        head, payload = split_bytes_field(raw, _POINTS_DATA_FIELD)
        return decode_points(PointCloud.FromString(head), payload)

    def image(self, sensor_frame: str, time_ns: int) -> tuple[bytes, str]:
        """(encoded bytes, format) of the image of ``sensor_frame`` at ``time_ns``."""
        msg = CompressedImage.FromString(self.read_raw(topics.sensor_topic(sensor_frame, topics.IMAGE_SUFFIX), time_ns))
        return msg.data, msg.format

    def camera_calibration(self, sensor_frame: str, time_ns: int | None = None) -> CameraCalibration:
        """The latest CameraCalibration of ``sensor_frame`` at or before ``time_ns`` (the first if None)."""
        topic = topics.sensor_topic(sensor_frame, topics.CALIBRATION_SUFFIX)
        table = self.message_table(topic)
        i = 0 if time_ns is None else max(int(np.searchsorted(table.log_time_ns, time_ns, side="right")) - 1, 0)
        return CameraCalibration.FromString(self._read_at(table, i))

    def frame_infos(self) -> list[FrameInfo]:
        """Every frame of the scene (index, time, annotated, sensor times), in order."""
        return [decode_object_labels(ObjectLabelsMsg.FromString(raw))[0] for _, raw in self.iter_raw(topics.OBJECTS)]

    def labels(self, frame_index: int) -> tuple[FrameInfo, ObjectLabels]:
        """(frame info, objects) of frame ``frame_index``."""
        table = self.message_table(topics.OBJECTS)
        if not 0 <= frame_index < len(table.log_time_ns):
            raise AvdataError(f"scene {self.name!r}: expected frame index in [0, {len(table.log_time_ns)}), got {frame_index}")
        info, labels = decode_object_labels(ObjectLabelsMsg.FromString(self._read_at(table, frame_index)))
        if info.frame_index != frame_index:
            raise InputError(f"{self.path}: labels message {frame_index} says frame_index {info.frame_index}")
        return info, labels

    def visibility(self, sensor_frame: str, frame_index: int) -> VisibilityLabels | None:
        """The visibility labels of ``sensor_frame`` for frame ``frame_index``, or None if absent."""
        topic = topics.sensor_topic(sensor_frame, topics.VISIBILITY_SUFFIX)
        if topic not in self._tables:
            return None
        if topic not in self._visibility_rows:
            # frame index -> message row, decoded once per topic; later calls read one message.
            self._visibility_rows[topic] = {
                decode_visibility(VisibilityLabelsMsg.FromString(raw))[1]: row
                for row, (_, raw) in enumerate(self.iter_raw(topic))
            }
        row = self._visibility_rows[topic].get(frame_index)
        if row is None:
            return None
        return decode_visibility(VisibilityLabelsMsg.FromString(self._read_at(self._tables[topic], row)))[3]

    def iter_visibility(self) -> list[tuple[str, int, int, VisibilityLabels]]:
        """(sensor_frame, frame_index, time_ns, labels) of every visibility message."""
        out: list[tuple[str, int, int, VisibilityLabels]] = []
        for topic in self.topics:
            if topic.endswith("/" + topics.VISIBILITY_SUFFIX):
                out.extend(decode_visibility(VisibilityLabelsMsg.FromString(raw)) for _, raw in self.iter_raw(topic))
        return out

    def sensors(self) -> dict[str, dict[str, Any]]:
        """Sensor frame -> spec, as declared in the scene metadata."""
        return dict(self.metadata.get("sensors", {}))

    def ego_frame(self) -> str | None:
        """The primary agent's body frame: ``ego`` if present, else the first vehicle agent, else None."""
        agents = self.metadata.get("agents", {})
        if "ego" in agents:
            return "ego"
        vehicles = [name for name, spec in agents.items() if spec.get("kind") == "vehicle"]
        return vehicles[0] if vehicles else None


def decode_points(msg: PointCloud, data: bytes | memoryview | None = None) -> np.ndarray:
    """A structured array (N,) from a Foxglove PointCloud (fields at their packed offsets).

    Args:
        msg: the message; its ``data`` is used unless ``data`` is given.
        data: the point bytes when they were split off the message (no copy is made).
    """
    dtype = np.dtype(
        {
            "names": [f.name for f in msg.fields],
            "formats": [_NUMPY_OF_FOXGLOVE[f.type].newbyteorder("<") for f in msg.fields],
            "offsets": [f.offset for f in msg.fields],
            "itemsize": msg.point_stride,
        }
    )
    return np.frombuffer(msg.data if data is None else data, dtype=dtype)


def _records_start(compression: str) -> int:
    # Chunk record: opcode(1) length(8) start(8) end(8) uncompressed_size(8) crc(4)
    # compression(4 + len) records_length(8) records.
    return 1 + 8 + 8 + 8 + 8 + 4 + 4 + len(compression.encode()) + 8


def _transform_of(tf: Any) -> Transform:
    q = tf.rotation
    t = tf.translation
    return Transform.from_quat_wxyz(np.array([q.w, q.x, q.y, q.z]), np.array([t.x, t.y, t.z]))
