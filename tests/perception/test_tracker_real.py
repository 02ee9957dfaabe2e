"""The Kalman tracker on AB3DMOT's PointRCNN detections of KITTI tracking val 0001, 0006 and 0008."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np
import pytest

from avdata.perception.detection_files import read_detections, upright
from avdata.perception.tracker import KalmanTracker
from tests.realdata import REALDATA


@pytest.fixture(scope="module")
def tracked() -> dict[str, list[tuple[object, object]]]:
    found = read_detections(REALDATA / "kitti_tracking_detections", "ab3dmot")
    out = {}
    for scene, frames in found.scenes.items():
        tracker = KalmanTracker()
        steps = []
        none = next(iter(frames.values())).select(np.zeros(0, dtype=np.int64))
        for frame_index in range(max(frames) + 1):  # every frame, as AB3DMOT (frames without a detection too)
            empty = replace(none, timestamp_ns=frame_index * 100_000_000)
            detections = upright(frames.get(frame_index, empty))
            steps.append((detections, tracker(detections)))
        out[scene] = steps
    return out


def test_no_output_points_away_from_its_detection(tracked) -> None:
    updates = 0
    for steps in tracked.values():
        for detections, tracks in steps:
            updated = tracks.detection_index >= 0
            detection_yaw = detections.boxes.yaw()[tracks.detection_index[updated]]
            difference = (tracks.boxes.yaw()[updated] - detection_yaw + np.pi) % (2 * np.pi) - np.pi
            assert np.all(np.abs(difference) < np.pi / 2)
            updates += int(updated.sum())
    assert updates == 8018


def test_per_class_settings_give_ab3dmots_output(tracked) -> None:
    # Boxes reported per class and sequence, and track ids, as AB3DMOT's own code (model.py with the PointRCNN
    # KITTI configuration, rebuilt from its source and run on the same files outside the repository) reports them.
    expected = {"0001": ({"car": 3546, "cyclist": 40, "pedestrian": 2610}, 711),
                "0006": ({"car": 725, "cyclist": 47, "pedestrian": 1350}, 224),
                "0008": ({"car": 1272, "cyclist": 710, "pedestrian": 2672}, 637)}
    for scene, (per_class, n_tracks) in expected.items():
        classes = Counter(c for _, tracks in tracked[scene] for c in tracks.boxes.classes.tolist())
        ids = {i for _, tracks in tracked[scene] for i in tracks.boxes.ids.tolist()}
        assert (dict(classes), len(ids)) == (per_class, n_tracks)
