"""KITTI camera calibration as a ROS / Foxglove viewer reads it (Issue 17.1), on the real files.

A pinhole CameraCalibration projects points of its ``frame_id`` with ``[u v w]^T = P [x y z 1]^T``
(``u = (fx x + Tx) / z + cx``). Every real label's corners (devkit ``compute_box_3d``, written out
here), moved from ``world`` into each camera frame through the stored graph and projected by that
formula with the stored P, must land within 0.5 px of KITTI's ``P_i · R0_rect · Tr_velo_to_cam``
(equivalently ``P_i`` applied to the label's rectified-camera-0 corners). Every camera calibration
has a real image size (never 0x0).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter, KittiRawConverter, KittiTrackingConverter
from avdata.schema import DatasetReader
from tests.realdata import REALDATA

#: avdata corner k is devkit corner KITTI_OF_AVDATA[k].
KITTI_OF_AVDATA = [4, 5, 1, 0, 7, 6, 2, 3]
REAL = REALDATA / "kitti"


def parse_calib(path: Path) -> dict[str, np.ndarray]:
    out = {}
    for line in path.read_text().splitlines():
        if line.strip():
            key, *values = line.replace(":", " ").split()
            out[key] = np.array(values, dtype=float)
    return out


def devkit_corners(hwl: np.ndarray, location: np.ndarray, rotation_y: np.ndarray) -> np.ndarray:
    """(N, 8, 3) corners by the devkit's ``compute_box_3d`` (rectified camera 0), in avdata's corner order."""
    h, w, l = hwl.T
    x = np.stack([l / 2, l / 2, -l / 2, -l / 2, l / 2, l / 2, -l / 2, -l / 2], axis=1)
    y = np.stack([0 * h, 0 * h, 0 * h, 0 * h, -h, -h, -h, -h], axis=1)
    z = np.stack([w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2], axis=1)
    c, s = np.cos(rotation_y)[:, None], np.sin(rotation_y)[:, None]
    corners = np.stack([c * x + s * z, y, -s * x + c * z], axis=2) + location[:, None, :]
    return corners[:, KITTI_OF_AVDATA]


def ros_project(P: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of (N, 3) points in the calibration's frame by the ROS pinhole formula."""
    homogeneous = np.c_[points, np.ones(len(points))] @ np.asarray(P, dtype=np.float64).reshape(3, 4).T
    return homogeneous[:, :2] / homogeneous[:, 2:]


def label_values(lines: list[str], lead: int) -> tuple[list[int], np.ndarray]:
    rows = [line.split() for line in lines if line.strip() and line.split()[lead - 1] != "DontCare"]
    return [int(r[0]) for r in rows] if lead == 3 else [], np.array([r[lead:lead + 14] for r in rows], dtype=float)


def projection_errors(reader, frame_index: int, calib: dict[str, np.ndarray], expected_rect0: np.ndarray,
                      labels_order: np.ndarray) -> list[float]:
    """Max |ROS(stored) - P_i corners| per camera 2, 3 for one frame's boxes."""
    info, labels = reader.labels(frame_index)
    world = labels.boxes.corners()[labels_order].reshape(-1, 3)
    reference_corners = expected_rect0.reshape(-1, 3)
    in_front = reference_corners[:, 2] > 0.5
    errors = []
    for cam in (2, 3):
        P_kitti = calib[f"P{cam}"].reshape(3, 4)
        expected = ros_project(P_kitti, reference_corners[in_front])
        calibration = reader.camera_calibration(f"ego/cam{cam}", info.timestamp_ns)
        assert calibration.width > 0 and calibration.height > 0
        assert np.allclose(np.array(calibration.P).reshape(3, 4)[:, 3], 0.0)  # the frame is the camera's own
        cam_T_world = reader.graph.lookup(f"ego/cam{cam}", "world", info.timestamp_ns)
        got = ros_project(calibration.P, cam_T_world.apply(world[in_front]))
        errors.append(float(np.abs(got - expected).max()))
    return errors


def test_object_labels_project_by_ros_formula_within_half_a_pixel(tmp_path):
    run_conversion(KittiObjectConverter(ConvertConfig(src=REAL / "object", dst=tmp_path, quiet=True)))
    reader = DatasetReader(tmp_path).scene("training_000000")
    worst = []
    for frame_index in range(3):
        calib = parse_calib(REAL / "object" / "training" / "calib" / f"{frame_index:06d}.txt")
        lines = (REAL / "object" / "training" / "label_2" / f"{frame_index:06d}.txt").read_text().splitlines()
        _, values = label_values(lines, 1)
        expected = devkit_corners(values[:, 7:10], values[:, 10:13], values[:, 13])
        order = np.arange(len(values))
        worst.extend(projection_errors(reader, frame_index, calib, expected, order))
    # Both sides are exact formulas on the same numbers; the residue is KITTI's 7-digit rotations,
    # orthonormalised in the graph.
    assert max(worst) < 0.5
    print(f"object: max ROS-formula vs P_i R0 Tr error {max(worst):.2e} px over {3 * 2} images")


def test_tracking_labels_project_by_ros_formula_within_half_a_pixel(tmp_path):
    run_conversion(KittiTrackingConverter(ConvertConfig(src=REAL / "tracking", dst=tmp_path, quiet=True)))
    reader = DatasetReader(tmp_path).scene("training_0001")
    calib = parse_calib(REAL / "tracking" / "training" / "calib" / "0001.txt")
    lines = (REAL / "tracking" / "training" / "label_02" / "0001.txt").read_text().splitlines()
    frames, values = label_values(lines, 3)
    frames = np.array(frames)
    ids = np.array([line.split()[1] for line in lines if line.strip() and line.split()[2] != "DontCare"])
    worst = []
    for frame_index in range(0, 447, 7):
        rows = frames == frame_index
        if not np.any(rows):
            continue
        _, labels = reader.labels(frame_index)
        by_id = {oid: k for k, oid in enumerate(labels.boxes.ids.tolist())}
        order = np.array([by_id[i] for i in ids[rows]])
        expected = devkit_corners(values[rows, 7:10], values[rows, 10:13], values[rows, 13])
        worst.extend(projection_errors(reader, frame_index, calib, expected, order))
    assert worst and max(worst) < 0.5
    print(f"tracking: max ROS-formula vs P_i R0 Tr error {max(worst):.2e} px over {len(worst)} image frames")


@pytest.mark.parametrize("kind", ["object", "tracking", "raw"])
def test_every_camera_calibration_has_a_real_image_size(tmp_path, kind):
    converter = {"object": KittiObjectConverter, "tracking": KittiTrackingConverter, "raw": KittiRawConverter}[kind]
    run_conversion(converter(ConvertConfig(src=REAL / kind, dst=tmp_path, quiet=True)))
    dataset = DatasetReader(tmp_path)
    reader = dataset.scene(dataset.scenes[0])
    sizes = set()
    for cam in range(4):
        calibration = reader.camera_calibration(f"ego/cam{cam}")
        sizes.add((calibration.width, calibration.height))
        spec = reader.sensors()[f"ego/cam{cam}"]
        assert (spec["width"], spec["height"]) == (calibration.width, calibration.height)
    # KITTI crops the four rectified images of a drive to one size: the real image_2 PNG's (IHDR), or raw's S_rect_02.
    if kind == "raw":
        line = next(line for line in (REAL / "raw" / "2011_09_26" / "calib_cam_to_cam.txt").read_text().splitlines()
                    if line.startswith("S_rect_02:"))
        expected = tuple(int(float(v)) for v in line.split()[1:])
    else:
        png = next((REAL / kind / "training").glob("image_02/0001/000000.png" if kind == "tracking"
                                                   else "image_2/000000.png")).read_bytes()
        expected = tuple(int.from_bytes(png[i:i + 4], "big") for i in (16, 20))
    assert sizes == {expected}
