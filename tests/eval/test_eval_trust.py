"""Evaluation input rules of issue 34 item 5 and issue 33 items 4 and 6, each on the input that broke it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pyarrow.parquet as pq
import pytest

from avdata.cli import main
from avdata.errors import InputError
from avdata.eval.detection.av2 import read_detections
from avdata.eval.detection.waymo import WaymoBoxes, WaymoType, evaluate_waymo_detection
from avdata.eval.problems import EvalWarning
from avdata.eval.safety import evaluate_safety
from avdata.eval.unified import read_table
from tests.eval.eval_unified_synth import make_frames, make_tables, write_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, pa.Table]:
    objects, visibility = make_tables()
    return write_dataset(tmp_path_factory.mktemp("eval") / "ds", objects, visibility), objects


def _detections(objects: pa.Table, score: float) -> pa.Table:
    columns = ["scene", "frame_index", "object_id", "class", "x_world_m", "y_world_m", "z_world_m", "length_m",
               "width_m", "height_m", "yaw_world_rad"]
    return objects.select(columns).append_column("score", pa.array(np.full(len(objects), score)))


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    status = main(argv)
    out, err = capsys.readouterr()
    return status, out, err


def test_negative_scores_count_by_default(dataset, tmp_path, capsys) -> None:
    # Was: --score-threshold 0 by default dropped every logit below 0 without a word (recall 0).
    root, objects = dataset
    pq.write_table(_detections(objects, -2.5), tmp_path / "dets.parquet")
    argv = ["eval", "detection", str(root), str(tmp_path / "dets.parquet"), "--protocol", "avdata", "--json",
            str(tmp_path / "r.json")]
    status, _, err = _run(argv, capsys)
    assert status == 0, err
    result = json.loads((tmp_path / "r.json").read_text())["all"]
    assert result["recall"] == 1.0 and result["FP"] == 0 and result["TP"] > 0
    assert _run([*argv, "--score-threshold", "0"], capsys)[0] == 0
    assert json.loads((tmp_path / "r.json").read_text())["all"]["TP"] == 0  # a threshold given still applies


def test_an_unknown_class_warns_with_its_name_and_count(dataset, tmp_path, capsys) -> None:
    root, objects = dataset
    dets = _detections(objects, 0.9)
    classes = dets["class"].to_pylist()
    classes[:3] = ["Car", "Car", "Van"]  # KITTI spellings
    dets = dets.set_column(3, "class", pa.array(classes))
    pq.write_table(dets, tmp_path / "dets.parquet")
    status, _, err = _run(["eval", "detection", str(root), str(tmp_path / "dets.parquet"), "--protocol", "avdata"], capsys)
    assert status == 0
    assert err.splitlines() == [
        f"avdata: warning: {tmp_path}/dets.parquet: class: 2 row(s) of class 'Car', which is not one of the evaluated "
        f"classes; they can only be false positives",
        f"avdata: warning: {tmp_path}/dets.parquet: class: 1 row(s) of class 'Van', which is not one of the evaluated "
        f"classes; they can only be false positives"]


def test_overlap_nlz_as_text_is_refused(tmp_path) -> None:
    # Was: "false" read as True (a non-empty string), so every such prediction was excused as in a no-label zone.
    rows = [{"scene": "s", "frame_index": 0, "score": 0.5, "overlap_nlz": flag} for flag in (True, "false")]
    (tmp_path / "p.json").write_text(json.dumps(rows))
    with pytest.raises(InputError, match=r"p.json: row 1: overlap_nlz: expected true or false, got 'false'"):
        read_table(tmp_path / "p.json", ("scene", "frame_index", "score"))
    pq.write_table(pa.table({"scene": ["s"], "frame_index": [0], "score": [0.5], "overlap_nlz": [1]}), tmp_path / "p.parquet")
    with pytest.raises(InputError, match=r"row 0: overlap_nlz: expected true or false, got 1"):
        read_table(tmp_path / "p.parquet", ("scene", "frame_index", "score"))
    (tmp_path / "ok.json").write_text(json.dumps([{"scene": "s", "frame_index": 0, "score": 0.5, "overlap_nlz": False}]))
    assert read_table(tmp_path / "ok.json", ("scene", "frame_index", "score"))["overlap_nlz"].to_pylist() == [False]


def _waymo_boxes(types: list[int], frames: list[int]) -> WaymoBoxes:
    n = len(types)
    box = np.tile([10.0, 0.0, 1.0, 4.5, 2.0, 1.6, 0.0], (n, 1))
    box[:, 0] += np.arange(n) * 10
    return WaymoBoxes(frame_id=np.asarray(frames), box=box, type=np.asarray(types), difficulty=np.ones(n, np.int64),
                      score=np.full(n, 0.9, np.float32))


def test_waymo_empty_ground_truth_is_refused_and_an_empty_type_warns() -> None:
    # Was: all zeros printed without a word, where the nuScenes protocol warns.
    vehicles = _waymo_boxes([int(WaymoType.VEHICLE)] * 2, [0, 0])
    with pytest.raises(InputError, match=r"ground truth: expected ground truth of the evaluated classes "
                                         r"\(VEHICLE, PEDESTRIAN, SIGN, CYCLIST\), got none"):
        evaluate_waymo_detection(_waymo_boxes([], []), vehicles)
    with pytest.warns(EvalWarning, match=r"^ground truth: no object of class\(es\) PEDESTRIAN, SIGN, CYCLIST; "
                                         r"their AP and APH are 0$"):
        result = evaluate_waymo_detection(vehicles, vehicles)
    assert result[(WaymoType.VEHICLE, 1)].ap == pytest.approx(1.0)


def test_waymo_predictions_of_unknown_scenes_or_frames_are_refused(dataset, tmp_path, capsys) -> None:
    # Was: scored as frames without ground truth (their boxes false positives), silently.
    root, objects = dataset
    columns = {"scene": ["s0", "s0"], "frame_index": [0, 99], "score": [0.5, 0.5], "source_class": ["TYPE_VEHICLE"] * 2,
               **{c: [1.0, 1.0] for c in ("x_ego_m", "y_ego_m", "z_ego_m", "length_m", "width_m", "height_m", "yaw_ego_rad")}}
    pq.write_table(pa.table(columns), tmp_path / "p.parquet")
    status, _, err = _run(["eval", "detection", str(root), str(tmp_path / "p.parquet"), "--protocol", "waymo"], capsys)
    assert (status, err) == (1, f"avdata: error: {tmp_path}/p.parquet: row 1: frame_index: expected a frame of scene "
                                f"'s0' (0..19), got 99\n")
    columns["scene"] = ["s0", "elsewhere"]
    pq.write_table(pa.table(columns), tmp_path / "p.parquet")
    status, _, err = _run(["eval", "detection", str(root), str(tmp_path / "p.parquet"), "--protocol", "waymo"], capsys)
    assert (status, err) == (1, f"avdata: error: {tmp_path}/p.parquet: scene: expected scenes of the dataset (1), got "
                                f"unknown 'elsewhere'\n")


def _av2_detections(path: Path, **change: list) -> Path:
    columns = {"log_id": ["log-a"], "timestamp_ns": [1], "category": ["REGULAR_VEHICLE"], "tx_m": [1.0], "ty_m": [0.0],
               "tz_m": [0.0], "length_m": [4.0], "width_m": [2.0], "height_m": [1.5], "qw": [1.0], "qx": [0.0],
               "qy": [0.0], "qz": [0.0], "score": [0.5]} | change
    feather.write_feather(pa.table(columns), path)
    return path


def test_av2_negative_sizes_are_refused(tmp_path) -> None:
    # README promised it; the AV2 protocol took a negative width as a box.
    path = _av2_detections(tmp_path / "d.feather", width_m=[-2.0])
    with pytest.raises(InputError, match=r"d.feather: row 0: width_m: expected a size >= 0, got -2.0"):
        read_detections(path)


def test_av2_detections_of_unannotated_sweeps_are_refused_and_unknown_categories_warn(tmp_path) -> None:
    from avdata.eval.detection.av2 import Av2DetectionConfig, evaluate_av2_detection

    gts = read_detections(_av2_detections(tmp_path / "g.feather", timestamp_ns=[1]))
    config = Av2DetectionConfig(eval_only_roi_instances=False)
    with pytest.raises(InputError, match=r"row 0: expected detections at annotated sweeps of the ground truth .*"
                                         r"got timestamp_ns 2 \(1 such row\(s\)\)"):
        evaluate_av2_detection(read_detections(_av2_detections(tmp_path / "d.feather", timestamp_ns=[2])), gts, config)
    with pytest.warns(EvalWarning, match=r"1 row\(s\) of category 'CAR', which is not one of the evaluated"):
        evaluate_av2_detection(read_detections(_av2_detections(tmp_path / "d.feather", category=["CAR"])), gts, config)


def test_safety_leaves_the_ego_out_of_the_tracks(tmp_path) -> None:
    # Ground truth given as tracks, with the ego's own box among the objects: were invented violations.
    objects, _ = make_tables(n_frames=6)
    frames = make_frames(objects)
    ego_rows = [{**objects.slice(0, 1).to_pylist()[0], "frame_index": f, "object_id": "ego-box", "class": "car",
                 "x_world_m": float(f), "y_world_m": 0.0, "yaw_world_rad": 0.0, "vx_world_mps": 10.0,
                 "vy_world_mps": 0.0} for f in range(6)]
    with_ego = pa.concat_tables([objects, pa.Table.from_pylist(ego_rows, schema=objects.schema)])
    result = evaluate_safety(frames, with_ego, with_ego, exclude_ids=frozenset({"ego-box"}))
    assert result.invented_violations == 0 and result.track_violating_pairs == result.violating_pairs
    # The ego seen by another agent's sensor, under a track id of its own: still the ego.
    ids = with_ego["object_id"].to_pylist()
    renamed = with_ego.set_column(with_ego.column_names.index("object_id"), "object_id",
                                  pa.array(["track-7" if i == "ego-box" else i for i in ids]))
    assert evaluate_safety(frames, with_ego, renamed, exclude_ids=frozenset({"ego-box"})).invented_violations == 0


def test_kitti_result_files_of_images_without_labels_are_refused(tmp_path, capsys) -> None:
    # Were passed over without a word (only the label folder's images were read).
    (tmp_path / "label_2").mkdir()
    (tmp_path / "results").mkdir()
    line = "Car 0.00 0 0 100 100 200 200 1.5 1.6 4.0 0 1.5 10 0"
    (tmp_path / "label_2" / "000000.txt").write_text(line + "\n")
    for image in ("000000", "000007"):
        (tmp_path / "results" / f"{image}.txt").write_text(line + " 0.9\n")
    status, _, err = _run(["eval", "detection", str(tmp_path), str(tmp_path / "results"), "--protocol", "kitti"], capsys)
    assert (status, err) == (1, f"avdata: error: {tmp_path}/results: expected result files of the images of "
                                f"{tmp_path}/label_2, got 1 other(s): 000007.txt\n")
    (tmp_path / "results" / "000007.txt").unlink()
    assert _run(["eval", "detection", str(tmp_path), str(tmp_path / "results"), "--protocol", "kitti"], capsys)[0] == 0


def test_avdata_detection_warns_for_a_class_without_ground_truth(dataset, tmp_path, capsys) -> None:
    # As the nuScenes, KITTI and tracking protocols do (the avdata detection protocol said nothing).
    root, objects = dataset
    dets = _detections(objects, 0.9)
    classes = dets["class"].to_pylist()
    classes[0] = "bus"
    pq.write_table(dets.set_column(3, "class", pa.array(classes)), tmp_path / "dets.parquet")
    status, _, err = _run(["eval", "detection", str(root), str(tmp_path / "dets.parquet"), "--protocol", "avdata"], capsys)
    assert status == 0
    assert err == (f"avdata: warning: {root}: no object of class(es) bus; their detections count only as false "
                   f"positives\n")


@pytest.mark.parametrize(("column", "values", "expected"), [
    ("width_m", ["2.0"], "expected numbers, got string"),
    ("timestamp_ns", [1.5], "expected integers, got double"),
    ("category", [3], "expected text, got int64")])
def test_av2_typed_columns_are_checked(tmp_path, column: str, values: list, expected: str) -> None:
    # A width given as the text "2.0" was converted without a word.
    path = _av2_detections(tmp_path / "d.feather", **{column: values})
    with pytest.raises(InputError, match=rf"d.feather: column '{column}': {expected}$"):
        read_detections(path)


@pytest.mark.parametrize(("change", "expected"), [
    # finite but absurd: 1e308 m was scored (a far false positive, a size error of any value)
    ({"tx_m": [1e308]}, r"row 0: expected a centre within 1e\+07 m and sizes up to 1000 m, got \[1e\+308, "),
    ({"length_m": [1e308]}, r"row 0: expected a centre within 1e\+07 m and sizes up to 1000 m, got \[1.0, 0.0, 0.0, 1e\+308"),
    # NumPy's strings drop trailing NULs: the detections of "log-a\x00" were scored as log-a's
    ({"log_id": ["log-a\x00"]}, r"row 0: log_id: expected text without NUL characters, got 'log-a\\x00'"),
])
def test_av2_absurd_boxes_and_names_with_nul_are_refused(tmp_path, change: dict, expected: str) -> None:
    path = _av2_detections(tmp_path / "d.feather", **change)
    with pytest.raises(InputError, match=rf"^{path}: {expected}"):
        read_detections(path)


def test_av2_messages_about_detection_rows_name_the_file(tmp_path, capsys) -> None:
    # "avdata: error: expected detections of the ground-truth logs, ..." named no file.
    split = tmp_path / "val"
    (split / "log-a").mkdir(parents=True)
    gt = feather.read_table(_av2_detections(tmp_path / "g.feather"))
    gt = gt.drop(["log_id", "score"]).append_column("num_interior_pts", pa.array([10]))
    feather.write_feather(gt.append_column("track_uuid", pa.array(["t0"])), split / "log-a" / "annotations.feather")
    for change, message in (({"log_id": ["log-b"]}, "log_id: expected detections of the ground-truth logs, got logs "
                                                    "['log-b'] without ground truth"),
                            ({"timestamp_ns": [2]}, "row 0: expected detections at annotated sweeps of the ground truth "
                                                    "(the timestamps of log-a/annotations.feather), got timestamp_ns 2 "
                                                    "(1 such row(s))")):
        path = _av2_detections(tmp_path / "d.feather", **change)
        status, _, err = _run(["eval", "detection", str(split), str(path), "--protocol", "av2", "--no-roi"], capsys)
        assert (status, err.splitlines()) == (1, [f"avdata: error: {path}: {message}"])
