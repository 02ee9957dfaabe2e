"""The BEV baseline as a detector: its output, batched = one by one, checkpoints round-trip, bad files one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from avdata.errors import InputError
from avdata.perception.bev import BevCenterNet, BevDetector, load_checkpoint, save_checkpoint
from avdata.perception.detector import BatchedDetector, Detector, detect_items, load_detector


def _item(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    cloud = np.c_[rng.uniform(-30, 30, (2000, 2)), rng.uniform(-1.5, 1.0, 2000), rng.uniform(0, 1, 2000)]
    return {"frame": "ego", "timestamp_ns": 1000 + seed, "points": {"ego/lidar": torch.tensor(cloud, dtype=torch.float32)}}


@pytest.fixture(scope="module")
def detector() -> BevDetector:
    torch.manual_seed(0)
    # Low threshold: an untrained network peaks near its prior of 0.1, so it gives boxes to compare.
    return BevDetector(BevCenterNet(2), ("car", "pedestrian"), min_score=0.0, batch_size=2)


def test_bev_detector_is_a_batched_detector(detector: BevDetector) -> None:
    assert isinstance(detector, Detector) and isinstance(detector, BatchedDetector)
    items = [_item(i) for i in range(3)]
    batched = detect_items(detector, items)
    single = [detector(item) for item in items]
    for a, b, item in zip(batched, single, items, strict=True):
        assert a.timestamp_ns == item["timestamp_ns"] and a.boxes.frame == "ego"
        assert len(a) == 60  # the top-k peaks, all kept at min_score 0
        assert set(a.boxes.classes) <= {"car", "pedestrian"}
        np.testing.assert_allclose(a.boxes.center, b.boxes.center, atol=1e-4)
        np.testing.assert_allclose(a.scores, b.scores, atol=1e-6)
        assert np.all(np.hypot(a.boxes.center[:, 0], a.boxes.center[:, 1]) <= 40.0)


def test_checkpoint_round_trip_and_factory(detector: BevDetector, tmp_path: Path) -> None:
    path = tmp_path / "bev.pt"
    save_checkpoint(detector, path)
    loaded = load_detector("avdata.perception.bev:load_checkpoint", path)
    assert isinstance(loaded, BevDetector) and loaded.classes == ("car", "pedestrian")
    loaded.min_score = 0.0
    a, b = detector(_item(7)), loaded(_item(7))
    np.testing.assert_array_equal(a.boxes.center, b.boxes.center)
    np.testing.assert_array_equal(a.scores, b.scores)


@pytest.mark.parametrize(("content", "message"), [
    (None, "no such file"),
    (b"not a checkpoint", "unreadable file"),
    ({"format": "other"}, "expected a checkpoint with format"),
    ({"format": "avdata-bev-centernet-1", "classes": ["car"], "state_dict": {}}, "weights do not fit"),
])
def test_bad_checkpoints_are_one_line(tmp_path: Path, content: object, message: str) -> None:
    path = tmp_path / "bad.pt"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        torch.save(content, path)
    with pytest.raises(InputError, match=message):
        load_checkpoint(path)


@pytest.mark.parametrize(("spec", "message"), [
    ("nocolon", "expected 'package.module:callable'"),
    ("avdata.no_such_module:fn", "cannot import"),
    ("avdata.perception.bev:no_such", "has no 'no_such'"),
    ("avdata.perception.bev:CHECKPOINT_FORMAT", "to be callable"),
])
def test_bad_detector_names_are_one_line(spec: str, message: str) -> None:
    with pytest.raises(InputError, match=message):
        load_detector(spec, None)


def test_items_without_points_have_no_detections(detector: BevDetector) -> None:
    empty = {"frame": "ego", "timestamp_ns": 5, "points": {}}
    found = detector.detect_batch([_item(1), empty])
    assert len(found[0]) == 60 and len(found[1]) == 0 and found[1].timestamp_ns == 5 and found[1].boxes.frame == "ego"
