"""The Parquet index, derived from the scene MCAP files (which stay the source of truth).

``index/frames.parquet``      one row per (scene, frame): time, annotated, sensor times, ego pose in world
``index/objects.parquet``     one row per (scene, frame, object): classes, box in world and in ego, velocity
``index/visibility.parquet``  one row per (scene, frame, sensor, object): what that sensor could see

Column names carry frames and units (``x_world_m``, ``yaw_ego_rad``, ``timestamp_ns``). Boxes are
moved between frames only by :meth:`Boxes3D.transform`, with the transforms looked up in each scene's
FrameGraph at every object's frame time in one batched call; full orientations are kept (``qw_world``
... ``qz_ego``) beside the yaws (``np.arctan2`` of the box x axis, in (-pi, pi]). A scene without an
ego agent has NaN ego columns (pose in ``frames``, boxes in ``objects``); in a scene with one, a frame
whose boxes or pose cannot be looked up is an :class:`InputError` naming scene, frame and time, never a silent NaN.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from avdata import portable_math
from avdata.errors import AvdataError, FrameLookupError, InputError
from avdata.frames import Boxes3D, FrameGraph, Transform
from avdata.outputs import name_full_disk, temporary_path
from avdata.schema import topics
from avdata.schema.metadata import ego_frame_of
from avdata.schema.records import FrameInfo, VisibilityLabels
from avdata.schema.scene_reader import SceneReader, frame_graph
from avdata.schema.scene_writer import WrittenScene

INDEX_TABLES = ("frames", "objects", "visibility")

FRAMES_SCHEMA = pa.schema(
    [
        ("scene", pa.string()),
        ("frame_index", pa.int32()),
        ("timestamp_ns", pa.int64()),
        ("annotated", pa.bool_()),
        ("split", pa.string()),
        ("sensor_timestamps_ns", pa.map_(pa.string(), pa.int64())),
        ("ego_frame", pa.string()),
        ("world_T_ego_x_m", pa.float64()),
        ("world_T_ego_y_m", pa.float64()),
        ("world_T_ego_z_m", pa.float64()),
        ("world_T_ego_qw", pa.float64()),
        ("world_T_ego_qx", pa.float64()),
        ("world_T_ego_qy", pa.float64()),
        ("world_T_ego_qz", pa.float64()),
        ("n_objects", pa.int32()),
    ]
)

_BOX_COLUMNS = [
    f"{axis}_{frame}_m" for frame in ("world", "ego") for axis in ("x", "y", "z")
] + [f"q{c}_{frame}" for frame in ("world", "ego") for c in "wxyz"]

OBJECTS_SCHEMA = pa.schema(
    [
        ("scene", pa.string()),
        ("frame_index", pa.int32()),
        ("timestamp_ns", pa.int64()),
        ("object_id", pa.string()),
        ("class", pa.string()),
        ("source_class", pa.string()),
        ("length_m", pa.float64()),
        ("width_m", pa.float64()),
        ("height_m", pa.float64()),
    ]
    + [(name, pa.float64()) for name in _BOX_COLUMNS]
    + [
        ("yaw_world_rad", pa.float64()),
        ("yaw_ego_rad", pa.float64()),
        ("vx_world_mps", pa.float64()),
        ("vy_world_mps", pa.float64()),
        ("vz_world_mps", pa.float64()),
        ("vx_ego_mps", pa.float64()),
        ("vy_ego_mps", pa.float64()),
        ("vz_ego_mps", pa.float64()),
        ("attributes_json", pa.string()),
        ("extras_json", pa.string()),
    ]
)

VISIBILITY_SCHEMA = pa.schema(
    [
        ("scene", pa.string()),
        ("frame_index", pa.int32()),
        ("timestamp_ns", pa.int64()),
        ("sensor", pa.string()),
        ("object_id", pa.string()),
        ("in_fov", pa.bool_()),
        ("n_points", pa.int32()),
        ("visible_fraction", pa.float32()),
        ("occlusion", pa.int8()),
        ("truncation", pa.float32()),
        ("box2d_x0_px", pa.float32()),
        ("box2d_y0_px", pa.float32()),
        ("box2d_x1_px", pa.float32()),
        ("box2d_y1_px", pa.float32()),
        ("visible_pixel_fraction", pa.float32()),
        ("alpha_rad", pa.float32()),
    ]
)

SCHEMAS = {"frames": FRAMES_SCHEMA, "objects": OBJECTS_SCHEMA, "visibility": VISIBILITY_SCHEMA}


@dataclass(frozen=True, slots=True, kw_only=True)
class SceneLabels:
    """One scene's frames and objects as the index reads them: columns over its M objects, frame after frame.

    Built from a scene file by :func:`scene_labels`, or by the scene writer from what it wrote
    (the same values the file decodes to, without reading it back).

    Attributes:
        name: the scene name.
        path: the scene file (for messages).
        ego: the primary agent's body frame, or None.
        graph: returns the scene's frame tree; called only when a pose is looked up.
        infos: (F,) the frames, in order (``infos[i].frame_index == i``).
        counts: (F,) objects per frame.
        reference: (M,) each object's reference frame.
        center: (M, 3) box centres.
        size_lwh: (M, 3) box sizes.
        quat_wxyz: (M, 4) box orientations, as decoded (unit, w >= 0).
        velocity: (M, 3) velocities, NaN for objects of frames without velocities.
        ids: (M,) object ids.
        classes: (M,) unified classes.
        source_classes: (M,) the source's classes.
        attributes_json: (M,) each object's attributes as sorted-key JSON ("{}" when the frame has none).
        extras_json: (M,) each object's extras, likewise.
        visibility: (sensor_frame, frame_index, time_ns, labels) of every visibility message, by topic.
    """

    name: str
    path: Path | str
    ego: str | None
    graph: Callable[[], FrameGraph]
    infos: list[FrameInfo]
    counts: np.ndarray
    reference: np.ndarray
    center: np.ndarray
    size_lwh: np.ndarray
    quat_wxyz: np.ndarray
    velocity: np.ndarray
    ids: np.ndarray
    classes: np.ndarray
    source_classes: np.ndarray
    attributes_json: list[str]
    extras_json: list[str]
    visibility: list[tuple[str, int, int, VisibilityLabels]]


def scene_index(scene: SceneReader, split: str = "") -> dict[str, pa.Table]:
    """The three index tables of one scene, computed from its MCAP file."""
    return index_tables(scene_labels(scene), split)


def scene_labels(scene: SceneReader) -> SceneLabels:
    """What the index needs of a scene file, decoded message by message (each checked as it is read)."""
    if topics.OBJECTS not in scene.topics:
        raise AvdataError(f"{scene.path}: no frame in the scene (no {topics.OBJECTS} message): every frame was "
                          "refused when it was written, or none was given")
    decoded = [scene.labels(i) for i in range(len(scene.times(topics.OBJECTS)))]
    with_objects = [labels for _, labels in decoded if len(labels)]
    boxes = [labels.boxes for labels in with_objects]

    def column(values: list[np.ndarray], shape: tuple[int, ...], dtype: type) -> np.ndarray:
        return np.concatenate(values) if values else np.zeros(shape, dtype=dtype)

    return SceneLabels(
        name=scene.name, path=scene.path, ego=scene.ego_frame(), graph=lambda: scene.graph,
        infos=[info for info, _ in decoded],
        counts=np.array([len(labels) for _, labels in decoded], dtype=np.int64),
        reference=np.repeat(np.array([b.frame for b in boxes], dtype=str), [len(b) for b in boxes]),
        center=column([b.center for b in boxes], (0, 3), np.float64),
        size_lwh=column([b.size_lwh for b in boxes], (0, 3), np.float64),
        quat_wxyz=column([b.quat_wxyz for b in boxes], (0, 4), np.float64),
        velocity=column([b.velocity if b.velocity is not None else np.full((len(b), 3), np.nan) for b in boxes],
                        (0, 3), np.float64),
        ids=column([b.ids for b in boxes], (0,), str),  # type: ignore[misc]  # labels' boxes carry ids and classes
        classes=column([b.classes for b in boxes], (0,), str),  # type: ignore[misc]  # labels' boxes carry ids and classes
        source_classes=column([labels.source_classes for labels in with_objects], (0,), str),
        attributes_json=[json.dumps(a, sort_keys=True) for labels in with_objects
                         for a in (labels.attributes or [{}] * len(labels))],
        extras_json=[json.dumps(e, sort_keys=True) for labels in with_objects
                     for e in (labels.extras or [{}] * len(labels))],
        visibility=scene.iter_visibility(),
    )


def written_scene_labels(written: WrittenScene) -> SceneLabels:
    """What the index needs of a scene just written, from the writer's own values (no read-back).

    The values are those the file decodes to: the box columns of all frames go through one
    :class:`Boxes3D` (the row-wise normalisation the reader applies per frame), the JSON strings are
    taken as written (the writer's ``canonical_json`` is the reader's text), the frame tree is built by the reader's
    :func:`frame_graph` from the transforms written, and visibility messages are decoded from
    their bytes.

    Raises:
        AvdataError: anything the reader would refuse (frame indices out of order, no frames, a
            broken frame tree); the caller then reads the file, which reports it as before.
    """
    frames = written.frames
    if not frames:
        raise AvdataError(f"{written.path}: no frames written")
    for i, (info, _, _, _) in enumerate(frames):
        if info.frame_index != i:
            raise AvdataError(f"{written.path}: labels message {i} says frame_index {info.frame_index}")
    with_objects = [(labels, attributes, extras) for _, labels, attributes, extras in frames if len(labels)]
    boxes = [labels.boxes for labels, _, _ in with_objects]
    counts = [len(b) for b in boxes]

    def column(values: list[np.ndarray], shape: tuple[int, ...], dtype: type) -> np.ndarray:
        return np.concatenate(values) if values else np.zeros(shape, dtype=dtype)

    center = column([b.center for b in boxes], (0, 3), np.float64)
    size = column([b.size_lwh for b in boxes], (0, 3), np.float64)
    decoded = Boxes3D(center=center, size_lwh=size, quat_wxyz=column([b.quat_wxyz for b in boxes], (0, 4), np.float64),
                      frame="")

    def json_column(per_frame: list[list[str]]) -> list[str]:
        # The writer's texts are already the reader's (``canonical_json``).
        return [text for texts, n in zip(per_frame, counts, strict=True) for text in (texts or ["{}"] * n)]

    static, stamped = written.static_transforms, written.transforms
    visibility = sorted(written.visibility, key=lambda item: item[0])  # stable: file order within a topic
    return SceneLabels(
        name=written.metadata["name"], path=written.path, ego=ego_frame_of(written.metadata),
        graph=functools.cache(lambda: frame_graph(static, stamped)),  # looked up once per index table
        infos=[info for info, _, _, _ in frames],
        counts=np.array([len(labels) for _, labels, _, _ in frames], dtype=np.int64),
        reference=np.repeat(np.array([b.frame for b in boxes], dtype=str), counts),
        center=center, size_lwh=size, quat_wxyz=decoded.quat_wxyz,
        velocity=column([b.velocity if b.velocity is not None else np.full((len(b), 3), np.nan) for b in boxes],
                        (0, 3), np.float64),
        ids=column([b.ids for b in boxes], (0,), str),  # type: ignore[misc]  # labels' boxes carry ids and classes
        classes=column([b.classes for b in boxes], (0,), str),  # type: ignore[misc]  # labels' boxes carry ids and classes
        source_classes=column([labels.source_classes for labels, _, _ in with_objects], (0,), str),
        attributes_json=json_column([attributes for _, attributes, _ in with_objects]),
        extras_json=json_column([extras for _, _, extras in with_objects]),
        visibility=[labels for _, labels in visibility],
    )


def index_tables(scene: SceneLabels, split: str = "") -> dict[str, pa.Table]:
    """The three index tables of one scene.

    Poses are looked up once per table, batched over all frame (or object) times.
    """
    ego = scene.ego
    infos = scene.infos
    times = np.array([info.timestamp_ns for info in infos], dtype=np.int64)
    n_frames = len(infos)
    frame_indices = np.array([info.frame_index for info in infos], dtype=np.int64)
    if ego is None or not n_frames:
        pose = np.full((n_frames, 7), np.nan)
    else:
        world_T_ego = _lookup(scene, "world", ego, times, frame_indices)
        pose = np.hstack([world_T_ego.translation, world_T_ego.quat_wxyz()])
    frames: dict[str, Any] = {
        "scene": [scene.name] * n_frames,
        "frame_index": [info.frame_index for info in infos],
        "timestamp_ns": times,
        "annotated": [info.annotated for info in infos],
        "split": [split] * n_frames,
        "sensor_timestamps_ns": [list(info.sensor_timestamps_ns.items()) for info in infos],
        "ego_frame": [ego] * n_frames,
        **{name: pose[:, i] for i, name in enumerate(list(FRAMES_SCHEMA.names)[7:14])},
        "n_objects": scene.counts.tolist(),
    }
    objects = _objects_columns(scene, times, frame_indices)
    frame_times = dict(zip(frames["frame_index"], times.tolist(), strict=True))
    messages = scene.visibility
    counts = [len(vis) for _, _, _, vis in messages]

    def rows(values: list[Any]) -> np.ndarray:  # one value per message, repeated for each of its rows
        return np.repeat(np.asarray(values), counts) if messages else np.zeros(0)

    def column(name: str) -> np.ndarray | list[Any]:  # every message's rows, concatenated in order
        return np.concatenate([getattr(vis, name) for _, _, _, vis in messages]) if messages else []

    box2d = np.concatenate([vis.box2d_xyxy for _, _, _, vis in messages]) if messages else np.zeros((0, 4))
    visibility: dict[str, Any] = {
        "scene": [scene.name] * sum(counts),
        "frame_index": rows([frame_index for _, frame_index, _, _ in messages]),
        "timestamp_ns": rows([frame_times.get(frame_index, -1) for _, frame_index, _, _ in messages]),
        "sensor": rows([sensor for sensor, _, _, _ in messages]).tolist(),
        "object_id": np.asarray(column("object_ids"), dtype=str).tolist(),
        **{name: column(name) for name in ("in_fov", "n_points", "visible_fraction", "occlusion", "truncation")},
        **{name: box2d[:, i] for i, name in enumerate(("box2d_x0_px", "box2d_y0_px", "box2d_x1_px", "box2d_y1_px"))},
        "visible_pixel_fraction": column("visible_pixel_fraction"),
        "alpha_rad": column("alpha_rad"),
    }
    return {
        "frames": _table(frames, FRAMES_SCHEMA),
        "objects": _table(objects, OBJECTS_SCHEMA),
        "visibility": _table(visibility, VISIBILITY_SCHEMA),
    }


def _table(columns: dict[str, Any], schema: pa.Schema) -> pa.Table:
    """``pa.table(columns, schema=schema)`` without importing pandas.

    Every ``pa.array`` call imports pandas (pyarrow 26 asks whether its argument is a pandas object
    first): start-up time and a share of a conversion's peak memory for nothing. Arrays built from their buffers hold
    the same values (``tests/schema`` compares them with ``pa.table``'s).
    """
    return pa.Table.from_arrays([_array(columns[field.name], field.type) for field in schema], schema=schema)


def _array(values: Any, arrow_type: pa.DataType) -> pa.Array:
    """One column of :data:`SCHEMAS` (a list or numpy array; strings may be None) as an Arrow array."""
    if pa.types.is_string(arrow_type):
        values = list(values)
        joined = "".join(values) if _STR_TYPES.issuperset(map(type, values)) else None
        if joined is not None and joined.isascii():
            # Every value ASCII text (ids, classes, JSON): a character is a byte, so one encode of the whole column.
            data = joined.encode()
            lengths = np.fromiter(map(len, values), dtype=np.int64, count=len(values))
            valid: pa.Buffer | None = None
        else:
            texts = [None if v is None else v.encode() if isinstance(v, str) else _not_text(v, arrow_type)
                     for v in values]
            data = b"".join(t for t in texts if t is not None)
            lengths = np.fromiter((0 if t is None else len(t) for t in texts), dtype=np.int64, count=len(texts))
            valid = _validity([t is not None for t in texts])
        ends = np.cumsum(lengths)
        if len(ends) and ends[-1] > np.iinfo(np.int32).max:  # Arrow's string offsets are int32
            raise AvdataError(f"expected at most 2 GiB of text in one index column of a scene, got {int(ends[-1])} bytes")
        offsets = np.concatenate([[0], ends]).astype(np.int32)
        return pa.Array.from_buffers(arrow_type, len(values), [valid, pa.py_buffer(offsets), pa.py_buffer(data)])
    if pa.types.is_map(arrow_type):  # a list of [(key, value), ...] per row
        offsets = np.zeros(len(values) + 1, dtype=np.int32)
        np.cumsum([len(pairs) for pairs in values], out=offsets[1:])
        pairs = [pair for row in values for pair in row]
        return pa.MapArray.from_arrays(_array(offsets, pa.int32()), _array([k for k, _ in pairs], arrow_type.key_type),
                                       _array([v for _, v in pairs], arrow_type.item_type), type=arrow_type)
    if pa.types.is_boolean(arrow_type):
        flags = np.asarray(values, dtype=bool)
        return pa.Array.from_buffers(arrow_type, len(flags), [None, pa.py_buffer(np.packbits(flags, bitorder="little"))])
    numbers = np.ascontiguousarray(values)  # an empty list gives float64, cast below like any other
    if numbers.dtype.kind not in "iuf":
        raise TypeError(f"expected numbers for an Arrow {arrow_type} column, got {numbers.dtype}")
    target = _NUMPY_TYPES[arrow_type]
    if numbers.dtype != target:
        numbers = _safe_cast(numbers, target)
    return pa.Array.from_buffers(arrow_type, len(numbers), [None, pa.py_buffer(numbers)])


#: The numpy type of each numeric Arrow type.
_NUMPY_TYPES = {pa.from_numpy_dtype(np.dtype(code)): np.dtype(code) for code in "bBhHiIlLqQefd"}


def _safe_cast(numbers: np.ndarray, target: np.dtype) -> np.ndarray:
    """``numbers`` as ``target``, refused as Arrow's safe cast refuses it: a value that does not survive the cast.

    In numpy, not with ``pa.Array.cast``: Arrow's first cast in a process builds its compute function registry,
    which would then stay in a conversion's peak memory. Floats to a narrower float round, as in Arrow.
    """
    with np.errstate(invalid="ignore", over="ignore"):
        cast = numbers.astype(target)
        if numbers.dtype.kind == "f" and target.kind == "f":
            return cast
        bad = cast.astype(numbers.dtype) != numbers
    if np.any(bad):
        value = numbers[np.argmax(bad)].item()
        raise pa.ArrowInvalid(f"value {value!r} does not fit an Arrow {pa.from_numpy_dtype(target)} column")
    return cast


#: Types of index text values (numpy's string scalars are str).
_STR_TYPES = frozenset({str, np.str_})


def _not_text(value: Any, arrow_type: pa.DataType) -> bytes:
    raise TypeError(f"expected str or None for an Arrow {arrow_type} column, got {type(value).__name__} {value!r}")


def _validity(valid: list[bool]) -> pa.Buffer | None:
    """The validity bitmap of a column (None when every value is there, as Arrow writes it)."""
    return None if all(valid) else pa.py_buffer(np.packbits(np.asarray(valid, dtype=bool), bitorder="little"))


def _objects_columns(scene: SceneLabels, frame_times: np.ndarray, frame_indices: np.ndarray) -> dict[str, Any]:
    n = len(scene.ids)
    if not n:
        return {field.name: [] for field in OBJECTS_SCHEMA}
    times = np.repeat(frame_times, scene.counts)
    frame_indices = np.repeat(frame_indices, scene.counts)
    reference = scene.reference
    size = scene.size_lwh
    columns: dict[str, Any] = {
        "scene": [scene.name] * n,
        "frame_index": frame_indices,
        "timestamp_ns": times,
        "object_id": scene.ids.tolist(),
        "class": scene.classes.tolist(),
        "source_class": scene.source_classes.tolist(),
        "length_m": size[:, 0],
        "width_m": size[:, 1],
        "height_m": size[:, 2],
    }
    # Boxes of one reference frame (normally all of them: labels are stored in ``world``) as one batch.
    groups = []
    for frame_name in np.unique(reference):
        rows = np.flatnonzero(reference == frame_name)
        group = Boxes3D(center=scene.center[rows], size_lwh=size[rows], quat_wxyz=scene.quat_wxyz[rows],
                        frame=str(frame_name), velocity=scene.velocity[rows])
        groups.append((rows, group))
    for target, suffix in (("world", "world"), (scene.ego, "ego")):
        moved_center = np.full((n, 3), np.nan)
        moved_quat = np.full((n, 4), np.nan)
        moved_yaw = np.full(n, np.nan)
        moved_velocity = np.full((n, 3), np.nan)
        for rows, group in groups:
            if target is None:
                continue  # no ego agent: the ego columns stay NaN (module docstring)
            moved = group.transform(_lookup(scene, target, group.frame, times[rows], frame_indices[rows]), target)
            moved_center[rows] = moved.center
            moved_quat[rows] = moved.quat_wxyz
            rotation = moved.rotation_matrix()
            # portable_math: numpy's arctan2 loop gives other last bits on AVX-512 than on AVX2 (docs/determinism.md).
            moved_yaw[rows] = portable_math.arctan2(rotation[:, 1, 0], rotation[:, 0, 0])  # in (-pi, pi]
            moved_velocity[rows] = moved.velocity
        for i, axis in enumerate("xyz"):
            columns[f"{axis}_{suffix}_m"] = moved_center[:, i]
            columns[f"v{axis}_{suffix}_mps"] = moved_velocity[:, i]
        for i, c in enumerate("wxyz"):
            columns[f"q{c}_{suffix}"] = moved_quat[:, i]
        columns[f"yaw_{suffix}_rad"] = moved_yaw
    columns["attributes_json"] = scene.attributes_json
    columns["extras_json"] = scene.extras_json
    return columns


class IndexWriter:
    """Streams each scene's index rows into ``index/*.parquet`` (temp names, renamed on close).

    One row group per scene: memory stays at one scene's rows however large the dataset, and an
    interrupted rebuild leaves the previous index in place.
    """

    def __init__(self, index_dir: Path):
        index_dir.mkdir(parents=True, exist_ok=True)
        self._paths = {name: (temporary_path(index_dir / f"{name}.parquet"), index_dir / f"{name}.parquet")
                       for name in INDEX_TABLES}
        self._writers: dict[str, pq.ParquetWriter] = {}
        try:
            for name, (tmp, _) in self._paths.items():
                self._writers[name] = pq.ParquetWriter(tmp, SCHEMAS[name])
        except OSError as error:  # a full disk before the first row: no temporary table stays
            self.__exit__(type(error), error, None)
            raise name_full_disk(error, self._paths[name][1]) from None

    def __enter__(self) -> IndexWriter:
        return self

    def add(self, part: dict[str, pa.Table]) -> None:
        """Appends one scene's tables."""
        for name, writer in self._writers.items():
            if part[name].num_rows:
                try:
                    writer.write_table(part[name])
                except OSError as error:  # a full disk: one line naming the table (avdata.executors.lock)
                    raise name_full_disk(error, self._paths[name][1]) from None
        # Arrow's default allocator (mimalloc) keeps freed buffers for reuse; handing them back after each
        # scene keeps them out of a conversion's peak memory.
        pa.default_memory_pool().release_unused()

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        closing_error: OSError | None = None
        for name, writer in self._writers.items():
            try:
                writer.close()
            except OSError as error:  # a full disk at the last row group: no table is renamed
                closing_error = closing_error or name_full_disk(error, self._paths[name][1])
        for tmp, final in self._paths.values():
            if exc_type is None and closing_error is None:
                os.replace(tmp, final)
            else:
                tmp.unlink(missing_ok=True)
        if closing_error is not None and exc_type is None:
            raise closing_error


def _lookup(
    scene: SceneLabels, target: str, source: str, times_ns: np.ndarray, frame_indices: np.ndarray
) -> Transform:
    """``target_T_source`` at each time (batched).

    Raises:
        InputError: some time cannot be looked up; names the scene, the first such frame and time.
    """
    graph = scene.graph()
    try:
        return graph.lookup(target, source, times_ns)
    except FrameLookupError as error:
        # Only on failure: find the first frame that fails, to name it.
        bad = next((i for i, t in enumerate(times_ns.tolist()) if not graph.can_lookup(target, source, t)), 0)
        raise InputError(
            f"{scene.path}: scene {scene.name!r} frame {int(frame_indices[bad])} at {int(times_ns[bad])} ns: {error}"
        ) from error
