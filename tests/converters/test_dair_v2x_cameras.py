"""DAIR-V2X-C cameras: real point clouds projected through the unified graph, against the devkit's formula.

The real pair (../shared/realdata/dair_v2x) has no images or camera calibrations, so
:func:`tests.converters.test_dair_v2x.build_dair` writes them in the official format around the real
files: a JPEG per side drawn with OpenCV, ``calib/camera_intrinsic/<id>.json`` (``cam_K`` flat 3x3
row-major, ``cam_D`` 5 numbers) and ``calib/lidar_to_camera`` / ``calib/virtuallidar_to_camera``
(``rotation`` 3x3, ``translation`` 3x1), named by the per-side ``data_info.json`` rows
(``image_path``, ``image_timestamp``, ``calib_camera_intrinsic_path``,
``calib_lidar_to_camera_path`` / ``calib_virtuallidar_to_camera_path``).

Oracle, from the DAIR-V2X devkit (AIR-THU/DAIR-V2X):

- ``tools/visualize/vis_utils.py``: ``get_lidar2cam`` reads ``rotation`` / ``translation`` of the
  lidar_to_camera file, ``get_cam_8_points`` maps lidar points into the camera as ``R @ p + t`` (so
  the file is camera_T_lidar), ``get_cam_calib_intrinsic`` builds ``[cam_K | 0]`` from
  ``np.array(cam_K).reshape([3, 3], order="C")`` and ``points_cam2img`` divides by the third row:
  pixel = ``(cam_K @ (R @ p + t))[:2] / (cam_K @ (R @ p + t))[2]``; ``cam_D`` is never applied
  (``tools/dataset_converter/gen_kitti/gen_calib2kitti.py`` reads it and drops it).
- ``v2x/dataset/base_dataset.py`` ``get_annos``: the extrinsic is ``calib_lidar_to_camera_path`` when the
  row has it, else ``calib_virtuallidar_to_camera_path``; the intrinsic ``calib_camera_intrinsic_path``.
- ``v2x/dataset/dair_v2x_for_detection.py`` (``prev_inf_frame``): ``image_timestamp`` differences / 1000.0
  are ms, as ``pointcloud_timestamp``'s: both are µs.
- ``v2x/dataset/dataset_utils/frame.py`` ``VICFrame.transform``: the vehicle's novatel_to_world is named by
  the image's frame id, one pose for the image and the sweep.

Bound where the extrinsic rotation is not orthonormal (the converter stores R' = U Vᵀ of R = U S Vᵀ,
as for the other DAIR calibrations): with ε = max |RᵀR - I|, ‖R - R'‖₂ = max |s - 1| ≤ max |s² - 1|
= ‖RᵀR - I‖₂ ≤ 3ε, so a point p moves by η ≤ 3ε‖p‖ in the camera. A camera point (x, y, z) moved by
δ projects to u' - u = (fx δx - (u - cx) δz) / z' (and v likewise; K without skew, as DAIR's), so
|Δ(u, v)| ≤ η (max(fx, fy) + |(u, v) - (cx, cy)|) / (z - η).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from avdata.cli import main
from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.dair_v2x import DairV2xConverter
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from avdata.sources.pcd import read_pcd
from tests.converters.test_dair_v2x import CAMERAS, IMAGE_SIZE, REAL, SCENE, build_dair

#: (side folder, lidar, camera, frame id, extrinsic name)
SIDES = [("vehicle-side", "ego/lidar", "ego/camera", *CAMERAS["vehicle-side"][:2]),
         ("infrastructure-side", "infra/lidar", "infra/camera", *CAMERAS["infrastructure-side"][:2])]


def convert(src: Path, dst: Path):
    return run_conversion(DairV2xConverter(ConvertConfig(src=src, dst=dst, quiet=True)))


def devkit_pixels(src: Path, side: str, frame: str, extrinsic: str, points_lidar: np.ndarray) -> np.ndarray:
    """(N, 3) u, v, depth: the devkit's ``cam_K @ (R @ p + t)`` from the raw files (vis_utils.py)."""
    raw = json.loads((src / side / "calib" / extrinsic / f"{frame}.json").read_text())
    rotation, translation = np.array(raw["rotation"]), np.array(raw["translation"]).reshape(3, 1)
    cam_K = np.array(json.loads((src / side / "calib" / "camera_intrinsic" / f"{frame}.json").read_text())["cam_K"])
    points_camera = rotation @ points_lidar.T + translation
    uvw = cam_K.reshape([3, 3], order="C") @ points_camera
    return np.column_stack([uvw[0] / uvw[2], uvw[1] / uvw[2], points_camera[2]])


def unified_pixels(dst: Path, lidar: str, camera: str) -> tuple[np.ndarray, np.ndarray]:
    """((N, 2) u, v, (N, 3) the stored cloud): ``ego/camera <- ego/lidar`` from the graph, then the stored P."""
    dataset = DatasetReader(dst)
    time_ns = dataset.sensor_time(SCENE, 0, camera)
    cloud = dataset.points(SCENE, 0, lidar)
    xyz = np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float64)
    points_camera = dataset.frame_graph(SCENE).lookup(camera, lidar, time_ns).apply(xyz)
    P = np.array(dataset.scene(SCENE).camera_calibration(camera, time_ns).P).reshape(3, 4)
    uvw = np.column_stack([points_camera, np.ones(len(xyz))]) @ P.T
    return uvw[:, :2] / uvw[:, 2:], xyz


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list]:
    root = tmp_path_factory.mktemp("dair_cameras")
    build_dair(root / "src", skew=0.0)
    result = convert(root / "src", root / "dst")
    assert result.written == [SCENE] and result.problems == []
    return root / "src", root / "dst", result.problems


@pytest.mark.parametrize(("side", "lidar", "camera", "frame", "extrinsic"), SIDES)
def test_real_points_project_where_the_devkit_projects(converted, side, lidar, camera, frame, extrinsic) -> None:
    src, dst, _ = converted
    ours, xyz = unified_pixels(dst, lidar, camera)
    real = read_pcd(REAL / side / "velodyne" / f"{frame}.pcd")
    real_xyz = np.stack([real["x"], real["y"], real["z"]], axis=1).astype(np.float64)
    np.testing.assert_array_equal(xyz, real_xyz)  # the stored cloud is the real one, untouched
    devkit = devkit_pixels(src, side, frame, extrinsic, real_xyz)
    in_front = devkit[:, 2] > 1.0
    in_image = in_front & np.all((devkit[:, :2] >= 0) & (devkit[:, :2] < IMAGE_SIZE), axis=1)
    assert in_front.sum() > 10_000 and in_image.sum() > 1_000  # the real scene is in view, not a few points
    np.testing.assert_allclose(ours[in_front], devkit[in_front, :2], rtol=1e-6, atol=0)


def test_non_orthonormal_extrinsic_is_repaired_within_the_stated_bound(tmp_path: Path) -> None:
    build_dair(tmp_path / "src", skew=0.0, camera_skew=2e-5)
    result = convert(tmp_path / "src", tmp_path / "dst")
    assert [(p.severity, Path(p.file).parent.name) for p in result.problems] == [
        ("warning", "lidar_to_camera"), ("warning", "virtuallidar_to_camera")]
    assert all("not orthonormal" in p.message for p in result.problems)
    residuals = DatasetReader(tmp_path / "dst").scene(SCENE).metadata["calibration_residuals"]
    for side, lidar, camera, frame, extrinsic in SIDES:
        epsilon = residuals[f"{side.removesuffix('-side')} {extrinsic}"]
        assert 1e-5 < epsilon < 1e-4
        ours, xyz = unified_pixels(tmp_path / "dst", lidar, camera)
        devkit = devkit_pixels(tmp_path / "src", side, frame, extrinsic, xyz)
        cam_K = np.array(json.loads((tmp_path / "src" / side / "calib" / "camera_intrinsic" / f"{frame}.json")
                                    .read_text())["cam_K"]).reshape(3, 3)
        eta = 3 * epsilon * np.linalg.norm(xyz, axis=1)
        in_front = devkit[:, 2] > 1.0 + eta
        offset = np.linalg.norm(devkit[:, :2] - cam_K[:2, 2], axis=1)
        bound = eta * (max(cam_K[0, 0], cam_K[1, 1]) + offset) / (devkit[:, 2] - eta)
        error = np.linalg.norm(ours - devkit[:, :2], axis=1)
        assert np.all(error[in_front] <= bound[in_front] + 1e-9)
        assert error[in_front].max() > 1e-3  # the repair moved pixels: the comparison is not vacuous


def test_images_stored_untouched_at_their_times_with_their_calibration(converted) -> None:
    src, dst, _ = converted
    assert validate_dataset(dst) == []
    dataset = DatasetReader(dst)
    scene = dataset.scene(SCENE)
    graph = dataset.frame_graph(SCENE)
    times_us = scene.metadata["pairs"][0]["source_timestamps_us"]
    assert times_us == {"vehicle": 1626155145901946, "infrastructure": 1626155145843210,
                        "vehicle_image": 1626155145863530, "infrastructure_image": 1626155145816412}
    for side, lidar, camera, frame, extrinsic in SIDES:
        time_ns = int(CAMERAS[side][2]) * 1000
        assert dataset.sensor_time(SCENE, 0, camera) == time_ns
        data, fmt = dataset.image(SCENE, 0, camera)
        assert fmt == "jpeg" and bytes(data) == (src / side / "image" / f"{frame}.jpg").read_bytes()
        intrinsic = json.loads((src / side / "calib" / "camera_intrinsic" / f"{frame}.json").read_text())
        calibration = scene.camera_calibration(camera, time_ns)
        assert (calibration.timestamp.seconds * 10**9 + calibration.timestamp.nanos) == time_ns
        assert list(calibration.K) == intrinsic["cam_K"] and list(calibration.D) == intrinsic["cam_D"]
        assert calibration.distortion_model == "plumb_bob"
        assert (calibration.width, calibration.height) == IMAGE_SIZE
        np.testing.assert_array_equal(np.array(calibration.P).reshape(3, 4),
                                      np.hstack([np.reshape(intrinsic["cam_K"], (3, 3)), np.zeros((3, 1))]))
        assert list(calibration.R) == np.eye(3).ravel().tolist()
        assert scene.metadata["sensors"][camera] == {"kind": "camera", "width": 1920, "height": 1080,
                                                     "source": f"{side}/image/{frame}.jpg"}
        # /tf_static holds the camera's pose in the lidar: the inverse of DAIR's lidar_to_camera
        raw = json.loads((src / side / "calib" / extrinsic / f"{frame}.json").read_text())
        camera_T_lidar = np.eye(4)
        camera_T_lidar[:3, :3], camera_T_lidar[:3, 3] = raw["rotation"], np.ravel(raw["translation"])
        np.testing.assert_allclose(graph.lookup(lidar, camera, time_ns).as_matrix() @ camera_T_lidar, np.eye(4),
                                   atol=1e-12)
    # the vehicle image is 38 ms before the sweep: the frame's one ego pose is stamped at both times
    np.testing.assert_allclose(graph.lookup("world", "ego/camera", 1626155145863530000).as_matrix(),
                               graph.lookup("world", "ego/camera", 1626155145901946000).as_matrix(), atol=0)


def test_without_a_vehicle_data_info_images_take_the_sweep_time_and_files_by_frame_id(tmp_path: Path) -> None:
    build_dair(tmp_path / "src", skew=0.0)
    (tmp_path / "src" / "vehicle-side" / "data_info.json").unlink()
    result = convert(tmp_path / "src", tmp_path / "dst")
    assert result.problems == []
    scene = DatasetReader(tmp_path / "dst").scene(SCENE)
    assert scene.metadata["time"] == "scene-relative: 0"
    assert scene.frame_infos()[0].sensor_timestamps_ns == {"ego/lidar": 0, "infra/lidar": 0, "ego/camera": 0,
                                                           "infra/camera": 0}


def run_cli(src: Path, dst: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    status = main(["convert", "dair-v2x", str(src), str(dst), "--quiet"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return status, [line for line in err.splitlines() if line.startswith(("error:", "warning:"))]


def kept_sensors(dst: Path) -> set[str]:
    scene = DatasetReader(dst).scene(SCENE)
    assert len(scene.labels(0)[1]) == 23  # every box kept
    return set(scene.frame_infos()[0].sensor_timestamps_ns)


def test_a_missing_image_costs_only_that_image(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    build_dair(tmp_path / "src", skew=0.0)
    image = tmp_path / "src" / "vehicle-side" / "image" / "017314.jpg"
    image.unlink()
    status, lines = run_cli(tmp_path / "src", tmp_path / "dst", capsys)
    assert status == 0
    assert lines == [f"warning: {SCENE}: {image}: image missing: camera ego/camera not converted"]
    assert kept_sensors(tmp_path / "dst") == {"ego/lidar", "infra/lidar", "infra/camera"}
    assert "ego/camera" not in DatasetReader(tmp_path / "dst").frame_graph(SCENE).frames


def _truncate(path: Path) -> str:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return "expected the file to end with the EOI marker ff d9, got"


def _png(path: Path) -> str:
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    return "expected a JPEG file (bytes ff d8), got 89 50 4e 47 0d 0a 1a 0a"


def _cut_in_header(path: Path) -> str:
    path.write_bytes(path.read_bytes()[:300])
    return "runs past the end of the 300-byte file (truncated file?)"


def _edit_json(path: Path, field: str, value: object) -> None:
    data = json.loads(path.read_text())
    data[field] = value
    path.write_text(json.dumps(data))


@pytest.mark.parametrize(("rel", "damage"), [
    ("image/001366.jpg", _truncate),
    ("image/001366.jpg", _png),
    ("image/001366.jpg", _cut_in_header),
    ("calib/camera_intrinsic/001366.json", lambda p: _edit_json(p, "cam_K", [2000.0, 0.0, 960.0, 0.0, 2000.0, 540.0,
                                                                             0.0, 0.0])
     or "field cam_K: expected finite numbers of shape (3, 3), got [2000.0, 0.0, 960.0, 0.0, 2000.0, 540.0, 0.0, 0.0]"),
    ("calib/camera_intrinsic/001366.json", lambda p: _edit_json(p, "cam_D", [-0.3, "k2", 0.0, 0.0, 0.0])
     or "field cam_D: expected numbers, got [-0.3, 'k2', 0.0, 0.0, 0.0]"),
    ("calib/camera_intrinsic/001366.json", lambda p: _edit_json(p, "cam_K", [0.0, 0.0, 960.0, 0.0, 2000.0, 540.0,
                                                                             0.0, 0.0, 1.0])
     or "field cam_K: expected [fx, s, cx, 0, fy, cy, 0, 0, 1] with fx, fy > 0, got [0.0, 0.0, 960.0"),
    ("calib/virtuallidar_to_camera/001366.json", lambda p: _edit_json(p, "rotation", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
     or "field rotation: expected finite numbers of shape (3, 3), got [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]"),
    ("calib/virtuallidar_to_camera/001366.json", lambda p: _edit_json(p, "translation", [[0.4], ["up"], [1.1]])
     or "field translation: expected numbers, got [[0.4], ['up'], [1.1]]"),
])
def test_a_damaged_image_or_camera_calibration_costs_only_that_camera(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], rel: str, damage) -> None:
    build_dair(tmp_path / "src", skew=0.0)
    path = tmp_path / "src" / "infrastructure-side" / rel
    expected = damage(path)
    status, lines = run_cli(tmp_path / "src", tmp_path / "dst", capsys)
    assert status == 1 and len(lines) == 1
    assert lines[0].startswith(f"error: {SCENE}: {path}: ") and expected in lines[0]
    assert lines[0].endswith("; camera infra/camera not converted")
    assert kept_sensors(tmp_path / "dst") == {"ego/lidar", "infra/lidar", "ego/camera"}


def test_a_data_info_row_naming_another_image_costs_that_camera(tmp_path: Path, capsys) -> None:
    build_dair(tmp_path / "src", skew=0.0)
    data_info = tmp_path / "src" / "vehicle-side" / "data_info.json"
    rows = json.loads(data_info.read_text())
    data_info.write_text(json.dumps([{**rows[0], "image_path": "image/017315.jpg"}]))
    status, lines = run_cli(tmp_path / "src", tmp_path / "dst", capsys)
    assert status == 1 and lines == [
        f"error: {SCENE}: {data_info}: frame 017314: field image_path: expected 'image/017314.jpg' (the pair's "
        "vehicle_image_path), got 'image/017315.jpg'; camera ego/camera not converted"]
    assert kept_sensors(tmp_path / "dst") == {"ego/lidar", "infra/lidar", "infra/camera"}
