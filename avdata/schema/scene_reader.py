"""Random access into one scene's MCAP file through its summary and message indexes.

Opening a scene maps the file and reads only the MCAP summary (CRC-checked) and the metadata
record; the message indexes after each chunk are read on the first message access. A message is
then a zero-copy view into the mapping (uncompressed chunks) or one chunk decompression
(zstd/lz4, done when a message in the chunk is first read), never a scan of the file. Reads are
positional, so one reader can be shared by threads; a reader pickled into another process maps
the file again there.

Every failure caused by the file's bytes (structure, CRC, protobuf, decompression, values the
format forbids) is an :class:`~avdata.errors.InputError` naming the file, the topic or record and
the value.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from functools import lru_cache
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from google.protobuf.message import DecodeError, Message

from avdata.errors import AvdataError, InputError, one_line
from avdata.frames import FrameGraph, Transform
from avdata.schema import topics
from avdata.schema.mcap.chunk_index import MessageTable
from avdata.schema.mcap.fileio import ByteSource
from avdata.schema.mcap.reader import McapReader
from avdata.schema.metadata import ego_frame_of
from avdata.schema.points import NUMERIC_TYPES
from avdata.schema.protos import ObjectLabelsMsg, VisibilityLabelsMsg
from avdata.schema.records import FrameInfo, ObjectLabels, VisibilityLabels, decode_object_labels, decode_visibility
from avdata.schema.wire import bytes_field_span

_POINTS_DATA_FIELD = PointCloud.DESCRIPTOR.fields_by_name["data"].number
_NUMPY_OF_FOXGLOVE = {code: dtype for dtype, code in NUMERIC_TYPES.items()}
_M = TypeVar("_M", bound=Message)


def scene_metadata(path: str | Path) -> dict[str, Any]:
    """The ``avdata.scene`` metadata of a scene file, read through the summary alone (no message index).

    Raises:
        InputError: the file is missing, damaged or not an avdata scene.
        FormatVersionError: the scene was written by a newer major format version.
    """
    reader = McapReader(path)
    try:
        return _scene_metadata(reader)
    finally:
        reader.close()


def _scene_metadata(reader: McapReader) -> dict[str, Any]:
    record = reader.metadata(topics.SCENE_METADATA)
    if record is None:
        raise InputError(f"{reader.path}: missing '{topics.SCENE_METADATA}' metadata record (not an avdata scene)")
    try:
        metadata = json.loads(record["json"])
    except (KeyError, json.JSONDecodeError) as error:
        raise InputError(f"{reader.path}: metadata '{topics.SCENE_METADATA}': expected a JSON object under 'json', "
                         f"got {str(record)[:80]!r}") from error
    if not isinstance(metadata, dict) or not isinstance(metadata.get("name"), str):
        raise InputError(f"{reader.path}: metadata '{topics.SCENE_METADATA}': expected a JSON object with a string "
                         f"'name', got {str(metadata)[:80]!r}")
    for key in ("agents", "sensors"):
        value = metadata.get(key, {})
        if not isinstance(value, dict) or not all(isinstance(spec, dict) for spec in value.values()):
            raise InputError(f"{reader.path}: metadata '{topics.SCENE_METADATA}': expected {key!r} to map names to "
                             f"objects, got {str(value)[:80]!r}")
    topics.check_version(metadata.get("format_version", "0"), str(reader.path))
    return metadata


class SceneReader:
    """Reads one scene file: metadata, frame graph, sensor messages and labels.

    Args:
        path: the scene's ``.mcap`` file, or the source of its bytes (an object in a store:
            :class:`~avdata.schema.mcap.fileio.RangedFile`, read by ranged requests).
        verify: check each chunk's CRC-32 the first time one of its messages is read (off by
            default: ``avdata validate`` checks every byte; see README for the cost).

    Raises:
        InputError: the file is missing, truncated, corrupted or not an avdata scene.
        FormatVersionError: the scene was written by a newer major format version.
    """

    def __init__(self, path: str | Path | ByteSource, *, verify: bool = False):
        if isinstance(path, str | Path):
            path = Path(path)
            if not path.is_file():
                raise InputError(f"{path}: scene file does not exist")
        self._mcap = McapReader(path, verify=verify)
        #: The file's path, or the object's URI.
        self.path: Path | str = self._mcap.path
        self.metadata: dict[str, Any] = _scene_metadata(self._mcap)
        self.name: str = self.metadata["name"]
        self._channel_ids = {channel.topic: channel.id for channel in self._mcap.channels.values()}
        self._graph: FrameGraph | None = None
        self._visibility_rows: dict[str, dict[int, int]] = {}
        # (topic, time) -> where the points lie in the message and their dtype
        self._cloud_layouts: dict[tuple[str, int], tuple[int, int, np.dtype]] = {}

    # ----------------------------------------------------------------- low level
    @property
    def topics(self) -> list[str]:
        """Every topic with at least one message, sorted."""
        return self._mcap.topics()

    def message_table(self, topic: str) -> MessageTable:
        """Positions of every message on ``topic``."""
        table = self._mcap.table(topic)
        if table is None:
            raise AvdataError(f"scene {self.name!r}: no topic {topic}; topics: {', '.join(self.topics)}")
        return table

    def times(self, topic: str) -> np.ndarray:
        """(M,) log times of the messages on ``topic``, sorted."""
        return self.message_table(topic).log_time_ns

    def read_raw(self, topic: str, time_ns: int) -> memoryview:
        """The serialized message on ``topic`` logged at exactly ``time_ns`` (a read-only view)."""
        chunk_i, offset = self._locate(topic, time_ns)
        return self._mcap.read_message(chunk_i, offset, self._channel_ids[topic], int(time_ns))

    def _locate(self, topic: str, time_ns: int) -> tuple[int, int]:
        """(chunk, record offset) of the first message on ``topic`` at ``time_ns``; AvdataError if there is none."""
        found = self._mcap.find(topic, int(time_ns))
        if found is None:
            table = self.message_table(topic)
            raise AvdataError(
                f"scene {self.name!r}: no message on {topic} at {time_ns} ns "
                f"(has {len(table.log_time_ns)} from {table.log_time_ns[0]} to {table.log_time_ns[-1]} ns)"
            )
        return found

    def prefetch(self, wanted: Iterable[tuple[str, int]]) -> None:
        """Fetches the messages on these (topic, time) together, in parallel requests, for an object in a store.

        The reads that follow then make none: one round trip for all of a frame's sensors instead of one each.
        A local file needs nothing.
        """
        self._mcap.prefetch(wanted)

    def messages(self, topic: str, start_ns: int | None = None, end_ns: int | None = None
                 ) -> Iterator[tuple[int, memoryview]]:
        """(log_time_ns, serialized message) on ``topic`` with ``start_ns <= log time < end_ns``, in time order.

        The window is half-open, as the ``mcap`` library's ``iter_messages(start_time, end_time)``;
        None leaves that side open. A topic without messages yields nothing.
        """
        table = self._mcap.table(topic)
        if table is None:
            return
        times = table.log_time_ns
        first = 0 if start_ns is None else int(np.searchsorted(times, start_ns, side="left"))
        last = len(times) if end_ns is None else int(np.searchsorted(times, end_ns, side="left"))
        for i in range(first, last):
            yield int(times[i]), self._read_at(topic, i)

    def close(self) -> None:
        """Unmaps the file (remapped on the next read); arrays handed out stay valid."""
        self._mcap.close()

    def _read_at(self, topic: str, i: int) -> memoryview:
        return self._mcap.read(self.message_table(topic), i, self._channel_ids[topic])

    def _parse(self, message_type: type[_M], topic: str, time_ns: int, raw: memoryview | bytes) -> _M:
        try:
            message: _M = message_type.FromString(raw)
        except (DecodeError, ValueError, TypeError) as error:
            raise InputError(f"{self.path}: {topic} @ {time_ns} ns: cannot decode {message_type.__name__} "
                             f"({one_line(error)})") from error
        return message

    # ----------------------------------------------------------------- decoded access
    @property
    def graph(self) -> FrameGraph:
        """The scene's frame tree from ``/tf_static`` and ``/tf`` (built on first use)."""
        if self._graph is None:
            try:
                self._graph = self._build_graph()
            except InputError:
                raise
            except AvdataError as error:
                raise InputError(f"{self.path}: frame tree: {one_line(error)}") from error
        return self._graph

    def _build_graph(self) -> FrameGraph:
        return frame_graph(
            (tf for time_ns, raw in self.messages(topics.TF_STATIC)
             for tf in self._parse(FrameTransforms, topics.TF_STATIC, time_ns, raw).transforms),
            (tf for time_ns, raw in self.messages(topics.TF)
             for tf in self._parse(FrameTransforms, topics.TF, time_ns, raw).transforms))

    def _point_cloud(self, sensor_frame: str, time_ns: int) -> tuple[str, tuple[int, int], int, memoryview, np.dtype]:
        topic = topics.sensor_topic(sensor_frame, topics.POINTS_SUFFIX)
        location = self._locate(topic, time_ns)
        raw = self._mcap.read_message(*location, self._channel_ids[topic], int(time_ns))
        layout = self._cloud_layouts.get((topic, int(time_ns)))
        if layout is None:
            # Decoded once per message: walking the wire format costs more than the rest of a read.
            try:
                head, start, end = bytes_field_span(raw, _POINTS_DATA_FIELD)
                dtype = point_dtype(PointCloud.FromString(head))
                if (end - start) % dtype.itemsize:
                    raise ValueError(f"{end - start} bytes of points is not a multiple of the stride {dtype.itemsize}")
            except (DecodeError, ValueError, TypeError, KeyError, IndexError) as error:
                raise InputError(f"{self.path}: {topic} @ {time_ns} ns: cannot decode PointCloud "
                                 f"({one_line(error)})") from error
            layout = self._cloud_layouts[(topic, int(time_ns))] = (start, end, dtype)
        start, end, dtype = layout
        return topic, location, start, raw[start:end], dtype

    def points(self, sensor_frame: str, time_ns: int) -> np.ndarray:
        """The point cloud of ``sensor_frame`` at ``time_ns``: a read-only structured array (N,) in the sensor frame.

        For uncompressed local scenes the array is a zero-copy view into the memory-mapped file (for an
        object in a store, into the fetched chunk); it stays valid after :meth:`close`. Copy it (or use
        :meth:`points_into`) to modify it.
        """
        _, _, _, payload, dtype = self._point_cloud(sensor_frame, time_ns)
        return np.frombuffer(payload, dtype=dtype)

    def points_into(self, sensor_frame: str, time_ns: int, buffer: Any) -> np.ndarray:
        """Reads the point cloud of ``sensor_frame`` at ``time_ns`` into the caller's writable ``buffer``.

        One copy, straight from the file (``preadv``) for uncompressed scenes, e.g. into shared
        memory of a DataLoader.

        Args:
            sensor_frame: the sensor frame ``<agent>/<sensor>``.
            time_ns: the message time.
            buffer: a writable buffer (numpy array, bytearray, shared memory) of at least the
                cloud's size in bytes.

        Returns:
            (N,) structured array viewing the start of ``buffer``.

        Raises:
            AvdataError: ``buffer`` is too small or read-only.
        """
        topic, location, payload_start, payload, dtype = self._point_cloud(sensor_frame, time_ns)
        target = memoryview(buffer).cast("B")
        if target.readonly or target.nbytes < payload.nbytes:
            raise AvdataError(f"expected a writable buffer of at least {payload.nbytes} bytes for {topic} @ {time_ns} "
                              f"ns, got {'a read-only one' if target.readonly else f'{target.nbytes} bytes'}")
        target = target[: payload.nbytes]
        offset = self._mcap.payload_file_offset(*location)
        if offset is None or self._mcap.verify or not self._mcap.local:
            target[:] = payload
        else:
            self._mcap.read_into(offset + payload_start, target)
        return np.frombuffer(target, dtype=dtype)

    def image(self, sensor_frame: str, time_ns: int) -> tuple[bytes, str]:
        """(encoded bytes, format) of the image of ``sensor_frame`` at ``time_ns``."""
        topic = topics.sensor_topic(sensor_frame, topics.IMAGE_SUFFIX)
        msg = self._parse(CompressedImage, topic, time_ns, self.read_raw(topic, time_ns))
        return msg.data, msg.format

    def camera_calibration(self, sensor_frame: str, time_ns: int | None = None) -> CameraCalibration:
        """The latest CameraCalibration of ``sensor_frame`` at or before ``time_ns`` (the first if None)."""
        topic = topics.sensor_topic(sensor_frame, topics.CALIBRATION_SUFFIX)
        table = self.message_table(topic)
        i = 0 if time_ns is None else max(int(np.searchsorted(table.log_time_ns, time_ns, side="right")) - 1, 0)
        msg = self._parse(CameraCalibration, topic, int(table.log_time_ns[i]), self._read_at(topic, i))
        if len(msg.K) != 9 or len(msg.P) != 12 or len(msg.R) not in (0, 9):
            raise InputError(f"{self.path}: {topic} @ {int(table.log_time_ns[i])} ns: expected 9 K, 9 R and 12 P "
                             f"values, got {len(msg.K)}, {len(msg.R)} and {len(msg.P)}")
        return msg

    def _labels_at(self, row: int) -> tuple[FrameInfo, ObjectLabels]:
        table = self.message_table(topics.OBJECTS)
        time_ns = int(table.log_time_ns[row])
        msg = self._parse(ObjectLabelsMsg, topics.OBJECTS, time_ns, self._read_at(topics.OBJECTS, row))
        try:
            return decode_object_labels(msg)
        except (AvdataError, ValueError, TypeError, KeyError) as error:
            raise InputError(f"{self.path}: {topics.OBJECTS} @ {time_ns} ns: {one_line(error)}") from error

    def frame_classes(self) -> list[tuple[bool, list[str]]]:
        """(annotated, the unified class of each object) of every frame, in order; the boxes are not decoded.

        What ``avdata info`` counts, read from the scene itself instead of the Parquet index.
        """
        if topics.OBJECTS not in self.topics:
            return []
        times = self.times(topics.OBJECTS).tolist()
        frames: list[tuple[bool, list[str]]] = []
        for row, time_ns in enumerate(times):
            msg = self._parse(ObjectLabelsMsg, topics.OBJECTS, time_ns, self._read_at(topics.OBJECTS, row))
            frames.append((bool(msg.annotated), list(msg.classes)))
        return frames

    def frame_infos(self) -> list[FrameInfo]:
        """Every frame of the scene (index, time, annotated, sensor times), in order."""
        return [self._labels_at(row)[0] for row in range(len(self.times(topics.OBJECTS)))]

    def labels(self, frame_index: int) -> tuple[FrameInfo, ObjectLabels]:
        """(frame info, objects) of frame ``frame_index``."""
        table = self.message_table(topics.OBJECTS)
        if not 0 <= frame_index < len(table.log_time_ns):
            raise AvdataError(f"scene {self.name!r}: expected frame index in [0, {len(table.log_time_ns)}), got {frame_index}")
        info, labels = self._labels_at(frame_index)
        if info.frame_index != frame_index:
            raise InputError(f"{self.path}: labels message {frame_index} says frame_index {info.frame_index}")
        return info, labels

    def _visibility_at(self, topic: str, row: int) -> tuple[str, int, int, VisibilityLabels]:
        time_ns = int(self.times(topic)[row])
        msg = self._parse(VisibilityLabelsMsg, topic, time_ns, self._read_at(topic, row))
        try:
            return decode_visibility(msg)
        except (AvdataError, ValueError, TypeError) as error:
            raise InputError(f"{self.path}: {topic} @ {time_ns} ns: {one_line(error)}") from error

    def visibility(self, sensor_frame: str, frame_index: int) -> VisibilityLabels | None:
        """The visibility labels of ``sensor_frame`` for frame ``frame_index``, or None if absent."""
        topic = topics.sensor_topic(sensor_frame, topics.VISIBILITY_SUFFIX)
        if self._mcap.table(topic) is None:
            return None
        if topic not in self._visibility_rows:
            # frame index -> message row, decoded once per topic; later calls read one message.
            self._visibility_rows[topic] = {
                self._visibility_at(topic, row)[1]: row for row in range(len(self.times(topic)))
            }
        row = self._visibility_rows[topic].get(frame_index)
        if row is None:
            return None
        return self._visibility_at(topic, row)[3]

    def iter_visibility(self) -> list[tuple[str, int, int, VisibilityLabels]]:
        """(sensor_frame, frame_index, time_ns, labels) of every visibility message."""
        out: list[tuple[str, int, int, VisibilityLabels]] = []
        for topic in self.topics:
            if topic.endswith("/" + topics.VISIBILITY_SUFFIX):
                out.extend(self._visibility_at(topic, row) for row in range(len(self.times(topic))))
        return out

    def sensors(self) -> dict[str, dict[str, Any]]:
        """Sensor frame -> spec, as declared in the scene metadata."""
        return dict(self.metadata.get("sensors", {}))

    def ego_frame(self) -> str | None:
        """The primary agent's body frame: ``ego`` if present, else the first vehicle agent, else None."""
        return ego_frame_of(self.metadata)


def point_dtype(msg: PointCloud) -> np.dtype:
    """The numpy dtype of a Foxglove PointCloud's packed points (fields at their offsets, little-endian).

    Raises:
        ValueError: an unknown field type, or fields that do not fit the point stride.
    """
    return _point_dtype(tuple((f.name, f.offset, f.type) for f in msg.fields), msg.point_stride)


@lru_cache(maxsize=64)
def _point_dtype(fields: tuple[tuple[str, int, int], ...], stride: int) -> np.dtype:
    # Cached: a scene's clouds share a handful of layouts, and building a dtype from its fields is not free.
    try:
        formats = [_NUMPY_OF_FOXGLOVE[kind].newbyteorder("<") for _, _, kind in fields]
    except KeyError as error:
        raise ValueError(f"unknown point field type {error}") from error
    if stride <= 0:
        raise ValueError(f"expected a positive point stride, got {stride}")
    return np.dtype({"names": [name for name, _, _ in fields], "formats": formats,
                     "offsets": [offset for _, offset, _ in fields], "itemsize": stride})


def decode_points(msg: PointCloud, data: bytes | memoryview | None = None) -> np.ndarray:
    """A structured array (N,) from a Foxglove PointCloud (fields at their packed offsets).

    Args:
        msg: the message; its ``data`` is used unless ``data`` is given.
        data: the point bytes when they were split off the message (no copy is made).
    """
    return np.frombuffer(msg.data if data is None else data, dtype=point_dtype(msg))


def frame_graph(static: Iterable[FrameTransform], stamped: Iterable[FrameTransform]) -> FrameGraph:
    """A scene's frame tree from its ``/tf_static`` and ``/tf`` transforms, each in file order.

    The scene writer builds the index's graph with it from the transforms it wrote, so both see
    the same poses.
    """
    graph = FrameGraph()
    graph.add_frame("world")
    for tf in static:
        graph.add_static(tf.parent_frame_id, tf.child_frame_id, _transform_of(tf))
    # (parent, child) -> rows of (time_ns, qw, qx, qy, qz, tx, ty, tz), converted in one batch.
    samples: dict[tuple[str, str], list[tuple[float, ...]]] = {}
    for tf in stamped:
        q, t = tf.rotation, tf.translation
        samples.setdefault((tf.parent_frame_id, tf.child_frame_id), []).append(
            (tf.timestamp.seconds * 1_000_000_000 + tf.timestamp.nanos, q.w, q.x, q.y, q.z, t.x, t.y, t.z))
    for (parent, child), rows in samples.items():
        times = np.array([row[0] for row in rows], dtype=np.int64)
        values = np.array([row[1:] for row in rows], dtype=np.float64)
        graph.add_stamped(parent, child, times, Transform.from_quat_wxyz(values[:, :4], values[:, 4:]))
    return graph


def _transform_of(tf: Any) -> Transform:
    q = tf.rotation
    t = tf.translation
    return Transform.from_quat_wxyz(np.array([q.w, q.x, q.y, q.z]), np.array([t.x, t.y, t.z]))
