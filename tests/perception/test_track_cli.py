"""``avdata track DATASET OUT``: the three real KITTI sequences tracked and scored, each output format read
back, resume, two workers, hostile detection files, a user's tracker and a tracker config."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from avdata.cli import main
from avdata.exporters.nuscenes import sample_token
from tests.realdata import REALDATA

DETECTIONS = REALDATA / "kitti_tracking_detections"
CSV = DETECTIONS / "pointrcnn_Car_val" / "0006.txt"
LABELS = {"0001": REALDATA / "kitti" / "tracking" / "training" / "label_02" / "0001.txt",
          "0006": DETECTIONS / "label_02" / "0006.txt", "0008": DETECTIONS / "label_02" / "0008.txt"}
FRAMES = {"0001": 447, "0006": 270, "0008": 390}
# The nuScenes devkit's TRACKING_NAMES (python-sdk/nuscenes/eval/tracking/constants.py).
TRACKING_NAMES = {"bicycle", "bus", "car", "motorcycle", "pedestrian", "trailer", "truck"}


def kitti_dataset(root: Path, sequences: tuple[str, ...] = ("0001", "0006", "0008")) -> Path:
    """The KITTI tracking sequences converted (0001 with its oxts; 0006 and 0008 have none: identity poses)."""
    src = root / "src" / "training"
    tracking = REALDATA / "kitti" / "tracking" / "training"
    for folder in ("calib", "oxts", "label_02"):
        (src / folder).mkdir(parents=True)
    for seq in sequences:
        if seq == "0001":
            for folder in ("calib", "oxts", "label_02"):
                (src / folder / "0001.txt").symlink_to(tracking / folder / "0001.txt")
        else:
            (src / "calib" / f"{seq}.txt").symlink_to(DETECTIONS / "calib_object_keys" / f"{seq}.txt")
            (src / "label_02" / f"{seq}.txt").symlink_to(LABELS[seq])
    assert main(["convert", "kitti-tracking", str(src.parent), str(root / "ds"), "--quiet"]) == 0
    return root / "ds"


def kitti_gt(root: Path, sequences: tuple[str, ...]) -> Path:
    (root / "label_02").mkdir(parents=True)
    for seq in sequences:
        (root / "label_02" / f"{seq}.txt").symlink_to(LABELS[seq])
    (root / "evaluate_tracking.seqmap.val").write_text("".join(f"{s} empty 0 {FRAMES[s]}\n" for s in sequences))
    return root


def evaluate(gt: Path, tracks: Path, json_path: Path, iou: str = "2d@0.5") -> dict:
    assert main(["eval", "tracking", str(gt), str(tracks), "--protocol", "kitti-3dmot", "--split", "val", "--iou", iou,
                 "--classes", "car", "pedestrian", "--json", str(json_path)]) == 0
    return json.loads(json_path.read_text())


@pytest.fixture(scope="module")
def tracked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The three sequences converted and tracked once (KITTI output, world where a sequence has poses)."""
    root = tmp_path_factory.mktemp("track")
    dataset = kitti_dataset(root)
    assert main(["track", str(dataset), str(root / "tracks"), "--detections", str(DETECTIONS), "--format", "ab3dmot",
                 "--quiet"]) == 0
    return root


def test_track_then_evaluate_the_three_real_sequences(tracked: Path, tmp_path: Path) -> None:
    gt = kitti_gt(tmp_path / "gt", ("0001", "0006", "0008"))
    table = evaluate(gt, tracked / "tracks", tmp_path / "r.json")
    # Measured (docs/tracking.md); AB3DMOT publishes Car sAMOTA 0.9308, MOTA 0.8598 over all 11 val sequences.
    assert table["car"]["sAMOTA"] == pytest.approx(0.9201, abs=1e-4)
    assert table["car"]["MOTA"] == pytest.approx(0.8331, abs=1e-4)
    assert table["car"]["script_MOTA"] == pytest.approx(0.8304, abs=1e-4)
    assert (table["car"]["IDS"], table["car"]["FRAG"], table["car"]["FP"], table["car"]["FN"]) == (2, 12, 245, 384)
    # Pedestrian: false pedestrian tracks of 0006 and 0008 (which have none) outscore the true ones of 0001; no
    # sampled threshold has a MOTA above 0, so the script keeps every track.
    assert table["pedestrian"]["MOTA"] == pytest.approx(-0.0377, abs=1e-4)
    assert table["pedestrian"]["script_MOTA"] == pytest.approx(-54.1604, abs=1e-4)
    assert evaluate(gt, tracked / "tracks", tmp_path / "r3.json", "3d@0.25")["car"]["MOTP"] == pytest.approx(0.7969, abs=1e-4)


def test_world_against_sensor_frame_on_the_moving_sequence(tracked: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    # 0001 is the only sequence with oxts: there the world frame removes the ego's ~10 m/s from the motion model
    # (docs/tracking.md, "World against sensor frame").
    assert main(["track", str(tracked / "ds"), str(tmp_path / "sensor"), "--detections", str(DETECTIONS), "--format",
                 "ab3dmot", "--frame", "sensor", "--scenes", "training_0001", "--quiet"]) == 0
    gt = kitti_gt(tmp_path / "gt", ("0001",))
    world = evaluate(gt, tracked / "tracks", tmp_path / "w.json")
    sensor = evaluate(gt, tmp_path / "sensor", tmp_path / "s.json")
    assert (world["car"]["sAMOTA"], world["car"]["MOTA"], world["car"]["FN"]) == pytest.approx((0.9095, 0.8327, 162), abs=1e-4)
    assert (sensor["car"]["sAMOTA"], sensor["car"]["MOTA"], sensor["car"]["FN"]) == pytest.approx((0.9112, 0.8261, 194),
                                                                                              abs=1e-4)
    # 0001 alone holds every pedestrian of the three: MOTA 0.679 in the sensor frame (AB3DMOT's setting; target 0.60).
    assert (world["pedestrian"]["MOTA"], world["pedestrian"]["sAMOTA"]) == pytest.approx((0.7170, 0.8618), abs=1e-4)
    assert (sensor["pedestrian"]["MOTA"], sensor["pedestrian"]["sAMOTA"]) == pytest.approx((0.6792, 0.7969), abs=1e-4)


def test_resume_and_two_workers_give_the_same_bytes(tracked: Path, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    args = ["track", str(tracked / "ds"), str(tracked / "tracks"), "--detections", str(DETECTIONS), "--format", "ab3dmot"]
    capsys.readouterr()
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "0 scenes tracked, 3 already complete, 0 failed" in captured.out
    # The scenes without poses are said once each; 0001 has oxts and is tracked in world.
    assert [line for line in captured.err.splitlines() if "no poses" in line] == [
        f"track: training_{s}: no poses (world_T_ego is the identity), tracked in the sensor frame" for s in ("0006", "0008")]
    assert main(["track", str(tracked / "ds"), str(tmp_path / "two"), "--detections", str(DETECTIONS), "--format",
                 "ab3dmot", "--workers", "2", "--scenes", "training_0006", "training_0008", "--quiet"]) == 0
    for seq in ("0006", "0008"):
        assert (tmp_path / "two" / f"{seq}.txt").read_bytes() == (tracked / "tracks" / f"{seq}.txt").read_bytes()


def test_unified_and_nuscenes_outputs_read_back(tracked: Path, tmp_path: Path) -> None:
    common = ["--detections", str(DETECTIONS), "--format", "ab3dmot", "--scenes", "training_0006", "--quiet"]
    assert main(["track", str(tracked / "ds"), str(tmp_path / "u"), "--output-format", "unified", *common]) == 0
    assert main(["track", str(tracked / "ds"), str(tmp_path / "n"), "--output-format", "nuscenes", *common]) == 0
    kitti_lines = (tracked / "tracks" / "0006.txt").read_text().splitlines()
    table = pq.read_table(tmp_path / "u" / "tracks.parquet").to_pydict()
    # The same tracks as the KITTI file (every PointRCNN class has a unified and a nuScenes tracking name).
    assert sorted(zip(table["frame_index"], map(int, table["object_id"]), strict=True)) == sorted(
        (int(line.split()[0]), int(line.split()[1])) for line in kitti_lines)
    assert main(["eval", "tracking", str(tracked / "ds"), str(tmp_path / "u" / "tracks.parquet"), "--protocol", "avdata",
                 "--classes", "car", "--json", str(tmp_path / "u.json")]) == 0
    car = json.loads((tmp_path / "u.json").read_text())["car"]
    # Scored against all three scenes' objects: those of 0001 and 0008 are misses here.
    assert (car["MOTA"], car["CLR_FP"], car["CLR_FN"], car["IDSW"]) == (pytest.approx(0.0919, abs=1e-4), 139, 4235, 4)
    submission = json.loads((tmp_path / "n" / "tracking_results.json").read_text())
    assert submission["meta"] == dict.fromkeys(("use_camera", "use_external", "use_lidar", "use_map", "use_radar"), False)
    # Every sample of the scene is present (the devkit requires it), as `avdata export nuscenes` names them.
    assert set(submission["results"]) == {sample_token("training_0006", f) for f in range(FRAMES["0006"])}
    boxes = [box for token, found in submission["results"].items() for box in found if box["sample_token"] == token]
    assert len(boxes) == sum(len(found) for found in submission["results"].values()) == len(kitti_lines)
    for box in boxes:
        assert set(box) == {"sample_token", "translation", "size", "rotation", "velocity", "tracking_id", "tracking_name",
                            "tracking_score"}
        assert len(box["translation"]) == 3 and len(box["velocity"]) == 2 and min(box["size"]) > 0
        assert math.isclose(sum(q * q for q in box["rotation"]), 1.0, rel_tol=1e-9)
        assert isinstance(box["tracking_id"], str) and box["tracking_name"] in TRACKING_NAMES
        assert isinstance(box["tracking_score"], float) and 0.0 <= box["tracking_score"] <= 1.0


def test_a_frame_the_dataset_lacks_and_an_unknown_scene_cost_their_detections(tracked: Path, tmp_path: Path,
                                                                               capsys: pytest.CaptureFixture[str]) -> None:
    dets = tmp_path / "dets"
    dets.mkdir()
    lines = CSV.read_text().splitlines()
    (dets / "0006.txt").write_text("\n".join([*lines, lines[0].replace("0,", "999,", 1)]) + "\n")
    (dets / "0042.txt").write_text(lines[0] + "\n")
    capsys.readouterr()
    assert main(["track", str(tracked / "ds"), str(tmp_path / "out"), "--detections", str(dets), "--format", "ab3dmot",
                 "--quiet"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert f"avdata: error: {dets}: scene '0006' frame 999: expected a frame of training_0006 in {tracked / 'ds'}, got none " \
           "(1 detections dropped)" in err
    assert f"avdata: error: {dets}: scene '0042': expected a scene of {tracked / 'ds'} (by name, KITTI sequence or log id), " \
           "got '0042' (1 detections dropped)" in err
    assert not any("Traceback" in line for line in err)
    written = (tmp_path / "out" / "0006.txt").read_text().splitlines()
    assert written and max(int(line.split()[0]) for line in written) < FRAMES["0006"]
    assert (tmp_path / "out" / "0001.txt").read_text() == ""  # a scene without detections: no tracks


def test_a_bad_record_costs_that_record_and_exits_1(tracked: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    lines = CSV.read_text().splitlines()[:40]
    lines[3] = lines[3].replace(lines[3].split(",")[6], "inf", 1)  # the score
    (tmp_path / "dets").mkdir()
    (tmp_path / "dets" / "0006.txt").write_text("\n".join(lines) + "\n")
    assert main(["track", str(tracked / "ds"), str(tmp_path / "out"), "--detections", str(tmp_path / "dets"),
                 "--format", "ab3dmot", "--scenes", "training_0006", "--quiet"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0] == f"avdata: error: {tmp_path / 'dets' / '0006.txt'}: line 4: field score: expected a finite number, got 'inf'"
    written = (tmp_path / "out" / "0006.txt").read_text().splitlines()
    assert written and all(len(line.split()) == 18 for line in written)


def test_a_users_tracker_and_config(tracked: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "tracker.yaml"
    config.write_text("classes:\n  car: {metric: dist_3d, threshold: 1.0, algorithm: greedy, min_hits: 1, max_age: 1}\n")
    base = ["track", str(tracked / "ds"), "--detections", str(CSV), "--format", "ab3dmot", "--scenes", "training_0006",
            "--quiet"]
    args = [*base[:2], str(tmp_path / "a"), *base[2:], "--config", str(config)]
    assert main(args) == 0
    # Every detection is shown (min_hits 1, max_age 1: nothing coasts), so the output has one line per detection.
    assert len((tmp_path / "a" / "0006.txt").read_text().splitlines()) == len(CSV.read_text().splitlines())
    assert main([*base[:2], str(tmp_path / "b"), *base[2:], "--tracker", "avdata.perception.tracker:KalmanTracker"]) == 0
    config.write_text("classes:\n  car: {metric: mahalanobis}\n")
    assert main([*args, "--force"]) == 1
    assert "expected metric in ('giou_3d', 'iou_3d', 'dist_3d')" in capsys.readouterr().err


def test_unified_detections_are_tracked_in_world_and_refused_as_kitti(tracked: Path, tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    import pyarrow as pa

    # One car moving 1 m per frame along world x in the first three frames of 0001 (boxes in world).
    rows = {"scene": ["training_0001"] * 3, "frame_index": [0, 1, 2], "object_id": ["a", "b", "c"],
            "class": ["car"] * 3, "x_world_m": [10.0, 11.0, 12.0], "y_world_m": [0.0] * 3, "z_world_m": [0.0] * 3,
            "length_m": [4.0] * 3, "width_m": [1.8] * 3, "height_m": [1.5] * 3, "yaw_world_rad": [0.0] * 3,
            "score": [0.9] * 3}
    pq.write_table(pa.table(rows), tmp_path / "dets.parquet")
    common = ["track", str(tracked / "ds"), "--detections", str(tmp_path / "dets.parquet"), "--format", "unified",
              "--scenes", "training_0001", "--quiet"]
    assert main([*common[:2], str(tmp_path / "u"), *common[2:]]) == 0  # KITTI's own format needs 2D boxes: unified
    pq.write_table(pa.table({**rows, "frame_index": [0, 1, 999]}), tmp_path / "late.parquet")
    late = [*common[:2], str(tmp_path / "late"), "--detections", str(tmp_path / "late.parquet"), *common[4:]]
    capsys.readouterr()
    assert main(late) == 1  # the row beyond the scene costs that row (numpy's repr np.str_('...') was in the line)
    assert capsys.readouterr().err.splitlines()[0] == (f"avdata: error: {tmp_path / 'late.parquet'}: row 2: scene, "
                                                       f"frame_index: expected a frame of {tracked / 'ds'}, got "
                                                       "('training_0001', 999)")
    table = pq.read_table(tmp_path / "u" / "tracks.parquet").to_pydict()
    # One track, shown one frame after its last detection at its predicted box (AB3DMOT's max_age 2 for cars).
    assert table["frame_index"] == [0, 1, 2, 3] and len(set(table["object_id"])) == 1
    assert table["x_world_m"][:3] == pytest.approx([10.0, 11.0, 12.0], abs=0.3) and 12.0 < table["x_world_m"][3] < 13.0
    capsys.readouterr()
    assert main([*common[:2], str(tmp_path / "k"), *common[2:], "--output-format", "kitti"]) == 1
    assert capsys.readouterr().err.strip() == ("avdata: error: --output-format kitti: expected KITTI-style detections "
                                               "(their 2D boxes and raw scores), got --format unified")


def test_nuscenes_submission_matched_by_sample_token(tracked: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    box = {"translation": [20.0, 1.0, 0.5], "size": [1.8, 4.0, 1.5], "rotation": [1.0, 0.0, 0.0, 0.0],
           "velocity": [0.0, 0.0], "detection_name": "car", "detection_score": 0.8, "attribute_name": "vehicle.parked"}
    known = sample_token("training_0006", 0)
    results = {known: [box | {"sample_token": known}], "f" * 32: [box | {"sample_token": "f" * 32}]}
    (tmp_path / "dets.json").write_text(json.dumps({"meta": {}, "results": results}))
    capsys.readouterr()
    assert main(["track", str(tracked / "ds"), str(tmp_path / "out"), "--detections", str(tmp_path / "dets.json"),
                 "--format", "nuscenes", "--scenes", "training_0006", "--quiet"]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"avdata: error: {tmp_path / 'dets.json'}: results['{'f' * 32}']: sample_token: expected a sample of "
        f"{tracked / 'ds'} (as avdata export nuscenes names them), got '{'f' * 32}'"]
    table = pq.read_table(tmp_path / "out" / "tracks.parquet").to_pydict()
    # Shown in the scene's first min_hits frames, and one frame after at its prediction (max_age 2), in world.
    assert table["frame_index"] == [0, 1] and table["x_world_m"] == pytest.approx([20.0, 20.0])


def test_argoverse2_detections_matched_by_time_and_tracked_in_world(tmp_path: Path) -> None:
    import numpy as np
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.feather as feather

    log = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
    src = tmp_path / "av2" / "val"
    src.mkdir(parents=True)
    (src / log).symlink_to(REALDATA / "argoverse2" / "sensor" / "val" / log)
    assert main(["convert", "argoverse2", str(src.parent), str(tmp_path / "ds"), "--quiet"]) == 1  # missing sweeps
    # The log's cuboids of its first 5 times (in the ego frame of their time) as a detector's table.
    cuboids = feather.read_table(src / log / "annotations.feather").drop_columns(["track_uuid", "num_interior_pts"])
    times = pa.array(np.unique(cuboids["timestamp_ns"].to_numpy())[:5])
    cuboids = cuboids.filter(pc.is_in(cuboids["timestamp_ns"], times))
    n = cuboids.num_rows
    feather.write_feather(cuboids.append_column("log_id", pa.array([log] * n)).append_column("score", pa.array([0.9] * n)),
                          tmp_path / "dets.feather")
    assert main(["track", str(tmp_path / "ds"), str(tmp_path / "out"), "--detections", str(tmp_path / "dets.feather"),
                 "--format", "argoverse2", "--quiet"]) == 0
    assert main(["eval", "tracking", str(tmp_path / "ds"), str(tmp_path / "out" / "tracks.parquet"), "--protocol", "avdata",
                 "--classes", "car", "--json", str(tmp_path / "r.json")]) == 0
    car = json.loads((tmp_path / "r.json").read_text())["car"]
    # Moved to world at each sweep's time, the tracks lie on the ground truth (LocA ~1) and none is false.
    assert car["CLR_FP"] == 0 and car["LocA"] > 0.998


def test_a_tracker_config_of_strings_is_refused_not_converted(tmp_path: Path) -> None:
    from avdata.errors import InputError
    from avdata.perception.cli import load_tracker_config

    config = tmp_path / "tracker.yaml"
    config.write_text("process_sigma: [1, 1, 1, 1, 1, 1, 1, 1, 1, '1e3']\n")  # float('1e3') took the string as 1000
    with pytest.raises(InputError, match=r"tracker.yaml: invalid tracker config \(tracker: expected 10 positive "
                                         r"process_sigma, got \(1, 1, 1, 1, 1, 1, 1, 1, \.\.\.\)\)"):
        load_tracker_config(config)
    config.write_text("process_sigma: [1, 1, 1, 1, 1, 1, 1, 1, 1, 2]\n")
    assert load_tracker_config(config).process_sigma == (1, 1, 1, 1, 1, 1, 1, 1, 1, 2)
