"""The Kalman tracker on hand-made sequences, and constant-velocity prediction."""

from __future__ import annotations

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.frames import Boxes3D
from avdata.perception import Detections, KalmanTracker, TrackerConfig, predict_constant_velocity
from avdata.perception.tracker import Tracks

STEP_NS = 100_000_000


def _dets(t_index: int, centres: list[tuple[float, float]], classes: list[str] | None = None,
          yaws: list[float] | None = None) -> Detections:
    n = len(centres)
    xyz = np.c_[np.asarray(centres, float).reshape(n, 2), np.full(n, 0.8)]
    boxes = Boxes3D.from_yaw(xyz, np.tile([4.0, 1.8, 1.6], (n, 1)), np.asarray(yaws if yaws else [0.0] * n), "world",
                             classes=classes or ["car"] * n)
    return Detections(boxes=boxes, scores=np.full(n, 0.9), sensors=np.full(n, "s"), timestamp_ns=t_index * STEP_NS)


def test_constant_velocity_on_a_straight_line() -> None:
    rng = np.random.default_rng(0)
    tracker = KalmanTracker()
    speed = 10.0
    for k in range(50):
        x = speed * k * 0.1 + rng.normal(0, 0.2)
        y = 3.0 + rng.normal(0, 0.2)
        tracks = tracker(_dets(k, [(x, y)]))
    assert len(tracks.boxes) == 1
    assert tracks.boxes.ids.tolist() == ["0"]  # one identity all along
    vx, vy, _ = tracks.boxes.velocity[0]
    assert vx == pytest.approx(speed, abs=0.5) and vy == pytest.approx(0.0, abs=0.5)
    assert tracks.boxes.center[0, 0] == pytest.approx(speed * 4.9, abs=0.3)
    # Prediction of the estimate one second ahead lands one second further along the line.
    future = predict_constant_velocity(tracks, 10, 0.1)
    assert future.shape == (1, 10, 2)
    assert future[0, -1, 0] == pytest.approx(speed * 5.9, abs=0.8)


def test_two_crossing_tracks_keep_their_identities() -> None:
    tracker = KalmanTracker()
    ids_a, ids_b = set(), set()
    for k in range(30):
        a = (k * 1.0, 0.0)          # 10 m/s along +x
        b = (29.0 - k * 1.0, 6.0)   # 10 m/s along -x, 6 m to the side
        tracks = tracker(_dets(k, [a, b]))
        for tid, centre in zip(tracks.boxes.ids, tracks.boxes.center, strict=True):
            (ids_a if centre[1] < 3 else ids_b).add(tid)
    assert len(ids_a) == 1 and len(ids_b) == 1 and ids_a != ids_b


def test_classes_do_not_mix_and_gates_hold() -> None:
    tracker = KalmanTracker(TrackerConfig(min_hits=1, max_coast_frames=0))
    tracker(_dets(0, [(0.0, 0.0)], ["car"]))
    tracks = tracker(_dets(1, [(0.2, 0.0)], ["pedestrian"]))  # same place, other class: a new track
    assert sorted(tracks.boxes.ids.tolist()) == ["1"]
    tracks = tracker(_dets(2, [(10.0, 0.0)], ["pedestrian"]))  # 10 m jump: beyond the 1.5 m pedestrian gate
    assert tracks.boxes.ids.tolist() == ["2"]


def test_birth_needs_min_hits_and_death_after_max_age() -> None:
    tracker = KalmanTracker(TrackerConfig(min_hits=2, max_age=2, max_coast_frames=0))
    for k in range(3):
        tracks = tracker(_dets(k, [(k * 1.0, 0.0)]))
    assert tracks.boxes.ids.tolist() == ["0"]
    tracks = tracker(_dets(3, [(3.0, 0.0), (50.0, 50.0)]))  # a one-frame false positive
    assert tracks.boxes.ids.tolist() == ["0"]  # not reported: a single hit
    for k in range(4, 7):  # the object disappears: coasting is not reported, and after 2 misses it is gone
        tracks = tracker(_dets(k, []))
        assert len(tracks.boxes) == 0
    tracks = tracker(_dets(7, [(7.0, 0.0)]))
    tracks = tracker(_dets(8, [(8.0, 0.0)]))
    assert tracks.boxes.ids.tolist() == ["2"]  # a new identity: the old track was removed


def test_flipped_detection_heading_does_not_spin_the_track() -> None:
    tracker = KalmanTracker()
    for k in range(10):
        yaw = 0.05 if k % 2 == 0 else 0.05 + np.pi  # every other detection faces backwards
        tracks = tracker(_dets(k, [(k * 1.0, 0.0)], yaws=[yaw]))
    heading = tracks.boxes.yaw()[0]
    assert min(abs(heading - 0.05), abs(abs(heading - 0.05) - np.pi)) < 0.05


def test_inputs_are_checked() -> None:
    tracker = KalmanTracker()
    tracker(_dets(5, [(0.0, 0.0)]))
    with pytest.raises(InputError, match="non-decreasing"):
        tracker(_dets(4, [(0.0, 0.0)]))
    with pytest.raises(InputError, match="measurement sigmas"):
        TrackerConfig(measurement_sigma=(1.0, 1.0))
    with pytest.raises(InputError, match="velocities"):
        predict_constant_velocity(Tracks(boxes=Boxes3D.empty("world"), scores=np.zeros(0), timestamp_ns=0), 3, 0.1)


def test_a_users_tracker_is_any_callable() -> None:
    """The Tracker protocol: anything from Detections to Tracks (here: every detection is its own track)."""
    def echo(detections: Detections) -> Tracks:
        b = detections.boxes
        from dataclasses import replace
        boxes = replace(b, ids=np.arange(len(b)).astype(str), velocity=np.zeros((len(b), 3)))
        return Tracks(boxes=boxes, scores=detections.scores, timestamp_ns=detections.timestamp_ns)

    tracks = echo(_dets(0, [(1.0, 2.0)]))
    np.testing.assert_allclose(predict_constant_velocity(tracks, 2, 0.5)[0], [[1.0, 2.0], [1.0, 2.0]])
