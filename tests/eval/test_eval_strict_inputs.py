"""Eval inputs are as strict as TrackEval and the nuScenes devkit: each bad input gives one InputError line
naming the file, the sequence / sample / row and the value; accepted-but-odd inputs give an EvalWarning.

Bad inputs are built from the real files in ``../shared/realdata`` where they exist (KITTI tracking label_02
of sequence 0001, the KITTI object labels, the Lyft tables in the nuScenes schema) and from the synthetic
nuScenes and unified fixtures otherwise.
"""

import argparse
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from eval_nuscenes_synth import SCENES, write_nuscenes
from eval_unified_synth import perfect_dataset

from avdata.cli import main as avdata_main
from avdata.errors import InputError
from avdata.eval.cli import DETECTION_PROTOCOLS, PREDICTION_PROTOCOLS, TRACKING_PROTOCOLS, add_eval_subparser
from avdata.eval.detection.av2 import read_detections as read_av2_detections
from avdata.eval.detection.kitti import evaluate_kitti_detection, load_kitti_objects
from avdata.eval.detection.nuscenes import evaluate_nuscenes_detection, load_nuscenes_gt, load_nuscenes_submission
from avdata.eval.prediction import PredictionConfig, evaluate_prediction
from avdata.eval.problems import EvalWarning
from avdata.eval.tracking import COMBINED, TrackingMetric, evaluate_tracking, summary
from avdata.eval.tracking.kitti import kitti_tracking_sequences
from avdata.eval.tracking.nuscenes import load_nuscenes_tracking
from tests.realdata import REALDATA

REAL_LABEL = REALDATA / "kitti" / "tracking" / "training" / "label_02" / "0001.txt"
REAL_OBJECT_LABELS = REALDATA / "kitti" / "object" / "training" / "label_2"
LYFT_TABLES = REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train" / "v1.01-train"


def _run(argv):
    parser = argparse.ArgumentParser(prog="avdata")
    add_eval_subparser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.run(args)


# --- KITTI tracking (TrackEval's Kitti2DBox) on the real sequence 0001 ---------------------------------------


@pytest.fixture()
def kitti_tracking(tmp_path):
    """The real label file as ground truth with its seqmap, and a tracker that reports the labels (perfect)."""
    rows = [line for line in REAL_LABEL.read_text().splitlines() if line.strip()]
    n_frames = max(int(r.split()[0]) for r in rows) + 1
    gt, tr = tmp_path / "gt", tmp_path / "CIWT" / "data"
    (gt / "label_02").mkdir(parents=True)
    tr.mkdir(parents=True)
    shutil.copy(REAL_LABEL, gt / "label_02" / "0001.txt")
    (gt / "evaluate_tracking.seqmap.training").write_text(f"0001 empty 000000 {n_frames:06d}\n")
    tracker = [" ".join(r.split()[:17] + ["0.9"]) for r in rows if r.split()[2] != "DontCare"]
    (tr / "0001.txt").write_text("\n".join(tracker) + "\n")
    return gt, tr, tracker


def test_real_kitti_perfect_tracker_and_ignored_extra_file(kitti_tracking):
    gt, tr, _ = kitti_tracking
    (tr / "0099.txt").write_text("")
    with pytest.warns(EvalWarning, match=r"ignored 1 tracker file\(s\) of sequences not in the seqmap: 0099.txt"):
        seqs = kitti_tracking_sequences(gt, tr)
    car = summary(evaluate_tracking(seqs["car"], [TrackingMetric.HOTA, TrackingMetric.CLEAR])[COMBINED])
    assert car["HOTA"] == pytest.approx(1.0) and car["MOTA"] == pytest.approx(1.0) and car["CLR_TP"] > 1000


def test_real_kitti_nan_coordinate_is_refused(kitti_tracking):
    # TrackEval would compute a NaN IoU; one NaN used to turn car HOTA 1.0 into 0.0.
    gt, tr, tracker = kitti_tracking
    fields = tracker[10].split()
    fields[7] = "nan"
    (tr / "0001.txt").write_text("\n".join(tracker[:10] + [" ".join(fields)] + tracker[11:]) + "\n")
    with pytest.raises(InputError, match=r"CIWT/data/0001.txt:11: bbox top: expected a finite number, got nan"):
        kitti_tracking_sequences(gt, tr)


def test_real_kitti_non_numeric_value_is_refused(kitti_tracking):
    gt, tr, tracker = kitti_tracking
    fields = tracker[3].split()
    fields[1] = "seven"
    (tr / "0001.txt").write_text("\n".join(tracker[:3] + [" ".join(fields)] + tracker[4:]) + "\n")
    with pytest.raises(InputError, match=r"0001.txt:4: track id: expected a number, got 'seven'"):
        kitti_tracking_sequences(gt, tr)


@pytest.mark.parametrize("token", ["1_000", "\u0663", "1e309x"])
def test_real_kitti_number_a_c_reader_would_not_take_is_refused(kitti_tracking, token):
    # Python's float() took '1_000' as 1000 and Arabic-Indic digits as numbers; the devkit's sscanf stops there.
    gt, tr, tracker = kitti_tracking
    fields = tracker[3].split()
    fields[1] = token
    (tr / "0001.txt").write_text("\n".join(tracker[:3] + [" ".join(fields)] + tracker[4:]) + "\n")
    with pytest.raises(InputError, match=rf"0001.txt:4: track id: expected a number, got '{token}'"):
        kitti_tracking_sequences(gt, tr)


@pytest.mark.parametrize(("make", "message"), [
    (Path.mkdir, "expected a tracker file, got a folder"), (os.mkfifo, "expected a regular file, got a FIFO")])
def test_real_kitti_tracker_file_that_is_not_a_file_says_what_it_is(kitti_tracking, make, message):
    # Both were "got no such file"; reading a FIFO would have waited forever.
    gt, tr, _ = kitti_tracking
    (tr / "0001.txt").unlink()
    make(tr / "0001.txt")
    with pytest.raises(InputError, match=rf"data/0001.txt: {message}$"):
        kitti_tracking_sequences(gt, tr)


def test_real_kitti_missing_tracker_file_names_sequence_and_hints_data_folder(kitti_tracking):
    gt, tr, _ = kitti_tracking
    # TrackEval: "Tracker file not found". Pointing at CIWT/ instead of CIWT/data/ used to score 0.
    with pytest.raises(InputError, match=r"CIWT/0001.txt: expected the tracker file of sequence 0001, got no such "
                                         r"file \(the results are in .*CIWT/data; pass that folder\)"):
        kitti_tracking_sequences(gt, tr.parent)
    (tr / "0001.txt").unlink()
    with pytest.raises(InputError, match=r"data/0001.txt: expected the tracker file of sequence 0001"):
        kitti_tracking_sequences(gt, tr)


def test_real_kitti_missing_seqmap_is_refused(kitti_tracking):
    # TrackEval: "no seqmap found"; evaluating every label file instead gave car HOTA 0.59 for a perfect tracker.
    gt, tr, _ = kitti_tracking
    with pytest.raises(InputError, match=r"evaluate_tracking.seqmap.val: expected the seqmap of split 'val', got no "
                                         r"such file \(splits found: training\)"):
        kitti_tracking_sequences(gt, tr, split="val")


def test_real_kitti_duplicate_track_id_names_file_and_frame(kitti_tracking):
    gt, tr, tracker = kitti_tracking
    frame, tid = tracker[0].split()[:2]
    (tr / "0001.txt").write_text("\n".join(tracker + [tracker[0]]) + "\n")
    with pytest.raises(InputError, match=rf"CIWT/data/0001.txt: frame {frame}: expected each track id once per "
                                         rf"frame, got id {tid} 2 times"):
        kitti_tracking_sequences(gt, tr)


def test_real_kitti_frame_outside_sequence_is_refused(kitti_tracking):
    gt, tr, tracker = kitti_tracking
    (gt / "evaluate_tracking.seqmap.training").write_text("0001 empty 000000 000100\n")
    with pytest.raises(InputError, match=r"label_02/0001.txt:\d+: frame: expected frames in \[0, 100\), got 100"):
        kitti_tracking_sequences(gt, tr)


@pytest.mark.parametrize(("which", "field", "value", "message"), [
    ("tr", 0, "0.5", r"CIWT/data/0001.txt:4: frame: expected an integer, got 0.5"),
    ("tr", 1, "3.7", r"CIWT/data/0001.txt:4: track id: expected an integer, got 3.7"),
    ("tr", 1, "1e300", r"CIWT/data/0001.txt:4: track id: expected an integer, got 1e\+300"),
    ("gt", 3, "0.5", r"label_02/0001.txt:4: truncated: expected an integer, got 0.5"),
    # A 1e308 px box overflowed the IoU (RuntimeWarnings, inf areas) and was scored.
    ("tr", 8, "1e308", r"CIWT/data/0001.txt:4: bbox right: expected a value within 1e\+06, got 1e\+308"),
    ("gt", 9, "-1e308", r"label_02/0001.txt:4: bbox bottom: expected a value within 1e\+06, got -1e\+308")])
def test_real_kitti_field_beyond_what_it_can_be_is_refused(kitti_tracking, which, field, value, message):
    # Each was truncated (or wrapped) into another integer without a word: frame 0.5 scored as frame 0, track id
    # 3.7 as track 3, a ground-truth truncation level 0.5 as 0 (TrackEval's int() refuses the latter two).
    gt, tr, tracker = kitti_tracking
    path = tr / "0001.txt" if which == "tr" else gt / "label_02" / "0001.txt"
    lines = path.read_text().splitlines()
    fields = lines[3].split()
    fields[field] = value
    lines[3] = " ".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=message):
        kitti_tracking_sequences(gt, tr)


def test_kitti_bad_type_is_input_error(kitti_tracking):
    gt, tr, tracker = kitti_tracking
    (tr / "0001.txt").write_text(tracker[0].replace(" Car ", " Spaceship ", 1) + "\n")
    with pytest.raises(InputError, match=r"0001.txt:1: type: expected one of"):
        kitti_tracking_sequences(gt, tr)


def test_cli_prints_one_error_line_and_exits_1(kitti_tracking, capsys):
    gt, tr, _ = kitti_tracking
    status = avdata_main(["eval", "tracking", "--protocol", "kitti", str(gt), str(tr.parent)])
    err = capsys.readouterr().err
    assert status == 1 and err.count("\n") == 1 and err.startswith("avdata: error: ") and "Traceback" not in err


# --- KITTI object detection on the real labels ---------------------------------------------------------------


def test_kitti_detection_folder_without_labels_is_refused(tmp_path):
    # The root that `export` writes has no label_2: it used to print all-zero AP with exit 0.
    (tmp_path / "results").mkdir()
    with pytest.raises(InputError, match=r"expected KITTI label files \(label_2/\*.txt or \*.txt\), got none"):
        _run(["eval", "detection", "--protocol", "kitti", str(tmp_path), str(tmp_path / "results")])


def test_real_kitti_detection_class_without_ground_truth(tmp_path):
    # The real labels without their pedestrians: Pedestrian has no ground truth (a warning); asking only for
    # classes that have none at all is an error.
    labels = tmp_path / "label_2"
    labels.mkdir()
    for path in REAL_OBJECT_LABELS.glob("*.txt"):
        (labels / path.name).write_text("".join(line + "\n" for line in path.read_text().splitlines()
                                                if not line.startswith("Pedestrian")))
    gt = load_kitti_objects(labels)
    dt = load_kitti_objects(tmp_path / "label_2", image_ids=sorted(set(gt.image.tolist())))
    with pytest.warns(EvalWarning, match=r"no object of class\(es\) Pedestrian; their AP is 0"):
        res = evaluate_kitti_detection(gt, dt, classes=("Car", "Pedestrian"))
    assert all(v == 0.0 for per_diff in res.ap40["Pedestrian"].values() for v in per_diff.values())
    with pytest.raises(InputError, match=r"ground truth: expected objects of Pedestrian, got none \(classes in the "
                                         r"labels: .*Car"):
        evaluate_kitti_detection(gt, dt, classes=("Pedestrian",))


def test_real_kitti_label_with_nan_is_refused(tmp_path):
    labels = tmp_path / "label_2"
    shutil.copytree(REAL_OBJECT_LABELS, labels)
    first = sorted(labels.glob("*.txt"))[0]
    lines = first.read_text().splitlines()
    fields = lines[0].split()
    fields[11] = "nan"  # location x
    first.write_text("\n".join([" ".join(fields)] + lines[1:]) + "\n")
    with pytest.raises(InputError, match=rf"{first.name}: line 1: x: expected a finite number, got 'nan'"):
        load_kitti_objects(labels)


# --- nuScenes ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def nuscenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("nus")
    return root, write_nuscenes(root, 5)


def test_nuscenes_submission_must_cover_the_evaluated_samples(nuscenes, tmp_path):
    root, submission = nuscenes
    gt, ego, samples = load_nuscenes_gt(root / "v1.0-mini")
    data = json.loads(submission.read_text())
    dropped = sorted(data["results"])[0]
    del data["results"][dropped]
    bad = tmp_path / "missing.json"
    bad.write_text(json.dumps(data))
    # The devkit: "Samples in split doesn't match samples in predictions" (avdata scored mAP 0.434).
    with pytest.raises(InputError, match=rf"missing.json: results: expected every sample of the evaluated scenes "
                                         rf"\({len(samples)}\), missing 1, e.g. '{dropped}'"):
        load_nuscenes_submission(bad, ego, samples)
    # With --scenes, the samples of the other scenes are extras.
    _, ego1, samples1 = load_nuscenes_gt(root / "v1.0-mini", {SCENES[0]})
    with pytest.raises(InputError, match=r"results: expected only samples of the evaluated scenes, got \d+ other"):
        load_nuscenes_submission(submission, ego1, samples1)


def test_nuscenes_nan_translation_and_bad_score_are_refused(nuscenes, tmp_path):
    root, submission = nuscenes
    _, ego, samples = load_nuscenes_gt(root / "v1.0-mini")
    data = json.loads(submission.read_text())
    token = next(t for t, boxes in data["results"].items() if boxes)
    data["results"][token][0]["translation"][1] = float("nan")
    (tmp_path / "nan.json").write_text(json.dumps(data))
    with pytest.raises(InputError, match=rf"nan.json: results\['{token}'\]\[0\] translation: expected 3 finite "
                                         rf"numbers, got \[.*nan.*\]"):
        load_nuscenes_submission(tmp_path / "nan.json", ego, samples)
    data = json.loads(submission.read_text())
    data["results"][token][0]["detection_score"] = "high"
    (tmp_path / "score.json").write_text(json.dumps(data))
    with pytest.raises(InputError, match=r"\[0\] detection_score: expected a finite number, got 'high'"):
        load_nuscenes_submission(tmp_path / "score.json", ego, samples)
    tracking = json.loads((root / "tracking.json").read_text())
    token = next(t for t, boxes in tracking["results"].items() if boxes)
    tracking["results"][token][0]["translation"][0] = float("nan")
    (tmp_path / "track.json").write_text(json.dumps(tracking))
    with pytest.raises(InputError, match=r"track.json: results\[.*\]\[0\] translation: expected 3 finite numbers"):
        load_nuscenes_tracking(root / "v1.0-mini", tmp_path / "track.json")


def test_nuscenes_submission_with_a_key_given_twice_is_refused(nuscenes, tmp_path):
    # json.load keeps the last value of a repeated key without a word: which score was meant is unknown.
    root, submission = nuscenes
    _, ego, samples = load_nuscenes_gt(root / "v1.0-mini")
    text = submission.read_text()
    first = text.index('"detection_score": ')
    (tmp_path / "twice.json").write_text(text[:first] + '"detection_score": 0.125, ' + text[first:])
    with pytest.raises(InputError, match=r"twice.json: expected JSON \(submission\) with each key once per object, "
                                         r"got key 'detection_score' given twice in one object, with values 0.125 and"):
        load_nuscenes_submission(tmp_path / "twice.json", ego, samples)


def test_nuscenes_submission_that_is_a_fifo_is_refused_not_waited_on(nuscenes, tmp_path):
    root, _ = nuscenes
    _, ego, samples = load_nuscenes_gt(root / "v1.0-mini")
    os.mkfifo(tmp_path / "fifo.json")
    with pytest.raises(InputError, match=r"fifo.json: expected a regular file, got a FIFO$"):
        load_nuscenes_submission(tmp_path / "fifo.json", ego, samples)


def test_nuscenes_unknown_scene_is_named(nuscenes):
    root, submission = nuscenes
    # A mistyped --scenes name used to be blamed on the submission.
    with pytest.raises(InputError, match=r"scene.json: --scenes: expected scene names of the tables, got unknown "
                                         r"scene-9999"):
        _run(["eval", "detection", "--protocol", "nuscenes", str(root / "v1.0-mini"), str(submission),
              "--scenes", SCENES[0], "scene-9999"])


def test_nuscenes_classes_that_do_not_map_are_refused(tmp_path):
    # The real Lyft tables name their categories 'car', 'pedestrian', ... (not nuScenes' 'vehicle.car').
    with pytest.raises(InputError, match=r"category.json: expected nuScenes category names that map to the "
                                         r"detection classes, got none that do \(car\)"):
        load_nuscenes_gt(LYFT_TABLES)


def test_real_lyft_dangling_prev_next_links_warn_instead_of_key_error(tmp_path):
    # With categories renamed to nuScenes names, the real Lyft annotations still link to annotations outside
    # the tables (prev / next); the devkit's box_velocity would raise KeyError, the converter tolerates them.
    tables = tmp_path / "lyft"
    shutil.copytree(LYFT_TABLES, tables)
    categories = json.loads((tables / "category.json").read_text())
    rename = {"car": "vehicle.car", "pedestrian": "human.pedestrian.adult", "bus": "vehicle.bus.rigid",
              "truck": "vehicle.truck", "bicycle": "vehicle.bicycle", "motorcycle": "vehicle.motorcycle"}
    for c in categories:
        c["name"] = rename.get(c["name"], c["name"])
    (tables / "category.json").write_text(json.dumps(categories))
    n_links = sum((a["prev"] != "") + (a["next"] != "") for a in json.loads((tables / "sample_annotation.json").read_text()))
    with pytest.warns(EvalWarning, match=rf"{n_links} prev/next link\(s\) point to annotations not in the table"):
        gt, ego, samples = load_nuscenes_gt(tables)
    assert len(gt) == 4 and np.isnan(gt.velocity_mps).all() and len(samples) == 1


def test_nuscenes_class_without_ground_truth_warns_and_none_is_an_error(nuscenes):
    root, submission = nuscenes
    gt, ego, samples = load_nuscenes_gt(root / "v1.0-mini")
    pred = load_nuscenes_submission(submission, ego, samples)
    only_cars = gt.take(gt.name == "car")
    with pytest.warns(EvalWarning, match=r"no object of class\(es\) truck, bus, .* their AP is 0"):
        res = evaluate_nuscenes_detection(only_cars, pred)
    assert res.label_aps["truck"][2.0] == 0.0 and res.label_aps["car"][2.0] > 0
    with pytest.raises(InputError, match=r"ground truth: expected boxes of the nuScenes detection classes"):
        evaluate_nuscenes_detection(gt.take(gt.name == "nothing"), pred)


# --- the avdata protocol and prediction ---------------------------------------------------------------------


@pytest.fixture()
def unified(tmp_path):
    return perfect_dataset(tmp_path / "ds")


def test_avdata_non_numeric_value_names_row_and_column(unified, tmp_path):
    root, rows = unified
    rows[5]["x_world_m"] = "abc"
    (tmp_path / "dets.json").write_text(json.dumps(rows))
    with pytest.raises(InputError, match=r"dets.json: row 5: x_world_m: expected a number, got 'abc'"):
        _run(["eval", "detection", "--protocol", "avdata", str(root), str(tmp_path / "dets.json")])
    rows[5]["x_world_m"] = float("nan")
    pq.write_table(pa.Table.from_pylist(rows), tmp_path / "dets.parquet")
    with pytest.raises(InputError, match=r"dets.parquet: row 5: x_world_m: expected a finite number, got nan"):
        _run(["eval", "detection", "--protocol", "avdata", str(root), str(tmp_path / "dets.parquet")])


def test_avdata_key_given_twice_is_refused(unified, tmp_path):
    root, rows = unified
    text = json.dumps(rows)
    first = text.index('"score": ')
    (tmp_path / "twice.json").write_text(text[:first] + '"score": 0.25, ' + text[first:])
    with pytest.raises(InputError, match=r"twice.json: expected JSON with each key once per object, got key 'score' "
                                         r"given twice in one object, with values 0.25 and 0.8"):
        _run(["eval", "detection", "--protocol", "avdata", str(root), str(tmp_path / "twice.json")])


@pytest.mark.parametrize("name", ["fifo.json", "fifo.parquet"])
def test_avdata_detections_that_are_a_fifo_are_refused(unified, tmp_path, name):
    root, _ = unified
    os.mkfifo(tmp_path / name)  # was called missing ("got no such file")
    with pytest.raises(InputError, match=rf"{name}: expected a regular file, got a FIFO$"):
        _run(["eval", "detection", "--protocol", "avdata", str(root), str(tmp_path / name)])
    if name.endswith(".parquet"):  # Argoverse 2 detections: pyarrow called it missing too
        with pytest.raises(InputError, match=rf"{name}: expected a regular file, got a FIFO$"):
            read_av2_detections(tmp_path / name)


def test_avdata_unknown_scene_and_impossible_frame(unified, tmp_path):
    root, rows = unified
    (tmp_path / "a.json").write_text(json.dumps(rows + [rows[0] | {"scene": "s9"}]))
    with pytest.raises(InputError, match=r"a.json: scene: expected scenes of the dataset \(1\), got unknown 's9'"):
        _run(["eval", "detection", "--protocol", "avdata", str(root), str(tmp_path / "a.json")])
    (tmp_path / "b.json").write_text(json.dumps(rows + [rows[0] | {"frame_index": 500}]))
    with pytest.raises(InputError, match=rf"b.json: row {len(rows)}: frame_index: expected a frame of scene 's0' "
                                         r"\(0..19\), got 500"):
        _run(["eval", "tracking", "--protocol", "avdata", str(root), str(tmp_path / "b.json")])


def test_avdata_duplicate_track_id_names_file_scene_and_frame(unified, tmp_path):
    root, rows = unified
    (tmp_path / "t.json").write_text(json.dumps(rows + [rows[7]]))
    with pytest.raises(InputError, match=rf"t.json: scene 's0' frame {rows[7]['frame_index']}: expected each track id "
                                         rf"once per frame, got object_id '{rows[7]['object_id']}' 2 times"):
        _run(["eval", "tracking", "--protocol", "avdata", str(root), str(tmp_path / "t.json")])


def test_plots_refused_where_nothing_would_be_drawn(unified, tmp_path):
    root, rows = unified
    (tmp_path / "d.json").write_text(json.dumps(rows))
    with pytest.raises(InputError, match=r"--plots: expected a protocol with curves to plot \(kitti, nuscenes for "
                                         r"detection\), got --protocol avdata"):
        _run(["eval", "detection", "--protocol", "avdata", str(root), str(tmp_path / "d.json"),
              "--plots", str(tmp_path / "p")])
    with pytest.raises(InputError, match=r"--plots: .*\(none for prediction\)"):
        _run(["eval", "prediction", str(root), str(tmp_path / "d.json"), "--plots", str(tmp_path / "p")])
    assert not (tmp_path / "p").exists()


def test_ks_above_the_number_of_modes_is_refused():
    gt = np.zeros((2, 3, 2))
    pred = np.zeros((2, 3, 3, 2))
    with pytest.raises(InputError, match=r"prediction ks: expected numbers of modes in \[1, 3\] \(the predictions "
                                         r"have 3 modes\), got 5"):
        evaluate_prediction(gt, pred, config=PredictionConfig(ks=(1, 5)))
    # The default takes those of 1, 5, 10 that exist.
    assert "minFDE_1" in evaluate_prediction(gt, pred) and "minFDE_5" not in evaluate_prediction(gt, pred)


def test_help_says_what_gt_and_pred_are_for_each_protocol(capsys):
    for task, protocols in (("detection", DETECTION_PROTOCOLS), ("tracking", TRACKING_PROTOCOLS),
                            ("prediction", PREDICTION_PROTOCOLS)):
        with pytest.raises(SystemExit):
            _run(["eval", task, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        for name, protocol in protocols.items():
            assert f"{name}: GT {' '.join(protocol.gt.split())} PRED {' '.join(protocol.pred.split())}" in text


def test_tracking_class_without_ground_truth_warns_and_none_is_an_error(kitti_tracking, capsys):
    gt, tr, tracker = kitti_tracking
    label = gt / "label_02" / "0001.txt"
    label.write_text("".join(line + "\n" for line in label.read_text().splitlines() if " Pedestrian " not in line))
    (tr / "0001.txt").write_text("\n".join(t for t in tracker if " Pedestrian " not in t) + "\n")
    assert avdata_main(["eval", "tracking", "--protocol", "kitti", str(gt), str(tr), "--json",
                        str(gt.parent / "out.json")]) == 0
    err = capsys.readouterr().err
    assert "avdata: warning: " in err and "no object of class(es) pedestrian" in err
    assert json.loads((gt.parent / "out.json").read_text())["car"]["HOTA"] == pytest.approx(1.0)
    with pytest.raises(InputError, match=r"expected ground truth of the evaluated classes \(pedestrian\), got none"):
        _run(["eval", "tracking", "--protocol", "kitti", str(gt), str(tr), "--classes", "pedestrian"])


@pytest.mark.parametrize(("ini", "message"), [
    ("[Sequence]\nseqLength=1_000\n", r"expected \[Sequence\] seqLength = <frames>, got seqLength = '1_000'"),
    ("[Sequence]\nseqLength=\u0663\n", r"expected \[Sequence\] seqLength = <frames>, got seqLength = '\u0663'"),
    (None, "seqinfo.ini missing"),
    (os.mkfifo, "expected a regular file, got a FIFO"),
])
def test_mot_sequence_length_is_read_strictly(tmp_path, ini, message):
    # int() took '1_000' and Arabic-Indic digits; configparser read a FIFO (waiting forever).
    from avdata.eval.tracking.mot import mot_sequences

    seq = tmp_path / "gt" / "MOT17-02"
    (seq / "gt").mkdir(parents=True)
    (seq / "gt" / "gt.txt").write_text("1,1,10,10,20,40,1,1,1\n")
    (tmp_path / "tr").mkdir()
    (tmp_path / "tr" / "MOT17-02.txt").write_text("1,1,10,10,20,40,1,-1,-1,-1\n")
    if isinstance(ini, str):
        (seq / "seqinfo.ini").write_text(ini)
    elif ini is not None:
        ini(seq / "seqinfo.ini")
    with pytest.raises(InputError, match=message):
        mot_sequences(tmp_path / "gt", tmp_path / "tr")
