"""Bad and partial Argoverse 2 input: each problem is one line naming the file (and row / column),
it costs only the record it is in, the rest converts, the exit status is non-zero, no traceback.

Layouts are the real val log symlinked file by file (tests/converters/test_argoverse2.py), with
annotations.feather cut to the real rows of the two sweeps the sample ships so that a clean log
converts without errors, and one file broken per case. A second log is the same files under
another log id.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.argoverse2 import LIDAR_FRAME, Argoverse2Converter
from avdata.converters.base import StrictError
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.converters.test_argoverse2 import LOG, REAL_LOG, SWEEPS, link_log

OTHER = "00000000-0000-4000-8000-000000000000"
REPO = Path(__file__).resolve().parents[2]


def layout(root: Path, logs: tuple[str, ...] = (LOG,)) -> Path:
    """``root/val/<log>`` for each log id: the real files, annotations cut to the shipped sweeps."""
    table = feather.read_table(REAL_LOG / "annotations.feather")
    table = table.filter(np.isin(table.column("timestamp_ns").to_numpy(), SWEEPS))
    for log in logs:
        log_dir = root / "val" / log
        link_log(REAL_LOG, log_dir)
        (log_dir / "annotations.feather").unlink()
        feather.write_feather(table, log_dir / "annotations.feather")
    return root


def replace(path: Path, data: bytes) -> Path:
    path.unlink()
    path.write_bytes(data)
    return path


def convert(src: Path, dst: Path, strict: bool = False):
    return valid(run_conversion(Argoverse2Converter(ConvertConfig(src=src, dst=dst, quiet=True, strict=strict))), dst)


def valid(result, dst: Path):
    """``result``, after checking that what the conversion wrote passes ``avdata validate`` (issue 34)."""
    if (dst / "avdata.json").is_file():
        assert validate_dataset(dst) == []
    return result


def errors_of(result) -> list:
    return [p for p in result.problems if p.severity == "error"]


def n_objects(dst: Path) -> int:
    return DatasetReader(dst).objects().num_rows


def test_clean_log_converts_without_problems(tmp_path):
    result = convert(layout(tmp_path / "src"), tmp_path / "out")
    assert result.problems == [] and result.written == [LOG]
    expected = feather.read_table(tmp_path / "src" / "val" / LOG / "annotations.feather").num_rows
    assert expected > 100 and n_objects(tmp_path / "out") == expected
    again = convert(tmp_path / "src", tmp_path / "out")
    assert again.complete == [LOG] and again.written == []


def test_truncated_sweep_costs_its_points_only(tmp_path):
    src = layout(tmp_path / "src")
    sweep = src / "val" / LOG / "sensors" / "lidar" / f"{SWEEPS[1]}.feather"
    replace(sweep, (REAL_LOG / "sensors" / "lidar" / sweep.name).read_bytes()[:300_000])
    result = convert(src, tmp_path / "out")
    errors = errors_of(result)
    assert len(errors) == 1 and errors[0].file == str(sweep)
    assert "unreadable feather file" in errors[0].message and "keeps its labels" in errors[0].message
    reader = DatasetReader(tmp_path / "out")
    scene = reader.scene(LOG)
    assert list(scene.times(f"/{LIDAR_FRAME}/points")) == [SWEEPS[0]]
    frames = reader.frames()
    assert frames.num_rows == 2
    labels_per_frame = [len(scene.labels(i)[1]) for i in range(2)]
    assert all(n > 0 for n in labels_per_frame)


def test_missing_sweep_is_named(tmp_path):
    src = layout(tmp_path / "src")
    (src / "val" / LOG / "sensors" / "lidar" / f"{SWEEPS[0]}.feather").unlink()
    result = convert(src, tmp_path / "out")
    errors = errors_of(result)
    assert len(errors) == 1
    assert errors[0].file.endswith(f"sensors/lidar/{SWEEPS[0]}.feather") and "1 missing" in errors[0].message
    assert DatasetReader(tmp_path / "out").frames().num_rows == 2


def test_sweep_with_wrong_column_type_is_named(tmp_path):
    src = layout(tmp_path / "src")
    sweep = src / "val" / LOG / "sensors" / "lidar" / f"{SWEEPS[0]}.feather"
    table = feather.read_table(REAL_LOG / "sensors" / "lidar" / sweep.name)
    table = table.set_column(0, "x", table.column("x").cast(pa.float64()))
    sweep.unlink()
    feather.write_feather(table, sweep)
    errors = errors_of(convert(src, tmp_path / "out"))
    assert len(errors) == 1 and errors[0].file == str(sweep)
    assert "column 'x': expected float16, got double" in errors[0].message


def test_annotation_row_with_nan_costs_that_row(tmp_path):
    src = layout(tmp_path / "src")
    path = src / "val" / LOG / "annotations.feather"
    table = feather.read_table(path)
    tx = table.column("tx_m").to_numpy().copy()
    tx[5] = np.nan
    table = table.set_column(table.column_names.index("tx_m"), "tx_m", pa.array(tx))
    replace(path, b"")
    feather.write_feather(table, path)
    result = convert(src, tmp_path / "out")
    errors = errors_of(result)
    assert len(errors) == 1 and errors[0].file == str(path)
    assert "row 5: column 'tx_m': expected a finite number within 1e+07, got nan; row dropped" == errors[0].message
    assert n_objects(tmp_path / "out") == table.num_rows - 1


def test_truncated_annotations_leave_frames_unannotated(tmp_path):
    src = layout(tmp_path / "src")
    path = src / "val" / LOG / "annotations.feather"
    replace(path, path.read_bytes()[:4000])
    result = convert(src, tmp_path / "out")
    errors = errors_of(result)
    assert len(errors) == 1 and errors[0].file == str(path) and "unreadable feather file" in errors[0].message
    frames = DatasetReader(tmp_path / "out").frames()
    assert frames.num_rows == 2 and not any(frames.column("annotated").to_pylist())


def test_log_missing_its_poses_fails_alone_and_the_cli_says_so_in_one_line(tmp_path):
    src = layout(tmp_path / "src", logs=(LOG, OTHER))
    poses = src / "val" / OTHER / "city_SE3_egovehicle.feather"
    poses.unlink()
    result = convert(src, tmp_path / "out")
    assert result.written == [LOG] and result.failed == [OTHER]
    assert len(errors_of(result)) == 1 and str(poses) in errors_of(result)[0].message
    proc = subprocess.run(
        [sys.executable, "-m", "avdata.cli", "convert", "argoverse2", str(src), str(tmp_path / "cli"), "--quiet"],
        capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=300,
    )
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {OTHER}:") and str(poses) in lines[0]
    assert DatasetReader(tmp_path / "cli").scenes == [LOG]


def test_truncated_pose_table_and_missing_intrinsics(tmp_path):
    src = layout(tmp_path / "src", logs=(LOG, OTHER))
    poses = src / "val" / OTHER / "city_SE3_egovehicle.feather"
    replace(poses, (REAL_LOG / "city_SE3_egovehicle.feather").read_bytes()[:10_000])
    intrinsics = src / "val" / LOG / "calibration" / "intrinsics.feather"
    intrinsics.unlink()
    result = convert(src, tmp_path / "out")
    errors = errors_of(result)
    assert result.written == [LOG] and result.failed == [OTHER]
    assert len(errors) == 2
    assert any(e.file == str(intrinsics) and "expected a feather file, got none; cameras skipped" in e.message
               for e in errors)
    assert any(str(poses) in e.message and "unreadable feather file" in e.message for e in errors)
    scene = DatasetReader(tmp_path / "out").scene(LOG)
    assert not [s for s, spec in scene.sensors().items() if spec.get("kind") == "camera"]


def test_damaged_image_is_skipped_and_named(tmp_path):
    src = layout(tmp_path / "src")
    folder = src / "val" / LOG / "sensors" / "cameras" / "ring_front_center"
    folder.mkdir(parents=True)
    good, bad = folder / f"{SWEEPS[0] - 2407723}.jpg", folder / f"{SWEEPS[1] - 2603730}.jpg"
    ok, jpeg = cv2.imencode(".jpg", np.zeros((32, 48, 3), np.uint8))
    assert ok
    good.write_bytes(jpeg.tobytes())
    bad.write_bytes(b"<html>not an image</html>")
    result = convert(src, tmp_path / "out")
    errors = errors_of(result)
    assert len(errors) == 1 and errors[0].file == str(bad)
    assert errors[0].message == "expected a JPEG file (bytes ff d8), got 3c 68 74 6d 6c 3e 6e 6f; skipped"
    scene = DatasetReader(tmp_path / "out").scene(LOG)
    assert list(scene.times("/ego/ring_front_center/image")) == [SWEEPS[0] - 2407723]
    # A download cut short keeps the JPEG's first bytes: only the missing end marker shows it.
    bad.write_bytes(jpeg.tobytes()[:-2])
    errors = errors_of(convert(src, tmp_path / "out-cut"))
    last = jpeg.tobytes()[-4:-2].hex(" ")
    assert [e.message for e in errors] == [
        f"expected the file to end with the EOI marker ff d9, got {last} (truncated file?); skipped"]


def test_folder_where_an_image_should_be_is_skipped_and_named(tmp_path):
    src = layout(tmp_path / "src")
    folder = src / "val" / LOG / "sensors" / "cameras" / "ring_front_center"
    folder.mkdir(parents=True)
    ok, jpeg = cv2.imencode(".jpg", np.zeros((32, 48, 3), np.uint8))
    (folder / f"{SWEEPS[0] - 2407723}.jpg").write_bytes(jpeg.tobytes())
    (folder / f"{SWEEPS[1] - 2603730}.jpg").mkdir()  # was an IsADirectoryError traceback
    result = convert(src, tmp_path / "out")
    (error,) = errors_of(result)
    assert error.file == str(folder / f"{SWEEPS[1] - 2603730}.jpg")
    assert error.message == "cannot read (Is a directory); skipped"
    assert list(DatasetReader(tmp_path / "out").scene(LOG).times("/ego/ring_front_center/image")) == [
        SWEEPS[0] - 2407723]


def test_root_without_splits_and_strict_mode(tmp_path):
    (tmp_path / "empty").mkdir()
    from avdata.errors import InputError

    with pytest.raises(InputError, match="expected an Argoverse 2 sensor root"):
        convert(tmp_path / "empty", tmp_path / "out0")
    src = layout(tmp_path / "src")
    (src / "val" / LOG / "sensors" / "lidar" / f"{SWEEPS[0]}.feather").unlink()
    with pytest.raises(StrictError, match=f"{SWEEPS[0]}.feather"):
        convert(src, tmp_path / "out", strict=True)
    assert not list((tmp_path / "out" / "scenes").glob("*.mcap"))


def test_annotations_without_rows_are_an_error(tmp_path):
    # A val/train log always has cuboids: an annotations table of zero rows lost every label, exit 0.
    src = layout(tmp_path / "src")
    path = src / "val" / LOG / "annotations.feather"
    table = feather.read_table(path).slice(0, 0)
    replace(path, b"")
    feather.write_feather(table, path)
    result = convert(src, tmp_path / "out")
    errors = errors_of(result)
    assert [(e.file, e.message) for e in errors] == [
        (str(path), "expected the cuboids of an annotated log, got 0 rows; frames unannotated")]
    frames = DatasetReader(tmp_path / "out").frames()
    assert frames.num_rows == 2 and not any(frames.column("annotated").to_pylist())


def rewrite(path: Path, table: pa.Table) -> None:
    replace(path, b"")
    feather.write_feather(table, path)


def test_null_category_costs_that_cuboid_only(tmp_path):
    # One null category lost all cuboids of the log.
    src = layout(tmp_path / "src")
    path = src / "val" / LOG / "annotations.feather"
    table = feather.read_table(path)
    category = table.column("category").to_pylist()
    category[7] = None
    rewrite(path, table.set_column(table.column_names.index("category"), "category", pa.array(category, pa.string())))
    result = convert(src, tmp_path / "out")
    assert [(e.file, e.message) for e in errors_of(result)] == [
        (str(path), "row 7: column 'category': expected a value, got null; row dropped")]
    assert n_objects(tmp_path / "out") == table.num_rows - 1


def test_negative_timestamp_costs_that_row_only(tmp_path):
    src = layout(tmp_path / "src")
    path = src / "val" / LOG / "annotations.feather"
    table = feather.read_table(path)
    times = table.column("timestamp_ns").to_numpy().copy()
    times[3] = -5
    rewrite(path, table.set_column(table.column_names.index("timestamp_ns"), "timestamp_ns", pa.array(times)))
    result = convert(src, tmp_path / "out")
    assert [(e.file, e.message) for e in errors_of(result)] == [
        (str(path), "row 3: column 'timestamp_ns': expected a time >= 0, got -5; row dropped")]
    assert result.written == [LOG] and n_objects(tmp_path / "out") == table.num_rows - 1


def test_bad_intrinsics_row_costs_that_camera_only(tmp_path):
    src = layout(tmp_path / "src")
    path = src / "val" / LOG / "calibration" / "intrinsics.feather"
    table = feather.read_table(path)
    names = table.column("sensor_name").to_pylist()
    fx = table.column("fx_px").to_numpy().copy()
    fx[names.index("ring_side_left")] = -1.0
    rewrite(path, table.set_column(table.column_names.index("fx_px"), "fx_px", pa.array(fx)))
    result = convert(src, tmp_path / "out")
    row = names.index("ring_side_left")
    assert (str(path), f"row {row} (ring_side_left): column 'fx_px': expected a positive value, got -1.0; that camera "
            "is skipped") in [(e.file, e.message) for e in errors_of(result)]
    sensors = DatasetReader(tmp_path / "out").scene(LOG).sensors()
    cameras = {name for name, spec in sensors.items() if spec.get("kind") == "camera"}
    assert "ego/ring_side_left" not in cameras and len(cameras) == len(names) - 1


def test_duplicated_sensor_pose_is_an_error_and_costs_that_sensor(tmp_path):
    # The later row of a sensor given twice won silently and moved the camera from 1.6 m to 9 m.
    src = layout(tmp_path / "src")
    path = src / "val" / LOG / "calibration" / "egovehicle_SE3_sensor.feather"
    table = feather.read_table(path)
    row = table.column("sensor_name").to_pylist().index("ring_front_center")
    moved = table.slice(row, 1)
    moved = moved.set_column(moved.column_names.index("tx_m"), "tx_m", pa.array([9.0]))
    rewrite(path, pa.concat_tables([table, moved]))
    result = convert(src, tmp_path / "out")
    messages = [e.message for e in errors_of(result) if e.file == str(path)]
    assert messages == ["column 'sensor_name': 'ring_front_center' given 2 times; that sensor is not converted"]
    sensors = DatasetReader(tmp_path / "out").scene(LOG).sensors()
    assert "ego/ring_front_center" not in sensors and "ego/ring_side_left" in sensors


def test_sweep_with_a_flipped_exponent_bit_costs_that_sweep(tmp_path):
    # AV2 sweeps are uncompressed feather (no checksum): a flipped exponent bit in a float16 coordinate
    # turns it into an infinity, which was stored as is.
    src = layout(tmp_path / "src")
    sweep = src / "val" / LOG / "sensors" / "lidar" / f"{SWEEPS[0]}.feather"
    raw = bytearray((REAL_LOG / "sensors" / "lidar" / sweep.name).read_bytes())
    y = feather.read_table(REAL_LOG / "sensors" / "lidar" / sweep.name).column("y").chunk(0).to_numpy()
    start = raw.find(y[:64].tobytes())
    assert start > 0 and raw.find(y[:64].tobytes(), start + 1) < 0
    point = 17
    raw[start + 2 * point : start + 2 * point + 2] = np.float16(np.inf).tobytes()  # exponent bits all set
    sweep.unlink()
    sweep.write_bytes(bytes(raw))
    result = convert(src, tmp_path / "out")
    errors = errors_of(result)
    assert len(errors) == 1 and errors[0].file == str(sweep)
    assert errors[0].message == (f"point {point}, y: expected a finite value within +-1e+07, got inf "
                                 "(damaged bytes?); the frame keeps its labels, without points")
    scene = DatasetReader(tmp_path / "out").scene(LOG)
    assert SWEEPS[0] not in list(scene.times(f"/{LIDAR_FRAME}/points"))


def test_null_in_an_ego_pose_costs_that_pose_only(tmp_path):
    # A null in city_SE3_egovehicle costs that pose row: one line naming the file, row, column and value;
    # every frame and cuboid is still written (the sweeps' own poses are intact).
    src = layout(tmp_path / "src")
    path = src / "val" / LOG / "city_SE3_egovehicle.feather"
    table = feather.read_table(path)
    times = table.column("timestamp_ns").to_numpy()
    row = int(np.flatnonzero(~np.isin(times, SWEEPS))[-1])
    tx = table.column("tx_m").to_pylist()
    tx[row] = None
    rewrite(path, table.set_column(table.column_names.index("tx_m"), "tx_m", pa.array(tx, pa.float64())))
    result = convert(src, tmp_path / "out")
    assert [(e.file, e.message) for e in errors_of(result)] == [
        (str(path), f"row {row}: column 'tx_m': expected a value, got null; row dropped; frames at its time lose what "
                    "needs the ego pose")]
    assert result.written == [LOG]
    clean = convert(layout(tmp_path / "clean"), tmp_path / "clean_out")
    assert clean.problems == []
    scene, clean_scene = DatasetReader(tmp_path / "out").scene(LOG), DatasetReader(tmp_path / "clean_out").scene(LOG)
    assert n_objects(tmp_path / "out") == n_objects(tmp_path / "clean_out")
    assert len(scene.times("/tf")) == len(clean_scene.times("/tf")) - 1


def test_a_sweep_named_beyond_int64_nanoseconds_is_a_stray(tmp_path):
    # Its name was an OverflowError traceback that lost the whole run.
    src = layout(tmp_path / "src")
    sweeps = src / "val" / LOG / "sensors" / "lidar"
    stray = sweeps / f"{10**30}.feather"
    os.symlink(os.readlink(sweeps / f"{SWEEPS[0]}.feather"), stray)
    result = convert(src, tmp_path / "out")
    assert errors_of(result) == [] and result.written == [LOG]
    assert [(p.file, p.message) for p in result.problems] == [(str(stray), "not a <timestamp_ns>.feather sweep; ignored")]
    assert list(DatasetReader(tmp_path / "out").scene(LOG).times(f"/{LIDAR_FRAME}/points")) == list(SWEEPS)


def test_a_log_folder_whose_name_cannot_name_a_scene_fails_alone(tmp_path):
    # A folder named 'bad name' beside the log stopped the run with a line naming neither it nor the source.
    src = layout(tmp_path / "src")
    (src / "val" / "bad name").mkdir()
    result = convert(src, tmp_path / "out")
    assert result.written == [LOG] and result.failed == ["bad name"]
    assert [(p.scene, p.file, p.message) for p in errors_of(result)] == [
        ("bad name", str(src), "expected a scene name of letters, digits, '_', '-', '.', got 'bad name'")]
    assert DatasetReader(tmp_path / "out").scenes == [LOG]
