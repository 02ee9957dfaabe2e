"""The Kalman tracker on hand-made sequences, and constant-velocity prediction."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.frames import Boxes3D
from avdata.perception import Detections, KalmanTracker, TrackerConfig, predict_constant_velocity
from avdata.perception.tracker import ClassConfig, Tracks, giou_3d

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


def _config(**car) -> TrackerConfig:
    fields = {"metric": "dist_3d", "threshold": 2.0, "algorithm": "hungarian", "min_hits": 1, "max_age": 1} | car
    return TrackerConfig(classes={"*": ClassConfig(**fields)})


def test_classes_do_not_mix_and_distance_threshold_holds() -> None:
    tracker = KalmanTracker(_config())
    tracker(_dets(0, [(0.0, 0.0)], ["car"]))
    tracks = tracker(_dets(1, [(0.2, 0.0)], ["pedestrian"]))  # same place, other class: a new track
    assert sorted(tracks.boxes.ids.tolist()) == ["1"]
    tracks = tracker(_dets(2, [(1.9, 0.0)], ["pedestrian"]))  # 1.7 m from the track: within 2 m, same id
    assert tracks.boxes.ids.tolist() == ["1"]
    tracks = tracker(_dets(3, [(10.0, 0.0)], ["pedestrian"]))  # far beyond 2 m (even after its velocity): new
    assert tracks.boxes.ids.tolist() == ["2"]


def test_default_is_ab3dmots_kitti_configuration() -> None:
    config = TrackerConfig()
    assert config.of("car") == ClassConfig(metric="giou_3d", threshold=-0.2, algorithm="hungarian", min_hits=3, max_age=2)
    assert config.of("pedestrian") == ClassConfig(metric="giou_3d", threshold=-0.4, algorithm="greedy", min_hits=1,
                                                  max_age=4)
    assert config.of("cyclist") == ClassConfig(metric="dist_3d", threshold=2.0, algorithm="hungarian", min_hits=3,
                                               max_age=4)


def test_birth_needs_min_hits_and_max_age_as_ab3dmot() -> None:
    tracker = KalmanTracker(_config(min_hits=3, max_age=2))
    shown = [len(tracker(_dets(k, [(k * 1.0, 0.0)])).boxes) for k in range(5)]
    assert shown == [1, 1, 1, 1, 1]  # the first min_hits frames report everything, then 3 hits are reached
    tracks = tracker(_dets(5, [(5.0, 0.0), (50.0, 50.0)]))  # a one-frame false positive
    assert tracks.boxes.ids.tolist() == ["0"]  # one hit: not reported after the first 3 frames
    tracks = tracker(_dets(6, []))  # since_update 1 < max_age 2: still reported, at its predicted box
    assert tracks.boxes.ids.tolist() == ["0"] and tracks.detection_index.tolist() == [-1]
    assert tracks.boxes.center[0, 0] == pytest.approx(6.0, abs=0.1)
    assert len(tracker(_dets(7, [])).boxes) == 0  # since_update 2: removed
    tracker(_dets(8, [(8.0, 0.0)]))
    assert "0" not in tracker(_dets(9, [(9.0, 0.0)])).boxes.ids.tolist()


def test_orientation_correction_turns_the_track_and_no_output_opposes_its_detection() -> None:
    tracker = KalmanTracker(_config())
    for k in range(12):
        yaw = 0.05 if k % 3 else 0.05 + np.pi  # every third detection faces backwards
        dets = _dets(k, [(k * 1.0, 0.0)], yaws=[yaw])
        tracks = tracker(dets)
        assert tracks.detection_index.tolist() == [0]
        diff = (tracks.boxes.yaw()[0] - yaw + np.pi) % (2 * np.pi) - np.pi
        assert abs(diff) < np.pi / 2  # the output follows its detection, flipped or not
    assert tracks.boxes.ids.tolist() == ["0"]


def test_greedy_takes_the_best_pair_first_hungarian_the_best_sum() -> None:
    from avdata.perception.tracker import _greedy

    similarity = np.array([[0.9, 0.8], [0.85, 0.1]])
    rows, cols = _greedy(similarity)
    assert sorted(zip(rows.tolist(), cols.tolist(), strict=True)) == [(0, 0), (1, 1)]  # 0.9 first, then 0.1 is left


def test_giou_3d_worked_by_hand() -> None:
    # Two 2 x 2 x 2 cubes side by side 3 m apart: IoU 0; hull 5 x 2 x 2 = 20; union 16 -> GIoU = -4/20.
    a = np.array([[0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0]])
    b = np.array([[3.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0], [1.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0]])
    np.testing.assert_allclose(giou_3d(a, b), [[-0.2, 4.0 / 12.0]])  # overlapping by half: IoU 4/12, hull = union
    np.testing.assert_allclose(giou_3d(a, a), [[1.0]])


def test_tracks_carry_the_updating_detections_extras_and_mean_score() -> None:
    tracker = KalmanTracker(_config())
    for k, score in enumerate((0.9, 0.5, 0.7)):
        dets = _dets(k, [(k * 1.0, 0.0), (k * 1.0, 20.0)])
        dets = replace(dets, scores=np.array([score, 0.2]), extras={"box2d_px": np.array([[k, 0, 1, 1], [k, 5, 6, 6.0]])})
        tracks = tracker(dets.select(np.array([1, 0])))  # the order of the detections does not matter
    order = np.argsort(tracks.boxes.ids.astype(int))
    # id 0 is the y = 20 m object (first in the selected order), scored 0.2 each time; id 1 has (0.9 + 0.5 + 0.7) / 3
    np.testing.assert_allclose(tracks.scores[order], [0.2, 0.7])
    assert tracks.detection_index[order].tolist() == [0, 1]
    np.testing.assert_allclose(tracks.extras["box2d_px"][order], [[2, 5, 6, 6], [2, 0, 1, 1]])


def test_inputs_are_checked() -> None:
    tracker = KalmanTracker()
    tracker(_dets(5, [(0.0, 0.0)]))
    with pytest.raises(InputError, match="non-decreasing"):
        tracker(_dets(4, [(0.0, 0.0)]))
    with pytest.raises(InputError, match="positive measurement_sigma"):
        TrackerConfig(measurement_sigma=(1.0, 1.0))
    with pytest.raises(InputError, match="velocities"):
        predict_constant_velocity(Tracks(boxes=Boxes3D.empty("world"), scores=np.zeros(0), timestamp_ns=0), 3, 0.1)
    camera = Boxes3D.from_kitti_camera(np.array([[1.5, 1.6, 4.0]]), np.array([[1.0, 1.5, 20.0]]), np.array([0.3]),
                                       "ego/cam0", classes=np.array(["car"]))
    y_down = Detections(boxes=camera, scores=np.array([0.9]), sensors=np.array(["cam"]), timestamp_ns=0)
    with pytest.raises(InputError, match="expected boxes upright about \\+z of 'ego/cam0', got one tilted by 90.0"):
        KalmanTracker()(y_down)
    with pytest.raises(InputError, match="expected scores in \\[0, 1\\]"):
        replace(y_down, scores=np.array([3.2]))


def test_a_users_tracker_is_any_callable() -> None:
    """The Tracker protocol: anything from Detections to Tracks (here: every detection is its own track)."""
    def echo(detections: Detections) -> Tracks:
        b = detections.boxes
        from dataclasses import replace
        boxes = replace(b, ids=np.arange(len(b)).astype(str), velocity=np.zeros((len(b), 3)))
        return Tracks(boxes=boxes, scores=detections.scores, timestamp_ns=detections.timestamp_ns)

    tracks = echo(_dets(0, [(1.0, 2.0)]))
    np.testing.assert_allclose(predict_constant_velocity(tracks, 2, 0.5)[0], [[1.0, 2.0], [1.0, 2.0]])


@pytest.mark.parametrize(("fields", "message"), [
    # min_hits .nan was a ValueError traceback, threshold [1] and true passed as 1, max_age 2.5 as 3.
    ({"min_hits": float("nan")}, "got nan, 1, 2.0"),
    ({"threshold": [1]}, "got 1, 1, [1]"),
    ({"threshold": True}, "got 1, 1, True"),
    ({"max_age": 2.5}, "got 1, 2.5, 2.0"),
    ({"min_hits": 2**70}, "got 1180591620717411303424, 1, 2.0"),
])
def test_class_config_fields_are_checked_by_type(fields: dict, message: str) -> None:
    with pytest.raises(InputError) as error:
        _config(**fields)
    assert str(error.value) == ("tracker: expected integers min_hits, max_age in [1, 1000000] and a finite number "
                                f"threshold, {message}")


@pytest.mark.parametrize("tolerance", [float("nan"), float("inf"), -0.1, np.pi / 2, "x", None, [1]])
def test_upright_tolerance_is_an_angle_below_a_right_angle(tolerance: object) -> None:
    # nan and inf let a y-down camera frame through; "x" and None were tracebacks on the first frame.
    with pytest.raises(InputError, match=r"expected upright_tolerance_rad in \[0, pi/2\), got "):
        TrackerConfig(upright_tolerance_rad=tolerance)  # type: ignore[arg-type]  # what a YAML file can give


def test_sigmas_are_tuples_of_numbers() -> None:
    with pytest.raises(InputError, match="expected 10 positive process_sigma, got '1111111111'"):
        TrackerConfig(process_sigma="1111111111")  # type: ignore[arg-type]  # a YAML string was ten 1.0s
    with pytest.raises(InputError, match=r"expected 7 positive measurement_sigma, got \(True, 1, 1"):
        TrackerConfig(measurement_sigma=(True, 1, 1, 1, 1, 1, 1))


def test_a_users_tracker_that_is_not_one_is_one_line() -> None:
    from avdata.perception.tracker import checked_tracks, load_tracker

    # os:getcwd returns a string: called on the first frame, it was a TypeError traceback in `avdata track`.
    with pytest.raises(InputError, match="^--tracker: expected 'os:getcwd' to return a callable tracker, got str$"):
        load_tracker("os:getcwd", "--tracker")
    with pytest.raises(InputError, match="^case c: tracker: expected the tracker to return Tracks, got dict$"):
        checked_tracks({}, "case c: tracker")
    assert isinstance(load_tracker("kalman", "--tracker"), KalmanTracker)


def test_zero_width_boxes_have_giou_zero_and_are_tracked() -> None:
    # Two flat boxes on one line: union and hull are 0, and 0 / 0 made linear_sum_assignment raise a traceback.
    flat = np.array([[10.0, 0.0, 0.0, 4.0, 0.0, 1.5, 0.0]])
    np.testing.assert_array_equal(giou_3d(flat, flat + [1.0, 0, 0, 0, 0, 0, 0]), [[0.0]])
    tracker = KalmanTracker()
    for k in range(3):
        dets = _dets(k, [(10.0 + k, 0.0)])
        flat_dets = replace(dets, boxes=Boxes3D.from_yaw(dets.boxes.center, np.array([[4.0, 0.0, 1.5]]),
                                                         np.zeros(1), "world", classes=["car"]))
        tracks = tracker(flat_dets)
    assert len(tracks.boxes) == 1 and np.all(np.isfinite(tracks.boxes.center))



@pytest.mark.parametrize(("fields", "message"), [
    # A GIoU or IoU threshold above 1 never matched: every detection started a track, without a word.
    ({"metric": "giou_3d", "threshold": 2.5}, "expected the giou_3d threshold in [-1, 1], got 2.5"),
    ({"metric": "iou_3d", "threshold": 2.0}, "expected the iou_3d threshold in [0, 1], got 2.0"),
    ({"metric": "dist_3d", "threshold": -1.0}, "expected the dist_3d threshold in [0, inf], got -1.0"),
])
def test_a_threshold_its_metric_cannot_reach_is_refused(fields: dict, message: str) -> None:
    with pytest.raises(InputError) as error:
        _config(**fields)
    assert str(error.value) == f"tracker: {message}"
