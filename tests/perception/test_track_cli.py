"""``avdata track``: hostile detection files, a user's tracker, a tracker config."""

from __future__ import annotations

from avdata.cli import main
from tests.realdata import REALDATA

CSV = REALDATA / "kitti_tracking_detections" / "pointrcnn_Car_val" / "0006.txt"


def test_a_bad_record_costs_that_record_and_exits_1(tmp_path, capsys):
    lines = CSV.read_text().splitlines()[:40]
    lines[3] = lines[3].replace(lines[3].split(",")[6], "inf", 1)  # the score
    (tmp_path / "dets").mkdir()
    (tmp_path / "dets" / "0006.txt").write_text("\n".join(lines) + "\n")
    assert main(["track", str(tmp_path / "out"), "--detections", str(tmp_path / "dets"), "--format", "ab3dmot"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0] == f"avdata: error: {tmp_path / 'dets' / '0006.txt'}: line 4: field score: expected a finite number, got 'inf'"
    written = (tmp_path / "out" / "0006.txt").read_text().splitlines()
    assert written and all(len(line.split()) == 18 for line in written)


def test_a_users_tracker_and_config(tmp_path, capsys):
    config = tmp_path / "tracker.yaml"
    config.write_text("classes:\n  car: {metric: dist_3d, threshold: 1.0, algorithm: greedy, min_hits: 1, max_age: 1}\n")
    args = ["track", str(tmp_path / "a"), "--detections", str(CSV), "--format", "ab3dmot", "--config", str(config)]
    assert main(args) == 0
    # Every detection is shown (min_hits 1, max_age 1: nothing coasts), so the output has one line per detection.
    assert len((tmp_path / "a" / "0006.txt").read_text().splitlines()) == len(CSV.read_text().splitlines())
    assert main(["track", str(tmp_path / "b"), "--detections", str(CSV), "--format", "ab3dmot",
                 "--tracker", "avdata.perception.tracker:KalmanTracker"]) == 0
    config.write_text("classes:\n  car: {metric: mahalanobis}\n")
    assert main(args + ["--force"]) == 1
    assert "expected metric in ('giou_3d', 'iou_3d', 'dist_3d')" in capsys.readouterr().err
