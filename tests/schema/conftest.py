"""A small two-agent dataset written through DatasetWriter, shared by the schema tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from avdata.frames import Boxes3D, Transform
from avdata.schema import DatasetWriter, ObjectLabels, VisibilityLabels

T0 = 1_600_000_000_000_000_000
PERIOD = 100_000_000
EGO_T_LIDAR = Transform.from_euler("ZYX", [0.05, 0.01, -0.02], [1.2, 0.0, 1.9])
WORLD_T_INFRA = Transform.from_euler("ZYX", [2.0, 0.5, 0.0], [30.0, 10.0, 0.0])
INFRA_T_LIDAR = Transform.from_euler("ZYX", [0.0, np.radians(30), 0.0], [0.0, 0.0, 15.0])


def world_T_ego(i: int) -> Transform:
    return Transform.from_yaw(0.05 * i, [2.0 * i, 0.1 * i, 0.0])


def cloud(i: int, n: int = 2000) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(i)
    xyz = rng.uniform(-50, 50, size=(n, 3)).astype(np.float32)
    return {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
            "intensity": rng.uniform(0, 1, n).astype(np.float32), "ring": rng.integers(0, 64, n).astype(np.uint16)}


def boxes(i: int) -> Boxes3D:
    return Boxes3D.from_yaw([[10.0 + i, 2.0, 0.8], [5.0, -3.0 - 0.5 * i, 0.9]], [[4.5, 1.9, 1.6], [0.7, 0.6, 1.8]],
                            [0.1 * i, -1.0], "world", ids=["car-1", "ped-2"], classes=["car", "pedestrian"],
                            velocity=[[10.0, 0.0, 0.0], [0.0, -5.0, 0.0]])


def write_dataset(root: Path, n_frames: int = 4, compression: str = "none") -> Path:
    with DatasetWriter(root, source="unit-test", source_version="0", compression=compression) as writer:
        with writer.scene("scene-a", {"split": "train"}) as scene:
            scene.add_agent("ego", kind="vehicle", origin="rear axle")
            scene.add_agent("infra_1", kind="infrastructure", origin="pole base")
            scene.add_sensor("ego/lidar", kind="lidar")
            scene.add_sensor("infra_1/lidar", kind="lidar")
            scene.add_sensor("ego/cam", kind="camera")
            scene.add_static_transform("ego", "ego/lidar", EGO_T_LIDAR)
            scene.add_static_transform("world", "infra_1", WORLD_T_INFRA)
            scene.add_static_transform("infra_1", "infra_1/lidar", INFRA_T_LIDAR)
            scene.add_static_transform("ego", "ego/cam", Transform.from_euler("ZYX", [-np.pi / 2, 0, -np.pi / 2]))
            scene.add_camera_calibration("ego/cam", T0, np.array([[500, 0, 320], [0, 500, 240], [0, 0, 1.0]]), 640, 480)
            for i in range(n_frames):
                t = T0 + i * PERIOD
                scene.add_transform("world", "ego", t, world_T_ego(i))
                scene.add_point_cloud("ego/lidar", t, cloud(i))
                scene.add_point_cloud("infra_1/lidar", t + 1000, cloud(100 + i, 500))
                scene.add_image("ego/cam", t, b"\x89PNG-fake-" + bytes([i]), "png")
                labels = ObjectLabels(boxes=boxes(i), source_classes=["Car", "Pedestrian"],
                                      attributes=[{"state": "moving"}, {}], extras=[{"num_lidar_pts": 12.0}, {}])
                scene.add_frame(i, t, labels, {"ego/lidar": t, "infra_1/lidar": t + 1000, "ego/cam": t})
                scene.add_visibility("ego/lidar", i, t, VisibilityLabels(
                    object_ids=["car-1", "ped-2"], in_fov=[True, False], n_points=[40, 0],
                    visible_fraction=[0.75, 0.0], occlusion=[1, 3]))
        with writer.scene("scene-b", {"split": "val"}) as scene:
            scene.add_agent("ego", kind="vehicle", origin="rear axle")
            scene.add_static_transform("ego", "ego/lidar", EGO_T_LIDAR)
            scene.add_transform("world", "ego", T0, world_T_ego(0))
            scene.add_point_cloud("ego/lidar", T0, cloud(7))
            scene.add_frame(0, T0, ObjectLabels.empty("world"), {"ego/lidar": T0}, annotated=False)
    return root


@pytest.fixture(scope="session")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("ds") / "dataset")
