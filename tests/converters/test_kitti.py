"""KITTI object and tracking converters against the real sample files in ../shared/realdata/kitti.

The reference values are computed here straight from the text files with KITTI's own formulas
(devkit ``compute_box_3d``, ``P · R0_rect · Tr_velo_to_cam · x``), not with the converter's readers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter, KittiTrackingConverter
from avdata.schema import DatasetReader
from tests.realdata import REALDATA

REAL = REALDATA / "kitti"
OBJECT = REAL / "object"
TRACKING = REAL / "tracking"

#: KITTI devkit corner order (x: ±l/2, y: 0 bottom / -h top, z: ±w/2) -> avdata's (nuScenes order):
#: avdata corner k is KITTI corner KITTI_OF_AVDATA[k].
KITTI_OF_AVDATA = [4, 5, 1, 0, 7, 6, 2, 3]



def parse_calib(path: Path) -> dict[str, np.ndarray]:
    out = {}
    for line in path.read_text().splitlines():
        if line.strip():
            key, *values = line.replace(":", " ").split()
            out[key] = np.array(values, dtype=float)
    return out


def rect_from_velo(calib: dict[str, np.ndarray], rect_key: str, velo_key: str) -> np.ndarray:
    """(4, 4) R0_rect · Tr_velo_to_cam as KITTI composes them, unorthonormalised."""
    r0 = np.eye(4)
    r0[:3, :3] = calib[rect_key].reshape(3, 3)
    tr = np.eye(4)
    tr[:3, :] = calib[velo_key].reshape(3, 4)
    return r0 @ tr


def kitti_corners(hwl: np.ndarray, location: np.ndarray, rotation_y: np.ndarray) -> np.ndarray:
    """(N, 8, 3) devkit compute_box_3d corners in the rectified camera."""
    h, w, l = hwl.T
    x = np.stack([l / 2, l / 2, -l / 2, -l / 2, l / 2, l / 2, -l / 2, -l / 2], axis=1)
    y = np.stack([0 * h, 0 * h, 0 * h, 0 * h, -h, -h, -h, -h], axis=1)
    z = np.stack([w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2], axis=1)
    c, s = np.cos(rotation_y)[:, None], np.sin(rotation_y)[:, None]
    return np.stack([c * x + s * z, y, -s * x + c * z], axis=2) + location[:, None, :]


def label_rows(path: Path) -> list[list[str]]:
    return [line.split() for line in path.read_text().splitlines() if line.strip()]


def project_errors(dataset: DatasetReader, scene: str, frame_index: int, rect_T_velo: np.ndarray,
                   calib: dict[str, np.ndarray]) -> list[float]:
    """Max pixel error per camera (2, 3) between the unified graph + CameraCalibration and KITTI's formula."""
    reader = dataset.scene(scene)
    t = dataset.sensor_time(scene, frame_index, "ego/velodyne")
    points = dataset.points(scene, frame_index, "ego/velodyne")
    xyz = np.stack([points["x"], points["y"], points["z"]], axis=1).astype(np.float64)
    errors = []
    for cam in (2, 3):
        P = calib[f"P{cam}"].reshape(3, 4)
        reference = (P @ rect_T_velo @ np.c_[xyz, np.ones(len(xyz))].T).T
        in_front = reference[:, 2] > 1.0
        reference = reference[in_front, :2] / reference[in_front, 2:]
        cam_T_velo = reader.graph.lookup(f"ego/cam{cam}", "ego/velodyne", t)
        K = np.array(reader.camera_calibration(f"ego/cam{cam}", t).K).reshape(3, 3)
        in_cam = cam_T_velo.apply(xyz[in_front]) @ K.T
        pixels = in_cam[:, :2] / in_cam[:, 2:]
        errors.append(float(np.abs(pixels - reference).max()))
    return errors


@pytest.fixture(scope="module")
def object_dataset(tmp_path_factory) -> DatasetReader:
    dst = tmp_path_factory.mktemp("kitti_object")
    result = run_conversion(KittiObjectConverter(ConvertConfig(src=OBJECT, dst=dst, quiet=True)))
    assert result.written == ["training_000000"] and not result.problems
    return DatasetReader(dst)


@pytest.fixture(scope="module")
def tracking_dataset(tmp_path_factory) -> tuple[DatasetReader, object]:
    dst = tmp_path_factory.mktemp("kitti_tracking")
    result = run_conversion(KittiTrackingConverter(ConvertConfig(src=TRACKING, dst=dst, quiet=True)))
    return DatasetReader(dst), result


def test_object_projection_through_graph_matches_kitti_formula(object_dataset):
    worst = []
    for frame_index in range(3):
        calib = parse_calib(OBJECT / "training" / "calib" / f"{frame_index:06d}.txt")
        rect_T_velo = rect_from_velo(calib, "R0_rect", "Tr_velo_to_cam")
        worst.extend(project_errors(object_dataset, "training_000000", frame_index, rect_T_velo, calib))
    print(f"object max projection error: {max(worst):.6f} px")
    assert max(worst) < 0.01


def test_tracking_projection_through_graph_matches_kitti_formula(tracking_dataset):
    dataset, _ = tracking_dataset
    calib = parse_calib(TRACKING / "training" / "calib" / "0001.txt")
    rect_T_velo = rect_from_velo(calib, "R_rect", "Tr_velo_cam")
    worst = [e for frame_index in (0, 1) for e in project_errors(dataset, "training_0001", frame_index,
                                                                   rect_T_velo, calib)]
    print(f"tracking max projection error: {max(worst):.6f} px")
    assert max(worst) < 0.01


def test_object_corners_back_in_rectified_camera_match_kitti_formula(object_dataset):
    reader = object_dataset.scene("training_000000")
    worst = 0.0
    for frame_index in range(3):
        rows = [r for r in label_rows(OBJECT / "training" / "label_2" / f"{frame_index:06d}.txt")
                if r[0] != "DontCare"]
        values = np.array([r[1:] for r in rows], dtype=float)
        expected = kitti_corners(values[:, 7:10], values[:, 10:13], values[:, 13])
        info, labels = reader.labels(frame_index)
        assert labels.boxes.frame == "world"
        corners = labels.boxes.to("ego/cam0", reader.graph, info.timestamp_ns).corners()
        worst = max(worst, float(np.abs(corners - expected[:, KITTI_OF_AVDATA]).max()))
        assert labels.source_classes.tolist() == [r[0] for r in rows]
    print(f"object max corner error: {worst:.2e} m")
    assert worst < 1e-4


def test_object_labels_visibility_and_classes(object_dataset):
    reader = object_dataset.scene("training_000000")
    _, labels = reader.labels(1)
    rows = label_rows(OBJECT / "training" / "label_2" / "000001.txt")
    care = [r for r in rows if r[0] != "DontCare"]
    assert labels.source_classes.tolist() == ["Truck", "Car", "Cyclist"]
    assert labels.boxes.classes.tolist() == ["truck", "car", "cyclist"]
    assert labels.boxes.ids.tolist() == ["000001_0", "000001_1", "000001_2"]
    vis = reader.visibility("ego/cam2", 1)
    np.testing.assert_array_equal(vis.object_ids, labels.boxes.ids)
    np.testing.assert_array_equal(vis.occlusion, [int(r[2]) for r in care])
    np.testing.assert_allclose(vis.truncation, [float(r[1]) for r in care], atol=1e-6)
    np.testing.assert_allclose(vis.alpha_rad, [float(r[3]) for r in care], atol=1e-6)
    np.testing.assert_allclose(vis.box2d_xyxy, np.array([r[4:8] for r in care], dtype=float), atol=1e-4)
    dont_care = np.array([r[4:8] for r in rows if r[0] == "DontCare"], dtype=float)
    np.testing.assert_allclose(vis.ignore_regions_xyxy, dont_care, atol=1e-4)
    assert reader.metadata["kitti_sample_ids"] == [0, 1, 2]
    assert reader.metadata["time_nominal"] is True
    objects = object_dataset.objects()
    assert objects.column("source_class").to_pylist() == ["Pedestrian", "Truck", "Car", "Cyclist", "Misc", "Car"]
    assert objects.column("class").to_pylist() == ["pedestrian", "truck", "car", "cyclist", "other", "car"]


def test_tracking_partial_copy_converts_every_pose_and_label(tracking_dataset):
    dataset, result = tracking_dataset
    assert result.written == ["training_0001"] and result.n_errors == 0
    warnings = [p for p in result.problems if p.severity == "warning"]
    assert sorted(Path(p.file).parent.name for p in warnings) == ["image_02", "image_03", "velodyne"]
    assert all("445 of 447 frames" in p.message for p in warnings)
    frames = dataset.frames()
    assert frames.num_rows == 447
    np.testing.assert_array_equal(frames.column("timestamp_ns").to_numpy(), np.arange(447) * 100_000_000)
    with_points = [i for i, times in enumerate(frames.column("sensor_timestamps_ns").to_pylist())
                   if "ego/velodyne" in dict(times)]
    assert with_points == [0, 1]
    reader = dataset.scene("training_0001")
    assert reader.metadata["time_nominal"] is True and "nominal" in reader.metadata["time"]
    rows = label_rows(TRACKING / "training" / "label_02" / "0001.txt")
    care = [r for r in rows if r[2] != "DontCare"]
    assert dataset.objects().num_rows == len(care)
    assert dataset.visibility().num_rows == len(care)


def test_tracking_corners_ids_and_visibility(tracking_dataset):
    dataset, _ = tracking_dataset
    reader = dataset.scene("training_0001")
    rows = label_rows(TRACKING / "training" / "label_02" / "0001.txt")
    worst = 0.0
    for frame_index in (0, 1, 100, 446):
        frame_rows = [r for r in rows if int(r[0]) == frame_index and r[2] != "DontCare"]
        values = np.array([r[3:] for r in frame_rows], dtype=float).reshape(-1, 14)
        info, labels = reader.labels(frame_index)
        assert labels.boxes.ids.tolist() == [r[1] for r in frame_rows]
        assert labels.source_classes.tolist() == [r[2] for r in frame_rows]
        corners = labels.boxes.to("ego/cam0", reader.graph, info.timestamp_ns).corners()
        expected = kitti_corners(values[:, 7:10], values[:, 10:13], values[:, 13])
        if len(frame_rows):
            worst = max(worst, float(np.abs(corners - expected[:, KITTI_OF_AVDATA]).max()))
        vis = reader.visibility("ego/cam2", frame_index)
        np.testing.assert_array_equal(vis.occlusion, values[:, 1].astype(int))
        np.testing.assert_allclose(vis.box2d_xyxy, values[:, 3:7], atol=1e-4)
        assert [e["kitti_truncation_level"] for e in labels.extras or []] == values[:, 0].tolist()
        dont_care = [r[6:10] for r in rows if int(r[0]) == frame_index and r[2] == "DontCare"]
        np.testing.assert_allclose(vis.ignore_regions_xyxy, np.array(dont_care, dtype=float).reshape(-1, 4), atol=1e-4)
    print(f"tracking max corner error: {worst:.2e} m")
    assert worst < 1e-4


def test_tracking_oxts_speeds_match_forward_velocity(tracking_dataset):
    """Poses from oxts (Mercator scale, heading) against the packets' own forward velocity ``vf``.

    Frame-to-frame, the issue's 0.2 m/s cannot hold on this real sequence with any constant period:
    the synced oxts packets are 100 Hz samples nearest to ~9.7 Hz sweeps, so consecutive packets are
    100 or 110 ms apart (see the raw drive's oxts timestamps), and GPS noise adds a few cm. At the
    nominal 10 Hz the per-frame median error is < 0.1 m/s but single frames reach 1.2 m/s. Over 3 s
    windows with KITTI's real mean sweep period (measured from the raw velodyne timestamps), the
    speeds match ``vf`` within 0.2 m/s, which checks the pose conversion itself.
    """
    dataset, _ = tracking_dataset
    graph = dataset.scene("training_0001").graph
    times = np.arange(447, dtype=np.int64) * 100_000_000
    world_T_ego = graph.lookup("world", "ego", times)
    assert np.allclose(world_T_ego[0].as_matrix(), np.eye(4), atol=1e-9)
    oxts = np.loadtxt(TRACKING / "training" / "oxts" / "0001.txt")
    vf = oxts[:, 8]
    nominal = np.linalg.norm(np.diff(world_T_ego.translation, axis=0), axis=1) / 0.1
    frame_error = np.abs(nominal - (vf[1:] + vf[:-1]) / 2.0)
    raw_times = (REAL / "raw" / "2011_09_26" / "2011_09_26_drive_0001_sync" / "velodyne_points" / "timestamps.txt")
    seconds = [float(line.split(":")[-1]) + 60 * int(line.split(":")[-2]) for line in raw_times.read_text().split("\n")
               if line.strip()]
    period_s = (seconds[-1] - seconds[0]) / (len(seconds) - 1)
    window = 30
    path = np.linalg.norm(world_T_ego.translation[window:] - world_T_ego.translation[:-window], axis=1)
    mean_vf = np.array([np.trapezoid(vf[i : i + window + 1]) / window for i in range(len(vf) - window)])
    window_error = np.abs(path / (window * period_s) - mean_vf)
    print(f"tracking speed error: per frame at nominal 10 Hz median {np.median(frame_error):.3f} max "
          f"{frame_error.max():.3f} m/s; 3 s windows at the real {period_s * 1e3:.1f} ms period max "
          f"{window_error.max():.3f} m/s")
    assert 0.102 < period_s < 0.105
    assert np.median(frame_error) < 0.1
    assert window_error.max() < 0.2
    # Heading: the ego x axis in world turns by the oxts yaw change since the first packet.
    heading = np.arctan2(world_T_ego.rotation[:, 1, 0], world_T_ego.rotation[:, 0, 0])
    assert np.abs(np.angle(np.exp(1j * (heading - (oxts[:, 5] - oxts[0, 5]))))).max() < 0.01
