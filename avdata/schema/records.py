"""The label records of the unified format, each with its paired encode/decode.

``ObjectLabels`` is one frame's annotated objects (topic ``/labels/objects``);
``VisibilityLabels`` is what one sensor could see of them (``/<agent>/<sensor>/visibility``).
Both are columnar: N objects as arrays, never a Python object per box.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Final

import numpy as np

from avdata.errors import AvdataError
from avdata.frames import Boxes3D
from avdata.schema.limits import FLOAT32_MAX, MAX_CAMERA_VALUE_PX
from avdata.schema.protos import ObjectLabelsMsg, VisibilityLabelsMsg

#: The unified class taxonomy (docs/conventions.md). Converters map their source's classes onto these and
#: keep the source string verbatim beside it.
UNIFIED_CLASSES: tuple[str, ...] = (
    "car",
    "truck",
    "bus",
    "trailer",
    "construction_vehicle",
    "pedestrian",
    "cyclist",
    "motorcycle",
    "bicycle",
    "traffic_cone",
    "barrier",
    "animal",
    "other",
)

#: RGB in [0, 1] per unified class, for every view of the labels (Foxglove markers, rendered pictures, plots).
CLASS_COLORS: dict[str, tuple[float, float, float]] = {
    "car": (0.2, 0.6, 1.0),
    "truck": (0.1, 0.3, 0.9),
    "bus": (0.5, 0.2, 0.9),
    "pedestrian": (1.0, 0.3, 0.2),
    "cyclist": (1.0, 0.8, 0.1),
    "bicycle": (1.0, 0.8, 0.1),
    "motorcycle": (1.0, 0.5, 0.0),
}
#: Colour of classes without their own.
OTHER_CLASS_COLOR = (0.6, 0.6, 0.6)


@dataclass(frozen=True, slots=True, kw_only=True)
class ObjectLabels:
    """Every annotated object of one frame.

    Attributes:
        boxes: N boxes with ``ids`` and ``classes`` (unified taxonomy) set; their ``frame`` is the
            reference frame of every vector here. ``boxes.velocity`` is the velocity (m/s) or None.
        source_classes: (N,) the source's class strings, verbatim.
        acceleration: (N, 3) m/s² in the boxes' frame, or None.
        angular_velocity: (N, 3) rad/s in the boxes' frame, or None.
        attributes: per object a dict of string attributes (e.g. nuScenes attributes), or None.
        extras: per object a dict of source-specific numbers (e.g. ``num_lidar_pts``), or None.
    """

    boxes: Boxes3D
    source_classes: np.ndarray = None  # type: ignore[assignment]  # the unified classes when left out
    acceleration: np.ndarray | None = None
    angular_velocity: np.ndarray | None = None
    attributes: list[dict[str, str]] | None = None
    extras: list[dict[str, float]] | None = None

    def __post_init__(self) -> None:
        n = len(self.boxes)
        ids, classes = required_ids_and_classes(self.boxes)
        if not (np.all(np.isfinite(self.boxes.center)) and np.all(np.isfinite(self.boxes.size_lwh))):
            bad = ids[~np.all(np.isfinite(np.hstack([self.boxes.center, self.boxes.size_lwh])), axis=1)]
            raise AvdataError(f"expected finite box centres and sizes, got NaN or inf for object ids {bad[:5].tolist()}")
        unknown = sorted(set(classes.tolist()) - set(UNIFIED_CLASSES))
        if unknown:
            raise AvdataError(f"expected classes of the unified taxonomy {UNIFIED_CLASSES}, got {unknown}")
        source = classes if self.source_classes is None else np.asarray(self.source_classes, dtype=str)
        object.__setattr__(self, "source_classes", source)
        for name in ("source_classes", "attributes", "extras"):
            value = getattr(self, name)
            if value is not None and len(value) != n:
                raise AvdataError(f"expected {n} {name}, got {len(value)}")
            if name != "source_classes" and value is not None and not all(isinstance(v, dict) for v in value):
                kind = next(type(v).__name__ for v in value if not isinstance(v, dict))
                raise AvdataError(f"expected {name} as one dict per object, got a {kind}")
        for name in ("acceleration", "angular_velocity"):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=np.float64).reshape(-1, 3)
                if value.shape[0] != n:
                    raise AvdataError(f"expected {n} {name} vectors, got {value.shape[0]}")
                object.__setattr__(self, name, value)

    @classmethod
    def empty(cls, frame: str) -> ObjectLabels:
        """No objects, in ``frame``."""
        no_strings = np.zeros(0, dtype=str)
        boxes = Boxes3D(center=np.zeros((0, 3)), size_lwh=np.zeros((0, 3)), quat_wxyz=np.zeros((0, 4)),
                        frame=frame, ids=no_strings, classes=no_strings)
        return cls(boxes=boxes)

    def __len__(self) -> int:
        return len(self.boxes)


def required_ids_and_classes(boxes: Boxes3D) -> tuple[np.ndarray, np.ndarray]:
    """(ids, classes) of boxes that must carry both, as labels do."""
    if boxes.ids is None or boxes.classes is None:
        raise AvdataError("expected labelled boxes with ids and classes, got boxes without them")
    return boxes.ids, boxes.classes


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameInfo:
    """The per-frame facts stored beside the objects: index, time, whether labelled, sensor times."""

    frame_index: int
    timestamp_ns: int
    annotated: bool = True
    sensor_timestamps_ns: dict[str, int] = field(default_factory=dict)


def encode_object_labels(info: FrameInfo, labels: ObjectLabels) -> ObjectLabelsMsg:
    """The protobuf message of one frame's labels."""
    boxes = labels.boxes
    ids, classes = required_ids_and_classes(boxes)
    msg = ObjectLabelsMsg(
        timestamp_ns=int(info.timestamp_ns),
        frame_id=boxes.frame,
        frame_index=int(info.frame_index),
        annotated=bool(info.annotated),
        sensor_frames=list(info.sensor_timestamps_ns.keys()),
        sensor_timestamps_ns=[int(t) for t in info.sensor_timestamps_ns.values()],
        ids=ids.tolist(),
        classes=classes.tolist(),
        source_classes=labels.source_classes.tolist(),
        center=boxes.center.ravel().tolist(),
        size_lwh=boxes.size_lwh.ravel().tolist(),
        quat_wxyz=boxes.quat_wxyz.ravel().tolist(),
    )
    if boxes.velocity is not None:
        msg.velocity.extend(boxes.velocity.ravel().tolist())
    if labels.acceleration is not None:
        msg.acceleration.extend(labels.acceleration.ravel().tolist())
    if labels.angular_velocity is not None:
        msg.angular_velocity.extend(labels.angular_velocity.ravel().tolist())
    if labels.attributes is not None:
        msg.attributes_json.extend(canonical_jsons(labels.attributes))
    if labels.extras is not None:
        msg.extras_json.extend(canonical_jsons(labels.extras))
    return msg


#: Value types whose JSON decodes to an equal value of the same type.
_ROUND_TRIP_TYPES: Final = frozenset({str, int, float, bool, type(None)})
_STR_TYPE: Final = frozenset({str})
#: ``json.dumps(value, sort_keys=True)``'s encoder, made once: ``dumps`` makes one per call for any non-default
#: argument, a set-up that is a large share of encoding one small object, and a conversion encodes one per box.
_CANONICAL_ENCODER: Final = json.JSONEncoder(sort_keys=True)


def canonical_jsons(values: Sequence[dict[str, Any]]) -> list[str]:
    """Each of ``values`` as JSON text, exactly as every reader re-encodes what it decodes (keys sorted).

    Written so, the text the index stores for an object is the text in the file, without decoding
    it again. Only non-string keys (``{10: 1, 9: 1}`` is written with "9" first, read back with
    "10" first) and nested objects need the decode and re-encode; a flat object of strings and
    numbers, every object the converters write, is its own canonical text.

    Flat objects are encoded in one call as a list and the text split where one object ends and the next
    begins: a call per object would spend most of its time setting the encoder up. Each boundary is the text
    "}, {", so when the text holds exactly ``len(values) - 1`` of them (none inside a string), those are
    the boundaries.
    """
    if len(values) > 1 and _flat(values):
        text = _CANONICAL_ENCODER.encode(values)
        if text.count("}, {") == len(values) - 1:
            inner = text[2:-2].split("}, {")  # without the list's "[{" and "}]"
            return [f"{{{part}}}" for part in inner]
    return [_canonical_json(value) for value in values]


def _flat(values: Sequence[dict[str, Any]]) -> bool:
    """Whether every object has only string keys and values that decode to equal values of the same type."""
    return (_ROUND_TRIP_TYPES.issuperset(map(type, itertools.chain.from_iterable(v.values() for v in values)))
            and _STR_TYPE.issuperset(map(type, itertools.chain.from_iterable(values))))


def _canonical_json(value: dict[str, Any]) -> str:
    text = _CANONICAL_ENCODER.encode(value)
    if _flat([value]):
        return text
    return json.dumps(json.loads(text), sort_keys=True)


def decode_object_labels(msg: ObjectLabelsMsg) -> tuple[FrameInfo, ObjectLabels]:
    """Inverse of :func:`encode_object_labels`."""
    n = len(msg.ids)

    def vectors(values: object, width: int) -> np.ndarray | None:
        array = np.asarray(values, dtype=np.float64)
        return array.reshape(n, width) if array.size else None

    boxes = Boxes3D(
        center=np.asarray(msg.center, dtype=np.float64).reshape(n, 3),
        size_lwh=np.asarray(msg.size_lwh, dtype=np.float64).reshape(n, 3),
        quat_wxyz=np.asarray(msg.quat_wxyz, dtype=np.float64).reshape(n, 4),
        frame=msg.frame_id,
        ids=np.asarray(list(msg.ids), dtype=str),
        classes=np.asarray(list(msg.classes), dtype=str),
        velocity=vectors(msg.velocity, 3),
    )
    labels = ObjectLabels(
        boxes=boxes,
        source_classes=np.asarray(list(msg.source_classes), dtype=str),
        acceleration=vectors(msg.acceleration, 3),
        angular_velocity=vectors(msg.angular_velocity, 3),
        attributes=[json.loads(a) for a in msg.attributes_json] if len(msg.attributes_json) else None,
        extras=[json.loads(e) for e in msg.extras_json] if len(msg.extras_json) else None,
    )
    info = FrameInfo(
        frame_index=int(msg.frame_index),
        timestamp_ns=int(msg.timestamp_ns),
        annotated=bool(msg.annotated),
        sensor_timestamps_ns=dict(zip(msg.sensor_frames, (int(t) for t in msg.sensor_timestamps_ns), strict=True)),
    )
    return info, labels


def _float32(name: str, value: object, bound: float = FLOAT32_MAX) -> np.ndarray:
    """A visibility field as float32, refusing infinities and magnitudes over ``bound`` (NaN means unknown).

    A value beyond float32's range would be stored as infinity: a silent change, so it is an error instead.
    """
    wide = np.asarray(value, dtype=np.float64)
    bad = np.abs(wide) > bound  # False for NaN
    if bad.any():
        raise AvdataError(f"visibility field {name}: expected values within +-{bound:g} (NaN for unknown), got "
                          f"{float(wide[bad][0])!r}")
    return wide.astype(np.float32)


@dataclass(frozen=True, slots=True, kw_only=True)
class VisibilityLabels:
    """What one sensor could see of each object at one time (arrays of length N).

    Attributes:
        object_ids: (N,) ids matching ``ObjectLabels`` ids.
        in_fov: (N,) whether the object's box intersects the sensor's field of view and range.
        n_points: (N,) lidar returns on the object, -1 unknown.
        visible_fraction: (N,) fraction of the object's sensor-facing surface the sensor sees, NaN unknown.
        occlusion: (N,) 0 fully visible, 1 partly, 2 largely, 3 fully occluded or unknown.
        truncation: (N,) fraction of the object outside the image, NaN unknown (cameras).
        box2d_xyxy: (N, 4) projected 2D box (x0, y0, x1, y1) in pixels, NaN when not in the image.
        visible_pixel_fraction: (N,) visible pixels over projected pixels, NaN unknown.
        alpha_rad: (N,) observation angle (KITTI ``alpha``), NaN unknown.
        ignore_regions_xyxy: (M, 4) image regions to ignore in evaluation (KITTI DontCare).
    """

    # Fields left out (None) are filled with their "unknown" value in __post_init__, so every
    # attribute is an array afterwards; the ignores tell mypy the None default is only a marker.
    object_ids: np.ndarray
    in_fov: np.ndarray
    n_points: np.ndarray = None  # type: ignore[assignment]  # filled in __post_init__
    visible_fraction: np.ndarray = None  # type: ignore[assignment]  # filled in __post_init__
    occlusion: np.ndarray = None  # type: ignore[assignment]  # filled in __post_init__
    truncation: np.ndarray = None  # type: ignore[assignment]  # filled in __post_init__
    box2d_xyxy: np.ndarray = None  # type: ignore[assignment]  # filled in __post_init__
    visible_pixel_fraction: np.ndarray = None  # type: ignore[assignment]  # filled in __post_init__
    alpha_rad: np.ndarray = None  # type: ignore[assignment]  # filled in __post_init__
    ignore_regions_xyxy: np.ndarray = None  # type: ignore[assignment]  # filled in __post_init__

    def __post_init__(self) -> None:
        ids = np.asarray(self.object_ids, dtype=str).reshape(-1)
        n = ids.shape[0]
        defaults = {
            "in_fov": (bool, np.ones(n, dtype=bool)),
            "n_points": (np.int32, np.full(n, -1, dtype=np.int32)),
            "visible_fraction": (np.float32, np.full(n, np.nan, dtype=np.float32)),
            "occlusion": (np.int32, np.full(n, 3, dtype=np.int32)),
            "truncation": (np.float32, np.full(n, np.nan, dtype=np.float32)),
            "visible_pixel_fraction": (np.float32, np.full(n, np.nan, dtype=np.float32)),
            "alpha_rad": (np.float32, np.full(n, np.nan, dtype=np.float32)),
        }
        object.__setattr__(self, "object_ids", ids)
        for name, (dtype, default) in defaults.items():
            value = getattr(self, name)
            if value is None:
                value = default
            else:
                value = (_float32(name, value) if dtype is np.float32 else np.asarray(value, dtype=dtype)).reshape(-1)
            if value.shape[0] != n:
                raise AvdataError(f"expected {n} values of visibility field {name}, got {value.shape[0]}")
            object.__setattr__(self, name, value)
        occlusion = self.occlusion
        if np.any((occlusion < 0) | (occlusion > 3)):
            raise AvdataError(f"expected occlusion levels 0..3, got {sorted(set(occlusion.tolist()))}")
        box = self.box2d_xyxy
        if box is None:
            box = np.full((n, 4), np.nan, dtype=np.float32)
        else:
            box = _float32("box2d_xyxy", box, MAX_CAMERA_VALUE_PX).reshape(-1, 4)
        if box.shape[0] != n:
            raise AvdataError(f"expected {n} 2D boxes, got {box.shape[0]}")
        object.__setattr__(self, "box2d_xyxy", box)
        regions = self.ignore_regions_xyxy
        if regions is None:
            regions = np.zeros((0, 4), dtype=np.float32)
        else:
            regions = _float32("ignore_regions_xyxy", regions, MAX_CAMERA_VALUE_PX).reshape(-1, 4)
        object.__setattr__(self, "ignore_regions_xyxy", regions)
        # Read-only copies, as Boxes3D keeps: a scene writer's index takes the labels it was given as what the
        # file holds, so nobody may change them afterwards.
        for name in _VISIBILITY_FIELDS:
            value = np.array(getattr(self, name))
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return int(self.object_ids.shape[0])


_VISIBILITY_FIELDS: Final = tuple(f.name for f in fields(VisibilityLabels))


def encode_visibility(sensor_frame: str, frame_index: int, timestamp_ns: int, vis: VisibilityLabels) -> VisibilityLabelsMsg:
    """The protobuf message of one sensor's visibility labels."""
    return VisibilityLabelsMsg(
        timestamp_ns=int(timestamp_ns),
        sensor_frame=sensor_frame,
        frame_index=int(frame_index),
        object_ids=vis.object_ids.tolist(),
        in_fov=vis.in_fov.tolist(),
        n_points=vis.n_points.tolist(),
        visible_fraction=vis.visible_fraction.tolist(),
        occlusion=vis.occlusion.tolist(),
        truncation=vis.truncation.tolist(),
        box2d_xyxy=vis.box2d_xyxy.ravel().tolist(),
        visible_pixel_fraction=vis.visible_pixel_fraction.tolist(),
        alpha_rad=vis.alpha_rad.tolist(),
        ignore_regions_xyxy=vis.ignore_regions_xyxy.ravel().tolist(),
    )


def decode_visibility(msg: VisibilityLabelsMsg) -> tuple[str, int, int, VisibilityLabels]:
    """(sensor_frame, frame_index, timestamp_ns, labels) from a message."""
    vis = VisibilityLabels(
        object_ids=np.asarray(list(msg.object_ids), dtype=str),
        in_fov=np.asarray(msg.in_fov, dtype=bool),
        n_points=np.asarray(msg.n_points, dtype=np.int32),
        visible_fraction=np.asarray(msg.visible_fraction, dtype=np.float32),
        occlusion=np.asarray(msg.occlusion, dtype=np.int32),
        truncation=np.asarray(msg.truncation, dtype=np.float32),
        box2d_xyxy=np.asarray(msg.box2d_xyxy, dtype=np.float32),
        visible_pixel_fraction=np.asarray(msg.visible_pixel_fraction, dtype=np.float32),
        alpha_rad=np.asarray(msg.alpha_rad, dtype=np.float32),
        ignore_regions_xyxy=np.asarray(msg.ignore_regions_xyxy, dtype=np.float32),
    )
    return msg.sensor_frame, int(msg.frame_index), int(msg.timestamp_ns), vis
