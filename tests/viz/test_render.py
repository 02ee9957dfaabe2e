"""Rendered pictures: boxes land on the objects (real KITTI labels' own 2D boxes), the BEV puts them where they are."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from avdata.cli import main
from avdata.errors import InputError
from avdata.schema import DatasetReader
from avdata.schema.records import CLASS_COLORS
from avdata.viz.render import BevView, render_bev, render_camera

REAL_LABELS = Path(__file__).resolve().parents[2].parent / "shared" / "realdata" / "kitti" / "object" / "training" / "label_2"
#: KITTI type -> unified class, for the types in the real samples that have a class colour.
KITTI_TO_UNIFIED = {"Car": "car", "Pedestrian": "pedestrian", "Cyclist": "cyclist", "Truck": "truck"}


def _bgr(cls: str) -> np.ndarray:
    r, g, b = CLASS_COLORS[cls]
    return np.array([int(b * 255), int(g * 255), int(r * 255)], np.uint8)


@pytest.mark.parametrize("sample", [0, 1, 2])
def test_projected_boxes_lie_on_the_labelled_objects(kitti_object: Path, sample: int) -> None:
    """Every pixel drawn in a class's colour lies inside a 2D box that KITTI's annotators drew for an object
    of that class (15 px margin for line width), and every such object gets some."""
    ds = DatasetReader(kitti_object)
    picture = render_camera(ds, ds.scenes[0], sample, "ego/cam2")
    assert picture is not None and picture.ndim == 3
    rows = [line.split() for line in (REAL_LABELS / f"{sample:06d}.txt").read_text().splitlines()]
    for kitti_type, cls in KITTI_TO_UNIFIED.items():
        boxes = np.array([[float(v) for v in r[4:8]] for r in rows if r[0] == kitti_type])
        if not len(boxes):
            continue
        ys, xs = np.nonzero(np.all(picture == _bgr(cls), axis=2))
        inside = np.zeros(len(xs), bool)
        for x0, y0, x1, y1 in boxes:
            inside |= (xs >= x0 - 15) & (xs <= x1 + 15) & (ys >= y0 - 15) & (ys <= y1 + 15)
        assert len(xs) > 20 and inside.all(), (kitti_type, len(xs), int((~inside).sum()))


def test_bev_draws_each_box_at_its_place(generated: Path) -> None:
    ds = DatasetReader(generated)
    scene = ds.scenes[0]
    view = BevView(range_m=50.0, pixels_per_m=4.0)
    picture = render_bev(ds, scene, 1, view)
    reader = ds.scene(scene)
    info, labels = reader.labels(1)
    boxes = labels.boxes.to("ego", reader.graph, info.timestamp_ns)
    near = np.all(np.abs(boxes.center[:, :2]) < 45, axis=1) & (boxes.classes == "car")
    assert near.sum() >= 2
    for corners in boxes.bev_corners()[near]:
        # The front-left corner's pixel (x forward = up, y left = left) is drawn in the car colour.
        u = 200 - corners[0, 1] * 4.0
        v = 200 - corners[0, 0] * 4.0
        patch = picture[int(v) - 2:int(v) + 3, int(u) - 2:int(u) + 3].reshape(-1, 3)
        assert np.any(np.all(patch == _bgr("car"), axis=1)), corners[0]


def test_render_command_png_and_video(generated: Path, tmp_path: Path) -> None:
    assert main(["render", str(generated), str(tmp_path / "f.png"), "--frame", "2", "--color-by", "agent"]) == 0
    picture = cv2.imread(str(tmp_path / "f.png"))
    assert picture.shape[1] == 960 and picture.shape[0] > 960  # the BEV and the camera below it
    assert main(["render", str(generated), str(tmp_path / "s.mp4"), "--video"]) == 0
    video = cv2.VideoCapture(str(tmp_path / "s.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    assert main(["render", str(generated), str(tmp_path / "f.png"), "--frame", "7"]) == 1
    assert main(["render", str(generated), str(tmp_path / "f.jpg")]) == 1
    with pytest.raises(InputError, match="color_by"):
        BevView(color_by="speed")
