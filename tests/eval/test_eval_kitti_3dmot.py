"""AB3DMOT's KITTI 3D MOT protocol on a hand-worked sequence, and on the real PointRCNN detections tracked by avdata."""

from __future__ import annotations

import numpy as np
import pytest

from avdata.eval.problems import EvalWarning
from avdata.eval.tracking.kitti_3dmot import evaluate_kitti_3dmot

_BOX = "1.5 1.6 4.0 1.0 1.5 20.0 0.0"


def _line(frame: int, track: int, cls: str, box: str, occluded: int = 0, score: float | None = None) -> str:
    return f"{frame} {track} {cls} 0 {occluded} 0.0 {box} {_BOX}" + ("" if score is None else f" {score}")


def test_hand_worked_sequence(tmp_path):
    (tmp_path / "gt" / "label_02").mkdir(parents=True)
    (tmp_path / "tr").mkdir()
    car = "100 100 200 200"
    gt = [_line(f, 0, "Car", car) for f in range(4)]
    gt += [_line(1, 1, "Car", "600 100 700 200", occluded=3),
           "1 -1 DontCare -1 -1 -10 800 100 900 200 -1 -1 -1 -1000 -1000 -1000 -10"]
    tr = [_line(0, 5, "Car", car, score=0.9), _line(1, 5, "Car", car, score=0.9), _line(2, 7, "Car", car, score=0.8),
          _line(1, 9, "Car", "400 100 500 200", score=0.3),   # a false positive
          _line(1, 10, "Car", "600 100 700 200", score=0.95),  # on the ignored (occluded 3) car: neither TP nor FP
          _line(1, 11, "Car", "800 100 900 200", score=0.95)]  # inside the DontCare region: no FP
    (tmp_path / "gt" / "label_02" / "0000.txt").write_text("\n".join(gt) + "\n")
    (tmp_path / "tr" / "0000.txt").write_text("\n".join(tr) + "\n")
    row = evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", ["0000"], ("car",)).table["car"]
    # n_gt = 4 (TP 3 + FN 1 without a threshold); TP scores 0.9, 0.9, 0.8.
    # r = 1/40 .. 20/40: threshold 0.9 -> TP 2, FN 2, FP 0, IDS 0: MOTA 0.5, sMOTA = min(1, 0.5 / r) = 1.
    # r = 21/40 .. 30/40: threshold 0.8 -> TP 3, FN 1, FP 0 (0.3 is below), IDS 1: MOTA 0.5, sMOTA = 0.5 / r.
    # r > 3/4 is never reached: 0.
    assert row["sAMOTA"] == pytest.approx((20 + sum(20 / k for k in range(21, 31))) / 40)
    assert row["AMOTA"] == pytest.approx(30 * 0.5 / 40)
    assert row["AMOTP"] == pytest.approx(30 * 1.0 / 40)
    assert (row["MOTA"], row["IDS"], row["FP"], row["FN"], row["threshold"]) == (0.5, 0, 0, 2, 0.9)
    # Every score: 0.95 -> MOTA 0 (no TP), 0.9 -> 0.5, 0.8 -> 0.5 (IDS 1), 0.3 -> 0.25: the tie goes to 0.9.
    assert (row["script_MOTA"], row["script_threshold"]) == (0.5, 0.9)
    # 3D IoU: the tracker boxes are the ground-truth boxes, so the matches and counts are the same, MOTP 1.
    row3d = evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", ["0000"], ("car",), "3d", 0.7).table["car"]
    assert (row3d["MOTA"], row3d["MOTP"], row3d["sAMOTA"]) == (0.5, pytest.approx(1.0), pytest.approx(row["sAMOTA"]))
    # No cyclist in the ground truth: a warning, and the metrics are not defined.
    with pytest.warns(EvalWarning, match="class cyclist has no scored ground truth"):
        cyclist = evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", ["0000"], ("cyclist",)).table["cyclist"]
    assert np.isnan(cyclist["sAMOTA"]) and cyclist["FP"] == 0


def test_a_sitting_person_is_a_neighbour_of_pedestrian(tmp_path):
    # KITTI tracking names a sitting person "Person": a pedestrian track on it is neither TP nor FP.
    (tmp_path / "gt" / "label_02").mkdir(parents=True)
    (tmp_path / "tr").mkdir()
    walker, sitter = "100 100 150 200", "400 100 450 200"
    (tmp_path / "gt" / "label_02" / "0000.txt").write_text(
        _line(0, 0, "Pedestrian", walker) + "\n" + _line(0, 1, "Person", sitter) + "\n")
    (tmp_path / "tr" / "0000.txt").write_text(
        _line(0, 3, "Pedestrian", walker, score=0.9) + "\n" + _line(0, 4, "Pedestrian", sitter, score=0.9) + "\n")
    row = evaluate_kitti_3dmot(tmp_path / "gt", tmp_path / "tr", ["0000"], ("pedestrian",)).table["pedestrian"]
    assert (row["TP"], row["FP"], row["FN"], row["MOTA"]) == (1, 0, 0, 1.0)
