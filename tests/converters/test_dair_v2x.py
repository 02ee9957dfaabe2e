"""DAIR-V2X-C converter on the real cooperative pair, against the DAIR devkit's formulas written out here.

Real files (linked in place from ../shared/realdata/dair_v2x): both PCDs (binary_compressed, mixed
types), both per-side label files and ``cooperative/selected_data_info.json`` (system_error_offset
-0.7, -0.54). The calib folders are not published with them, so they are built here in the official
format (``lidar_to_novatel`` nested under ``transform``, translations as 3x1), with a rotation that is
not orthonormal like the real re-calibrations; the infrastructure pose is chosen so that
infra -> vehicle equals the real derived ``cooperative/calib/lidar_i2v/017314.json``.

Oracle formulas (DAIR-V2X ``v2x/v2x_utils/transformation_utils.py`` ``trans_lidar_i2v`` and OpenCOOD's
``dair`` datasets ``veh_side_rot_and_trans_to_trasnformation_matrix`` /
``inf_side_rot_and_trans_to_trasnformation_matrix``): vehicle lidar->world = novatel_to_world @
lidar_to_novatel with the raw matrices; infra lidar->world = virtuallidar_to_world with
t_x += delta_x, t_y += delta_y. Box corners: centre ± R_z(rotation)·(l, w, h)/2.
"""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.base import Report
from avdata.converters.dair_v2x import DairV2xConverter
from avdata.loaders import Collaboration, FrameDataset, FrameOptions
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.converters.v2x_eval import check_eval_three_missed_one_false
from tests.realdata import REALDATA

REPO = Path(__file__).resolve().parents[2]
REAL = REALDATA / "dair_v2x"
SCENE = "coop_017314"
OFFSET = np.array([-0.7, -0.54, 0.0])


def yaw_matrix(yaw: float) -> np.ndarray:
    return np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])


def homogeneous(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = rotation, translation
    return matrix


#: Camera files per side (frame id, the data_info field of the extrinsic, image time in µs).
CAMERAS = {"vehicle-side": ("017314", "lidar_to_camera", "1626155145863530"),
           "infrastructure-side": ("001366", "virtuallidar_to_camera", "1626155145816412")}
IMAGE_SIZE = (1920, 1080)


def pitch_matrix(pitch: float) -> np.ndarray:
    """Rotation about x (the optical frame's right axis: a positive angle tilts the view down)."""
    return np.array([[1.0, 0.0, 0.0], [0.0, np.cos(pitch), -np.sin(pitch)], [0.0, np.sin(pitch), np.cos(pitch)]])


#: Lidar axes (x forward, y left, z up) into optical ones (x right, y down, z forward).
OPTICAL_R_LIDAR = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def write_camera_files(root: Path, camera_skew: float) -> dict[str, dict]:
    """Per side: a JPEG (OpenCV, drawn here), ``calib/camera_intrinsic`` and the lidar-to-camera extrinsic.

    Real-looking DAIR values: 1920 x 1080, fx ~ 2000 px, plumb_bob ``cam_D``; the vehicle camera looks
    forward from just below the lidar, the infrastructure camera down the road, tilted 12° down. The
    extrinsic rotation is skewed off orthonormal by ``camera_skew`` like the real re-calibrations.
    Returns the data_info.json fields of each side's frame.
    """
    poses = {"vehicle-side": (pitch_matrix(np.radians(1.5)) @ yaw_matrix(np.radians(0.8)), np.array([0.35, 0.05, -0.45])),
             "infrastructure-side": (pitch_matrix(np.radians(12.0)) @ yaw_matrix(np.radians(-2.0)),
                                     np.array([0.4, 0.2, 1.1]))}
    intrinsics = {"vehicle-side": ([2183.4, 0.0, 940.6, 0.0, 2329.3, 567.6, 0.0, 0.0, 1.0],
                                   [-0.4828, 0.5010, -0.000996, 0.000294, 0.0]),
                  "infrastructure-side": ([1994.2, 0.0, 963.1, 0.0, 1946.6, 540.8, 0.0, 0.0, 1.0],
                                          [-0.3202, 0.1152, 0.00112, -0.00047, -0.0181])}
    rows = {}
    for side, (frame, extrinsic, image_time) in CAMERAS.items():
        tilt, position_lidar = poses[side]
        rotation = tilt @ OPTICAL_R_LIDAR + camera_skew * np.array([[0, 1, 0], [1, 0, 0], [0, 0, 0]])
        cam_K, cam_D = intrinsics[side]
        image = np.zeros((IMAGE_SIZE[1], IMAGE_SIZE[0], 3), np.uint8)
        image[:, :, 0] = np.arange(IMAGE_SIZE[0]) % 256
        image[:, :, 2] = 80 if side == "vehicle-side" else 200
        ok, jpeg = cv2.imencode(".jpg", image)
        assert ok
        files = {f"image/{frame}.jpg": jpeg.tobytes(),
                 f"calib/camera_intrinsic/{frame}.json": json.dumps({"cam_K": cam_K, "cam_D": cam_D}).encode(),
                 f"calib/{extrinsic}/{frame}.json": json.dumps({
                     "rotation": rotation.tolist(), "translation": (-tilt @ OPTICAL_R_LIDAR @ position_lidar)[:, None].tolist()
                 }).encode()}
        for rel, data in files.items():
            (root / side / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / side / rel).write_bytes(data)
        rows[side] = {"image_path": f"image/{frame}.jpg", "image_timestamp": image_time,
                      "calib_camera_intrinsic_path": f"calib/camera_intrinsic/{frame}.json",
                      f"calib_{extrinsic}_path": f"calib/{extrinsic}/{frame}.json"}
    return rows


def build_dair(root: Path, skew: float, camera_skew: float = 0.0) -> dict[str, np.ndarray]:
    """The official layout around the real files; returns the raw 4x4 matrices the devkit would build."""
    for rel in ("vehicle-side/velodyne/017314.pcd", "vehicle-side/label/lidar/017314.json",
                "infrastructure-side/velodyne/001366.pcd", "infrastructure-side/label/virtuallidar/001366.json",
                "cooperative/selected_data_info.json"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).symlink_to(REAL / rel)
    # lidar_to_novatel: a real-looking mount, rotation skewed off orthonormal by ``skew``.
    lidar_to_novatel = homogeneous(yaw_matrix(np.radians(-90.6)) + skew * np.array([[0, 1, 0], [1, 0, 0], [0, 0, 0]]),
                                   np.array([0.96, 0.02, 1.71]))
    novatel_to_world = homogeneous(yaw_matrix(1.234) @ [[1, 0, 0], [0, np.cos(0.01), -np.sin(0.01)],
                                                        [0, np.sin(0.01), np.cos(0.01)]],
                                   np.array([2043.71, -1287.45, 19.8]))
    i2v = json.loads((REAL / "cooperative/calib/lidar_i2v/017314.json").read_text())
    vehicle_lidar_to_world = novatel_to_world @ lidar_to_novatel
    infra_to_world = vehicle_lidar_to_world @ homogeneous(np.asarray(i2v["rotation"]), np.ravel(i2v["translation"]))
    files = {
        "vehicle-side/calib/lidar_to_novatel/017314.json": {"transform": {
            "rotation": lidar_to_novatel[:3, :3].tolist(), "translation": lidar_to_novatel[:3, 3:].tolist()}},
        "vehicle-side/calib/novatel_to_world/017314.json": {
            "rotation": novatel_to_world[:3, :3].tolist(), "translation": novatel_to_world[:3, 3:].tolist()},
        "infrastructure-side/calib/virtuallidar_to_world/001366.json": {
            "rotation": infra_to_world[:3, :3].tolist(), "translation": (infra_to_world[:3, 3:] - OFFSET[:, None]).tolist()},
    }
    # cooperative/label_world: the vehicle's labels moved to world by the devkit chain.
    labels = json.loads((REAL / "vehicle-side/label/lidar/017314.json").read_text())
    heading = np.arctan2(vehicle_lidar_to_world[1, 0], vehicle_lidar_to_world[0, 0])
    world_labels = []
    for entry in labels:
        location = np.array([entry["3d_location"][k] for k in "xyz"])
        centre = vehicle_lidar_to_world[:3, :3] @ location + vehicle_lidar_to_world[:3, 3]
        world_labels.append({**entry, "3d_location": dict(zip("xyz", centre.tolist(), strict=True)),
                             "rotation": float(entry["rotation"]) + float(heading)})
    files["cooperative/label_world/017314.json"] = world_labels
    camera_rows = write_camera_files(root, camera_skew)
    files["vehicle-side/data_info.json"] = [{"pointcloud_path": "velodyne/017314.pcd",
                                             "pointcloud_timestamp": "1626155145901946",
                                             **camera_rows["vehicle-side"]}]
    files["infrastructure-side/data_info.json"] = [{"pointcloud_path": "velodyne/001366.pcd",
                                                    "pointcloud_timestamp": "1626155145843210",
                                                    **camera_rows["infrastructure-side"]}]
    for rel, content in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(json.dumps(content))
    raw_infra = homogeneous(infra_to_world[:3, :3], infra_to_world[:3, 3] - OFFSET)
    raw_infra[:3, 3] += OFFSET  # the devkit's inf_side_rot_and_trans_to_trasnformation_matrix
    return {"vehicle": vehicle_lidar_to_world, "infra": raw_infra}


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray], list]:
    root = tmp_path_factory.mktemp("dair")
    matrices = build_dair(root / "src", skew=2e-5)
    result = run_conversion(DairV2xConverter(ConvertConfig(src=root / "src", dst=root / "dst", quiet=True)))
    assert result.written == [SCENE] and result.n_errors == 0
    return root / "dst", matrices, result.problems


def test_non_orthonormal_rotation_warned_and_recorded(converted: tuple[Path, dict, list]) -> None:
    dst, _, problems = converted
    # the infrastructure pose was built through the skewed vehicle mount, so it is skewed too
    assert [(p.severity, Path(p.file).parent.name) for p in problems] == [
        ("warning", "lidar_to_novatel"), ("warning", "virtuallidar_to_world")]
    assert all("not orthonormal" in p.message for p in problems)
    residuals = DatasetReader(dst).scene(SCENE).metadata["calibration_residuals"]
    assert 1e-5 < residuals["vehicle lidar_to_novatel"] < 1e-4
    assert residuals["vehicle novatel_to_world"] < 1e-12
    assert 1e-5 < residuals["infrastructure virtuallidar_to_world"] < 1e-4
    assert validate_dataset(dst) == []


def test_world_points_equal_devkit_chain(converted: tuple[Path, dict, list]) -> None:
    dst, matrices, _ = converted
    dataset = DatasetReader(dst)
    graph = dataset.frame_graph(SCENE)
    scene = dataset.scene(SCENE)
    assert scene.frame_infos()[0].timestamp_ns == 1626155145901946000
    assert scene.frame_infos()[0].sensor_timestamps_ns == {
        "ego/lidar": 1626155145901946000, "infra/lidar": 1626155145843210000,
        "ego/camera": 1626155145863530000, "infra/camera": 1626155145816412000}
    residuals = scene.metadata["calibration_residuals"]
    for sensor, key, residual in (("ego/lidar", "vehicle", residuals["vehicle lidar_to_novatel"]),
                                  ("infra/lidar", "infra", residuals["infrastructure virtuallidar_to_world"])):
        cloud = dataset.points(SCENE, 0, sensor)
        xyz = np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float64)
        ours = graph.lookup("world", sensor, scene.frame_infos()[0].timestamp_ns).apply(xyz)
        devkit = xyz @ matrices[key][:3, :3].T + matrices[key][:3, 3]
        # the orthonormalised rotation moves a point by at most ~residual x its range (stated bound)
        bound = 2 * residual * np.linalg.norm(xyz, axis=1) + 1e-6
        assert np.all(np.linalg.norm(ours - devkit, axis=1) <= bound)
    assert scene.points("ego/lidar", scene.frame_infos()[0].timestamp_ns).dtype.names == (
        "x", "y", "z", "intensity", "timestamp")


def test_exact_chain_when_calibration_is_orthonormal(tmp_path: Path) -> None:
    matrices = build_dair(tmp_path / "src", skew=0.0)
    result = run_conversion(DairV2xConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    assert result.n_errors == 0
    dataset = DatasetReader(tmp_path / "dst")
    cloud = dataset.points(SCENE, 0, "ego/lidar")
    xyz = np.stack([cloud["x"], cloud["y"], cloud["z"]], axis=1).astype(np.float64)
    time_ns = dataset.scene(SCENE).frame_infos()[0].timestamp_ns
    ours = dataset.frame_graph(SCENE).lookup("world", "ego/lidar", time_ns).apply(xyz)
    devkit = xyz @ matrices["vehicle"][:3, :3].T + matrices["vehicle"][:3, 3]
    np.testing.assert_allclose(ours, devkit, atol=1e-6, rtol=0)
    world_T_infra = dataset.frame_graph(SCENE).lookup("world", "infra/lidar", time_ns).as_matrix()
    np.testing.assert_allclose(world_T_infra[:3, 3], matrices["infra"][:3, 3], atol=1e-6)


def test_world_boxes_and_visibility_hints(converted: tuple[Path, dict, list]) -> None:
    dst, _, _ = converted
    scene = DatasetReader(dst).scene(SCENE)
    _, labels = scene.labels(0)
    world = json.loads((dst.parent / "src" / "cooperative" / "label_world" / "017314.json").read_text())
    assert len(labels) == len(world) == 23
    for i, entry in enumerate(world):
        l, w, h = (entry["3d_dimensions"][k] for k in "lwh")
        centre = np.array([entry["3d_location"][k] for k in "xyz"])
        signs = np.array([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)])
        corners = centre + (signs * [l / 2, w / 2, h / 2]) @ yaw_matrix(entry["rotation"]).T
        ours = labels.boxes.corners()[i]
        assert np.max(np.min(np.linalg.norm(ours[:, None] - corners[None], axis=2), axis=1)) < 1e-6
    assert dict(zip(labels.source_classes, labels.boxes.classes, strict=True))["Trafficcone"] == "traffic_cone"
    vehicle_hints = scene.visibility("ego/lidar", 0)
    assert vehicle_hints is not None and vehicle_hints.in_fov.all()  # every cooperative box is a vehicle label here
    assert vehicle_hints.n_points.max() > 50
    infra_hints = scene.visibility("infra/lidar", 0)
    assert infra_hints is not None and 0 < infra_hints.in_fov.sum() < len(labels)


def test_loader_collaborative_early_fusion_and_comm_range(converted: tuple[Path, dict, list]) -> None:
    dst, _, _ = converted
    def options(**link: float) -> FrameOptions:
        return FrameOptions(sensors=("*/lidar",), frame="ego/lidar",
                            collaboration=Collaboration(agents=("ego", "infra"), fusion="early", **link))

    fused = FrameDataset(dst, options())
    item = fused[0]
    assert item["agents"] == ["ego", "infra"] and item["agent_received"].tolist() == [True, True]
    agent_index = item["points"]["fused"][:, item["point_fields"]["fused"].index("agent_index")]
    assert (agent_index == 0).sum() == 62199 and (agent_index == 1).sum() == 53653
    distance = float(item["agent_distance_m"][1])
    cut = FrameDataset(dst, options(comm_range_m=distance - 1.0))[0]
    assert cut["agent_received"].tolist() == [True, False] and len(cut["points"]["fused"]) == 62199


def test_eval_detection_avdata_protocol(converted: tuple[Path, dict, list], tmp_path: Path) -> None:
    dst, _, _ = converted
    check_eval_three_missed_one_false(dst, tmp_path)


def test_bad_calibration_and_pcd_cost_their_record(tmp_path: Path) -> None:
    build_dair(tmp_path / "src", skew=0.05)  # beyond the 1e-2 limit: the scene cannot be placed in world
    result = run_conversion(DairV2xConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    assert result.failed == [SCENE] and len(result.problems) == 1
    assert "lidar_to_novatel/017314.json: field rotation: expected a rotation" in str(result.problems[0])
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "convert", "dair-v2x", str(tmp_path / "src"),
                           str(tmp_path / "dst2"), "--quiet"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr


def test_damaged_pcd_costs_only_that_cloud(tmp_path: Path) -> None:
    build_dair(tmp_path / "src", skew=0.0)
    infra_pcd = tmp_path / "src" / "infrastructure-side" / "velodyne" / "001366.pcd"
    raw = infra_pcd.read_bytes()
    infra_pcd.unlink()
    infra_pcd.write_bytes(raw[: len(raw) // 3])
    result = run_conversion(DairV2xConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    assert result.written == [SCENE] and result.n_errors == 1
    assert "001366.pcd" in result.problems[0].file
    assert result.problems[0].message == ("binary_compressed data: expected the compressed block of 760437 bytes within "
                                          "the file, got 254640 bytes after its sizes")
    scene = DatasetReader(tmp_path / "dst").scene(SCENE)
    assert set(scene.frame_infos()[0].sensor_timestamps_ns) == {"ego/lidar", "ego/camera", "infra/camera"}
    assert len(scene.labels(0)[1]) == 23


def test_a_side_label_path_that_is_a_folder_is_an_error_not_a_missing_file(tmp_path: Path) -> None:
    build_dair(tmp_path / "src", skew=0.0)
    side = tmp_path / "src" / "infrastructure-side" / "label" / "virtuallidar" / "001366.json"
    side.unlink()
    side.mkdir()
    result = run_conversion(DairV2xConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True)))
    assert result.written == [SCENE] and result.n_errors == 1
    assert [(p.severity, Path(p.file).name) for p in result.problems] == [("error", "001366.json")]
    assert "cannot read (Is a directory)" in result.problems[0].message
    assert len(DatasetReader(tmp_path / "dst").scene(SCENE).labels(0)[1]) == 23


def test_a_pair_list_that_is_a_fifo_is_named_as_such(tmp_path: Path) -> None:
    # It was reported as "cooperative/data_info.json: cannot read (No such file or directory)".
    import os

    build_dair(tmp_path / "src", skew=0.0)
    pairs = tmp_path / "src" / "cooperative" / "selected_data_info.json"
    pairs.unlink()
    os.mkfifo(pairs)
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "convert", "dair-v2x", str(tmp_path / "src"),
                           str(tmp_path / "dst"), "--quiet"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1
    assert proc.stderr == f"avdata: error: {pairs}: expected a regular file, got a FIFO\n"


def test_a_side_data_info_is_read_once_per_version_not_once_per_pair(tmp_path: Path, monkeypatch) -> None:
    # Each pair needs one row of each side's data_info.json; reading the whole list again for every pair
    # was quadratic on DAIR-V2X-C (~6,600 pairs).
    from avdata.converters.dair_v2x import pairs

    path = tmp_path / "data_info.json"
    path.write_text(json.dumps([{"pointcloud_path": f"velodyne/{k:06d}.pcd", "pointcloud_timestamp": str(k)}
                                for k in range(50)]))
    reads: list[Path] = []
    real_read = pairs.read_json
    monkeypatch.setattr(pairs, "read_json", lambda p: reads.append(p) or real_read(p))
    report = Report("coop_x", strict=False)
    rows = [pairs.data_info_row(path, f"{k:06d}", report) for k in range(50)]
    assert [row["pointcloud_timestamp"] for row in rows] == [str(k) for k in range(50)] and reads == [path]
    # A changed file is read again (its size and time are part of the key).
    path.write_text(json.dumps([{"pointcloud_path": "velodyne/000007.pcd", "pointcloud_timestamp": "99"}]))
    assert pairs.data_info_row(path, "000007", report)["pointcloud_timestamp"] == "99" and len(reads) == 2
    assert pairs.data_info_row(path, "000008", report) is None and len(reads) == 2
    assert [(p.severity, p.message) for p in report.problems] == [
        ("warning", "no entry with pointcloud_path of frame 000008 (frame 000008: no timestamps; camera files by frame id)")]


def test_a_task_s_converter_does_not_carry_every_pair(tmp_path: Path) -> None:
    # Pickled with each scene task, the converter carried the whole pair list: quadratic in the pairs.
    build_dair(tmp_path / "src", skew=0.0)
    converter = DairV2xConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "dst", quiet=True))
    assert converter.list_scenes() == [SCENE]
    copy = pickle.loads(pickle.dumps(converter))
    assert copy._scenes is None and converter._scenes is not None
    assert copy.list_scenes() == [SCENE]  # read again, once, where it runs
