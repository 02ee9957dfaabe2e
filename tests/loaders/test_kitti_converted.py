"""FrameDataset over the real KITTI object samples converted by avdata's KITTI converter.

Expected values come from KITTI's own formulas on the raw files (devkit: ``P2 · R0_rect ·
Tr_velo_to_cam · x`` for projection; the usual camera-to-velodyne box conversion), not from avdata.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.kitti import KittiObjectConverter
from avdata.loaders import FrameDataset, FrameOptions, LabelFilter
from avdata.schema import UNIFIED_CLASSES
from tests.realdata import REALDATA

OBJECT = REALDATA / "kitti" / "object"



def parse_calib(path: Path) -> dict[str, np.ndarray]:
    values = {}
    for line in path.read_text().splitlines():
        if ":" in line:
            key, rest = line.split(":", 1)
            values[key] = np.array(rest.split(), dtype=np.float64)
    return values


def rect_T_velo(calib: dict[str, np.ndarray]) -> np.ndarray:
    rect = np.eye(4)
    rect[:3, :3] = calib["R0_rect"].reshape(3, 3)
    velo = np.eye(4)
    velo[:3, :] = calib["Tr_velo_to_cam"].reshape(3, 4)
    return rect @ velo


@pytest.fixture(scope="module")
def kitti(tmp_path_factory: pytest.TempPathFactory) -> Path:
    dst = tmp_path_factory.mktemp("kitti_object")
    result = run_conversion(KittiObjectConverter(ConvertConfig(src=OBJECT, dst=dst, quiet=True)))
    assert result.written == ["training_000000"] and not result.problems
    return dst


def test_points_and_images_equal_the_raw_files(kitti: Path) -> None:
    ds = FrameDataset(kitti, sensors=["ego/velodyne", "ego/cam2"])
    assert len(ds) == 3
    for k in range(3):
        item = ds[k]
        raw = np.fromfile(OBJECT / "training" / "velodyne" / f"{k:06d}.bin", dtype=np.float32).reshape(-1, 4)
        # KITTI's ego is the velodyne frame: points come out untouched
        np.testing.assert_array_equal(item["points"]["ego/velodyne"].numpy()[:, :4], raw)
        image = item["images"]["ego/cam2"]
        png = cv2.imread(str(OBJECT / "training" / "image_2" / f"{k:06d}.png"), cv2.IMREAD_COLOR)
        np.testing.assert_array_equal(image.numpy().transpose(1, 2, 0), png[:, :, ::-1])


def test_projection_matches_kitti_formula(kitti: Path) -> None:
    ds = FrameDataset(kitti, sensors=["ego/velodyne", "ego/cam2"])
    for k in range(3):
        item = ds[k]
        calib = parse_calib(OBJECT / "training" / "calib" / f"{k:06d}.txt")
        xyz = item["points"]["ego/velodyne"][:, :3].numpy().astype(np.float64)
        homogeneous = np.c_[xyz, np.ones(len(xyz))]
        reference = (calib["P2"].reshape(3, 4) @ rect_T_velo(calib) @ homogeneous.T).T
        ours = (item["projections"]["ego/cam2"].numpy() @ homogeneous.T).T
        front = reference[:, 2] > 1.0
        error = np.abs(ours[front, :2] / ours[front, 2:] - reference[front, :2] / reference[front, 2:])
        assert error.max() < 0.01


def test_boxes_in_velodyne_frame_match_kitti_conversion(kitti: Path) -> None:
    ds = FrameDataset(kitti, classes=["car", "truck", "cyclist", "pedestrian"])
    for k in range(3):
        item = ds[k]
        calib = parse_calib(OBJECT / "training" / "calib" / f"{k:06d}.txt")
        rows = [line.split() for line in (OBJECT / "training" / "label_2" / f"{k:06d}.txt").read_text().splitlines()]
        rows = [r for r in rows if r[0] in ("Car", "Truck", "Cyclist", "Pedestrian")]
        values = np.array([r[8:15] for r in rows], dtype=np.float64)
        h, w, l = values[:, 0], values[:, 1], values[:, 2]
        bottom = values[:, 3:6]
        centre_rect = bottom - np.stack([np.zeros_like(h), h / 2.0, np.zeros_like(h)], axis=1)
        velo_T_rect = np.linalg.inv(rect_T_velo(calib))
        centre_velo = (velo_T_rect @ np.c_[centre_rect, np.ones(len(rows))].T).T[:, :3]
        yaw_velo = -values[:, 6] - np.pi / 2.0
        boxes = item["boxes"].numpy().astype(np.float64)
        assert len(boxes) == len(rows)
        np.testing.assert_allclose(boxes[:, :3], centre_velo, atol=1e-4)
        np.testing.assert_allclose(boxes[:, 3:6], np.stack([l, w, h], axis=1), atol=1e-5)
        # Tr_velo_to_cam is not exactly a rotation about one axis: compare headings to 1e-2 rad
        np.testing.assert_allclose(np.cos(boxes[:, 6]), np.cos(yaw_velo), atol=1e-2)
        np.testing.assert_allclose(np.sin(boxes[:, 6]), np.sin(yaw_velo), atol=1e-2)


def test_visible_to_camera_keeps_the_labelled_objects(kitti: Path) -> None:
    item = FrameDataset(kitti, FrameOptions(labels=LabelFilter(visible_to="ego/cam2", max_occlusion=1)))[1]
    rows = [line.split() for line in (OBJECT / "training" / "label_2" / "000001.txt").read_text().splitlines()]
    expected = [r[0].lower() for r in rows if r[0] != "DontCare" and int(r[2]) <= 1]
    assert expected == ["truck", "car"]  # the cyclist is occluded level 3
    assert [UNIFIED_CLASSES[i] for i in item["labels"].tolist()] == expected
    none_hidden = FrameDataset(kitti, FrameOptions(labels=LabelFilter(visible_to="ego/cam2", max_occlusion=0)))[1]
    assert len(none_hidden["object_ids"]) == sum(r[0] != "DontCare" and int(r[2]) == 0 for r in rows)
