"""Prediction values of the wrong kind or size: refused with one line naming file, record and value.

Found by a sweep that mutated one value (or the shape) of each protocol's prediction file in turn; each case here
was scored as if valid (text "1.5" or true read as numbers, 1e308 m boxes, a scene "s0\\x00" taken as "s0", a
quaternion of norm 2, a track given twice in one sample) or was a traceback (2**70, JSON nested 100000 deep).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from eval_nuscenes_synth import write_nuscenes
from eval_unified_synth import make_tables, write_dataset

from avdata.cli import main
from avdata.errors import InputError
from avdata.eval.detection.nuscenes import load_nuscenes_gt, load_nuscenes_submission
from avdata.eval.tracking.nuscenes import load_nuscenes_tracking
from avdata.eval.unified import DETECTION_COLUMNS, read_table

_COLUMNS = (*DETECTION_COLUMNS, "score")
_ROW = {"scene": "s0", "frame_index": 0, "object_id": "a", "class": "car", "x_world_m": 1.0, "y_world_m": 2.0,
        "z_world_m": 0.5, "length_m": 4.0, "width_m": 1.8, "height_m": 1.5, "yaw_world_rad": 0.1, "score": 0.9}


def _rows(**changes: Any) -> list[dict[str, Any]]:
    return [_ROW, {**_ROW, "object_id": "b", **changes}]


@pytest.mark.parametrize(("text", "message"), [
    (json.dumps(_rows(x_world_m=1e308)), r"row 1: x_world_m: expected a value in \[-1e\+07, 1e\+07\], got 1e\+308"),
    (json.dumps(_rows(length_m=1e308)), r"row 1: length_m: expected a value in \[0, 1000\], got 1e\+308"),
    (json.dumps(_rows(yaw_world_rad=1e308)), r"row 1: yaw_world_rad: expected a value in \[-12.5664, 12.5664\]"),
    (json.dumps(_rows(x_world_m=2**70)), r"row 1: x_world_m: expected a number \(64 bits\), got 1180591620717411303424"),
    (json.dumps(_rows(frame_index=1e308)), r"row 1: frame_index: expected an integer \(64 bits\), got 1e\+308"),
    (json.dumps([{**_ROW, "x_world_m": "1.5"}]), r"row 0: x_world_m: expected a number, got '1.5' \(a column of string\)"),
    (json.dumps([{**_ROW, "frame_index": True}]), r"row 0: frame_index: expected an integer, got True \(a column of bool\)"),
    (json.dumps(_rows(object_id=[1])), r"row 1: object_id: expected a string, got \[1\]"),
    (json.dumps(_rows(scene="s0\x00")), r"row 1: scene: expected text without NUL characters, got 's0\\x00'"),
    (json.dumps({"columns": 3, "rows": []}), r"expected 'columns' a list of distinct names and 'rows' a list, got columns 3"),
    (json.dumps({"columns": [*_COLUMNS, "score"], "rows": [[*_ROW.values(), 0.1]]}),
     r"expected 'columns' a list of distinct names and 'rows' a list, got columns \['scene'"),
    ("[" * 100_000 + "]" * 100_000, r"expected JSON, got maximum recursion depth exceeded"),
])
def test_avdata_json_value_of_the_wrong_kind_is_refused(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "dets.json"
    path.write_text(text)
    with pytest.raises(InputError, match=rf"^{path}: {message}"):
        read_table(path, _COLUMNS)


@pytest.mark.parametrize(("column", "values", "message"), [
    ("x_world_m", pa.array(["1.0", "2.0"]), r"row 0: x_world_m: expected a number, got '1.0' \(a column of string\)"),
    ("score", pa.array([True, False]), r"row 0: score: expected a number, got True \(a column of bool\)"),
    ("frame_index", pa.array([False, True]), r"row 0: frame_index: expected an integer, got False \(a column of bool\)"),
    ("class", pa.array([True, True]), r"row 0: class: expected a string, got True \(a column of bool\)"),
])
def test_avdata_parquet_column_of_the_wrong_type_is_refused(tmp_path: Path, column: str, values: pa.Array,
                                                            message: str) -> None:
    # A cast read text as numbers and booleans as 0/1: a bool frame_index moved every detection to frame 0 or 1.
    table = pa.Table.from_pylist(_rows())
    path = tmp_path / "dets.parquet"
    pq.write_table(table.set_column(table.column_names.index(column), column, values), path)
    with pytest.raises(InputError, match=rf"^{path}: {message}$"):
        read_table(path, _COLUMNS)


def test_a_scene_name_with_a_nul_is_not_taken_for_the_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # NumPy's strings drop trailing NULs: "s0\x00" matched scene s0 and was scored (exit 0).
    objects, visibility = make_tables(n_frames=3)
    root = write_dataset(tmp_path / "ds", objects, visibility)
    rows = objects.select(list(DETECTION_COLUMNS)).append_column("score", pa.array(np.ones(len(objects)))).to_pylist()
    rows[0]["scene"] = "s0\x00"
    path = tmp_path / "dets.json"
    path.write_text(json.dumps(rows))
    status = main(["eval", "detection", str(root), str(path), "--protocol", "avdata", "--json", str(tmp_path / "r.json")])
    assert (status, capsys.readouterr().err.splitlines()) == (
        1, [f"avdata: error: {path}: row 0: scene: expected text without NUL characters, got 's0\\x00'"])
    assert not (tmp_path / "r.json").exists()


@pytest.fixture(scope="module")
def nuscenes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("nus")
    write_nuscenes(root, 5)
    return root


def _first_box(data: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    token = next(t for t, boxes in data["results"].items() if boxes)
    return token, data["results"][token][0]


def _set(field: str, value: Any) -> Callable[[dict[str, Any]], None]:
    return lambda box: box.__setitem__(field, value)


@pytest.mark.parametrize(("change", "message"), [
    (_set("translation", ["1", "2", "3"]), r"translation: expected 3 numbers, got \['1', '2', '3'\]"),
    (_set("size", [True, True, True]), r"size: expected 3 numbers, got \[True, True, True\]"),
    (_set("translation", [1e308, 0, 0]), r"translation: expected 3 numbers within 1e\+07, got \[1e\+308, 0, 0\]"),
    (_set("size", [-1, 2, 3]), r"size: expected sizes in \[0, 1000\] m, got \[-1.0, 2.0, 3.0\]"),
    (_set("rotation", [2, 0, 0, 0]), r"rotation: expected a unit quaternion \(w, x, y, z\), got \[2.0, 0.0, 0.0, 0.0\]"),
    (_set("rotation", [0, 0, 0, 0]), r"rotation: expected a unit quaternion \(w, x, y, z\), got \[0.0, 0.0, 0.0, 0.0\]"),
    (_set("velocity", [float("inf"), 0]), r"velocity: expected 2 numbers within 1000 m/s \(NaN for none\), got \[inf, 0\]"),
    (_set("velocity", [True, 0]), r"velocity: expected 2 numbers within 1000 m/s \(NaN for none\), got \[True, 0\]"),
])
def test_nuscenes_detection_box_of_the_wrong_kind_is_refused(nuscenes: Path, tmp_path: Path,
                                                             change: Callable[[dict[str, Any]], None], message: str) -> None:
    # Each was scored as if valid (the zero quaternion was refused without naming the file).
    _, ego, samples = load_nuscenes_gt(nuscenes / "v1.0-mini")
    data = json.loads((nuscenes / "results.json").read_text())
    token, box = _first_box(data)
    change(box)
    path = tmp_path / "sub.json"
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=rf"^{path}: results\['{token}'\]\[0\] {message}$"):
        load_nuscenes_submission(path, ego, samples)


def test_nuscenes_tracking_ids_must_be_ids_once_per_sample(nuscenes: Path, tmp_path: Path) -> None:
    data = json.loads((nuscenes / "tracking.json").read_text())
    token, box = _first_box(data)
    path = tmp_path / "track.json"
    for track_id, message in ((None, r"\[0\] tracking_id: expected a string or an integer, got None"),
                              ([1], r"\[0\] tracking_id: expected a string or an integer, got \[1\]")):
        box["tracking_id"] = track_id  # str() made both an id ("None", "[1]")
        path.write_text(json.dumps(data))
        with pytest.raises(InputError, match=rf"^{path}: results\['{token}'\]{message}$"):
            load_nuscenes_tracking(nuscenes / "v1.0-mini", path)
    box["tracking_id"] = "x"
    data["results"][token].append(dict(box))  # the same track twice in one sample was scored
    path.write_text(json.dumps(data))
    last = len(data["results"][token]) - 1
    with pytest.raises(InputError, match=rf"^{path}: results\['{token}'\]\[{last}\] tracking_id: expected each track "
                                         rf"once per sample, got 'x' also at \[0\]$"):
        load_nuscenes_tracking(nuscenes / "v1.0-mini", path)


@pytest.mark.parametrize("text", ["[" * 100_000 + "]" * 100_000, '{"results": {"a": [' + "1" * 5000 + "]}}"])
def test_nuscenes_submission_too_deep_or_with_a_huge_integer_is_one_line(nuscenes: Path, tmp_path: Path,
                                                                         text: str) -> None:
    _, ego, samples = load_nuscenes_gt(nuscenes / "v1.0-mini")
    path = tmp_path / "sub.json"
    path.write_text(text)
    with pytest.raises(InputError, match=rf"^{path}: expected JSON \(submission\), got (maximum recursion|Exceeds)"):
        load_nuscenes_submission(path, ego, samples)


@pytest.fixture(scope="module")
def trajectories(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    """A dataset and a perfect two-mode, three-step prediction of two of its objects at frame 0."""
    objects, visibility = make_tables(n_frames=5)
    root = write_dataset(tmp_path_factory.mktemp("pred") / "ds", objects, visibility)
    where = {(r["frame_index"], r["object_id"]): (r["x_world_m"], r["y_world_m"]) for r in objects.to_pylist()}
    rows = [{"scene": "s0", "frame_index": 0, "object_id": obj, "mode": mode, "probability": 0.5, "step": step,
             "x_world_m": where[(step, obj)][0] + mode, "y_world_m": where[(step, obj)][1]}
            for obj in ("obj1", "obj2") for mode in (0, 1) for step in (1, 2, 3)]
    return root, rows


def _predict(capsys: pytest.CaptureFixture[str], root: Path, path: Path, *options: str) -> tuple[int, list[str]]:
    status = main(["eval", "prediction", str(root), str(path), *options])
    return status, capsys.readouterr().err.splitlines()


def test_prediction_probability_must_be_one_per_mode(trajectories, tmp_path: Path, capsys) -> None:
    # The probability of each mode is given on each step's row; a different one on one row was overwritten
    # by the last without a word (the ranking of the modes, and so ADE/FDE, followed whichever came last).
    root, rows = trajectories
    path = tmp_path / "p.json"
    path.write_text(json.dumps(rows))
    assert _predict(capsys, root, path)[0] == 0
    path.write_text(json.dumps([{**rows[0], "probability": 0.9}, *rows[1:]]))
    assert _predict(capsys, root, path) == (1, [f"avdata: error: {path}: row 0: probability: expected one probability "
                                                f"per mode (the same at each step), got 0.9 and 0.5"])


def test_prediction_shape_errors_name_the_file(trajectories, tmp_path: Path, capsys) -> None:
    # They began "predictions:", naming no file.
    root, rows = trajectories
    path = tmp_path / "p.json"
    path.write_text(json.dumps(rows[:-1]))
    assert _predict(capsys, root, path) == (1, [f"avdata: error: {path}: expected 2 agents x 2 modes x 3 steps = 12 "
                                                f"rows, got 11"])


@pytest.mark.parametrize(("task", "option", "value", "least"), [
    ("prediction", "--miss-threshold-m", "nan", " >= 0"),  # no prediction was a miss: MR 0
    ("prediction", "--miss-threshold-m", "-1", " >= 0"),   # every prediction was a miss
    ("detection", "--score-threshold", "nan", ""),         # every detection was dropped: recall 0
    ("detection", "--match-distance-m", "inf", " >= 0"),
])
def test_number_options_that_are_no_numbers_are_refused(trajectories, tmp_path: Path, capsys, task: str, option: str,
                                                        value: str, least: str) -> None:
    root, rows = trajectories
    path = tmp_path / "p.json"
    path.write_text(json.dumps(rows))
    status = main(["eval", task, str(root), str(path), "--protocol", "avdata", option, value])
    shown_value = float(value)
    assert (status, capsys.readouterr().err.splitlines()) == (
        1, [f"avdata: error: {option}: expected finite numbers{least}, got {shown_value}"])


def test_avdata_tracking_of_an_empty_tracker_or_image_boxes_is_one_line(trajectories, tmp_path: Path, capsys) -> None:
    root, _ = trajectories
    path = tmp_path / "tracks.json"
    path.write_text("[]")
    argv = ["eval", "tracking", str(root), str(path), "--protocol", "avdata"]
    # The classes come from the tracks: an empty tracker was a StopIteration traceback.
    assert (main(argv), capsys.readouterr().err.splitlines()) == (1, [
        f"avdata: error: {path}: expected tracks to take the classes from, got none (name the classes with --classes "
        f"to score a tracker that found nothing)"])
    assert main([*argv, "--classes", "car", "--json", str(tmp_path / "r.json")]) == 0
    assert json.loads((tmp_path / "r.json").read_text())["car"]["CLR_TP"] == 0
    # iou_2d was offered and always failed on "gt boxes: expected (N, 4) for iou_2d, got (N, 7)", naming no file.
    assert (main([*argv, "--similarity", "iou_2d"]), capsys.readouterr().err.splitlines()) == (1, [
        "avdata: error: --similarity: expected iou_bev, iou_3d, euclidean for --protocol avdata (its boxes are 3D, "
        "without image boxes), got iou_2d"])


def test_opv2v_predictions_of_unknown_frames_name_the_file(trajectories, tmp_path: Path, capsys) -> None:
    # "avdata: error: predictions: expected frames of the ground truth, ..." named no file.
    root, _ = trajectories
    path = tmp_path / "boxes.json"
    box = {"scene": "s0", "frame_index": 99, "score": 0.5, "x_ego_m": 1.0, "y_ego_m": 0.0, "z_ego_m": 0.0,
           "length_m": 4.0, "width_m": 2.0, "height_m": 1.5, "yaw_ego_rad": 0.0}
    path.write_text(json.dumps([box]))
    status = main(["eval", "detection", str(root), str(path), "--protocol", "opv2v"])
    assert (status, capsys.readouterr().err.splitlines()) == (
        1, [f"avdata: error: {path}: expected frames of the ground truth, got scene 's0' frame 99"])
