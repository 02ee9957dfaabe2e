"""A hand-checkable unified dataset for the loader tests.

Scene ``v2i`` (3 frames, 10 Hz from t0 = 1 s): the ego drives along world +y (yaw 90 deg) at
10 m/s from (10, 5, 0); three infrastructure agents stand still. Labels are boxes in ``world``.
Scene ``offset`` (3 frames): labels in the ego frame and a lidar whose messages come 20 ms after
each frame's time, so items must compensate ego motion through ``world``.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetWriter, ObjectLabels, VisibilityLabels

T0_NS = 1_000_000_000
PERIOD_NS = 100_000_000
N_FRAMES = 3
EGO_SPEED_MPS = 10.0
LIDAR_DELAY_NS = 20_000_000

#: ``ego_T_lidar``: 1 m forward, 2 m up, same axes.
EGO_T_LIDAR = Transform(rotation=np.eye(3), translation=np.array([1.0, 0.0, 2.0]))
#: ``ego_T_camera``: optical axes (x right, y down, z forward), 1.5 m forward, 1.5 m up.
EGO_T_CAMERA = Transform(
    rotation=np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), translation=np.array([1.5, 0.0, 1.5])
)
CAMERA_K = np.array([[100.0, 0.0, 4.0], [0.0, 100.0, 3.0], [0.0, 0.0, 1.0]])
#: Infrastructure poses in world: (x, y, yaw_rad). infra_00 is 25 m from the ego at frame 0,
#: infra_01 about 75 m, infra_02 about 120 m.
INFRA = {"infra_00": (30.0, 20.0, np.pi), "infra_01": (-50.0, 50.0, 0.0), "infra_02": (10.0, 125.0, -np.pi / 2)}
#: ``infra_T_lidar``: 6 m up the pole, pitched 30 deg down (rotation about +y).
INFRA_T_LIDAR = Transform.from_euler("ZYX", np.array([0.0, np.pi / 6, 0.0]), np.array([0.0, 0.0, 6.0]))

#: id, class, world centre at frame 0, size lwh, world yaw, world velocity
OBJECTS = [
    ("a", "car", (10.0, 25.0, 0.8), (4.0, 2.0, 1.6), 0.0, (0.0, 5.0, 0.0)),
    ("b", "pedestrian", (14.0, 8.0, 0.9), (0.6, 0.6, 1.8), np.pi / 2, (0.0, 0.0, 0.0)),
    ("c", "truck", (10.0, 105.0, 1.5), (8.0, 2.5, 3.0), np.pi, (0.0, 0.0, 0.0)),
    ("d", "cyclist", (6.0, 45.0, 0.9), (1.8, 0.6, 1.7), -np.pi / 2, (0.0, -3.0, 0.0)),
]

#: visibility per sensor: object id -> (in_fov, n_points, occlusion)
VISIBILITY = {
    "ego/lidar_top": {"a": (True, 50, 0), "b": (True, 3, 1), "c": (False, 0, 3), "d": (True, 10, 2)},
    "infra_00/lidar": {"a": (True, 80, 0), "b": (False, 0, 3), "c": (False, 0, 3), "d": (True, 4, 1)},
    "infra_02/lidar": {"a": (False, 0, 3), "b": (False, 0, 3), "c": (True, 20, 0), "d": (False, 0, 3)},
}
#: From frame 1 on, infra_00 sees b and loses d: a delayed capture's visibility differs from the current one.
INFRA_00_LATER = {"a": (True, 80, 0), "b": (True, 6, 0), "c": (False, 0, 3), "d": (False, 0, 3)}


def visibility_table(sensor: str, frame_index: int) -> dict[str, tuple[bool, int, int]]:
    """The visibility rows of ``sensor`` in a frame: object id -> (in_fov, n_points, occlusion)."""
    return INFRA_00_LATER if sensor == "infra_00/lidar" and frame_index >= 1 else VISIBILITY[sensor]


def world_T_ego(time_ns: int) -> Transform:
    """The ego's pose: yaw 90 deg, at (10, 5 + v t, 0) with t counted from T0_NS."""
    elapsed_s = (time_ns - T0_NS) / 1e9
    return Transform.from_yaw(np.pi / 2, np.array([10.0, 5.0 + EGO_SPEED_MPS * elapsed_s, 0.0]))


def world_T_infra(agent: str) -> Transform:
    x, y, yaw = INFRA[agent]
    return Transform.from_yaw(yaw, np.array([x, y, 0.0]))


def boxes_world(frame_index: int) -> Boxes3D:
    ids, classes, centers, sizes, yaws, velocities = zip(*OBJECTS, strict=True)
    elapsed_s = frame_index * PERIOD_NS / 1e9
    return Boxes3D.from_yaw(np.array(centers) + np.array(velocities) * elapsed_s, np.array(sizes), np.array(yaws),
                            "world", ids=np.array(ids), classes=np.array(classes), velocity=np.array(velocities))


def lidar_points(sensor: str, frame_index: int) -> dict[str, np.ndarray]:
    """A small known cloud in the sensor frame; infra clouds carry an int32 object id."""
    rng = np.random.default_rng(zlib.crc32(f"{sensor}/{frame_index}".encode()))
    n = 50 + 10 * frame_index + len(sensor)
    fields = {
        "x": rng.uniform(-20, 20, n).astype(np.float32),
        "y": rng.uniform(-20, 20, n).astype(np.float32),
        "z": rng.uniform(-2, 2, n).astype(np.float32),
        "intensity": rng.uniform(0, 1, n).astype(np.float32),
    }
    if sensor.startswith("infra"):
        fields["object_id"] = rng.integers(-1, 4, n).astype(np.int32)
    return fields


def camera_png(frame_index: int) -> bytes:
    """An 8x6 BGR image whose pixel (row 1, col 2) is (blue=10, green=20, red=30 + frame)."""
    image = np.zeros((6, 8, 3), dtype=np.uint8)
    image[1, 2] = (10, 20, 30 + frame_index)
    ok, png = cv2.imencode(".png", image)
    assert ok
    return png.tobytes()


def _write(root: Path) -> Path:
    with DatasetWriter(root, source="loader-tests") as writer:
        with writer.scene("v2i") as scene:
            scene.add_agent("ego", kind="vehicle", origin="rear axle on the ground")
            scene.add_sensor("ego/lidar_top", kind="lidar")
            scene.add_sensor("ego/cam_front", kind="camera", width=8, height=6)
            scene.add_static_transform("ego", "ego/lidar_top", EGO_T_LIDAR)
            scene.add_static_transform("ego", "ego/cam_front", EGO_T_CAMERA)
            for agent in INFRA:
                scene.add_agent(agent, kind="infrastructure", origin="foot of the pole")
                scene.add_sensor(f"{agent}/lidar", kind="lidar")
                scene.add_static_transform("world", agent, world_T_infra(agent))
                scene.add_static_transform(agent, f"{agent}/lidar", INFRA_T_LIDAR)
            scene.add_camera_calibration("ego/cam_front", T0_NS, CAMERA_K, 8, 6)
            sensors = ["ego/lidar_top", *(f"{a}/lidar" for a in INFRA)]
            for k in range(N_FRAMES):
                t = T0_NS + k * PERIOD_NS
                scene.add_transform("world", "ego", t, world_T_ego(t))
                for sensor in sensors:
                    scene.add_point_cloud(sensor, t, lidar_points(sensor, k))
                scene.add_image("ego/cam_front", t, camera_png(k), "png")
                scene.add_frame(k, t, ObjectLabels(boxes=boxes_world(k)), {s: t for s in sensors + ["ego/cam_front"]})
                for sensor in VISIBILITY:
                    table = visibility_table(sensor, k)
                    ids = list(table)
                    in_fov, n_points, occlusion = zip(*(table[i] for i in ids), strict=True)
                    scene.add_visibility(sensor, k, t, VisibilityLabels(
                        object_ids=np.array(ids), in_fov=np.array(in_fov), n_points=np.array(n_points),
                        occlusion=np.array(occlusion)))
        with writer.scene("offset") as scene:
            scene.add_agent("ego", kind="vehicle", origin="rear axle on the ground")
            scene.add_sensor("ego/lidar_top", kind="lidar")
            scene.add_static_transform("ego", "ego/lidar_top", EGO_T_LIDAR)
            for t in range(T0_NS, T0_NS + N_FRAMES * PERIOD_NS + 1, PERIOD_NS // 2):
                scene.add_transform("world", "ego", t, world_T_ego(t))
            for k in range(N_FRAMES):
                t = T0_NS + k * PERIOD_NS
                scene.add_point_cloud("ego/lidar_top", t + LIDAR_DELAY_NS, lidar_points("ego/lidar_top", k))
                boxes_ego = boxes_world(k).transform(world_T_ego(t).inverse(), "ego")
                scene.add_frame(k, t, ObjectLabels(boxes=boxes_ego), {"ego/lidar_top": t + LIDAR_DELAY_NS})
    return root


@pytest.fixture(scope="session")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The hand-checkable dataset (scenes ``v2i`` and ``offset``)."""
    return _write(tmp_path_factory.mktemp("loaders") / "ds")
