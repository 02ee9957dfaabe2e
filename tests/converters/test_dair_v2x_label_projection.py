"""DAIR-V2X-C labels projected onto each side's image through FrameDataset, against the devkit's formula.

The converted pair is the official layout built around the real files in REALDATA (``build_dair``); the
cooperative ``label_world`` boxes are the real vehicle-side labels moved to world by the devkit chain. The
devkit's projection (AIR-THU/DAIR-V2X ``tools/visualize/vis_utils.py``: ``get_cam_8_points`` maps lidar
points into the camera as ``R @ p + t`` of the lidar_to_camera file, ``points_cam2img`` divides
``cam_K @ p_cam`` by its third row) is applied to the real label's centre in its own lidar frame; the unified side takes the
cooperative (world) boxes of a FrameDataset item, expressed in the lidar frame, and its
``projections[camera]``. Centres, not corners: a ``label_world`` box is upright in world, the side label
upright in the tilted lidar frame, so their corners differ by the mount's roll, their centres do not.

With an orthonormal calibration both agree to float precision. With the mount's rotation skewed by ε
(max |RᵀR - I|, the converter stores the nearest rotation) a centre p (lidar frame) moves by
η <= 3 ε |p| (test_dair_v2x_cameras.py derives it), so the pixel moves by at most
η (max(fx, fy) + |(u, v) - (cx, cy)|) / (z - η): the calibration's own accuracy, which the test holds to.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.dair_v2x import DairV2xConverter
from avdata.loaders import FrameDataset
from avdata.schema import DatasetReader
from tests.converters.test_dair_v2x import CAMERAS, REAL, SCENE, build_dair


def devkit_vehicle_pixels(src: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(N, 2) pixels, (N,) depth, (N, 3) lidar-frame centres of the real vehicle-side labels, and cam_K."""
    frame, extrinsic, _ = CAMERAS["vehicle-side"]
    labels = json.loads((REAL / "vehicle-side" / "label" / "lidar" / f"{frame}.json").read_text())
    lidar = np.array([[e["3d_location"][k] for k in "xyz"] for e in labels], dtype=float)
    raw = json.loads((src / "vehicle-side" / "calib" / extrinsic / f"{frame}.json").read_text())
    camera = np.array(raw["rotation"]) @ lidar.T + np.array(raw["translation"]).reshape(3, 1)
    cam_K = np.array(json.loads((src / "vehicle-side" / "calib" / "camera_intrinsic" / f"{frame}.json").read_text())
                     ["cam_K"]).reshape([3, 3], order="C")
    uvw = cam_K @ camera
    return (uvw[:2] / uvw[2]).T, camera[2], lidar, cam_K


def unified_pixels(dst: Path, camera: str) -> np.ndarray:
    """(N, 2) pixels of the item's box centres (cooperative labels, ids ``<vehicle frame>_<k>``, k in file order)."""
    item = FrameDataset(dst, sensors=[camera], frame="ego/lidar", scenes=[SCENE])[0]
    order = np.argsort([int(object_id.removeprefix(f"{CAMERAS['vehicle-side'][0]}_")) for object_id in item["object_ids"]])
    centres = item["boxes"].double().numpy()[order, :3]
    uvw = np.c_[centres, np.ones(len(centres))] @ item["projections"][camera].numpy().T
    return uvw[:, :2] / uvw[:, 2:]


@pytest.mark.parametrize("skew", [0.0, 2e-5])
def test_vehicle_camera_projects_the_labels_where_the_devkit_does(tmp_path: Path, skew: float) -> None:
    build_dair(tmp_path / "src", skew=skew)
    result = run_conversion(DairV2xConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    assert result.written == [SCENE]
    devkit, depth, lidar, cam_K = devkit_vehicle_pixels(tmp_path / "src")
    ours = unified_pixels(tmp_path / "dst", "ego/camera")
    assert len(ours) == len(devkit) == 23
    in_front = depth > 2.0
    assert in_front.sum() >= 8  # labelled cars ahead of the camera, not a vacuous comparison
    error_px = np.linalg.norm(ours - devkit, axis=1)[in_front]
    float32_px = 1e-3  # the item's boxes are float32: ~4e-6 m at 50 m
    if skew == 0.0:
        assert error_px.max() < float32_px
        return
    epsilon = DatasetReader(tmp_path / "dst").scene(SCENE).metadata["calibration_residuals"]["vehicle lidar_to_novatel"]
    assert epsilon > 1e-6  # the skew really is there
    eta = 3 * epsilon * np.linalg.norm(lidar, axis=1)[in_front]
    offset = np.linalg.norm(devkit[in_front] - cam_K[:2, 2], axis=1)
    bound = eta * (cam_K[0, 0].max() + offset) / (depth[in_front] - eta)
    assert np.all(error_px <= bound + float32_px)
    assert error_px.max() > float32_px  # the repair is visible, and stays inside the calibration's accuracy


def test_infrastructure_camera_projects_the_cooperative_labels_where_the_devkit_does(tmp_path: Path) -> None:
    # The devkit places a world box in the infrastructure camera through the inverse of virtuallidar_to_world
    # with system_error_offset added to its translation (VICFrame), then virtuallidar_to_camera and cam_K.
    build_dair(tmp_path / "src", skew=0.0)
    result = run_conversion(DairV2xConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    assert result.written == [SCENE]
    src = tmp_path / "src"
    frame, extrinsic, _ = CAMERAS["infrastructure-side"]
    world = json.loads((src / "cooperative" / "label_world" / f"{CAMERAS['vehicle-side'][0]}.json").read_text())
    centres_world = np.array([[e["3d_location"][k] for k in "xyz"] for e in world], dtype=float)
    pose = json.loads((src / "infrastructure-side" / "calib" / "virtuallidar_to_world" / f"{frame}.json").read_text())
    offset = json.loads((REAL / "cooperative" / "selected_data_info.json").read_text())[0]["system_error_offset"]
    t_world = np.ravel(pose["translation"]) + [offset["delta_x"], offset["delta_y"], 0.0]
    lidar = (centres_world - t_world) @ np.array(pose["rotation"])  # R^T (p - t), row vectors
    raw = json.loads((src / "infrastructure-side" / "calib" / extrinsic / f"{frame}.json").read_text())
    camera = np.array(raw["rotation"]) @ lidar.T + np.array(raw["translation"]).reshape(3, 1)
    cam_K = np.array(json.loads((src / "infrastructure-side" / "calib" / "camera_intrinsic" / f"{frame}.json")
                                .read_text())["cam_K"]).reshape([3, 3], order="C")
    uvw = cam_K @ camera
    devkit = (uvw[:2] / uvw[2]).T
    item = FrameDataset(tmp_path / "dst", sensors=["infra/camera"], frame="infra/lidar", scenes=[SCENE])[0]
    order = np.argsort([int(object_id.split("_")[1]) for object_id in item["object_ids"]])
    centres = item["boxes"].double().numpy()[order, :3]
    ours_uvw = np.c_[centres, np.ones(len(centres))] @ item["projections"]["infra/camera"].numpy().T
    ours = ours_uvw[:, :2] / ours_uvw[:, 2:]
    in_front = camera[2] > 2.0
    assert in_front.sum() >= 5  # labelled objects ahead of the infrastructure camera, not a vacuous comparison
    assert np.linalg.norm(ours - devkit, axis=1)[in_front].max() < 1e-3  # float32 boxes: ~1e-3 px
