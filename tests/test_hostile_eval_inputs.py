"""``avdata eval`` on input files replaced by a folder, a FIFO or a broken link: one line naming the file, exit 1.

Found by a sweep that damaged each input file of each protocol in turn (and the V2X-Sim converter's tables); each
case here was silently passed over, worded wrongly or a traceback before. Inputs are built at test time (the AV2
ones from the real annotations in ``../shared/realdata``, V2X-Sim from the real Lyft tables).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pyarrow as pa
import pyarrow.feather as feather
import pyarrow.parquet as pq
import pytest

from avdata.cli import main
from avdata.demo import write_demo
from tests.realdata import REALDATA

AV2_ANNOTATIONS = REALDATA / "argoverse2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede" / "annotations.feather"


def _folder(path: Path) -> None:
    path.mkdir()


def _broken_link(path: Path) -> None:
    path.symlink_to(path.parent / "nowhere")


#: damage -> what puts it where a file was
DAMAGES: dict[str, Callable[[Path], None]] = {"folder": _folder, "fifo": os.mkfifo, "broken link": _broken_link}


def _damage(path: Path, how: str) -> None:
    path.unlink()
    DAMAGES[how](path)


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    status = main(["eval", *argv])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return status, err.splitlines()


def _mot(root: Path) -> tuple[Path, Path]:
    """Two MOTChallenge sequences of one box each, and a tracker that finds it."""
    gt, tr = root / "gt", root / "tr"
    tr.mkdir(parents=True)
    for name in ("MOT17-00", "MOT17-01"):
        (gt / name / "gt").mkdir(parents=True)
        (gt / name / "seqinfo.ini").write_text("[Sequence]\nseqLength=2\n")
        (gt / name / "gt" / "gt.txt").write_text("1,1,10,10,20,40,1,1,1\n2,1,12,10,20,40,1,1,1\n")
        (tr / f"{name}.txt").write_text("1,5,10,10,20,40,1,-1,-1,-1\n2,5,12,10,20,40,1,-1,-1,-1\n")
    return gt, tr


@pytest.mark.parametrize(("how", "message"), [("folder", "expected a ground-truth file, got a folder"),
                                              ("fifo", "expected a regular file, got a FIFO"),
                                              ("broken link", "expected a ground-truth file, got a broken symbolic link")])
def test_mot_ground_truth_not_a_file_is_named(tmp_path, capsys, how, message):
    # A broken gt.txt link was passed over by glob("*/gt/gt.txt"): its sequence left out, exit 0.
    gt, tr = _mot(tmp_path)
    assert _run(["tracking", "--protocol", "mot", str(gt), str(tr)], capsys)[0] == 0
    _damage(gt / "MOT17-01" / "gt" / "gt.txt", how)
    assert _run(["tracking", "--protocol", "mot", str(gt), str(tr)], capsys) == (
        1, [f"avdata: error: {gt}/MOT17-01/gt/gt.txt: {message}"])


@pytest.mark.parametrize(("how", "message"), [("folder", "expected a seqmap, got a folder"),
                                              ("fifo", "expected a regular file, got a FIFO"),
                                              ("broken link", "expected a seqmap, got a broken symbolic link")])
def test_kitti_seqmap_not_a_file_is_named_as_such(tmp_path, capsys, how, message):
    # Was "expected the seqmap of split 'training', got no such file (splits found: training)".
    gt, tr = tmp_path / "gt", tmp_path / "tr"
    (gt / "label_02").mkdir(parents=True)
    tr.mkdir()
    (gt / "label_02" / "0000.txt").write_text("0 0 Car 0 0 0 100 100 180 180 1 1 1 0 0 0 0\n")
    (tr / "0000.txt").write_text("0 3 Car 0 0 0 100 100 180 180 1 1 1 0 0 0 0 0.9\n")
    seqmap = gt / "evaluate_tracking.seqmap.training"
    seqmap.write_text("0000 empty 000000 000001\n")
    assert _run(["tracking", "--protocol", "kitti", str(gt), str(tr)], capsys)[0] == 0
    _damage(seqmap, how)
    assert _run(["tracking", "--protocol", "kitti", str(gt), str(tr)], capsys) == (
        1, [f"avdata: error: {seqmap}: {message}"])


@pytest.mark.parametrize("task", ["detection", "tracking", "prediction"])
def test_unified_prediction_table_that_is_a_folder_says_so(tmp_path, capsys, task):
    # Was "expected a Parquet or JSON table, got no such file" for a folder that is there.
    from tests.eval.eval_unified_synth import make_tables, write_dataset

    write_dataset(tmp_path / "ds", *make_tables())
    (tmp_path / "pred.parquet").mkdir()
    assert _run([task, "--protocol", "avdata", str(tmp_path / "ds"), str(tmp_path / "pred.parquet")], capsys) == (
        1, [f"avdata: error: {tmp_path}/pred.parquet: expected a Parquet or JSON table, got a folder"])


@pytest.mark.parametrize(("how", "message"), [
    ("folder", "unreadable feather file (Expected file path, but {path} is a directory)"),
    ("fifo", "expected a regular file, got a FIFO"),
    ("broken link", "expected a feather file, got none")])
def test_av2_annotations_not_a_file_are_named_not_the_log_passed_over(tmp_path, capsys, how, message):
    # A log whose annotations.feather was a folder, FIFO or broken link was left out of the ground truth: exit 0,
    # scored on the other logs alone.
    annotations = feather.read_table(AV2_ANNOTATIONS).slice(0, 40)
    for log in ("log-a", "log-b"):
        (tmp_path / "split" / log).mkdir(parents=True)
        feather.write_feather(annotations, tmp_path / "split" / log / "annotations.feather")
    detections = annotations.drop(["num_interior_pts"]).append_column("score", pa.array([0.5] * 40))
    feather.write_feather(detections.append_column("log_id", pa.array(["log-a"] * 40)), tmp_path / "dts.feather")
    argv = ["detection", "--protocol", "av2", "--no-roi", str(tmp_path / "split"), str(tmp_path / "dts.feather")]
    assert _run(argv, capsys)[0] == 0
    path = tmp_path / "split" / "log-b" / "annotations.feather"
    _damage(path, how)
    assert _run(argv, capsys) == (1, [f"avdata: error: {path}: {message.format(path=path)}"])


def _kitti_detection(root: Path) -> tuple[Path, Path]:
    """One labelled car and a result folder that finds it."""
    (root / "label_2").mkdir(parents=True)
    (root / "results").mkdir()
    (root / "label_2" / "000000.txt").write_text("Car 0.00 0 0 100 100 200 200 1.5 1.6 4.0 0 1.5 10 0\n")
    (root / "results" / "000000.txt").write_text("Car 0.00 0 0 101 100 201 200 1.5 1.6 4.0 0.05 1.5 10 0 0.9\n")
    return root, root / "results"


@pytest.mark.parametrize(("protocol", "make", "kind"), [
    ("kitti", Path.touch, "file"), ("kitti", os.mkfifo, "FIFO"), ("mot", Path.touch, "file"), ("mot", os.mkfifo, "FIFO")])
def test_result_folder_that_is_not_a_folder_says_what_it_is(tmp_path, capsys, protocol, make, kind):
    # Was "got no such folder" for a file or FIFO that is there.
    if protocol == "kitti":
        gt, _ = _kitti_detection(tmp_path)
        argv, what = ["detection", "--protocol", "kitti", str(gt)], "folder of KITTI .txt files"
    else:
        gt, _ = _mot(tmp_path)
        argv, what = ["tracking", "--protocol", "mot", str(gt)], "folder of tracker result files <seq>.txt"
    make(tmp_path / "odd")
    assert _run([*argv, str(tmp_path / "odd")], capsys) == (1, [f"avdata: error: {tmp_path}/odd: expected a {what}, "
                                                                 f"got a {kind}"])


def test_kitti_result_folder_without_any_result_file_is_said(tmp_path, capsys):
    # Each missing result file is an image without detections; a folder with none at all was scored 0 without a word.
    gt, results = _kitti_detection(tmp_path)
    (results / "000000.txt").unlink()
    argv = ["detection", "--protocol", "kitti", str(gt), str(results), "--classes", "Car"]
    status, lines = _run(argv, capsys)
    assert status == 0 and lines == [f"avdata: warning: {results}: expected result files <image>.txt, got none for the "
                                     f"1 image(s); all are scored as without detections"]
    (results / "000000.txt").write_text("")  # a tracker that found nothing: valid, and no word
    assert _run(argv, capsys) == (0, [])


@pytest.mark.parametrize("table", ["ego_pose", "sample_data", "sample_annotation"])
def test_v2x_sim_table_that_is_a_broken_link_is_named(tmp_path, capsys, table):
    # The converter sized its arrays from the file's stat() before reading it: a broken link was a traceback.
    from tests.converters.test_nuscenes_v2x_sim import VERSION, v2x_sim_tables

    v2x_sim_tables(tmp_path / "src")
    path = tmp_path / "src" / VERSION / f"{table}.json"
    _damage(path, "broken link")
    status = main(["convert", "nuscenes", "--variant", "v2x-sim", str(tmp_path / "src"), str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert (status, err.splitlines()) == (1, [f"avdata: error: {path}: unreadable (No such file or directory)"])


@pytest.mark.parametrize("option", ["--json", "--markdown"])
def test_a_result_file_that_cannot_be_written_is_named_without_a_traceback(tmp_path, capsys, option):
    # --json naming a folder was an IsADirectoryError traceback after the scores were printed.
    gt, tr = _mot(tmp_path)
    (tmp_path / "taken").mkdir()
    (tmp_path / "a_file").write_text("x")
    for target, why in ((tmp_path / "taken", "Is a directory"),
                        (tmp_path / "a_file" / "result", "a file is where its folder should be")):
        status, err = _run(["tracking", "--protocol", "mot", str(gt), str(tr), option, str(target)], capsys)
        assert (status, err) == (1, [f"avdata: error: {target}: cannot write this file ({why})"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "gt", "taken", "tr"]  # no temporary file left
    assert not list((tmp_path / "taken").iterdir())


@pytest.fixture(scope="module")
def demo_tracks(tmp_path_factory) -> tuple[Path, pa.Table]:
    """The demo dataset and its objects as tracks (the columns ``avdata eval safety --tracks`` takes)."""
    root = write_demo(tmp_path_factory.mktemp("safety") / "ds")
    objects = pq.read_table(root / "index" / "objects.parquet")
    return root, objects.select(["scene", "frame_index", "object_id", "x_world_m", "y_world_m", "length_m", "width_m",
                                 "yaw_world_rad", "vx_world_mps", "vy_world_mps"])


@pytest.mark.parametrize(("damage", "message"), [
    ("negative length", "row 0: length_m: expected a size >= 0, got -1.0"),
    ("a row twice", "scene 'demo-0000' frame 0: expected each track id once per frame, got object_id '1' 2 times"),
    ("unknown scene", "scene: expected scenes of the dataset (1), got unknown 'elsewhere'"),
    ("unknown frame", "row 0: frame_index: expected a frame of scene 'demo-0000' (0..4), got 99"),
])
def test_safety_tracks_that_are_no_tracks_are_refused(tmp_path, capsys, demo_tracks, damage, message):
    # Each was scored (exit 0): a negative length, a track given twice in a frame, rows of a scene the dataset does
    # not have (dropped without a word); a frame it does not have was refused without naming the file.
    root, tracks = demo_tracks
    assert _run(["safety", str(root), "--tracks", str(_write(tmp_path, tracks))], capsys)[0] == 0
    if damage == "negative length":
        tracks = tracks.set_column(5, "length_m", pa.array([-1.0] + tracks["length_m"].to_pylist()[1:]))
    elif damage == "a row twice":
        tracks = pa.concat_tables([tracks, tracks.slice(0, 1)])
    else:
        column, value = ("scene", "elsewhere") if damage == "unknown scene" else ("frame_index", 99)
        index = tracks.column_names.index(column)
        tracks = tracks.set_column(index, column, pa.array([value] + tracks[column].to_pylist()[1:], tracks[column].type))
    path = _write(tmp_path, tracks)
    assert _run(["safety", str(root), "--tracks", str(path)], capsys) == (1, [f"avdata: error: {path}: {message}"])


def _write(folder: Path, table: pa.Table) -> Path:
    path = folder / "tracks.parquet"
    pq.write_table(table, path)
    return path


@pytest.mark.parametrize(("line", "message"), [
    # id 5.2 was cast to track 5 (two tracks made one), frame 1.5 to frame 1, without a word
    ("1,5.2,10,10,20,40,1,-1,-1,-1", "1: id: expected an integer, got 5.2"),
    ("1.5,5,10,10,20,40,1,-1,-1,-1", "1: frame: expected an integer, got 1.5"),
    # a negative width is a negative area (an IoU of any value); 1e308 px overflowed the IoU
    ("1,5,10,10,-20,40,1,-1,-1,-1", "1: bb_width: expected a size >= 0, got -20"),
    ("1,5,1e308,10,20,40,1,-1,-1,-1", "1: bb_left: expected a value within 1e+06, got 1e+308"),
])
def test_mot_tracker_line_with_a_value_it_cannot_have_is_refused(tmp_path, capsys, line, message):
    gt, tr = _mot(tmp_path)
    assert _run(["tracking", "--protocol", "mot", str(gt), str(tr)], capsys)[0] == 0
    path = tr / "MOT17-00.txt"
    path.write_text(line + "\n" + path.read_text().splitlines()[1] + "\n")
    assert _run(["tracking", "--protocol", "mot", str(gt), str(tr)], capsys) == (1, [f"avdata: error: {path}:{message}"])
