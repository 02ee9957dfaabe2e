"""Hostile inputs that found defects, built at test time from ``../shared/realdata`` (Issue 16.2, 16.3, 16.7, 16.8).

Each case runs the ``avdata`` command line in-process and checks the outcome the issue states: exit status
1 with one line naming the file and the field / line and the value, no traceback, and exactly the bad
record lost (the rest compared with the clean conversion), or an exact score where the bad input used to
give a wrong one silently.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml

from avdata.cli import main
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.converters.opv2v_fixtures import build_opv2v, build_v2v4real
from tests.converters.test_dair_v2x import SCENE as DAIR_SCENE
from tests.converters.test_dair_v2x import build_dair
from tests.eval.eval_unified_synth import replace_index_table
from tests.realdata import REALDATA

OPV2V_SCENE = "validate.2021_08_21_17_30_41"
KITTI_OBJECT = REALDATA / "kitti" / "object" / "training"
KITTI_TRACKING_LABEL = REALDATA / "kitti" / "tracking" / "training" / "label_02" / "0001.txt"


def run(argv: list, capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str], str]:
    """(exit status, stderr lines, stdout) of ``avdata argv``; a traceback fails the test by raising."""
    status = main([str(a) for a in argv])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    assert_written_is_valid(argv)
    return status, captured.err.splitlines(), captured.out


def assert_written_is_valid(argv: list) -> None:
    """Whatever a conversion wrote passes ``avdata validate`` (issue 34: nothing written that validate refuses)."""
    if argv[:1] == ["convert"] and len(argv) > 3 and (Path(argv[3]) / "avdata.json").is_file():
        assert validate_dataset(argv[3]) == []


def replace(path: Path, data: bytes | None = None) -> Path:
    """Turns a (symlinked) source file into a real one holding ``data`` (None: leaves the path free)."""
    path.unlink()
    if data is not None:
        path.write_bytes(data)
    return path


def n_objects(dst: Path) -> dict[str, int]:
    objects = DatasetReader(dst).objects()
    scenes, counts = np.unique(objects.column("scene").to_numpy(zero_copy_only=False).astype(str), return_counts=True)
    return dict(zip(scenes.tolist(), counts.tolist(), strict=True))


# --- DAIR-V2X-C ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def dair_clean(tmp_path_factory) -> tuple[Path, dict[str, int]]:
    root = tmp_path_factory.mktemp("dair")
    build_dair(root / "src", skew=0.0)
    assert main(["convert", "dair-v2x", str(root / "src"), str(root / "clean"), "--quiet"]) == 0
    return root / "src", n_objects(root / "clean")


@pytest.fixture()
def dair(dair_clean, tmp_path: Path) -> tuple[Path, dict[str, int]]:
    """A copy of the clean source (symlinks to the real files) for one test to damage."""
    src, clean = dair_clean
    shutil.copytree(src, tmp_path / "src", symlinks=True)
    return tmp_path / "src", clean


def _edit_pairs(src: Path, edit) -> Path:
    path = src / "cooperative" / "selected_data_info.json"
    pairs = json.loads(path.read_text())
    replace(path, json.dumps(edit(pairs)).encode())
    return path


@pytest.mark.parametrize(("field", "value"), [("cooperative_label_path", 7), ("infrastructure_pointcloud_path", None),
                                              ("system_error_offset", {"delta_x": float("nan"), "delta_y": 0.0})])
def test_dair_bad_pair_field_costs_that_pair(dair, tmp_path: Path, capsys, field, value) -> None:
    # A number where a path belongs was a TypeError traceback; a NaN offset used to be written into every pose.
    src, _ = dair
    path = _edit_pairs(src, lambda pairs: [{**pairs[0], field: value}])
    status, err, _ = run(["convert", "dair-v2x", src, tmp_path / "out", "--quiet"], capsys)
    errors = [line for line in err if line.startswith("error:")]
    assert status == 1 and len(errors) == 1
    assert str(path) in errors[0] and DAIR_SCENE in errors[0]
    assert (field if field != "system_error_offset" else "delta_x") in errors[0]


def test_dair_empty_pair_list_is_an_error(dair, tmp_path: Path, capsys) -> None:
    # Used to write an empty dataset with exit status 0.
    src, _ = dair
    path = _edit_pairs(src, lambda pairs: [])
    status, err, _ = run(["convert", "dair-v2x", src, tmp_path / "out", "--quiet"], capsys)
    assert status == 1 and err == [f"avdata: error: {path}: expected a JSON list of cooperative pairs, got an empty list"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("damage", ["folder", "loop", "not a list", "no entry"])
def test_dair_unusable_data_info_is_named_and_costs_only_the_time(dair, tmp_path: Path, capsys, damage) -> None:
    # A data_info.json that is a folder, a symlink loop or not a list used to be skipped without a word
    # (the scene silently became scene-relative, time 0).
    src, clean = dair
    path = src / "vehicle-side" / "data_info.json"
    if damage == "folder":
        replace(path).mkdir()
    elif damage == "loop":
        replace(path)
        os.symlink(path.name, path)
    elif damage == "not a list":
        replace(path, b'{"pointcloud_path": "velodyne/017314.pcd"}')
    else:
        replace(path, b'[{"pointcloud_path": "velodyne/999999.pcd", "pointcloud_timestamp": "1"}]')
    status, err, _ = run(["convert", "dair-v2x", src, tmp_path / "out", "--quiet"], capsys)
    problems = [line for line in err if line.startswith(("error:", "warning:"))]
    assert len(problems) == 1 and str(path) in problems[0] and "017314" in problems[0]
    assert problems[0].startswith("warning:" if damage == "no entry" else "error:")
    assert status == (0 if damage == "no entry" else 1)
    assert n_objects(tmp_path / "out") == clean  # every box kept
    assert DatasetReader(tmp_path / "out").scene(DAIR_SCENE).metadata["time"] == "scene-relative: 0"


# --- OPV2V ----------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def opv2v(tmp_path_factory) -> tuple[Path, dict[str, int]]:
    root = tmp_path_factory.mktemp("opv2v")
    build_opv2v(root / "src")
    status = main(["convert", "opv2v", str(root / "src"), str(root / "clean"), "--quiet"])
    assert status == 0
    return root / "src", n_objects(root / "clean")


def _opv2v_copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, symlinks=True)
    return dst / "validate" / "2021_08_21_17_30_41"


@pytest.mark.parametrize("damage", ["folder", "loop", "dangling"])
def test_opv2v_frame_file_that_is_no_file_is_an_error(opv2v, tmp_path: Path, capsys, damage) -> None:
    # The RSU's frame YAML replaced by a folder or a broken link used to drop its boxes with exit status 0.
    src, clean = opv2v
    scenario = _opv2v_copy(src, tmp_path / "src")
    path = replace(scenario / "-1" / "000071.yaml")
    if damage == "folder":
        path.mkdir()
    else:
        os.symlink(path.name if damage == "loop" else "/nonexistent/000071.yaml", path)
    status, err, _ = run(["convert", "opv2v", tmp_path / "src", tmp_path / "out", "--quiet"], capsys)
    errors = [line for line in err if line.startswith("error:")]
    assert status == 1 and len(errors) == 1 and f"{path}: cannot read" in errors[0]
    assert errors[0].count(str(path)) == 1  # the file is named once
    # Only the RSU's view of frame 71 is lost: its hand-placed box (seen by nobody else) and the RSU-only actors.
    reader = DatasetReader(tmp_path / "out")
    ids = [set(reader.scene(OPV2V_SCENE).labels(i)[1].boxes.ids.tolist()) for i in range(3)]
    assert "9001" in ids[0] and "9001" not in ids[1] and "9001" in ids[2]
    assert n_objects(tmp_path / "out")[OPV2V_SCENE] < clean[OPV2V_SCENE]
    _, clean_labels = DatasetReader(src.parent / "clean").scene(OPV2V_SCENE).labels(0)
    assert ids[0] == set(clean_labels.boxes.ids.tolist())


def test_opv2v_unreadable_ego_frame_file_costs_that_frame(opv2v, tmp_path: Path, capsys) -> None:
    # A bad camera extrinsic in the ego's last frame YAML used to leave that frame without an ego pose:
    # the index could not be built and the whole dataset was lost (no manifest).
    src, clean = opv2v
    scenario = _opv2v_copy(src, tmp_path / "src")
    data = yaml.safe_load((scenario / "4279" / "000073.yaml").read_text())
    del data["camera3"]["extrinsic"][1]
    path = replace(scenario / "4279" / "000073.yaml", yaml.safe_dump(data).encode())
    status, err, _ = run(["convert", "opv2v", tmp_path / "src", tmp_path / "out", "--quiet"], capsys)
    errors = [line for line in err if line.startswith("error:")]
    assert status == 1 and len(errors) == 1 and f"{path}: field camera3.extrinsic: expected shape (4, 4)" in errors[0]
    assert any(f"{path}: frame 000073 left out: no readable frame file of the ego agent 4279" in line for line in err)
    reader = DatasetReader(tmp_path / "out")
    assert reader.frames().num_rows == 2  # frames 69 and 71, whole
    clean_reader = DatasetReader(src.parent / "clean")
    for i in range(2):
        assert reader.scene(OPV2V_SCENE).labels(i)[1].boxes.ids.tolist() == \
            clean_reader.scene(OPV2V_SCENE).labels(i)[1].boxes.ids.tolist()
    assert main(["validate", str(tmp_path / "out")]) == 0


@pytest.mark.parametrize(("damage", "message"), [("empty", "expected a PNG file"), ("truncated", "(truncated file?)"),
                                                  ("flipped", "CRC-32 does not match (damaged bytes)")])
def test_opv2v_damaged_first_png_costs_only_that_image(opv2v, tmp_path: Path, capsys, damage, message) -> None:
    # An empty first-frame PNG used to fail the whole scene; a truncated or bit-flipped one was stored without a word.
    src, clean = opv2v
    scenario = _opv2v_copy(src, tmp_path / "src")
    path = scenario / "-1" / "000069_camera0.png"
    data = path.read_bytes()
    flipped = data[: len(data) // 2] + bytes([data[len(data) // 2] ^ 4]) + data[len(data) // 2 + 1:]
    replace(path, {"empty": b"", "truncated": data[: len(data) // 2], "flipped": flipped}[damage])
    status, err, _ = run(["convert", "opv2v", tmp_path / "src", tmp_path / "out", "--quiet"], capsys)
    errors = [line for line in err if line.startswith("error:")]
    assert status == 1 and len(errors) == 1 and str(path) in errors[0] and message in errors[0]
    assert n_objects(tmp_path / "out") == clean
    scene = DatasetReader(tmp_path / "out").scene(OPV2V_SCENE)
    assert "infra_1/camera0" not in scene.frame_infos()[0].sensor_timestamps_ns
    assert "infra_1/camera0" in scene.frame_infos()[1].sensor_timestamps_ns


# --- eval -----------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def kitti_object_dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("kitti_object")
    for folder, suffix in {"calib": ".txt", "label_2": ".txt", "velodyne": ".bin", "image_2": ".png"}.items():
        (root / "src" / "training" / folder).mkdir(parents=True)
        for sample in ("000000", "000001", "000002"):
            (root / "src" / "training" / folder / f"{sample}{suffix}").symlink_to(KITTI_OBJECT / folder / f"{sample}{suffix}")
    assert main(["convert", "kitti-object", str(root / "src"), str(root / "ds"), "--quiet"]) == 0
    return root / "ds"


def _perfect(dataset: Path, path: Path, score: bool = True) -> Path:
    objects = pq.read_table(dataset / "index" / "objects.parquet")
    table = objects.select(["scene", "frame_index", "object_id", "class", "x_world_m", "y_world_m", "z_world_m",
                            "length_m", "width_m", "height_m", "yaw_world_rad"])
    if score:
        table = table.append_column("score", pa.array(np.full(table.num_rows, 0.9)))
    pq.write_table(table, path)
    return path


def test_eval_avdata_perfect_detector_on_real_kitti_scores_one(kitti_object_dataset, tmp_path: Path, capsys) -> None:
    # KITTI's visibility rows are camera labels without point counts (n_points -1, visible fraction NaN): all
    # ground truth used to count as invisible and a perfect detector scored precision 0, recall 0, exit 0.
    pred = _perfect(kitti_object_dataset, tmp_path / "det.parquet")
    status, _, out = run(["eval", "detection", "--protocol", "avdata", kitti_object_dataset, pred,
                          "--json", tmp_path / "r.json"], capsys)
    result = json.loads((tmp_path / "r.json").read_text())
    n_labels = pq.read_table(kitti_object_dataset / "index" / "objects.parquet").num_rows
    assert status == 0 and result["all"]["TP"] == n_labels > 0
    assert result["all"]["precision"] == 1.0 and result["all"]["recall"] == 1.0 and result["all"]["FN"] == 0
    status, err, _ = run(["eval", "tracking", "--protocol", "avdata", kitti_object_dataset,
                          _perfect(kitti_object_dataset, tmp_path / "trk.parquet", score=False),
                          "--json", tmp_path / "t.json"], capsys)
    assert status == 0 and json.loads((tmp_path / "t.json").read_text())["car"]["HOTA"] == pytest.approx(1.0)


def test_eval_avdata_detection_classes_are_checked_and_applied(kitti_object_dataset, tmp_path: Path, capsys) -> None:
    # --classes used to be ignored by the avdata, nuScenes, AV2 and Waymo detection protocols.
    pred = _perfect(kitti_object_dataset, tmp_path / "det.parquet")
    status, err, _ = run(["eval", "detection", "--protocol", "avdata", kitti_object_dataset, pred,
                          "--classes", "spaceship"], capsys)
    assert status == 1 and len(err) == 1 and err[0].startswith("avdata: error: --classes:") and "'spaceship'" in err[0]
    status, _, _ = run(["eval", "detection", "--protocol", "avdata", kitti_object_dataset, pred, "--classes",
                        "pedestrian", "--json", tmp_path / "r.json"], capsys)
    result = json.loads((tmp_path / "r.json").read_text())
    assert status == 0 and set(result) >= {"all", "class=pedestrian"} and "class=car" not in result
    status, err, _ = run(["eval", "detection", "--protocol", "nuscenes", tmp_path, pred, "--classes", "car"], capsys)
    assert status == 1 and err == ["avdata: error: --classes: expected --protocol kitti or avdata (the others do not "
                                   "use it), got --protocol nuscenes"]


def test_eval_avdata_without_visible_ground_truth_is_an_error(kitti_object_dataset, tmp_path: Path, capsys) -> None:
    dataset = tmp_path / "ds"
    shutil.copytree(kitti_object_dataset, dataset)
    visibility = pq.read_table(dataset / "index" / "visibility.parquet")
    replace_index_table(dataset, "visibility", visibility.set_column(visibility.column_names.index("in_fov"), "in_fov",
                                                                     pa.array(np.zeros(visibility.num_rows, bool))))
    status, err, _ = run(["eval", "detection", "--protocol", "avdata", dataset,
                          _perfect(kitti_object_dataset, tmp_path / "det.parquet")], capsys)
    assert status == 1 and len(err) == 1 and "expected ground truth seen by a sensor" in err[0] and str(dataset) in err[0]


def test_a_changed_index_value_stops_eval_and_a_damaged_cloud_stops_render(kitti_object_dataset, tmp_path: Path,
                                                                           capsys) -> None:
    # Were silent: a box size changed in objects.parquet (still valid Parquet) scored a perfect detector
    # below 1 with exit 0, and a flipped bit in a cloud was drawn: readers checked checksums on request only.
    pred = _perfect(kitti_object_dataset, tmp_path / "det.parquet")
    dataset = tmp_path / "ds"
    shutil.copytree(kitti_object_dataset, dataset)
    objects = pq.read_table(dataset / "index" / "objects.parquet")
    length = objects.column("length_m").to_numpy().copy()
    length[0] += 1.0
    pq.write_table(objects.set_column(objects.column_names.index("length_m"), "length_m", pa.array(length)),
                   dataset / "index" / "objects.parquet")
    status, err, _ = run(["eval", "detection", "--protocol", "avdata", dataset, pred], capsys)
    assert status == 1 and len(err) == 1
    assert err[0].startswith(f"avdata: error: {dataset}/index/objects.parquet: expected ") and "with CRC-32" in err[0]

    shutil.rmtree(dataset)
    shutil.copytree(kitti_object_dataset, dataset)
    scene = DatasetReader(dataset).scene("training_000000")
    lidar = scene.message_table("/ego/velodyne/points")
    payload = scene._mcap.payload_file_offset(int(lidar.chunk[0]), int(lidar.record_offset[0]))
    chunk_offset = scene._mcap.chunks[int(lidar.chunk[0])].offset
    scene.close()
    path = dataset / "scenes" / "training_000000.mcap"
    damaged = bytearray(path.read_bytes())
    damaged[payload + 1000] ^= 0x01  # inside a point's x: still a readable cloud, one point moved
    path.write_bytes(bytes(damaged))
    status, err, _ = run(["render", dataset, tmp_path / "frame.png", "--scene", "training_000000"], capsys)
    assert status == 1 and len(err) == 1 and f"training_000000.mcap: byte {chunk_offset}: chunk CRC mismatch" in err[0], err
    assert not (tmp_path / "frame.png").exists()


def _kitti_tracking(root: Path) -> tuple[Path, Path]:
    gt, tracker = root / "gt", root / "CIWT" / "data"
    (gt / "label_02").mkdir(parents=True)
    tracker.mkdir(parents=True)
    shutil.copy(KITTI_TRACKING_LABEL, gt / "label_02" / "0001.txt")
    (gt / "evaluate_tracking.seqmap.training").write_text("0001 empty 000000 000447\n")
    rows = [line.split() for line in KITTI_TRACKING_LABEL.read_text().splitlines() if line.strip()]
    (tracker / "0001.txt").write_text("\n".join(" ".join(r[:17] + ["0.9"]) for r in rows if r[2] != "DontCare") + "\n")
    return gt, tracker


def test_eval_kitti_tracking_non_utf8_seqmap_is_one_line(tmp_path: Path, capsys) -> None:
    # Was a UnicodeDecodeError traceback.
    gt, tracker = _kitti_tracking(tmp_path)
    seqmap = gt / "evaluate_tracking.seqmap.training"
    seqmap.write_bytes(b"0001 empty \xff000000 000447\n")
    status, err, _ = run(["eval", "tracking", "--protocol", "kitti", gt, tracker], capsys)
    assert status == 1 and err == [f"avdata: error: {seqmap}: expected UTF-8 text, got byte 0xff at offset 11"]


@pytest.mark.parametrize("link", ["loop", "dangling"])
def test_eval_kitti_detection_broken_result_link_is_an_error(tmp_path: Path, capsys, link) -> None:
    # A result file that is a broken link used to read as "an image without detections" (AP changed, exit 0).
    (tmp_path / "pred").mkdir()
    for label in sorted((KITTI_OBJECT / "label_2").glob("*.txt")):
        rows = [line.split() for line in label.read_text().splitlines() if line.strip()]
        (tmp_path / "pred" / label.name).write_text("\n".join(" ".join(r[:15] + ["0.8"]) for r in rows) + "\n")
    broken = replace(tmp_path / "pred" / "000001.txt")
    os.symlink(broken.name if link == "loop" else "/nonexistent/000001.txt", broken)
    status, err, _ = run(["eval", "detection", "--protocol", "kitti", KITTI_OBJECT, tmp_path / "pred"], capsys)
    assert status == 1 and len(err) == 1 and err[0].startswith(f"avdata: error: {broken}: unreadable")


# --- study files ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["cases"][0].update(comm_range_m=float("nan")), "cases[0]: expected comm_range_m to be a finite number, got nan"),
    (lambda d: d["cases"][1].update(rate_hz=float("inf")), "cases[1]: expected rate_hz to be a finite number, got inf"),
    (lambda d: d["cases"][1].update(latency_frames=-2), "cases[1]: expected latency_frames in [0, 100000], got -2"),
    (lambda d: d["evaluation"].update(prediction_horizon_s=-0.3),
     "expected evaluation.prediction_horizon_s in (0, 3600], got -0.3"),
    (lambda d: d["evaluation"].update(max_range_m=0), "expected evaluation.max_range_m in (0, 100000], got 0.0"),
    (lambda d: d["evaluation"].update(max_occlusion=7), "expected evaluation.max_occlusion in 0..3 (KITTI levels), got 7"),
])
def test_study_values_are_checked_before_any_trial_runs(tmp_path: Path, capsys, edit, message) -> None:
    # Each was accepted and either ran a meaningless study or failed later inside a worker.
    doc = yaml.safe_load((Path(__file__).resolve().parent / "studies" / "small_study.yaml").read_text())
    edit(doc)
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump(doc))
    status, err, _ = run(["study", "run", path, tmp_path / "out", "--quiet"], capsys)
    assert status == 1 and err == [f"avdata: error: {path}: {message}"]
    assert not (tmp_path / "out").exists()


def test_v2v4real_infinite_ass_id_costs_that_vehicle(tmp_path: Path, capsys) -> None:
    # Was an OverflowError traceback (int(inf)) that lost the scene.
    scenario = build_v2v4real(tmp_path / "src")
    assert main(["convert", "opv2v", str(tmp_path / "src"), str(tmp_path / "clean"), "--quiet"]) == 0
    path = scenario / "0" / "000002.yaml"
    data = yaml.safe_load(path.read_text())
    data["vehicles"][30]["ass_id"] = float("inf")
    path.write_text(yaml.safe_dump(data))
    status, err, _ = run(["convert", "opv2v", tmp_path / "src", tmp_path / "out", "--quiet"], capsys)
    errors = [line for line in err if line.startswith("error:")]
    assert status == 1 and len(errors) == 1 and str(path) in errors[0] and "field vehicles.30" in errors[0]
    scene = f"test.{scenario.name}"
    assert n_objects(tmp_path / "out")[scene] == n_objects(tmp_path / "clean")[scene] - 1


def test_generate_non_utf8_scenario_is_one_line(tmp_path: Path, capsys) -> None:
    # Was a UnicodeDecodeError traceback (UTF-16 files too).
    path = tmp_path / "scenario.yaml"
    path.write_bytes("seed: 1\n".encode("utf-16"))
    status, err, _ = run(["generate", path, tmp_path / "out", "--quiet"], capsys)
    assert status == 1 and err == [f"avdata: error: {path}: expected UTF-8 YAML, got byte 0xff at offset 0"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("damage", "file"), [("folder", "image_02/data/0000000001.png"),
                                              ("loop", "image_02/data/0000000001.png"),
                                              ("folder", "velodyne_points/data/0000000001.bin"),
                                              ("loop", "velodyne_points/data/0000000001.bin")])
def test_kitti_raw_sensor_file_that_is_no_file_costs_that_file(tmp_path: Path, capsys, damage, file) -> None:
    # An image or scan path that is a folder or a symlink loop was an IsADirectoryError / OSError traceback.
    from tests.converters.test_kitti_raw import assemble_drive

    assemble_drive(tmp_path / "src", n_frames=6)
    path = next((tmp_path / "src").rglob(file))
    replace(path)
    if damage == "folder":
        path.mkdir()
    else:
        os.symlink(path.name, path)
    status, err, _ = run(["convert", "kitti-raw", tmp_path / "src", tmp_path / "out", "--quiet"], capsys)
    errors = [line for line in err if line.startswith("error:") and str(path) in line]
    assert status == 1 and len(errors) == 1 and "frame 1 written without it" in errors[0]
    expected = ("Too many levels of symbolic links",) if damage == "loop" else ("Is a directory", "got a folder")
    assert any(text in errors[0] for text in expected)
    frames = DatasetReader(tmp_path / "out").frames()
    assert frames.num_rows == 6  # every frame written, frame 1 without that image


@pytest.mark.parametrize("value", [["abc", [0.0, 1.0, 2.0], [0.0, 0.0, 1.0]], [[1.0, 0.0, 2.0], [0.0, 1.0]], None])
def test_nuscenes_malformed_camera_intrinsic_costs_that_calibration(tmp_path: Path, capsys, value) -> None:
    # Was a ValueError traceback (inhomogeneous / non-numeric / wrong size) that lost the scene.
    from tests.converters.test_nuscenes_bad_input import lyft_copy

    root = lyft_copy(tmp_path / "src")
    path = next(root.glob("*/calibrated_sensor.json"))
    rows = json.loads(path.read_text())
    index = next(i for i, row in enumerate(rows) if row.get("camera_intrinsic"))
    rows[index]["camera_intrinsic"] = value
    path.write_text(json.dumps(rows))
    status, err, _ = run(["convert", "nuscenes", root, tmp_path / "out", "--quiet"], capsys)
    errors = [line for line in err if line.startswith("error:")]
    assert status == 1 and len(errors) == 1
    assert f"calibrated_sensor.json: calibrated_sensor {rows[index]['token']}: camera_intrinsic" in errors[0]
    assert n_objects(tmp_path / "out") == {DatasetReader(tmp_path / "out").scenes[0]: 4}


@pytest.mark.parametrize(("table", "field", "value"), [("sample_annotation", "num_lidar_pts", float("nan")),
                                                       ("sample_annotation", "num_radar_pts", "abc"),
                                                       ("sample_data", "height", float("inf"))])
def test_nuscenes_bad_integer_field_costs_that_row(tmp_path: Path, capsys, table, field, value) -> None:
    # Each was a ValueError / OverflowError traceback that lost the conversion.
    from tests.converters.test_nuscenes_bad_input import lyft_copy

    root = lyft_copy(tmp_path / "src")
    path = next(root.glob(f"*/{table}.json"))
    rows = json.loads(path.read_text())
    rows[0][field] = value
    path.write_text(json.dumps(rows))
    status, err, _ = run(["convert", "nuscenes", root, tmp_path / "out", "--quiet"], capsys)
    errors = [line for line in err if line.startswith("error:")]
    assert status == 1 and len(errors) == 1
    assert f"{table}.json: {table} {rows[0]['token']}: field '{field}': expected " in errors[0] and errors[0].endswith("dropped")


@pytest.mark.parametrize("edit", ["name not a string", "no scenes"])
def test_nuscenes_without_a_valid_scene_is_an_error(tmp_path: Path, capsys, edit) -> None:
    # The problems of rows that belong to no scene are reported with the first scene; without one they were
    # never printed and the run wrote an empty dataset with exit status 0.
    from tests.converters.test_nuscenes_bad_input import lyft_copy

    root = lyft_copy(tmp_path / "src")
    path = next(root.glob("*/scene.json"))
    rows = json.loads(path.read_text())
    path.write_text(json.dumps([{**rows[0], "name": 7}] if edit == "name not a string" else []))
    status, err, _ = run(["convert", "nuscenes", root, tmp_path / "out", "--quiet"], capsys)
    assert status == 1 and len(err) == 1
    assert err[0].startswith(f"avdata: error: {path}: expected at least one valid scene, got none")
    assert ("field 'name': expected a string, got 7" in err[0]) == (edit == "name not a string")


# --- round 4: frames the index could not place, magnitudes, configs, duplicate keys, special files ---------------


def test_av2_sweep_without_ego_pose_costs_that_sweep_not_the_dataset(tmp_path: Path, capsys) -> None:
    # The sweep's cuboids were dropped with an error, but the frame itself was written without an ego pose at its
    # time; the index build then failed and the whole dataset had no manifest.
    from tests.converters.test_argoverse2 import LOG, SWEEPS
    from tests.converters.test_argoverse2_bad_input import layout

    src = layout(tmp_path / "src")
    poses = src / "val" / LOG / "city_SE3_egovehicle.feather"
    table = pa.feather.read_table(poses)
    kept = table.filter(pa.compute.less(table.column("timestamp_ns"), SWEEPS[1]))
    assert 0 < kept.num_rows < table.num_rows
    replace(poses)
    pa.feather.write_feather(kept, poses)
    status, err, _ = run(["convert", "argoverse2", src, tmp_path / "dst", "--quiet"], capsys)
    assert status == 1
    refused = [line for line in err if "frame refused" in line]
    assert len(refused) == 1 and str(src / "val" / LOG) in refused[0] and "sweep 1" in refused[0]
    assert "the ego frame 'ego' cannot be placed" in refused[0]
    frames = DatasetReader(tmp_path / "dst").frames()
    assert frames.column("timestamp_ns").to_pylist() == [SWEEPS[0]]


def test_av2_damaged_image_is_not_listed_by_its_sweep(tmp_path: Path, capsys) -> None:
    # The sweep listed the damaged (unwritten) image as its camera message; loading it failed later.
    from tests.converters.test_argoverse2 import LOG, SWEEPS
    from tests.converters.test_argoverse2_bad_input import layout

    src = layout(tmp_path / "src")
    # The sample ships no images: a JPEG per sweep (as tests/converters/test_argoverse2_bad_input.py), the one of
    # sweep 1 damaged.
    folder = src / "val" / LOG / "sensors" / "cameras" / "ring_front_center"
    folder.mkdir(parents=True)
    ok, jpeg = cv2.imencode(".jpg", np.zeros((32, 48, 3), np.uint8))
    (folder / f"{SWEEPS[0] - 2407723}.jpg").write_bytes(jpeg.tobytes())
    nearest = folder / f"{SWEEPS[1] - 2603730}.jpg"
    nearest.write_bytes(b"<html>not an image</html>")
    status, err, _ = run(["convert", "argoverse2", src, tmp_path / "dst", "--quiet"], capsys)
    assert status == 1 and any(str(nearest) in line and "expected a JPEG file" in line for line in err)
    reader = DatasetReader(tmp_path / "dst")
    times = dict(zip(reader.frames().column("timestamp_ns").to_pylist(),
                     reader.frames().column("sensor_timestamps_ns").to_pylist(), strict=True))
    listed = dict(times[SWEEPS[1]]).get("ego/ring_front_center")
    assert listed != int(nearest.stem)
    for index in range(reader.frames().num_rows):  # every listed message exists
        for sensor in dict(reader.frames().column("sensor_timestamps_ns")[index].as_py()):
            if "ring" in sensor:
                assert reader.image(LOG, index, sensor)[1] == "jpeg"


def test_nuscenes_missing_sensor_files_are_not_listed_by_their_sample(tmp_path: Path, capsys) -> None:
    # The real Lyft sample ships its tables without the sample_data files: each sample listed 10 sensor messages
    # that were never written (a warning said so), and loading any of them failed.
    from tests.converters.test_nuscenes_bad_input import LYFT, VERSION

    rows = json.loads((LYFT / VERSION / "sample_data.json").read_text())
    assert not any((LYFT / row["filename"]).exists() for row in rows)
    status, err, _ = run(["convert", "nuscenes", LYFT, tmp_path / "dst"], capsys)
    assert status == 0 and sum("sensor file missing" in line for line in err) == len(rows)
    reader = DatasetReader(tmp_path / "dst")
    assert reader.objects().num_rows > 0
    frames = reader.frames()
    assert frames.num_rows == 1
    assert [dict(m) for m in frames.column("sensor_timestamps_ns").to_pylist()] == [{}]


def _boxes(frame: str = "world", size=(4.0, 2.0, 1.5), center=(10.0, 0.0, 0.0), velocity=None):
    from avdata.frames import Boxes3D
    from avdata.schema import ObjectLabels

    boxes = Boxes3D(center=np.array([center]), size_lwh=np.array([size]), quat_wxyz=np.array([[1.0, 0, 0, 0]]),
                    frame=frame, ids=np.array(["a"]), classes=np.array(["car"]),
                    velocity=None if velocity is None else np.array([velocity]))
    return ObjectLabels(boxes=boxes, source_classes=np.array(["Car"]))


@pytest.mark.parametrize(("labels", "sensors", "message"), [
    (lambda: _boxes(), {}, "the ego frame 'ego' cannot be placed: no pose of 'ego' in 'world' at 300 ns "
                                "(its poses span [100, 200] ns)"),
    (lambda: _boxes("ego/cam"), {}, "its objects (in 'ego/cam') cannot be placed: frame 'ego/cam' has no transform"),
    (lambda: _boxes(), {"ego/lidar": 200}, "sensor 'ego/lidar' has no message at 200 ns"),
    (lambda: _boxes(size=(2000.0, 2.0, 1.5)), {}, "expected a size in [0, 1000] m"),
    (lambda: _boxes(center=(1e30, 0.0, 0.0)), {}, "a centre within 1e+07 m"),
    (lambda: _boxes(velocity=(5e3, 0.0, 0.0)), {}, "a speed within 1000 m/s"),
])
def test_writer_refuses_a_frame_the_index_could_not_place_and_keeps_the_others(tmp_path: Path, labels, sensors,
                                                                              message) -> None:
    # Such a frame used to be written; the index build then failed for the whole dataset.
    from avdata.errors import InputError
    from avdata.frames import Transform
    from avdata.schema import DatasetWriter

    pose_times = (100, 200) if "ego frame" in message else (100, 200, 300)
    with DatasetWriter(tmp_path / "ds", source="test") as writer, writer.scene("s") as scene:
        scene.add_agent("ego", "vehicle", "rear axle")
        for t in pose_times:
            scene.add_transform("world", "ego", t, Transform.from_yaw(0.0, [1.0, 2.0, 0.0]))
        scene.add_frame(0, 100, _boxes())
        with pytest.raises(InputError, match="s.mcap: frame 1 at 300 ns: .*; frame refused") as error:
            scene.add_frame(scene.n_frames, 300, labels(), sensors)
        assert message in str(error.value)
        assert scene.n_frames == 1
        scene.add_frame(scene.n_frames, 200, _boxes())  # the next frame takes index 1
    frames = DatasetReader(tmp_path / "ds").frames()
    assert frames.column("timestamp_ns").to_pylist() == [100, 200]


def test_writer_refuses_absurd_transforms_and_intrinsics(tmp_path: Path) -> None:
    from avdata.errors import AvdataError, InputError
    from avdata.frames import Transform
    from avdata.schema import ObjectLabels, SceneWriter

    with SceneWriter(tmp_path / "s.mcap", "s") as scene:
        with pytest.raises(AvdataError, match=r"expected a translation within 1e\+07 m per axis, got \[100000000.0"):
            scene.add_transform("world", "ego", 0, Transform.from_yaw(0.0, [1e8, 0.0, 0.0]))
        with pytest.raises(AvdataError, match=r"expected a translation within 1e\+07 m"):
            scene.add_static_transform("ego", "ego/lidar", Transform.from_yaw(0.0, [0.0, -3e7, 0.0]))
        for K, size in ((np.diag([0.0, 700.0, 1.0]), (1242, 375)), (np.diag([-700.0, 700.0, 1.0]), (1242, 375)),
                        (np.diag([1e300, 700.0, 1.0]), (1242, 375)), (np.diag([700.0, 700.0, 1.0]), (-5, 375))):
            with pytest.raises(InputError, match="camera calibration of 'ego/cam' at 0 ns: expected finite K, R, P "
                                                 "with focal lengths > 0"):
                scene.add_camera_calibration("ego/cam", 0, K, *size)
        with pytest.raises(InputError, match=r"expected a time in \[0, 9223372036854775807\] ns, got 9223372036854775808"):
            scene.add_point_cloud("ego/lidar", 2**63, {"x": np.zeros(1, np.float32), "y": np.zeros(1, np.float32),
                                                       "z": np.zeros(1, np.float32)})
        scene.add_transform("world", "ego", 0, Transform.identity())  # a scene needs a frame to be kept
        scene.add_frame(0, 0, ObjectLabels.empty("world"))


def test_kitti_absurd_label_values_cost_their_line(tmp_path: Path, capsys) -> None:
    # A 1e30 m long car (or one 1e30 m away) was written into the scene; '1_000' was read as 1000 by float().
    from tests.converters.test_kitti_bad_corpus import object_copy

    src = object_copy(tmp_path / "src")
    assert main(["convert", "kitti-object", str(src), str(tmp_path / "clean"), "--quiet"]) == 0
    capsys.readouterr()
    label = src / "training" / "label_2" / "000001.txt"
    lines = label.read_text().splitlines()
    fields = [line.split() for line in lines]
    assert fields[0][0] != "DontCare" and fields[1][0] != "DontCare" and fields[2][0] != "DontCare"
    fields[0][10] = "1e30"      # length
    fields[1][11] = "-2e7"      # x
    fields[2][8] = "1_000"      # height
    replace(label, ("\n".join(" ".join(f) for f in fields) + "\n").encode())
    status, err, _ = run(["convert", "kitti-object", src, tmp_path / "dst", "--quiet"], capsys)
    assert status == 1
    assert any(f"{label}" in line and "line 1: dimensions: expected height, width, length <= 1000 m" in line
               for line in err)
    assert any("line 2: location: expected coordinates within 1e+07 m" in line for line in err)
    assert any("line 3: expected numbers after the class" in line and "1_000" in line for line in err)
    clean = n_objects(tmp_path / "clean")
    assert n_objects(tmp_path / "dst") == {scene: n - 3 for scene, n in clean.items()}


@pytest.mark.parametrize(("repeat", "loses"), [("P2", True), ("R0_rect", True), ("same-line", False)])
def test_kitti_calibration_key_given_twice_is_an_error(tmp_path: Path, capsys, repeat, loses) -> None:
    # The last P2 silently won.
    from tests.converters.test_kitti_bad_corpus import object_copy

    src = object_copy(tmp_path / "src")
    calib = src / "training" / "calib" / "000001.txt"
    lines = calib.read_text().splitlines()
    if repeat == "same-line":
        lines.append(lines[2])
    else:
        row = next(i for i, line in enumerate(lines) if line.startswith(f"{repeat}:"))
        values = lines[row].split()
        values[1] = repr(float(values[1]) * 1.01 + 0.5)
        lines.append(" ".join(values))
    replace(calib, ("\n".join(lines) + "\n").encode())
    status, err, _ = run(["convert", "kitti-object", src, tmp_path / "dst", "--quiet"], capsys)
    if not loses:
        assert status == 0 and not err
        return
    assert status == 1
    assert any(f"{calib}: line {len(lines)}: {repeat}: given again with different values" in line for line in err)
    assert DatasetReader(tmp_path / "dst").frames().num_rows == 2  # samples 000000 and 000002


def test_kitti_source_file_that_is_a_fifo_is_an_error_not_a_hang(tmp_path: Path, capsys) -> None:
    # Reading a FIFO waits for a writer forever: the conversion hung.
    from tests.converters.test_kitti_bad_corpus import object_copy

    src = object_copy(tmp_path / "src")
    fifo = replace(src / "training" / "label_2" / "000001.txt")
    os.mkfifo(fifo)
    status, err, _ = run(["convert", "kitti-object", src, tmp_path / "dst", "--quiet"], capsys)
    assert status == 1 and any(f"{fifo}: expected a regular file, got a FIFO" in line for line in err)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["egos"][0]["sensors"][0]["lidar"].update(azimuth_steps=10**9),
     "field egos[0].sensors[0].lidar.azimuth_steps: expected values in [1, 16384], got 1000000000"),
    (lambda d: d["infrastructure"]["sensors"][0]["lidar"].update(max_range_m=-5.0),
     "field infrastructure.sensors[0].lidar.max_range_m: expected values in [0.01, 10000], got -5.0"),
    (lambda d: d["egos"][0]["sensors"][1]["camera"].update(width=10**6),
     "field egos[0].sensors[1].camera.width: expected values in [1, 8192], got 1000000"),
    (lambda d: d["traffic"].update(vehicles=-3), "field traffic.vehicles: expected values in [0, 10000], got -3"),
    (lambda d: d["town"].update(grid=[2, 10**6]), "field town.grid: expected values in [2, 50], got (2, 1000000)"),
    (lambda d: d.update(frames=10**9), "field frames: expected values in [1, 100000], got 1000000000"),
    (lambda d: d.update(seed=2**40), "field seed: expected an integer <= 4294967295, got 1099511627776"),
    (lambda d: d["infrastructure"].update(count=10**7), "field infrastructure.count: expected values in [0, 1000]"),
])
def test_generate_absurd_config_values_are_one_line_before_any_work(tmp_path: Path, capsys, edit, message) -> None:
    # 1e9 azimuth steps was a MemoryError after the town was built; 1e6 intersections ran for hours.
    from avdata.generators.config import load_preset

    doc = load_preset("v2i-intersection").to_dict()
    edit(doc)
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(doc))
    status, err, _ = run(["generate", path, tmp_path / "out", "--quiet"], capsys)
    assert status == 1 and len(err) == 1 and err[0].startswith(f"avdata: error: {path}: {message}")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d.update(trials=10**9), "expected trials in [1, 1000]"),
    (lambda d: d.update(frames=10**12), "frames in [2, 100000]"),
    (lambda d: d["cases"][0].update(comm_range_m=1e300), "cases[0]: expected comm_range_m in [0, 100000], got 1e+300"),
    (lambda d: d["cases"][1].update(rate_hz=1e9), "cases[1]: expected rate_hz in (0, 1000], got 1000000000.0"),
    (lambda d: d["overrides"]["infrastructure"]["sensors"][0]["lidar"].update(azimuth_steps=10**9),
     "field infrastructure.sensors[0].lidar.azimuth_steps: expected values in [1, 16384]"),
])
def test_study_absurd_values_are_one_line_before_any_work(tmp_path: Path, capsys, edit, message) -> None:
    doc = yaml.safe_load((Path(__file__).resolve().parent / "studies" / "small_study.yaml").read_text())
    edit(doc)
    path = tmp_path / "study.yaml"
    path.write_text(yaml.safe_dump(doc))
    status, err, _ = run(["study", "run", path, tmp_path / "out", "--quiet"], capsys)
    assert status == 1 and len(err) == 1 and message in err[0] and err[0].startswith(f"avdata: error: {path}")
    assert not (tmp_path / "out").exists()


def test_opv2v_key_given_twice_in_a_frame_file_is_an_error(opv2v, tmp_path: Path, capsys) -> None:
    # PyYAML (and OpenCOOD) keep the last of two 'lidar_pose' keys without a word.
    src, clean = opv2v
    scenario = _opv2v_copy(src, tmp_path / "src")
    path = scenario / "-1" / "000071.yaml"
    text = path.read_text()
    assert text.startswith("lidar_pose:") or "\nlidar_pose:" in text
    replace(path, (text + "lidar_pose: [1.0, 2.0, 3.0, 0.0, 0.0, 0.0]\n").encode())
    status, err, _ = run(["convert", "opv2v", tmp_path / "src", tmp_path / "out", "--quiet"], capsys)
    errors = [row for row in err if row.startswith("error:")]
    assert status == 1 and len(errors) == 1
    assert f"{path}: line {len(text.splitlines()) + 1}: key 'lidar_pose' given twice in one mapping" in errors[0]
    reader = DatasetReader(tmp_path / "out")
    ids = [set(reader.scene(OPV2V_SCENE).labels(i)[1].boxes.ids.tolist()) for i in range(3)]
    assert "9001" in ids[0] and "9001" not in ids[1] and "9001" in ids[2]  # only the RSU's view of frame 71


def test_dair_key_given_twice_in_a_label_object_is_an_error(dair, tmp_path: Path, capsys) -> None:
    # json.load keeps the last of two keys without a word.
    src, clean = dair
    path = next((src / "cooperative" / "label_world").glob("*.json"))
    text = path.read_text()
    assert '"type": ' in text
    replace(path, text.replace('"type": ', '"type": "bus", "type": ', 1).encode())
    status, err, _ = run(["convert", "dair-v2x", src, tmp_path / "out", "--quiet"], capsys)
    assert status == 1 and any(f"{path}: key 'type' given twice in one object" in row for row in err)


@pytest.mark.parametrize("command", ["generate", "study"])
def test_config_key_given_twice_or_a_fifo_is_one_line(tmp_path: Path, capsys, command) -> None:
    # A repeated 'frames:' kept the last silently; a FIFO in place of the file hung.
    study = Path(__file__).resolve().parent / "studies" / "small_study.yaml"
    text = study.read_text() if command == "study" else "scenes: 1\nframes: 2\n"
    path = tmp_path / "config.yaml"
    path.write_text(text + "frames: 3\n")
    argv = (["generate", path, tmp_path / "out", "--quiet"] if command == "generate"
            else ["study", "run", path, tmp_path / "out", "--quiet"])
    status, err, _ = run(argv, capsys)
    assert status == 1 and len(err) == 1 and err[0].startswith(f"avdata: error: {path}: line ")
    assert "key 'frames' given twice in one mapping" in err[0]
    path.unlink()
    os.mkfifo(path)
    status, err, _ = run(argv, capsys)
    assert status == 1 and err == [f"avdata: error: {path}: expected a regular file, got a FIFO"]
    assert not (tmp_path / "out").exists()


def test_kitti_crlf_and_bom_text_files(tmp_path: Path, capsys) -> None:
    # CRLF is valid KITTI: the devkit reads these files with fscanf/sscanf, for which '\r' is white space; the
    # conversion is the same as with LF. A UTF-8 BOM is not KITTI (the devkit reads it as part of the first
    # token): the first line's class or key is then unknown and that line is reported.
    from tests.converters.test_kitti_bad_corpus import object_copy

    src = object_copy(tmp_path / "src")
    assert main(["convert", "kitti-object", str(src), str(tmp_path / "clean"), "--quiet"]) == 0
    for folder in ("label_2", "calib"):
        for path in sorted((src / "training" / folder).glob("*.txt")):
            replace(path, path.resolve().read_bytes().replace(b"\n", b"\r\n"))
    capsys.readouterr()
    status, err, _ = run(["convert", "kitti-object", src, tmp_path / "crlf", "--quiet"], capsys)
    assert status == 0 and not err
    clean, crlf = DatasetReader(tmp_path / "clean").objects(), DatasetReader(tmp_path / "crlf").objects()
    assert crlf.to_pandas().equals(clean.to_pandas())  # (NaN velocities compare equal here)
    label = src / "training" / "label_2" / "000001.txt"
    replace(label, b"\xef\xbb\xbf" + label.read_bytes())
    status, err, _ = run(["convert", "kitti-object", src, tmp_path / "bom", "--quiet"], capsys)
    assert status == 1 and len([row for row in err if row.startswith("error:")]) == 1
    assert any(f"{label}" in row and "line 1" in row for row in err)
    assert sum(n_objects(tmp_path / "bom").values()) == sum(n_objects(tmp_path / "clean").values()) - 1


@pytest.mark.parametrize(("table", "field", "value", "lost"), [
    ("sample_annotation", "size", [1e30, 2.0, 1.5], "object"),
    ("sample_annotation", "translation", [2e7, 0.0, 0.0], "object"),
    ("ego_pose", "translation", [1e12, 0.0, 0.0], "pose"),
])
def test_nuscenes_absurd_row_values_cost_that_row(tmp_path: Path, capsys, table, field, value, lost) -> None:
    # A 1e30 m box was written into the scene; a 1e12 m ego pose now reaches the writer's limit: both cost the
    # row (an annotation; the sample_data of a pose), not the scene.
    from tests.converters.test_nuscenes_bad_input import VERSION, lyft_copy

    src = lyft_copy(tmp_path / "src")
    assert main(["convert", "nuscenes", str(src), str(tmp_path / "clean"), "--quiet"]) == 0
    capsys.readouterr()
    path = src / VERSION / f"{table}.json"
    rows = json.loads(path.read_text())
    rows[0][field] = value
    path.write_text(json.dumps(rows))
    status, err, _ = run(["convert", "nuscenes", src, tmp_path / "dst", "--quiet"], capsys)
    assert status == 1 and any(f"{table} {rows[0]['token']}: field '{field}': expected 3 finite numbers" in line
                               for line in err)
    clean = DatasetReader(tmp_path / "clean")
    got = DatasetReader(tmp_path / "dst")
    assert got.frames().num_rows == clean.frames().num_rows
    assert got.objects().num_rows == clean.objects().num_rows - (1 if lost == "object" else 0)


def test_writer_refuses_visibility_of_a_frame_that_does_not_exist(tmp_path: Path) -> None:
    # Such rows were indexed with timestamp_ns -1 (no frame of that index); a repeat made two rows per object.
    from avdata.errors import InputError
    from avdata.schema import SceneWriter, VisibilityLabels

    visibility = VisibilityLabels(object_ids=np.array(["a"]), in_fov=np.array([True]), n_points=np.array([3]))
    scene = SceneWriter(tmp_path / "s.mcap", "s").__enter__()
    scene.add_frame(0, 100, _boxes())
    scene.add_visibility("ego/lidar", 0, 100, visibility)
    with pytest.raises(InputError, match=r"/ego/lidar/visibility: expected visibility of a written frame or the "
                                         r"next one \(0 \.\. 1\), once per sensor, got frame 0 again"):
        scene.add_visibility("ego/lidar", 0, 100, visibility)
    with pytest.raises(InputError, match=r"got frame 5$"):
        scene.add_visibility("ego/lidar", 5, 100, visibility)
    scene.add_visibility("ego/lidar", 1, 200, visibility)  # ahead of its frame: allowed ...
    with pytest.raises(InputError, match="visibility of frame 1, but only 1 frames were written"):
        scene.__exit__(None, None, None)  # ... but the frame must come
    assert not (tmp_path / "s.mcap").exists() and not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize(("table", "column", "value", "message"), [
    ("annotations.feather", "length_m", 2000.0, "row 0: column 'length_m': expected a finite positive size <= 1000 m, "
                                                "got 2000.0; row dropped"),
    ("annotations.feather", "tx_m", -3e7, "row 0: column 'tx_m': expected a finite number within 1e+07, got -30000000.0; "
                                          "row dropped"),
    ("calibration/intrinsics.feather", "k2", 1e30, "row 0 (ring_front_center): column 'k2': expected a finite number within "
                                                     "1e+06, got 1e+30; that camera is skipped"),
])
def test_av2_absurd_values_are_refused(tmp_path: Path, capsys, table, column, value, message) -> None:
    # Each was written into the scene as read (a 2 km cuboid, a distortion coefficient of 1e30).
    from tests.converters.test_argoverse2 import LOG
    from tests.converters.test_argoverse2_bad_input import layout

    src = layout(tmp_path / "src")
    path = src / "val" / LOG / table
    data = pa.feather.read_table(path)
    values = data.column(column).to_numpy().copy()
    values[0] = value
    data = data.set_column(data.column_names.index(column), column, pa.array(values))
    replace(path)
    pa.feather.write_feather(data, path)
    status, err, _ = run(["convert", "argoverse2", src, tmp_path / "dst", "--quiet"], capsys)
    assert status == 1 and any(str(path) in line and message in line for line in err), err


@pytest.mark.parametrize("damage", ["folder", "loop"])
def test_kitti_tracking_image_that_is_no_file_costs_that_image(tmp_path: Path, capsys, damage) -> None:
    # It was counted as missing (a warning, "partial download?") and the frame written without it, exit 0.
    from tests.converters.test_kitti_bad_corpus import tracking_copy

    src = tracking_copy(tmp_path / "src")
    path = replace(src / "training" / "image_02" / "0001" / "000001.png")
    if damage == "folder":
        path.mkdir()
    else:
        os.symlink(path.name, path)
    status, err, _ = run(["convert", "kitti-tracking", src, tmp_path / "dst", "--quiet"], capsys)
    assert status == 1 and any(f"{path}: expected a file, got a folder, a broken link or a special file; frame 1 "
                               "written without it" in line for line in err)
    reader = DatasetReader(tmp_path / "dst")
    assert reader.frames().num_rows == 447  # the frame stands without that image
    info = reader.scene("training_0001").frame_infos()[1]
    assert info.timestamp_ns == 100_000_000 and "ego/cam2" not in info.sensor_timestamps_ns


def test_yaml_with_an_8_mb_line_or_a_5000_digit_integer_is_quick_and_one_line(opv2v, tmp_path: Path, capsys) -> None:
    # PyYAML's pure-Python scanner took ~35 s for one 8 MB line (libyaml: < 1 s); int() refuses more than 4300
    # digits with a ValueError that was a traceback.
    import time

    src, _ = opv2v
    scenario = _opv2v_copy(src, tmp_path / "src")
    path = scenario / "-1" / "000071.yaml"
    replace(path, path.read_bytes() + b"extra_digits: " + b"1" * (8 << 20) + b"\n")
    start = time.monotonic()
    status, err, _ = run(["convert", "opv2v", tmp_path / "src", tmp_path / "out", "--quiet"], capsys)
    assert time.monotonic() - start < 20
    assert status == 1 and any(f"{path}: Exceeds the limit (4300 digits)" in line for line in err)
    config = tmp_path / "scenario.yaml"
    config.write_text("scenes: 1\nframes: " + "2" * 5000 + "\n")
    status, err, _ = run(["generate", config, tmp_path / "gen", "--quiet"], capsys)
    assert status == 1 and len(err) == 1 and err[0].startswith(f"avdata: error: {config}: Exceeds the limit (4300 digits)")


def test_kitti_tracking_png_with_one_flipped_bit_costs_that_image(tmp_path: Path, capsys) -> None:
    # Header and trailer intact: the first pass passed it and the damaged image was stored without a word;
    # earlier, a damaged image cost its whole frame (labels, scan and pose too).
    from tests.converters.test_kitti_bad_corpus import tracking_copy

    src = tracking_copy(tmp_path / "src")
    path = src / "training" / "image_02" / "0001" / "000000.png"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x08
    replace(path, bytes(data))
    status, err, _ = run(["convert", "kitti-tracking", src, tmp_path / "dst", "--quiet"], capsys)
    errors = [line for line in err if line.startswith("error:")]
    assert status == 1 and len(errors) == 1
    assert f"{path}: chunk b'IDAT' at byte" in errors[0] and "CRC-32 does not match (damaged bytes); frame 0 written " \
                                                               "without it" in errors[0]
    reader = DatasetReader(tmp_path / "dst")
    assert reader.frames().num_rows == 447
    assert "ego/cam2" not in reader.scene("training_0001").frame_infos()[0].sensor_timestamps_ns
    assert run(["validate", tmp_path / "dst"], capsys)[0] == 0
