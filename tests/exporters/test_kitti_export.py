"""Export to KITTI object files: real KITTI files converted, exported and re-parsed."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter, KittiTrackingConverter
from avdata.demo import write_demo
from avdata.exporters.cli import add_export_subparser
from avdata.exporters.kitti import export_kitti_object
from avdata.schema import DatasetReader
from tests.realdata import REALDATA

REAL = REALDATA / "kitti"


def run_cli(argv: list[str]) -> int:
    """``avdata export ...`` through the exporter's own sub-parser (as avdata.cli wires it)."""
    parser = argparse.ArgumentParser(prog="avdata")
    add_export_subparser(parser.add_subparsers())
    args = parser.parse_args(argv)
    return args.run(args)


def parse_calib(path: Path) -> dict[str, np.ndarray]:
    out = {}
    for line in path.read_text().splitlines():
        if line.strip():
            key, *values = line.replace(":", " ").split()
            out[key] = np.array(values, dtype=float)
    return out


def split_lines(path: Path) -> tuple[list[list[float]], list[str], list[list[str]]]:
    """(numbers of object lines, their classes, DontCare lines as fields)."""
    rows = [line.split() for line in path.read_text().splitlines() if line.strip()]
    objects = [r for r in rows if r[0] != "DontCare"]
    return [[float(v) for v in r[1:]] for r in objects], [r[0] for r in objects], [r for r in rows if r[0] == "DontCare"]


def test_object_export_round_trip(tmp_path):
    src = REAL / "object" / "training"
    converted = tmp_path / "unified"
    run_conversion(KittiObjectConverter(ConvertConfig(src=REAL / "object", dst=converted, quiet=True)))
    assert run_cli(["export", "kitti-object", str(converted), str(tmp_path / "kitti")]) == 0
    out = tmp_path / "kitti" / "training"
    worst_calib = 0.0
    for sample in ("000000", "000001", "000002"):
        values, classes, dont_care = split_lines(out / "label_2" / f"{sample}.txt")
        expected_values, expected_classes, expected_dont_care = split_lines(src / "label_2" / f"{sample}.txt")
        assert classes == expected_classes
        np.testing.assert_allclose(values, np.array(expected_values).reshape(-1, 14), atol=1e-9, rtol=0)
        assert dont_care == expected_dont_care
        assert (out / "label_2" / f"{sample}.txt").read_text().splitlines()[0] == \
            (src / "label_2" / f"{sample}.txt").read_text().splitlines()[0]
        calib, expected = parse_calib(out / "calib" / f"{sample}.txt"), parse_calib(src / "calib" / f"{sample}.txt")
        assert sorted(calib) == sorted(expected)
        worst_calib = max(worst_calib, max(float(np.abs(calib[k] - expected[k]).max()) for k in expected))
        assert (out / "velodyne" / f"{sample}.bin").read_bytes() == (src / "velodyne" / f"{sample}.bin").read_bytes()
        assert (out / "image_2" / f"{sample}.png").read_bytes() == (src / "image_2" / f"{sample}.png").read_bytes()
    # KITTI's own matrices are kept in the scene metadata, so the export repeats them exactly.
    assert worst_calib == 0.0
    assert (tmp_path / "kitti" / "ImageSets" / "train.txt").read_text().split() == ["000000", "000001", "000002"]


def test_tracking_export_keeps_track_labels_and_skips_frames_without_sensor_data(tmp_path):
    converted = tmp_path / "unified"
    run_conversion(KittiTrackingConverter(ConvertConfig(src=REAL / "tracking", dst=converted, quiet=True)))
    result = export_kitti_object(converted, tmp_path / "kitti")
    assert (result.training, result.testing, result.skipped_frames) == (2, 0, 445)
    # One warning for the scene, not one line per frame (and not an error: the export exits 0).
    assert [(p.severity, p.message) for p in result.problems] == [
        ("warning", "frames 2-446 skipped: no message of ego/velodyne, ego/cam2")]
    assert run_cli(["export", "kitti-object", str(converted), str(tmp_path / "cli"), "--quiet"]) == 0
    rows = [line.split() for line in (REAL / "tracking" / "training" / "label_02" / "0001.txt").read_text().splitlines()]
    for frame in (0, 1):
        expected = np.array([r[3:17] for r in rows if int(r[0]) == frame and r[2] != "DontCare"], dtype=float)
        values, classes, dont_care = split_lines(tmp_path / "kitti" / "training" / "label_2" / f"{frame:06d}.txt")
        assert classes == [r[2] for r in rows if int(r[0]) == frame and r[2] != "DontCare"]
        values = np.array(values)
        np.testing.assert_array_equal(values[:, 1], expected[:, 1])  # occlusion
        np.testing.assert_allclose(values[:, 2:], expected[:, 2:], atol=1e-4, rtol=0)
        assert len(dont_care) == sum(1 for r in rows if int(r[0]) == frame and r[2] == "DontCare")
    calib = parse_calib(tmp_path / "kitti" / "training" / "calib" / "000000.txt")
    original = parse_calib(REAL / "tracking" / "training" / "calib" / "0001.txt")
    for ours, theirs in (("R0_rect", "R_rect"), ("Tr_velo_to_cam", "Tr_velo_cam"), ("Tr_imu_to_velo", "Tr_imu_velo"),
                         ("P2", "P2"), ("P3", "P3")):
        np.testing.assert_array_equal(calib[ours], original[theirs])


def test_boxes_behind_the_camera_leave_no_numpy_warning():
    """A box with every corner behind the camera has no 2D box; numpy's All-NaN warning must not leak."""
    import warnings

    from avdata.exporters.kitti import _project
    from avdata.frames import Boxes3D

    boxes = Boxes3D.from_kitti_camera(np.array([[1.5, 1.6, 4.0], [1.5, 1.6, 4.0]]),
                                      np.array([[0.0, 1.5, -10.0], [0.0, 1.5, 20.0]]), np.zeros(2), "ego/cam0")
    P2 = np.array([[700.0, 0, 600, 45], [0, 700, 180, 0], [0, 0, 1, 0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        box2d, truncation, in_image = _project(boxes, P2, (1242, 375))
    assert in_image.tolist() == [False, True]
    assert box2d[0].tolist() == [-1.0, -1.0, -1.0, -1.0] and truncation[0] == 1.0
    assert np.all(np.isfinite(box2d[1])) and truncation[1] == 0.0


def test_export_of_a_non_kitti_dataset_projects_boxes(tmp_path):
    """The demo dataset (one camera, no cam0, boxes in world) exports with P2 = [K | 0], R0 = I."""
    root = write_demo(tmp_path / "demo")
    result = export_kitti_object(root, tmp_path / "kitti")
    assert result.training == 5 and not result.problems
    out = tmp_path / "kitti" / "training"
    calib = parse_calib(out / "calib" / "000000.txt")
    np.testing.assert_allclose(calib["P2"].reshape(3, 4), [[400, 0, 320, 0], [0, 400, 180, 0], [0, 0, 1, 0]], atol=1e-9)
    np.testing.assert_allclose(calib["R0_rect"], np.eye(3).ravel())
    values, classes, _ = split_lines(out / "label_2" / "000000.txt")
    assert set(classes) <= {"Car", "Pedestrian"} and classes
    points = np.fromfile(out / "velodyne" / "000000.bin", dtype=np.float32).reshape(-1, 4)
    assert points.shape[0] > 1000
    # A box re-read from the exported label and calib lands where the unified box is (camera frame).
    row = np.array(values[0])
    h, w, l = row[7:10]
    bottom = row[10:13]
    velo_T = np.eye(4)
    velo_T[:3, :] = calib["Tr_velo_to_cam"].reshape(3, 4)
    center_cam = bottom - np.array([0.0, h / 2, 0.0])
    center_lidar = np.linalg.solve(velo_T, np.r_[center_cam, 1.0])[:3]
    dataset = DatasetReader(root)
    reader = dataset.scene(dataset.scenes[0])
    info, labels = reader.labels(0)
    boxes = labels.boxes.to("ego/lidar_top", reader.graph, info.timestamp_ns)
    assert np.min(np.linalg.norm(boxes.center - center_lidar, axis=1)) < 0.01
