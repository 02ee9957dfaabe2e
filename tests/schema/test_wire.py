"""The hand-written protobuf encodings against the protobuf library's.

Poses and timestamps must be the library's bytes; markers must decode to the library-built message (the
reference below is how the scene writer built them before, from per-class templates).
"""

from __future__ import annotations

import numpy as np
import pytest
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneEntityDeletion_pb2 import SceneEntityDeletion
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from avdata.frames import Boxes3D
from avdata.schema.records import CLASS_COLORS, OTHER_CLASS_COLOR, FrameInfo, ObjectLabels, encode_object_labels
from avdata.schema.wire import frame_transform_body, object_labels, scene_update, timestamp_field, varint


def timestamp(time_ns: int) -> Timestamp:
    """The library's own Timestamp of ``time_ns``."""
    stamp = Timestamp()
    stamp.FromNanoseconds(time_ns)
    return stamp


TIMES_NS = [0, 1, 999_999_999, 1_000_000_000, 1_000_000_001, 1_532_402_927_647_951_000, 2**63 - 1]


@pytest.mark.parametrize("value", [1, 127, 128, 300, 2**31, 2**63 - 1, -1, -5, -(2**63)])
def test_varints_are_the_librarys(value: int) -> None:
    assert b"\x08" + varint(value) == Timestamp(seconds=value).SerializeToString()  # (0 is left out)


@pytest.mark.parametrize("time_ns", TIMES_NS)
def test_timestamp_fields_are_the_librarys(time_ns: int) -> None:
    assert timestamp_field(time_ns) == PointCloud(timestamp=timestamp(time_ns)).SerializeToString()


def _library_transform(parent: str, child: str, translation: list[float], quat_wxyz: list[float]) -> bytes:
    w, x, y, z = quat_wxyz
    tx, ty, tz = translation
    return FrameTransform(parent_frame_id=parent, child_frame_id=child, translation=Vector3(x=tx, y=ty, z=tz),
                          rotation=Quaternion(x=x, y=y, z=z, w=w)).SerializeToString()


def test_frame_transform_bodies_are_the_librarys_with_zeros_of_either_sign() -> None:
    rng = np.random.default_rng(4)
    specials = [0.0, -0.0, 1.0, -1.0, 5e-324, 1e7, float("inf")]
    cases = [("world", "ego", [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]), ("", "", [-0.0, 0.0, -0.0], [0.0, -0.0, 1.0, 0.0]),
             ("ego", "ego/caméra_0", [1.0, 2.0, 3.0], [0.5, 0.5, 0.5, 0.5]), ("p" * 200, "c", [1e-300, 0, 0], [1, 0, 0, 0])]
    for _ in range(500):
        values = rng.choice(specials + list(rng.normal(size=4) * 100), size=7).tolist()
        cases.append(("world", "ego", values[:3], values[3:]))
    for parent, child, translation, quat in cases:
        assert frame_transform_body(parent, child, translation, quat) == _library_transform(parent, child, translation,
                                                                                            quat)


def _library_markers(boxes: Boxes3D, time_ns: int) -> SceneUpdate:
    """The markers as the scene writer built them with the protobuf library (per-class templates copied per box)."""
    update = SceneUpdate()
    deletion = update.deletions.add(timestamp=timestamp(time_ns), type=SceneEntityDeletion.ALL)
    for object_id, cls, (cx, cy, cz), (qw, qx, qy, qz), (length, width, height) in zip(
            [str(i) for i in boxes.ids.tolist()], [str(c) for c in boxes.classes.tolist()], boxes.center.tolist(),
            boxes.quat_wxyz.tolist(), boxes.size_lwh.tolist(), strict=True):
        red, green, blue = CLASS_COLORS.get(cls, OTHER_CLASS_COLOR)
        entity = update.entities.add()
        entity.CopyFrom(SceneEntity(
            timestamp=deletion.timestamp, frame_id=boxes.frame,
            cubes=[CubePrimitive(color=Color(r=red, g=green, b=blue, a=0.4))],
            texts=[TextPrimitive(pose=Pose(orientation=Quaternion(w=1.0)), billboard=True, font_size=12.0,
                                 scale_invariant=True, color=Color(r=1.0, g=1.0, b=1.0, a=1.0))]))
        entity.id = object_id
        cube = entity.cubes[0]
        position, orientation, size = cube.pose.position, cube.pose.orientation, cube.size
        position.x, position.y, position.z = cx, cy, cz
        orientation.x, orientation.y, orientation.z, orientation.w = qx, qy, qz, qw
        size.x, size.y, size.z = length, width, height
        text = entity.texts[0]
        label_position = text.pose.position
        label_position.x, label_position.y, label_position.z = cx, cy, cz + height / 2.0 + 0.3
        text.text = f"{cls} {object_id}"
    return update


@pytest.mark.parametrize("n", [0, 1, 37])
def test_markers_decode_to_the_library_built_message(n: int) -> None:
    rng = np.random.default_rng(n)
    center = rng.normal(size=(n, 3)) * 50
    center[: n // 3] = 0.0  # zero coordinates, which the library leaves out
    center[n // 3 : n // 2, 2] = -0.0
    size = rng.uniform(0.0, 10.0, size=(n, 3))
    size[: n // 4, 1] = 0.0
    yaw = rng.uniform(-np.pi, np.pi, size=n)
    quat = np.stack([np.cos(yaw / 2), np.zeros(n), np.zeros(n), np.sin(yaw / 2)], axis=1)  # exact zeros in x, y
    classes = rng.choice([*CLASS_COLORS, "not_a_class", ""], size=n)
    ids = np.array([["", "7", "car-12", "ünïcode id", "x" * 300][i % 5] for i in range(n)])
    for frame in ("world", ""):
        boxes = Boxes3D(center=center, size_lwh=size, quat_wxyz=quat, frame=frame, ids=ids, classes=classes)
        for time_ns in TIMES_NS:
            ours = SceneUpdate.FromString(scene_update(time_ns, boxes))
            reference = _library_markers(boxes, time_ns)
            assert ours == reference
            assert ours.SerializeToString() == reference.SerializeToString()


def _labels(n: int, rng: np.random.Generator, *, frame: str = "world", extra: bool = True) -> ObjectLabels:
    """``n`` boxes with -0.0, NaN velocities and non-ASCII strings among them; every optional field when ``extra``."""
    center = rng.normal(0, 30, (n, 3))
    center[:1] = -0.0
    velocity = rng.normal(0, 5, (n, 3)) if extra else None
    if velocity is not None and n:
        velocity[-1] = np.nan
    quat_wxyz = rng.normal(0, 1, (n, 4))
    quat_wxyz /= np.linalg.norm(quat_wxyz, axis=1, keepdims=True)
    boxes = Boxes3D(center=center, size_lwh=rng.uniform(0.5, 5, (n, 3)), quat_wxyz=quat_wxyz,
                    frame=frame, ids=np.array([f"id-{i}-é" if i % 3 else "" for i in range(n)], dtype=str),
                    classes=np.array(["car", "pedestrian", "other"] * n, dtype=str)[:n], velocity=velocity)
    if not extra:
        return ObjectLabels(boxes=boxes)
    return ObjectLabels(boxes=boxes, source_classes=np.array([f"Src {i}" for i in range(n)], dtype=str),
                        acceleration=rng.normal(0, 1, (n, 3)), angular_velocity=rng.normal(0, 1, (n, 3)),
                        attributes=[{"state": "moving", "n": str(i)} for i in range(n)],
                        extras=[{"num_lidar_pts": float(i), "nested": {"b": 1, "a": [i]}} for i in range(n)])


@pytest.mark.parametrize(("n", "extra", "frame_index", "time_ns", "annotated", "sensors"), [
    (0, False, 0, 0, True, {}),
    (0, True, 1, 1_000_000_000, False, {"ego/lidar": 1_000_000_000, "ego/cam": 999_999_999}),
    (1, False, 7, 1_532_402_927_647_951_000, True, {"ego/lidar": 0}),
    (23, True, 2**32 - 1, 2**63 - 1, True, {"ego/lidar": 5, "infra/lidar": 2**63 - 1, "ego/cam": 5}),
    (50, True, 300, 42, False, {"ego/caméra": 41}),
])
def test_object_labels_are_the_librarys(n: int, extra: bool, frame_index: int, time_ns: int, annotated: bool,
                                        sensors: dict[str, int]) -> None:
    labels = _labels(n, np.random.default_rng(n), frame="" if n == 1 else "world", extra=extra)
    info = FrameInfo(frame_index=frame_index, timestamp_ns=time_ns, annotated=annotated, sensor_timestamps_ns=sensors)
    library = encode_object_labels(info, labels)
    encoded, attributes, extras = object_labels(info, labels)
    assert encoded == library.SerializeToString()
    assert (attributes, extras) == (list(library.attributes_json), list(library.extras_json))
    assert len(attributes) == (n if extra else 0)


@pytest.mark.parametrize(("frame_index", "time_ns"), [(-1, 0), (2**32, 0), (0, 2**63)])
def test_object_labels_refuse_what_the_message_cannot_hold(frame_index: int, time_ns: int) -> None:
    info = FrameInfo(frame_index=frame_index, timestamp_ns=time_ns)
    with pytest.raises(ValueError):
        encode_object_labels(info, ObjectLabels.empty("world"))
    with pytest.raises(ValueError):
        object_labels(info, ObjectLabels.empty("world"))
