"""AB3DMOT's KITTI 3D MOT protocol on a hand-worked sequence, and on the real PointRCNN detections tracked by avdata."""

from __future__ import annotations

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.eval.problems import EvalWarning
from avdata.eval.tracking.kitti_3dmot import (
    _count,
    _Frame,
    _id_events,
    _match_frame,
    _mota_by_threshold,
    evaluate_kitti_3dmot,
)

_BOX = "1.5 1.6 4.0 1.0 1.5 20.0 0.0"


def _line(frame: int, track: int, cls: str, box: str, occluded: int = 0, score: float | None = None) -> str:
    return f"{frame} {track} {cls} 0 {occluded} 0.0 {box} {_BOX}" + ("" if score is None else f" {score}")


def test_hand_worked_sequence(tmp_path):
    (tmp_path / "gt" / "label_02").mkdir(parents=True)
    (tmp_path / "tr").mkdir()
    car = "100 100 200 200"
    gt = [_line(f, 0, "Car", car) for f in range(4)]
    gt += [_line(1, 1, "Car", "600 100 700 200", occluded=3),   # ignored
           _line(0, 2, "Car", "300 100 340 120"),                # 20 px high: still counted (no height filter)
           "1 -1 DontCare -1 -1 -10 800 100 900 200 -1 -1 -1 -1000 -1000 -1000 -10"]
    tr = [_line(0, 5, "Car", car, score=0.9), _line(1, 5, "Car", car, score=0.7),  # track 5: mean 0.8
          _line(2, 7, "Car", car, score=0.6),
          _line(1, 9, "Car", "400 100 500 200", score=0.3),    # a false positive
          _line(1, 10, "Car", "600 100 700 180", score=0.95),  # on the ignored car (IoU 0.8): neither TP nor FP
          _line(1, 11, "Car", "800 100 900 200", score=0.95),  # inside the DontCare region: no FP
          _line(3, 12, "Car", "300 300 400 325", score=0.95),  # 25 px high: no FP
          _line(3, 13, "Car", "500 300 600 326", score=0.2)]   # 26 px high: a false positive
    (tmp_path / "gt" / "label_02" / "0000.txt").write_text("\n".join(gt) + "\n")
    (tmp_path / "tr" / "0000.txt").write_text("\n".join(tr) + "\n")
    row = evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", {"0000": 4}, ("car",)).table["car"]
    # n_gt = 5 (car 0 in 4 frames, car 2). A threshold keeps whole tracks by their mean score:
    #   0.95 (10, 11, 12): TP 0, FN 5, FP 0 -> MOTA 0
    #   0.8 (+5, both boxes, though one is scored 0.7): TP 2, FN 3 -> MOTA 0.4, MOTP (1 + 1 + 0.8) / 3 (the match
    #       to the ignored car counts in MOTP, as in the devkit)
    #   0.6 (+7): TP 3, FN 2, IDS 1 (5 -> 7) -> MOTA 0.4;  0.3 (+9): FP 1 -> 0.2;  0.2 (+13): FP 2 -> 0.0
    # The tie at 0.4 goes to the highest score, 0.8.
    assert (row["MOTA"], row["IDS"], row["FP"], row["FN"], row["TP"], row["threshold"]) == (
        pytest.approx(0.4), 0, 0, 3, 2, 0.8)
    assert row["MOTP"] == pytest.approx(2.8 / 3)
    # Recall points: match scores without a threshold 0.95, 0.8, 0.8, 0.6 of m = 4 matches + 2 FN = 6: each r = k/40
    # takes the next score (recalls 2/6, 3/6, 4/6 are the nearest left): (0.8, 1/40), (0.8, 2/40), (0.6, 3/40).
    # sMOTA_r = clip(1 - (3 - (1 - r) 5) / (5 r)) = 1 at each; MOTA 0.4 at each; MOTP 2.8/3, 2.8/3, 3.8/4.
    assert row["sAMOTA"] == pytest.approx(3 / 40)
    assert row["AMOTA"] == pytest.approx(3 * 0.4 / 40)
    assert row["AMOTP"] == pytest.approx((2 * 2.8 / 3 + 3.8 / 4) / 40)
    assert (row["script_MOTA"], row["script_threshold"]) == (pytest.approx(0.4), 0.8)
    # No cyclist in the ground truth: a warning, and the metrics are not defined.
    with pytest.warns(EvalWarning, match="class cyclist has no scored ground truth"):
        cyclist = evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", {"0000": 4}, ("cyclist",)).table["cyclist"]
    assert np.isnan(cyclist["sAMOTA"]) and cyclist["FP"] == 0


def test_3d_iou_of_identical_boxes_is_one(tmp_path):
    (tmp_path / "gt" / "label_02").mkdir(parents=True)
    (tmp_path / "tr").mkdir()
    (tmp_path / "gt" / "label_02" / "0000.txt").write_text("".join(_line(f, 0, "Car", "0 0 50 50") + "\n" for f in range(3)))
    (tmp_path / "tr" / "0000.txt").write_text("".join(_line(f, 4, "Car", "0 0 50 50", score=0.5) + "\n" for f in range(3)))
    row = evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", {"0000": 3}, ("car",), "3d", 0.7).table["car"]
    assert (row["MOTA"], row["MOTP"], row["TP"]) == (1.0, pytest.approx(1.0), 3)


def test_matching_takes_the_most_pairs_first():
    # Similarities: A-X 1, B-Y 1, A-Y 0.5, B-Z 0.5, C-X 0.5. The largest sum is {A-X, B-Y} (2.0), but the script's
    # Munkres on 1 - IoU with 1e9 on forbidden pairs takes three pairs {A-Y, B-Z, C-X} (cost 1.5 < 1e9 + 0).
    sim = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.5], [0.5, 0.0, 0.0]])
    frame = _Frame(np.arange(3), np.zeros(3, bool), np.array([10, 11, 12]), np.ones(3), np.zeros(3, bool), sim, "0000")
    _, matched_gt, tr_matched = _match_frame(frame, -np.inf)
    assert matched_gt.tolist() == [1, 2, 0] and tr_matched.all()


@pytest.mark.parametrize(("tracker_ids", "ignored", "expected"), [
    # matched ids per frame of one ground-truth trajectory -> (IDS, FRAG), worked by the devkit's rules
    ([5, 5, -1, 5, 7, 7, -1], [], (1, 2)),         # 5 -> 7 in consecutive frames; resumed at 3 and changed at 4
    ([5, 5, -1, 5, 7, 7, -1], [2], (1, 1)),        # an ignored frame 2 disarms the resumption at 3
    ([5, 5, -1, 5, 7, 7, -1], [3], (0, 0)),        # frame 3 ignored: neither the switch nor a fragment at 4
    ([5, -1, 5], [], (0, 1)),                      # the last frame counts a resumption on its own
    ([5, -1, 5, -1], [], (0, 0)),                  # a resumption needs the next frame tracked
    ([-1, -1, 5, 7], [], (1, 1)),                  # the first frame untracked: only the switch 5 -> 7 and its change
])
def test_id_switches_and_fragments_as_the_devkit_counts_them(tracker_ids, ignored, expected):
    n = len(tracker_ids)
    assert _id_events(np.zeros(n, np.int64), np.isin(np.arange(n), ignored), np.array(tracker_ids)) == expected


def test_a_sitting_person_is_a_neighbour_of_pedestrian(tmp_path):
    # KITTI tracking names a sitting person "Person": a pedestrian track on it is neither TP nor FP.
    (tmp_path / "gt" / "label_02").mkdir(parents=True)
    (tmp_path / "tr").mkdir()
    walker, sitter = "100 100 150 200", "400 100 450 200"
    (tmp_path / "gt" / "label_02" / "0000.txt").write_text(
        _line(0, 0, "Pedestrian", walker) + "\n" + _line(0, 1, "Person", sitter) + "\n")
    (tmp_path / "tr" / "0000.txt").write_text(
        _line(0, 3, "Pedestrian", walker, score=0.9) + "\n" + _line(0, 4, "Pedestrian", sitter, score=0.9) + "\n")
    row = evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", {"0000": 1}, ("pedestrian",)).table["pedestrian"]
    assert (row["TP"], row["FP"], row["FN"], row["MOTA"]) == (1, 0, 0, 1.0)


def test_the_threshold_scan_counts_as_each_threshold_alone():
    # _mota_by_threshold's shortcut (frames without conflicting pairs matched once) against a full count per threshold,
    # on random frames with conflicts, ignored ground truth, DontCare-like boxes and tracks spanning frames.
    rng = np.random.default_rng(3)
    frames = []
    track_score = rng.choice([0.2, 0.4, 0.6, 0.8], 12)
    for _ in range(30):
        n_gt, n_tr = rng.integers(0, 4), rng.integers(0, 5)
        gt_ids = rng.choice(6, n_gt, replace=False)
        tr_ids = rng.choice(12, n_tr, replace=False)
        sim = np.where(rng.random((n_gt, n_tr)) < 0.4, rng.uniform(0.5, 1.0, (n_gt, n_tr)), 0.0)
        frames.append(_Frame(gt_ids, rng.random(n_gt) < 0.2, tr_ids, track_score[tr_ids], rng.random(n_tr) < 0.2, sim,
                             "0000"))
    everything = _count(frames, -np.inf)
    thresholds = np.array([0.1, 0.2, 0.4, 0.6, 0.8, 0.9])
    expected = [_count(frames, t).metrics()["MOTA"] for t in thresholds.tolist()]
    np.testing.assert_allclose(_mota_by_threshold(frames, thresholds, everything.tp + everything.fn), expected)


@pytest.mark.parametrize(("where", "line", "message"), [
    # A frame far beyond the sequence: the evaluation walked every frame up to it (10^9 of them: hours; the
    # label reader now refuses frames from 10^6 on, the seqmap's length bounds them below that).
    ("tr", _line(999_999, 5, "Car", "0 0 50 50", score=0.5),
     "tr/0000.txt: line 2: frame: expected frames in [0, 3) (the seqmap's length), got 999999"),
    ("gt", _line(3, 0, "Car", "0 0 50 50"), "gt/label_02/0000.txt: line 2: frame: expected frames in [0, 3)"),
    # An unreadable line was reported as the repr of the reader's record: "LabelProblem(line=2, frame=0, ...)".
    ("tr", _line(0, 5, "Car", "0 0 50 x", score=0.5), "tr/0000.txt: line 2: expected numbers after the class, got "),
    # A type AB3DMOT does not evaluate was passed over: a misspelt class lost its boxes without a word.
    ("tr", _line(0, 5, "Cra", "0 0 50 50", score=0.5), "tr/0000.txt: line 2: type: expected a KITTI type (car, van, "
     "truck, pedestrian, person, person_sitting, cyclist, tram, misc, dontcare, any case), got 'Cra'"),
])
def test_bad_line_is_one_plain_error(tmp_path, where, line, message):
    (tmp_path / "gt" / "label_02").mkdir(parents=True)
    (tmp_path / "tr").mkdir()
    gt = [_line(0, 0, "Car", "0 0 50 50")] + ([line] if where == "gt" else [])
    tr = [_line(0, 4, "Car", "0 0 50 50", score=0.5)] + ([line] if where == "tr" else [])
    (tmp_path / "gt" / "label_02" / "0000.txt").write_text("\n".join(gt) + "\n")
    (tmp_path / "tr" / "0000.txt").write_text("\n".join(tr) + "\n")
    with pytest.raises(InputError) as error:
        evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", {"0000": 3}, ("car",))
    assert message in str(error.value) and "LabelProblem" not in str(error.value)


def test_types_are_compared_in_any_case_as_ab3dmot_does(tmp_path):
    # AB3DMOT lower-cases the types of both files; a tracker writing "car" scored MOTA 0 here without a word.
    (tmp_path / "gt" / "label_02").mkdir(parents=True)
    (tmp_path / "tr").mkdir()
    (tmp_path / "gt" / "label_02" / "0000.txt").write_text(_line(0, 0, "Car", "0 0 50 50") + "\n")
    rows = {}
    for spelling in ("Car", "car", "CAR"):
        (tmp_path / "tr" / "0000.txt").write_text(_line(0, 4, spelling, "0 0 50 50", score=0.5) + "\n")
        row = evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", {"0000": 1}, ("car",)).table["car"]
        rows[spelling] = (row["MOTA"], row["TP"], row["FP"], row["FN"])
    assert rows == dict.fromkeys(("Car", "car", "CAR"), (1.0, 1, 0, 0))
