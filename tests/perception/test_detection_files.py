"""Detection readers on AB3DMOT's real PointRCNN CSV, KITTI result files and hostile copies."""

from __future__ import annotations

import os

import numpy as np
import pytest

from avdata.errors import InputError
from avdata.perception.detection_files import camera_boxes, read_detections, upright
from tests.realdata import REALDATA

DETECTIONS = REALDATA / "kitti_tracking_detections"


def test_ab3dmot_csv_all_classes_merged_per_frame():
    found = read_detections(DETECTIONS, "ab3dmot")
    assert found.problems == []
    assert sum(len(d) for frames in found.scenes.values() for d in frames.values()) == 10660  # = lines of the 9 files
    first = found.scenes["0001"][0]
    assert first.boxes.frame == "ego/cam0" and first.timestamp_ns == 0
    # 0001.txt line 1: 0,2,786.7492,180.1760,1241.0000,374.0000,12.2286,1.5206,1.6824,4.4501,2.9312,1.6089,6.4281,...
    row = int(np.flatnonzero(np.isclose(first.extras["score_raw"], 12.2286))[0])
    assert first.boxes.classes[row] == "car"
    np.testing.assert_allclose(first.extras["box2d_px"][row], [786.7492, 180.1760, 1241.0, 374.0])
    assert first.scores[row] == pytest.approx(1 / (1 + np.exp(-12.2286)))
    np.testing.assert_allclose(first.boxes.size_lwh[row], [4.4501, 1.6824, 1.5206])
    np.testing.assert_allclose(first.boxes.center[row], [2.9312, 1.6089 - 1.5206 / 2, 6.4281])


def test_upright_view_round_trips_kitti_geometry():
    dets = read_detections(DETECTIONS / "pointrcnn_Car_val" / "0006.txt", "ab3dmot").scenes["0006"][0]
    flu = upright(dets)
    np.testing.assert_allclose(flu.boxes.rotation_matrix()[:, :, 2], np.tile([0.0, 0.0, 1.0], (len(flu), 1)), atol=1e-12)
    hwl, bottom, ry = camera_boxes(flu.boxes)
    np.testing.assert_allclose(hwl, dets.boxes.size_lwh[:, [2, 1, 0]], atol=1e-9)
    np.testing.assert_allclose(bottom, dets.boxes.center + [0, 1, 0] * dets.boxes.size_lwh[:, 2:3] / 2, atol=1e-9)
    assert np.all(np.abs(ry) <= np.pi)


def test_kitti_tracking_labels_read_without_scores_dontcare_skipped():
    found = read_detections(DETECTIONS / "label_02" / "0006.txt", "kitti-tracking")
    assert found.problems == []
    assert set(found.scenes) == {"0006"}
    assert all(np.all(d.scores == 1.0) for d in found.scenes["0006"].values())


def test_hostile_lines_cost_only_their_record(tmp_path):
    lines = (DETECTIONS / "pointrcnn_Car_val" / "0006.txt").read_text().splitlines()[:5]
    bad = list(lines)
    bad[1] = bad[1].replace(bad[1].split(",")[7], "abc", 1)  # h
    bad[2] = "0,2,1,2"
    bad[3] = bad[3].replace(",2,", ",9,", 1)  # class code
    (tmp_path / "0006.txt").write_text("\n".join(bad) + "\n")
    found = read_detections(tmp_path, "ab3dmot")
    assert sum(len(d) for d in found.scenes["0006"].values()) == 2
    assert len(found.problems) == 3
    assert found.problems[0] == f"{tmp_path / '0006.txt'}: line 2: field h: expected a number, got 'abc'"
    assert "line 3: expected 15 fields, got 4" in found.problems[1]
    assert "line 4: field type: expected 1, 2 or 3, got '9'" in found.problems[2]


def test_probability_out_of_range_is_refused_per_record(tmp_path):
    (tmp_path / "res").mkdir()
    line = "Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 1.0 1.5 20.0 -1.5 {}"
    (tmp_path / "res" / "000000.txt").write_text(line.format(0.9) + "\n" + line.format(3.2) + "\n")
    found = read_detections(tmp_path / "res", "kitti-object")
    assert len(found.scenes["res"][0]) == 1
    assert found.problems == [f"{tmp_path / 'res'}: scene res frame 0: field score: expected a probability in [0, 1], got 3.2"]
    with pytest.raises(InputError, match="expected a format"):
        read_detections(tmp_path, "csv")


def test_unified_table_in_world_with_the_datasets_times(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    from avdata.demo import write_demo
    from avdata.eval.unified import DETECTION_COLUMNS
    from avdata.schema.dataset import DatasetReader

    root = write_demo(tmp_path / "demo")
    reader = DatasetReader(root)
    table = reader.objects().select(list(DETECTION_COLUMNS))
    scores = np.full(table.num_rows, 0.8)
    scores[-1] = 1.5
    pq.write_table(table.append_column("score", pa.array(scores)), tmp_path / "dets.parquet")
    found = read_detections(tmp_path / "dets.parquet", "unified", dataset=root)
    assert found.problems == [f"{tmp_path / 'dets.parquet'}: row {table.num_rows - 1}: field score: expected a "
                              "probability in [0, 1], got 1.5"]
    assert sum(len(d) for frames in found.scenes.values() for d in frames.values()) == table.num_rows - 1
    frames = reader.frames().to_pydict()
    scene, first = frames["scene"][0], frames["frame_index"][0]
    dets = found.scenes[scene][first]
    assert dets.boxes.frame == "world" and dets.timestamp_ns == frames["timestamp_ns"][0]
    with pytest.raises(InputError, match="needs the dataset"):
        read_detections(tmp_path / "dets.parquet", "unified")


@pytest.mark.parametrize(("field", "value", "problem"), [
    # Each was a ValueError traceback of `avdata track` (isdigit() passed them, int() refused them).
    (0, "--1", "field frame: expected an integer >= 0 below 2^31, got '--1'"),
    (0, "\u00b2", "field frame: expected an integer >= 0 below 2^31, got '\u00b2'"),
    (1, "--2", "field type: expected 1, 2 or 3, got '--2'"),
    # Each was taken silently: an Arabic-Indic 3 as frame 3, '1_000' as 1000 (a C reader stops at '_'), a
    # 23-digit frame wrapped to another int64, a written 'nan' score as certain (1.0), boxes of 1e300 m.
    (0, "\u0663", "field frame: expected an integer >= 0 below 2^31, got '\u0663'"),
    (0, "9" * 23, f"field frame: expected an integer >= 0 below 2^31, got '{'9' * 23}'"),
    (2, "1_000", "field x1: expected a number, got '1_000'"),
    (6, "nan", "field score: expected a finite number, got 'nan'"),
    (7, "1e300", "field h: expected a size > 0 and <= 1000 m, got '1e300'"),
    (10, "-2e7", "field x: expected a value within 1e+07, got '-2e7'"),
    # AB3DMOT's type is a class code: any other text was taken as a class name (a detection of class 'other').
    (1, "x", "field type: expected 1, 2 or 3, got 'x'"),
    # An angle of 1e308 rad gave a box of arbitrary heading without a word.
    (13, "1e308", "field rotation_y: expected a value within 12.5664, got '1e308'"),
    (14, "-13", "field alpha: expected a value within 12.5664, got '-13'"),
])
def test_damaged_csv_field_costs_its_record_with_one_line(tmp_path, field, value, problem):
    lines = (DETECTIONS / "pointrcnn_Car_val" / "0006.txt").read_text().splitlines()[:5]
    fields = lines[2].split(",")
    fields[field] = value
    lines[2] = ",".join(fields)
    (tmp_path / "0006.txt").write_text("\n".join(lines) + "\n")
    found = read_detections(tmp_path, "ab3dmot")
    assert found.problems == [f"{tmp_path / '0006.txt'}: line 3: {problem}"]
    assert sum(len(d) for d in found.scenes["0006"].values()) == 4


def test_kitti_object_result_named_by_a_non_ascii_digit_is_a_problem(tmp_path):
    # '²'.isdigit() is true and int('²') a ValueError: a traceback.
    (tmp_path / "res").mkdir()
    line = "Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 1.0 1.5 20.0 -1.5 0.9\n"
    (tmp_path / "res" / "000000.txt").write_text(line)
    (tmp_path / "res" / "00000\u00b2.txt").write_text(line)
    found = read_detections(tmp_path / "res", "kitti-object")
    assert list(found.scenes["res"]) == [0]
    assert found.problems == [f"{tmp_path / 'res' / '00000².txt'}: file name: expected <frame>.txt with a frame number, "
                              f"got '00000².txt'"]


def test_detection_file_that_is_a_fifo_is_refused_not_waited_on(tmp_path):
    # read_text() on a FIFO waits for a writer forever: `avdata track` hung.
    os.mkfifo(tmp_path / "0006.txt")
    with pytest.raises(InputError, match="0006.txt: expected a regular file, got a FIFO"):
        read_detections(tmp_path, "ab3dmot")


@pytest.mark.parametrize(("field", "value", "problem"), [
    (1, "x", "field truncated: expected a number, got 'x'"), (2, "nan", "field occluded: expected a finite number, got 'nan'")])
def test_kitti_result_columns_that_are_not_kept_are_still_numbers(tmp_path, field, value, problem):
    # Truncation and occlusion were not read at all: any text there passed (the devkit's fscanf refuses it).
    (tmp_path / "res").mkdir()
    fields = "Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 1.0 1.5 20.0 -1.5 0.9".split()
    fields[field] = value
    (tmp_path / "res" / "000000.txt").write_text("Car 0 0 -1.5 10 20 30 40 1.5 1.6 4.0 1.0 1.5 20.0 -1.5 0.8\n"
                                                 + " ".join(fields) + "\n")
    found = read_detections(tmp_path / "res", "kitti-object")
    assert found.problems == [f"{tmp_path / 'res' / '000000.txt'}: line 2: {problem}"]
    assert len(found.scenes["res"][0]) == 1
