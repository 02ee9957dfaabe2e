"""Writes one scene as a self-contained MCAP file (Foxglove protobuf schemas + avdata's own).

The file is written under ``.<name>.mcap.<pid>.<random>.tmp`` (:func:`avdata.outputs.temporary_path`) and
renamed to its final name only when the writer's ``with`` block ends without an exception, so an interrupted job never leaves a
half-written scene under its final name. ``/tf_static`` is the first message in the file (stamped with the
earliest time written before it), so a reader streaming in file order gets the calibrations
first; static transforms are therefore declared before the first sensor message.

The writer refuses what the reader refuses, with an :class:`~avdata.errors.InputError` naming the
scene file and the value: times going backwards on a topic, two different poses of one frame at
one time, a frame both static and time-stamped or with two parents, duplicate object ids in
one frame, metadata that is not JSON. A frame is refused before anything of it is written (so the
caller can report it and go on with the next) when the index could not place it: its frame index is
not the next one, its objects' frame or the ego frame has no pose at its time (poses and sensor
messages are written before the frame that uses them), a sensor time has no message of that sensor,
or a value is finite but absurd (see :mod:`avdata.schema.limits`).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from mcap.well_known import MessageEncoding
from mcap_protobuf.schema import register_schema

from avdata import __version__
from avdata.errors import AvdataError, InputError
from avdata.frames import Transform
from avdata.outputs import temporary_path
from avdata.schema import topics
from avdata.schema.limits import MAX_CAMERA_VALUE_PX, MAX_COORDINATE_M, MAX_TIME_NS, box_magnitude_problem
from avdata.schema.mcap.fileio import WrittenBytes
from avdata.schema.mcap.records import Buffer
from avdata.schema.mcap.writer import McapWriter
from avdata.schema.metadata import CONVENTIONS, RESERVED_METADATA, ego_frame_of
from avdata.schema.points import NUMERIC_TYPES, pack_points
from avdata.schema.protos import ObjectLabelsMsg, VisibilityLabelsMsg
from avdata.schema.records import (
    FrameInfo,
    ObjectLabels,
    VisibilityLabels,
    encode_visibility,
)
from avdata.schema.wire import (
    frame_transform_body,
    length_delimited,
    object_labels,
    scene_update,
    timestamp_field,
    with_bytes_field,
)

_POINTS_DATA_FIELD = PointCloud.DESCRIPTOR.fields_by_name["data"].number
_IMAGE_DATA_FIELD = CompressedImage.DESCRIPTOR.fields_by_name["data"].number

#: CLI compression names -> MCAP chunk compression strings.
COMPRESSION = {"none": "", "zstd": "zstd", "lz4": "lz4"}
#: Encoded FrameTransform bodies a scene writer keeps (cleared when full; only a cache).
_TRANSFORM_CACHE_SIZE = 4096

class SceneWriter:
    """Writes one scene's messages into an MCAP file; use as a context manager.

    Args:
        path: the final ``.mcap`` path; the data goes to a unique ``.tmp`` name beside it until success.
        name: the scene name.
        metadata: source-specific scene metadata, any JSON object (e.g. a resume fingerprint
            dict); read back whole by :func:`~avdata.schema.scene_metadata`. avdata adds the
            keys of :data:`RESERVED_METADATA`, which it must not contain.
        compression: chunk compression, "none" (default: fastest, zero-copy reads), "zstd" or "lz4".

        on_written: called with a :class:`WrittenScene` once the file is under its final name
            (the dataset writer builds the scene's index rows from it instead of reading the file back).
        require_frames: refuse to keep a file without any frame (``/labels/objects``): a dataset's
            index cannot place such a scene, so :class:`~avdata.schema.DatasetWriter` sets it and a
            scene whose every frame was refused costs that scene only, not the dataset's index.
        written: the tally of bytes written the file adds to (a dataset writer's scenes share
            one; see :class:`~avdata.schema.mcap.fileio.WrittenBytes`); by default the file's own.

    Raises:
        InputError: an unknown compression, or metadata using a reserved key.
    """

    def __init__(self, path: Path, name: str, metadata: Mapping[str, Any] | None = None, compression: str = "none",
                 on_written: Callable[[WrittenScene], None] | None = None, require_frames: bool = False,
                 written: WrittenBytes | None = None):
        self.path = Path(path)
        self._written_bytes = written
        self._require_frames = require_frames
        if compression not in COMPRESSION:
            raise InputError(f"{self.path}: expected compression one of {sorted(COMPRESSION)}, got {compression!r}")
        self.name = name
        self._tmp_path = temporary_path(self.path)
        self._metadata: dict[str, Any] = dict(metadata or {})
        reserved = sorted(RESERVED_METADATA & set(self._metadata))
        if reserved:
            raise InputError(f"{self.path}: scene metadata keys {reserved} are written by avdata; got them from the caller")
        self._agents: dict[str, dict[str, Any]] = {}
        self._sensors: dict[str, dict[str, Any]] = {}
        self._static: dict[str, tuple[str, Transform]] = {}
        self._static_written = False
        # child frame -> (parent, last time, last pose) of its /tf samples
        self._stamped: dict[str, tuple[str, int, Transform]] = {}
        self._first_stamp: dict[str, int] = {}
        self._n_frames = 0
        self._visibility_frames: set[tuple[str, int]] = set()  # (topic, frame index) of each visibility message
        self._channels: dict[str, _Channel] = {}
        self._compression = compression
        self._file: BinaryIO | None = None
        self._writer: McapWriter | None = None
        self._on_written = on_written
        self._cloud_heads: dict[tuple[str, np.dtype], bytes] = {}
        self._image_heads: dict[tuple[str, str], bytes] = {}
        self._transform_bodies: dict[tuple[str, str, bytes, bytes], bytes] = {}
        self._calibration_bodies: dict[tuple[Any, ...], bytes] = {}
        # What the index reads, kept only for ``on_written``: per frame (info as the file decodes it,
        # labels, attributes and extras JSON as written), the transforms, and the visibility messages.
        self._frames: list[tuple[FrameInfo, ObjectLabels, list[str], list[str]]] = []
        self._static_written_tfs: list[FrameTransform] = []
        # Each /tf message's FrameTransforms encoding, decoded all at once when the scene is written.
        self._stamped_encodings: list[bytes] = []
        self._visibility: list[tuple[str, tuple[str, int, int, VisibilityLabels]]] = []
        self._metadata_json = ""

    # ----------------------------------------------------------------- lifecycle
    def __enter__(self) -> SceneWriter:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        stream = open(self._tmp_path, "wb")  # noqa: SIM115 - closed in __exit__
        self._file = stream
        self._writer = McapWriter(stream, library=f"avdata {__version__}", compression=COMPRESSION[self._compression],
                                  written=self._written_bytes)
        self._writer.before_first_chunk = self._write_static
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None and self._file is not None and self._writer is not None:
            try:
                self._finish(self._writer)
            except BaseException:
                self._abort()
                raise
            self._file.close()
            os.replace(self._tmp_path, self.path)
            if self._on_written is not None:
                self._on_written(WrittenScene(
                    path=self.path, metadata=json.loads(self._metadata_json), frames=self._frames,
                    static_transforms=self._static_written_tfs, transforms=self._stamped_tfs,
                    visibility=self._visibility))
        else:
            self._abort()

    @property
    def _stamped_tfs(self) -> list[FrameTransform]:
        """The /tf transforms written so far, decoded in one call: what the index builds the frame tree from."""
        return list(FrameTransforms.FromString(b"".join(self._stamped_encodings)).transforms)

    def _abort(self) -> None:
        if self._writer is not None:
            self._writer.abort()
        if self._file is not None and not self._file.closed:
            self._file.close()
        self._tmp_path.unlink(missing_ok=True)

    def _write_static(self) -> None:
        """The one ``/tf_static`` message, at the earliest time written so far (called before the first chunk)."""
        self._static_written = True
        if self._static and self._writer is not None:
            start = self._writer.earliest_log_time or 0
            stamp = timestamp_field(start)
            # FrameTransforms: field 1 repeated, one FrameTransform each.
            encoded = b"".join(
                length_delimited(b"\x0a", stamp + frame_transform_body(parent, child, tf.translation.tolist(),
                                                                        tf.quat_wxyz().tolist()))
                for child, (parent, tf) in self._static.items())
            if self._on_written is not None:
                self._static_written_tfs = list(FrameTransforms.FromString(encoded).transforms)
            self._write_parts(topics.TF_STATIC, FrameTransforms, [encoded], start)

    def _finish(self, writer: McapWriter) -> None:
        if self._require_frames and topics.OBJECTS not in self._channels:
            raise InputError(f"{self.path}: no frame written (every frame was refused, or none was given); "
                             "the scene is not kept")
        orphans = sorted((index, topic) for topic, index in self._visibility_frames if index >= self._n_frames)
        if orphans:  # visibility written ahead of a frame that never came (refused, or the caller stopped)
            raise InputError(f"{self.path}: {orphans[0][1]}: visibility of frame {orphans[0][0]}, but only "
                             f"{self._n_frames} frames were written")
        scene_meta = {
            **self._metadata,
            "name": self.name,
            "format_version": topics.FORMAT_VERSION,
            "writer": f"avdata {__version__}",
            "conventions": CONVENTIONS,
            "agents": self._agents,
            "sensors": self._sensors,
        }
        try:
            blob = json.dumps(scene_meta, sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as error:
            raise InputError(f"{self.path}: scene metadata must be a JSON object ({error})") from error
        self._metadata_json = blob
        writer.add_metadata(topics.SCENE_METADATA, {"json": blob})
        writer.finish()

    # ----------------------------------------------------------------- scene description
    def add_agent(self, name: str, kind: str, origin: str, **spec: Any) -> None:
        """Declares an agent (body frame ``name``): kind "vehicle" | "infrastructure" and where its origin is."""
        self._agents[name] = {"kind": kind, "origin": origin, **spec}

    def add_sensor(self, frame: str, kind: str, **spec: Any) -> None:
        """Declares a sensor frame ``<agent>/<sensor>`` of kind "lidar" | "camera" | "radar" with its spec."""
        self._sensors[frame] = {"kind": kind, **spec}

    # ----------------------------------------------------------------- transforms
    def add_static_transform(self, parent: str, child: str, parent_T_child: Transform) -> None:
        """A fixed pose of ``child`` in ``parent`` (calibration), written once on ``/tf_static``.

        Raises:
            InputError: after the first sensor data reached the file (``/tf_static`` goes first),
                for a child given twice with different values, or one that also has ``/tf`` poses.
        """
        _require_proper(parent_T_child, parent, child)
        if child in self._static:
            old_parent, old = self._static[child]
            if old_parent != parent or not old.allclose(parent_T_child, atol=1e-9):
                raise InputError(f"{self.path}: static transform {parent!r} -> {child!r} given twice with different "
                                 "values")
            return
        if child in self._stamped:
            raise InputError(f"{self.path}: frame {child!r} has time-stamped poses on /tf; it cannot also be static")
        if self._static_written:
            raise InputError(f"{self.path}: static transform {parent!r} -> {child!r} given after sensor data was "
                             "written; /tf_static goes first in the file, so declare calibrations first")
        self._static[child] = (parent, parent_T_child)

    def add_transform(self, parent: str, child: str, time_ns: int, parent_T_child: Transform) -> None:
        """A time-stamped pose of ``child`` in ``parent`` on ``/tf``.

        Raises:
            InputError: a different pose of ``child`` at the same time, a time before the last
                ``/tf`` message, a second parent, or a child that is static.
        """
        _require_proper(parent_T_child, parent, child)
        time_ns = int(time_ns)
        if child in self._static:
            raise InputError(f"{self.path}: frame {child!r} is static (on /tf_static); got a time-stamped pose at "
                             f"{time_ns} ns")
        previous = self._stamped.get(child)
        if previous is not None:
            old_parent, old_time, old_pose = previous
            if old_parent != parent:
                raise InputError(f"{self.path}: frame {child!r} has parent {old_parent!r}; got a pose in {parent!r} "
                                 f"at {time_ns} ns")
            # The reader's FrameGraph keeps one pose per time; the same tolerances as there.
            if time_ns == old_time and not (
                    np.allclose(old_pose.rotation, parent_T_child.rotation, rtol=0, atol=1e-12)
                    and np.allclose(old_pose.translation, parent_T_child.translation, rtol=0, atol=1e-9)):
                raise InputError(f"{self.path}: two different poses of {child!r} in {parent!r} at {time_ns} ns: "
                                 f"translation {old_pose.translation.tolist()} and {parent_T_child.translation.tolist()}")
        # FrameTransform's fields after the time (field 1), encoded once per (parent, child, pose):
        # a pose repeated at many times (KITTI object's calibrations, identity poses) is encoded once.
        key = (parent, child, parent_T_child.rotation.tobytes(), parent_T_child.translation.tobytes())
        body = self._transform_bodies.get(key)
        if body is None:
            if len(self._transform_bodies) >= _TRANSFORM_CACHE_SIZE:
                self._transform_bodies.clear()
            body = frame_transform_body(parent, child, parent_T_child.translation.tolist(),
                                        parent_T_child.quat_wxyz().tolist())
            self._transform_bodies[key] = body
        # FrameTransforms with one transform: field 1, length-delimited.
        message = length_delimited(b"\x0a", timestamp_field(time_ns) + body)
        self._write_parts(topics.TF, FrameTransforms, [message], time_ns)
        if self._on_written is not None:
            self._stamped_encodings.append(message)
        self._stamped[child] = (parent, time_ns, parent_T_child)
        self._first_stamp.setdefault(child, time_ns)

    # ----------------------------------------------------------------- sensor data
    def add_point_cloud(self, sensor_frame: str, time_ns: int, points: Mapping[str, np.ndarray] | np.ndarray) -> None:
        """A point cloud in its sensor frame: named columns (x, y, z first) or a structured array."""
        packed = pack_points(points)
        rest = self._cloud_heads.get((sensor_frame, packed.dtype))
        if rest is None:
            # Every field but the time (field 1) and the points, encoded once per sensor and layout:
            # protobuf writes fields in number order, so time + rest is the whole message's encoding.
            layout: Mapping[str, Any] = packed.dtype.fields or {}
            fields = [PackedElementField(name=name, offset=layout[name][1],
                                         type=NUMERIC_TYPES[layout[name][0].newbyteorder("=")])
                      for name in packed.dtype.names or ()]
            rest = PointCloud(frame_id=sensor_frame, pose=Pose(position=Vector3(), orientation=Quaternion(w=1.0)),
                              point_stride=packed.dtype.itemsize, fields=fields).SerializeToString()
            self._cloud_heads[(sensor_frame, packed.dtype)] = rest
        head = timestamp_field(time_ns) + rest
        payload = np.ascontiguousarray(packed).view(np.uint8).data
        parts = with_bytes_field(head, _POINTS_DATA_FIELD, payload)
        self._write_parts(topics.sensor_topic(sensor_frame, topics.POINTS_SUFFIX), PointCloud, parts, time_ns)

    def add_image(self, sensor_frame: str, time_ns: int, data: bytes, fmt: str) -> None:
        """An encoded image, stored byte-for-byte as the source gave it ("png" | "jpeg")."""
        if fmt not in ("png", "jpeg"):
            raise AvdataError(f"expected image format 'png' or 'jpeg', got {fmt!r}")
        rest = self._image_heads.get((sensor_frame, fmt))
        if rest is None:  # the fields after the time, encoded once per camera and format
            rest = self._image_heads[(sensor_frame, fmt)] = CompressedImage(frame_id=sensor_frame,
                                                                            format=fmt).SerializeToString()
        parts = with_bytes_field(timestamp_field(time_ns) + rest, _IMAGE_DATA_FIELD, data)
        self._write_parts(topics.sensor_topic(sensor_frame, topics.IMAGE_SUFFIX), CompressedImage, parts, time_ns)

    def add_camera_calibration(
        self,
        sensor_frame: str,
        time_ns: int,
        K: np.ndarray,
        width: int,
        height: int,
        D: np.ndarray | None = None,
        distortion_model: str = "plumb_bob",
        R: np.ndarray | None = None,
        P: np.ndarray | None = None,
    ) -> None:
        """A camera's intrinsics (Foxglove CameraCalibration) for the optical frame ``sensor_frame``.

        Args:
            sensor_frame: the camera's optical frame ``<agent>/<sensor>``.
            time_ns: the time from which the calibration holds.
            K: (3, 3) intrinsic matrix.
            width: image width in pixels.
            height: image height in pixels.
            D: distortion coefficients (empty for rectified / undistorted images).
            distortion_model: "plumb_bob" or "rational_polynomial".
            R: (3, 3) rectification rotation, identity when None.
            P: (3, 4) projection matrix for the (rectified) frame, [K | 0] when None.

        Raises:
            InputError: K, R, P or D not finite, a focal length (K[0, 0], K[1, 1]) <= 0, an entry of K,
                P or D beyond :data:`MAX_CAMERA_VALUE_PX`, or an image side outside [0, MAX_CAMERA_VALUE_PX].
        """
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
        R = np.eye(3) if R is None else np.asarray(R, dtype=np.float64).reshape(3, 3)
        P = np.hstack([K, np.zeros((3, 1))]) if P is None else np.asarray(P, dtype=np.float64).reshape(3, 4)
        distortion = np.zeros(0) if D is None else np.asarray(D, dtype=np.float64).ravel()
        # Every field after the time (field 1), checked and encoded once per calibration (as the point cloud's):
        # the check depends on nothing but the key's values.
        key = (sensor_frame, int(width), int(height), distortion_model, distortion.tobytes(), K.tobytes(), R.tobytes(),
               P.tobytes())
        body = self._calibration_bodies.get(key)
        if body is None:
            matrices = np.concatenate([K.ravel(), P.ravel(), distortion])
            if (not (np.all(np.isfinite(matrices)) and np.all(np.isfinite(R)) and K[0, 0] > 0.0 and K[1, 1] > 0.0
                     and np.all(np.abs(matrices) <= MAX_CAMERA_VALUE_PX))
                    or not (0 <= int(width) <= MAX_CAMERA_VALUE_PX and 0 <= int(height) <= MAX_CAMERA_VALUE_PX)):
                raise InputError(f"{self.path}: camera calibration of {sensor_frame!r} at {int(time_ns)} ns: expected "
                                 f"finite K, R, P with focal lengths > 0, entries within {MAX_CAMERA_VALUE_PX:g} px and "
                                 f"image sides in [0, {MAX_CAMERA_VALUE_PX:g}], got K {K.ravel().tolist()}, "
                                 f"P {P.ravel().tolist()}, {int(width)} x {int(height)}")
            width, height = int(width), int(height)
            body = CameraCalibration(frame_id=sensor_frame, width=width, height=height,
                                     distortion_model=distortion_model, D=distortion.tolist(), K=K.ravel().tolist(),
                                     R=R.ravel().tolist(), P=P.ravel().tolist()).SerializeToString()
            self._calibration_bodies[key] = body
        head = timestamp_field(time_ns)
        self._write_parts(topics.sensor_topic(sensor_frame, topics.CALIBRATION_SUFFIX), CameraCalibration,
                          [head + body], time_ns)

    # ----------------------------------------------------------------- labels
    @property
    def n_frames(self) -> int:
        """Frames written so far: the index the next frame must have (a refused frame takes none)."""
        return self._n_frames

    def add_frame(
        self,
        frame_index: int,
        time_ns: int,
        labels: ObjectLabels,
        sensor_timestamps_ns: Mapping[str, int] | None = None,
        annotated: bool = True,
    ) -> None:
        """One frame: its objects (possibly none) on ``/labels/objects`` and their viewer markers.

        Args:
            frame_index: 0, 1, 2 ... in time order within the scene.
            time_ns: the frame's time (the labels' time).
            labels: the objects, boxes in any frame of the tree (usually ``world``).
            sensor_timestamps_ns: sensor frame -> time of the message that belongs to this frame.
            annotated: False for frames whose objects were not labelled (sweeps, test splits).

        Raises:
            InputError: the frame cannot be indexed (see :meth:`frame_problem`); nothing of it is
                written, so the caller can report it and go on with the next frame under the same index.
        """
        problem = self.frame_problem(frame_index, time_ns, labels, sensor_timestamps_ns)
        if problem is not None:
            raise InputError(f"{self.path}: frame {frame_index} at {int(time_ns)} ns: {problem}; frame refused")
        # The info as the file decodes it (what the index is built from): the integer and bool fields the
        # message holds; the encoding refuses what it cannot hold.
        info = FrameInfo(frame_index=int(frame_index), timestamp_ns=int(time_ns), annotated=bool(annotated),
                         sensor_timestamps_ns={sensor: int(t) for sensor, t in (sensor_timestamps_ns or {}).items()})
        encoded, attributes, extras = object_labels(info, labels)
        self._write_parts(topics.OBJECTS, ObjectLabelsMsg, [encoded], time_ns)
        self._write_parts(topics.MARKERS, SceneUpdate, [scene_update(time_ns, labels.boxes)], time_ns)
        self._n_frames += 1
        if self._on_written is not None:
            self._frames.append((info, labels, attributes, extras))

    def frame_problem(self, frame_index: int, time_ns: int, labels: ObjectLabels,
                      sensor_timestamps_ns: Mapping[str, int] | None = None) -> str | None:
        """Why a frame could not be indexed from what this writer has written so far, or None.

        The index looks up the ego pose at the frame's time and each object's box in ``world`` and
        in the ego frame, and loaders read each sensor's message at its listed time; all of that
        must already be written. Also refused: a frame index out of sequence, duplicate object ids
        and values beyond the magnitude limits of :mod:`avdata.schema.limits` (sizes < 0 or beyond
        ``MAX_BOX_SIZE_M``, centres beyond ``MAX_COORDINATE_M``, speeds beyond ``MAX_SPEED_MPS``).

        Args:
            frame_index: the index the frame would get.
            time_ns: the frame's time.
            labels: the frame's objects.
            sensor_timestamps_ns: sensor frame -> time of its message in this frame.
        """
        if frame_index != self._n_frames:
            return f"expected frame index {self._n_frames} (frames are numbered 0, 1, 2 ... as written), got {frame_index}"
        time_ns = int(time_ns)
        if not 0 <= time_ns <= MAX_TIME_NS:
            return f"expected a time in [0, {MAX_TIME_NS}] ns, got {time_ns}"
        boxes = labels.boxes
        if len(boxes):
            ids = boxes.ids
            if ids is not None and len(ids) > 1 and len(set(ids.tolist())) < len(ids):  # hashing, not np.unique's sort
                unique, counts = np.unique(ids, return_counts=True)
                return f"expected unique object ids, got {unique[counts > 1][:5].tolist()} more than once"
            bad = box_magnitude_problem(boxes)
            if bad is not None:
                return bad
            unplaced = self._pose_problem(boxes.frame, time_ns)
            if unplaced is not None:
                return f"its objects (in {boxes.frame!r}) cannot be placed: {unplaced}"
        ego = ego_frame_of({"agents": self._agents})
        if ego is not None:
            unplaced = self._pose_problem(ego, time_ns)
            if unplaced is not None:
                return f"the ego frame {ego!r} cannot be placed: {unplaced}"
        for sensor, sensor_ns in (sensor_timestamps_ns or {}).items():
            if not self._has_sensor_message(sensor, int(sensor_ns)):
                return f"sensor {sensor!r} has no message at {int(sensor_ns)} ns"
        return None

    def _has_sensor_message(self, sensor: str, time_ns: int) -> bool:
        """Whether ``sensor`` has a point cloud or an image at ``time_ns`` in what was written so far."""
        for suffix in (topics.POINTS_SUFFIX, topics.IMAGE_SUFFIX):
            channel = self._channels.get(topics.sensor_topic(sensor, suffix))
            if channel is not None and channel.times is not None and time_ns in channel.times:
                return True
        return False

    def _pose_problem(self, frame: str, time_ns: int) -> str | None:
        """Why ``frame`` has no pose in ``world`` at ``time_ns`` from the transforms written so far, or None.

        The frame tree interpolates a time-stamped edge only inside its recorded times (no
        extrapolation), and ``/tf`` times never go back, so an edge must already span ``time_ns``.
        """
        seen: set[str] = set()
        while frame != "world":
            if frame in seen:
                return f"frame {frame!r} is its own ancestor"
            seen.add(frame)
            static = self._static.get(frame)
            if static is not None:
                frame = static[0]
                continue
            stamped = self._stamped.get(frame)
            if stamped is None:
                return f"frame {frame!r} has no transform to 'world'"
            parent, last_ns, _ = stamped
            first_ns = self._first_stamp[frame]
            if not first_ns <= time_ns <= last_ns:
                return f"no pose of {frame!r} in {parent!r} at {time_ns} ns (its poses span [{first_ns}, {last_ns}] ns)"
            frame = parent
        return None

    def add_visibility(self, sensor_frame: str, frame_index: int, time_ns: int, visibility: VisibilityLabels) -> None:
        """What ``sensor_frame`` could see of each object in frame ``frame_index``.

        Raises:
            InputError: ``frame_index`` is neither a written frame nor the next one (the index would give
                its rows no frame), or the sensor has visibility for that frame already.
        """
        topic = topics.sensor_topic(sensor_frame, topics.VISIBILITY_SUFFIX)
        if not 0 <= frame_index <= self._n_frames or (topic, frame_index) in self._visibility_frames:
            raise InputError(f"{self.path}: {topic}: expected visibility of a written frame or the next one "
                             f"(0 .. {self._n_frames}), once per sensor, got frame {frame_index}"
                             f"{' again' if (topic, frame_index) in self._visibility_frames else ''}")
        raw = encode_visibility(sensor_frame, frame_index, time_ns, visibility).SerializeToString()
        self._write_parts(topic, VisibilityLabelsMsg, [raw], time_ns)
        self._visibility_frames.add((topic, frame_index))
        if self._on_written is not None:
            self._visibility.append((topic, (sensor_frame, int(frame_index), int(time_ns), visibility)))

    # ----------------------------------------------------------------- plumbing
    def _write_parts(self, topic: str, message_type: type, parts: list[Buffer], time_ns: int) -> None:
        if self._writer is None:
            raise AvdataError(f"scene {self.name!r}: write inside 'with SceneWriter(...)', got a write outside it")
        time_ns = int(time_ns)
        if not 0 <= time_ns <= MAX_TIME_NS:
            raise InputError(f"{self.path}: {topic}: expected a time in [0, {MAX_TIME_NS}] ns, got {time_ns} ns")
        channel = self._channels.get(topic)
        if channel is None:
            # mcap-protobuf-support only calls writer.register_schema(name=, encoding=, data=), which
            # McapWriter has with the same meaning.
            schema_id = register_schema(self._writer, message_type)  # type: ignore[arg-type]  # McapWriter has the register_schema it calls
            channel = self._channels[topic] = _Channel(self._writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=schema_id),
                sensor_data=message_type is PointCloud or message_type is CompressedImage)
        elif time_ns < channel.last_ns:
            raise InputError(f"{self.path}: {topic}: expected non-decreasing times, got {time_ns} ns after "
                             f"{channel.last_ns} ns")
        channel.last_ns = time_ns
        if channel.times is not None:
            channel.times.add(time_ns)
        self._writer.add_message(channel.id, time_ns, time_ns, channel.sequence, parts)
        channel.sequence += 1


class _Channel:
    """A topic's MCAP channel id, the sequence number of its next message and the time of its last one.

    A sensor data topic's (point clouds, images) also keeps the times of its messages, for the check that
    each frame's sensor times exist.
    """

    __slots__ = ("id", "sequence", "last_ns", "times")

    def __init__(self, channel_id: int, *, sensor_data: bool):
        self.id = channel_id
        self.sequence = 0
        self.last_ns = 0
        self.times: set[int] | None = set() if sensor_data else None


@dataclass(frozen=True, slots=True, kw_only=True)
class WrittenScene:
    """What a :class:`SceneWriter` wrote that the index reads, handed to its ``on_written``.

    Attributes:
        path: the scene file, under its final name.
        metadata: the scene metadata as the file's record decodes.
        frames: per frame, in order: (info as decoded, labels as given, attributes JSON, extras
            JSON as written: empty when the frame has none).
        static_transforms: the ``/tf_static`` transforms, as written.
        transforms: the ``/tf`` transforms, in file order.
        visibility: (topic, (sensor frame, frame index, time, labels)) of each visibility message, in file
            order. The labels as given: ``VisibilityLabels`` holds every field in its message type (float32,
            int32, bool, str), so they are what the message decodes to, without decoding it.
    """

    path: Path
    metadata: dict[str, Any]
    frames: list[tuple[FrameInfo, ObjectLabels, list[str], list[str]]]
    static_transforms: list[FrameTransform]
    transforms: list[FrameTransform]
    visibility: list[tuple[str, tuple[str, int, int, VisibilityLabels]]]


def _require_proper(transform: Transform, parent: str, child: str) -> None:
    # Python floats: for one 3x3 matrix, numpy's per-call overhead costs more than the arithmetic.
    if transform.shape != ():
        raise AvdataError(f"expected one transform {parent!r} -> {child!r}, got a batch of shape {transform.shape}")
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = transform.rotation.tolist()
    translation = transform.translation.tolist()
    if not all(map(math.isfinite, (m00, m01, m02, m10, m11, m12, m20, m21, m22, *translation))):
        raise AvdataError(f"transform {parent!r} -> {child!r}: expected finite values, got NaN or inf")
    if max(map(abs, translation)) > MAX_COORDINATE_M:
        raise AvdataError(f"transform {parent!r} -> {child!r}: expected a translation within {MAX_COORDINATE_M:g} m "
                          f"per axis, got {translation} m")
    det = m00 * (m11 * m22 - m12 * m21) - m01 * (m10 * m22 - m12 * m20) + m02 * (m10 * m21 - m11 * m20)
    if not det > 0.0:
        raise AvdataError(
            f"transform {parent!r} -> {child!r} is a reflection; every frame on disk is right-handed: "
            "convert the left-handed source at the converter boundary"
        )
