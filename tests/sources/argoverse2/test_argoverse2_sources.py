"""avdata.sources.argoverse2 on the real files: the ROI raster cell for cell and the constants against
av2-api 0.3.6 (its venv), the readers' exact types and their one-line errors."""

from __future__ import annotations

import os

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest

from avdata.errors import InputError
from avdata.sources import argoverse2 as av2
from avdata.sources.argoverse2.files import ANNOTATION_COLUMNS
from avdata.sources.argoverse2.roi import read_drivable_areas
from tests.eval.eval_oracle_env import run_oracle
from tests.realdata import REALDATA

REAL_LOG = (REALDATA / "argoverse2" / "sensor" / "val"
            / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede")
SWEEP = REAL_LOG / "sensors" / "lidar" / "315966265259836000.feather"


@pytest.fixture(scope="module")
def oracle(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("av2_map") / "map.npz"
    constants = run_oracle("av2", "av2_map_and_constants.py", str(REAL_LOG), str(out))
    with np.load(out) as arrays:
        return {"constants": constants, **{k: arrays[k] for k in arrays.files}}


def test_roi_raster_equals_av2_cell_for_cell(oracle):
    roi = av2.log_roi(REAL_LOG)
    assert roi.mask.shape == oracle["roi"].shape
    assert int((roi.mask != oracle["roi"]).sum()) == 0
    np.testing.assert_array_equal(oracle["R"], np.eye(2))
    np.testing.assert_array_equal(oracle["t"], -roi.origin_city_m)
    assert float(oracle["s"]) == roi.cells_per_m
    # about 5.8 M of 20 M cells: a real, non-trivial region
    assert 0.1 < roi.mask.mean() < 0.5


def test_roi_lookup_truncates_like_av2_and_is_false_off_the_grid():
    polygons = read_drivable_areas(REAL_LOG / "map")
    roi = av2.log_roi(REAL_LOG)
    assert roi.contains(polygons[0][:, :2]).all()
    height, width = roi.mask.shape
    corner = roi.origin_city_m + np.array([width, height]) / roi.cells_per_m
    assert not roi.contains(np.array([[corner[0] + 1.0, corner[1] + 1.0], roi.origin_city_m - 1.0])).any()
    # (x, y) in cell (i, j) when floor(10 * (p - origin)) = (j, i), like av2's astype(int64)
    row, col = np.argwhere(roi.mask == 1)[len(np.argwhere(roi.mask == 1)) // 2]
    inside = roi.origin_city_m + (np.array([col, row]) + 0.99) / roi.cells_per_m
    assert roi.contains(inside[None])[0]


def test_map_archive_with_a_key_given_twice_is_refused(tmp_path):
    # json keeps the last value of a repeated key without a word: which boundary the map meant is unknown.
    (archive,) = (REAL_LOG / "map").glob("log_map_archive_*.json")
    text = archive.read_text()
    first = text.index('"area_boundary": ')
    (tmp_path / archive.name).write_text(text[:first] + '"area_boundary": [], ' + text[first:])
    with pytest.raises(InputError, match=rf"{archive.name}: expected drivable_areas with area_boundary x, y, z, "
                                         r"got DuplicateKeyError\(\"key 'area_boundary' given twice in one object"):
        read_drivable_areas(tmp_path)


def test_map_archive_that_is_a_fifo_is_refused_not_waited_on(tmp_path):
    os.mkfifo(tmp_path / "log_map_archive_x.json")
    with pytest.raises(InputError, match=r"log_map_archive_x.json: expected a regular file, got a FIFO$"):
        read_drivable_areas(tmp_path)


def test_constants_equal_av2(oracle):
    constants = oracle["constants"]
    assert list(av2.ANNOTATION_CATEGORIES) == constants["annotation_categories"]
    assert list(av2.COMPETITION_CATEGORIES) == constants["competition_categories"]
    assert list(av2.RING_CAMERAS) == constants["ring_cameras"]
    assert list(av2.STEREO_CAMERAS) == constants["stereo_cameras"]
    assert av2.MAX_LIDAR_CAM_TIMESTAMP_DIFF_NS == constants["max_lidar_ring_cam_timestamp_diff_ns"]
    assert sorted(av2.CLASS_MAP) == sorted(constants["annotation_categories"])


def test_readers_keep_the_stored_types_and_values():
    sweep = av2.read_sweep(SWEEP)
    table = feather.read_table(SWEEP)
    for name in ("x", "y", "z", "intensity", "laser_number", "offset_ns"):
        assert sweep[name].tobytes() == table.column(name).to_numpy().tobytes()
    assert sweep["x"].dtype == np.float16 and len(sweep["x"]) == 99229
    rows = av2.read_poses(REAL_LOG / "city_SE3_egovehicle.feather")
    assert rows.dropped == [] and rows.repaired == []
    poses = rows.columns
    assert poses["quat_wxyz"].shape == (2706, 4) and np.all(np.diff(poses["timestamp_ns"]) > 0)
    intrinsics, dropped = av2.read_intrinsics(REAL_LOG / "calibration" / "intrinsics.feather")
    assert dropped == []
    front = intrinsics["ring_front_center"]
    assert (front.width_px, front.height_px) == (1550, 2048)
    np.testing.assert_array_equal(front.D_plumb_bob, [front.k1, front.k2, 0.0, 0.0, front.k3])
    np.testing.assert_array_equal(front.K, [[front.fx_px, 0, front.cx_px], [0, front.fy_px, front.cy_px], [0, 0, 1]])
    assert sorted(av2.read_sensor_poses(REAL_LOG / "calibration" / "egovehicle_SE3_sensor.feather")[0]) == sorted(
        [*av2.RING_CAMERAS, *av2.STEREO_CAMERAS, *av2.LIDARS])
    assert av2.city_name(REAL_LOG) == "PIT"


def test_reader_errors_name_the_file_and_column(tmp_path):
    truncated = tmp_path / "sweep.feather"
    truncated.write_bytes(SWEEP.read_bytes()[:1000])
    with pytest.raises(InputError, match=r"sweep.feather: unreadable feather file"):
        av2.read_sweep(truncated)
    with pytest.raises(InputError, match=r"none.feather: expected a feather file, got none"):
        av2.read_sweep(tmp_path / "none.feather")
    table = feather.read_table(REAL_LOG / "city_SE3_egovehicle.feather")
    times = table.column("timestamp_ns").to_numpy().copy()
    times[3] = times[2]
    feather.write_feather(table.set_column(0, "timestamp_ns", pa.array(times)), tmp_path / "poses.feather")
    rows = av2.read_poses(tmp_path / "poses.feather")  # a time given twice: which pose is meant is unknown
    assert rows.dropped == [f"column 'timestamp_ns': {times[2]} given 2 times; those rows dropped"]
    assert len(rows.columns["timestamp_ns"]) == table.num_rows - 2 and times[2] not in rows.columns["timestamp_ns"]
    feather.write_feather(table.drop_columns(["qw"]), tmp_path / "no_qw.feather")
    with pytest.raises(InputError, match=r"no_qw.feather: expected columns .* missing \['qw'\]"):
        av2.read_poses(tmp_path / "no_qw.feather")
    annotations = feather.read_table(REAL_LOG / "annotations.feather")
    length = annotations.column("length_m").to_numpy().copy()
    length[7] = -1.0
    feather.write_feather(annotations.set_column(annotations.column_names.index("length_m"), "length_m",
                                                 pa.array(length)), tmp_path / "annotations.feather")
    rows = av2.read_annotations(tmp_path / "annotations.feather")
    assert rows.dropped == ["row 7: column 'length_m': expected a finite positive size <= 1000 m, got -1.0"]
    assert len(rows.columns["length_m"]) == annotations.num_rows - 1


def test_timestamp_files_sorts_and_sets_strays_apart(tmp_path):
    for name in ("20.feather", "3.feather", "notes.txt", "7.jpg"):
        (tmp_path / name).write_bytes(b"")
    times, paths, strays = av2.timestamp_files(tmp_path, "feather")
    assert times.tolist() == [3, 20] and [p.name for p in paths] == ["3.feather", "20.feather"]
    assert sorted(p.name for p in strays) == ["7.jpg", "notes.txt"]
    assert av2.timestamp_files(tmp_path / "absent", "jpg")[0].size == 0
    assert all(av2.unified_class(c) in {"car", "truck", "bus", "trailer", "pedestrian", "cyclist", "motorcycle",
                                        "bicycle", "traffic_cone", "barrier", "animal", "other"}
               for c in av2.ANNOTATION_CATEGORIES)


@pytest.mark.parametrize("columns", [None, list(ANNOTATION_COLUMNS), ["timestamp_ns", "qw"]],
                         ids=["every column", "all named", "two columns"])
def test_a_store_object_reaches_arrow_as_arrow_memory_never_python_bytes(columns, monkeypatch):
    # Arrow decompresses on its thread pools; a worker dropping the last reference to Python bytes (or a PythonFile)
    # after the read returned takes the GIL, which during interpreter exit aborts the process. A file:// location
    # takes the store path: ranged reads of a pyarrow stream.
    from avdata.storage import location

    sources = []
    buffer_reader = pa.BufferReader
    monkeypatch.setattr(pa, "BufferReader", lambda source: sources.append(type(source)) or buffer_reader(source))
    monkeypatch.setattr(pa, "PythonFile", lambda *args, **kwargs: pytest.fail("a PythonFile reached Arrow"))
    path = REAL_LOG / "annotations.feather"
    table = av2.read_table(location(f"file://{path}"), columns)
    assert sources and set(sources) == {pa.Buffer}
    expected = feather.read_table(path)
    assert table.equals(expected if columns is None else expected.select(columns))
