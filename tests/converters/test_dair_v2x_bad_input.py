"""Bad DAIR-V2X input costs the object it is in, with one line naming file and entry (issue 34)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.dair_v2x import DairV2xConverter
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.converters.test_dair_v2x import build_dair


def test_a_label_world_entry_given_twice_is_an_error_not_a_second_object(tmp_path: Path) -> None:
    # The copied entry became a second object at the same place.
    build_dair(tmp_path / "src", skew=0.0)
    path = tmp_path / "src" / "cooperative" / "label_world" / "017314.json"
    entries = json.loads(path.read_text())
    path.unlink()
    path.write_text(json.dumps([*entries, entries[1]]))
    result = run_conversion(DairV2xConverter(ConvertConfig(src=tmp_path / "src", dst=tmp_path / "out", quiet=True)))
    errors = [p for p in result.problems if p.severity == "error"]
    assert [(e.file, e.message) for e in errors] == [
        (str(path), f"object [{len(entries)}]: expected one entry per object, got the same as object [1]; dropped")]
    assert DatasetReader(tmp_path / "out").objects().num_rows == len(entries)
    assert validate_dataset(tmp_path / "out") == []


def _convert(src: Path, dst: Path) -> tuple[list, list]:
    result = run_conversion(DairV2xConverter(ConvertConfig(src=src, dst=dst, quiet=True)))
    if (dst / "avdata.json").is_file():
        assert validate_dataset(dst) == []
    return result.written, [(e.file, e.message) for e in result.problems if e.severity == "error"]


def _rewrite(path: Path, text: str) -> Path:
    path.unlink()  # a link to the real file is replaced, never written through
    path.write_text(text)
    return path


@pytest.mark.parametrize(("field", "value", "message"), [
    ("cooperative_label_path", 1e308, "field cooperative_label_path: expected a relative path, got 1e+308"),
    ("infrastructure_pointcloud_path", 12.5, "field infrastructure_pointcloud_path: expected a relative path, got 12.5"),
    ("system_error_offset", [], "system_error_offset delta_x / delta_y, got TypeError"),
    ("cooperative_label_path", "cooperative/label_world/017314.json\x00x",  # a NUL: a ValueError traceback
     "field cooperative_label_path: expected a relative path, got 'cooperative/label_world/017314.json\\x00x'"),
    # A path outside the source folder read a file of another tree (and named it in the error).
    ("cooperative_label_path", "/etc/hostname", "field cooperative_label_path: expected a relative path, got '/etc/hostname'"),
    ("vehicle_pointcloud_path", "../vehicle-side/velodyne/017314.pcd",
     "field vehicle_pointcloud_path: expected a relative path, got '../vehicle-side/velodyne/017314.pcd'"),
])
def test_a_pair_field_of_another_type_costs_that_pair(tmp_path: Path, field: str, value: object, message: str) -> None:
    # A number where a path belongs was a TypeError traceback (1e308) or a path "12.5"; an offset of [] meant none.
    build_dair(tmp_path / "src", skew=0.0)
    path = tmp_path / "src" / "cooperative" / "selected_data_info.json"
    pairs = json.loads(path.read_text())
    _rewrite(path, json.dumps([{**pairs[0], field: value}]))
    written, errors = _convert(tmp_path / "src", tmp_path / "out")
    assert written == [] and len(errors) == 1 and errors[0][1].startswith(f"{path}: coop_017314: ")
    assert message in errors[0][1]


def test_an_infinite_timestamp_costs_that_time(tmp_path: Path) -> None:
    # int(inf) was an OverflowError traceback.
    build_dair(tmp_path / "src", skew=0.0)
    path = tmp_path / "src" / "infrastructure-side" / "data_info.json"
    rows = json.loads(path.read_text())
    _rewrite(path, json.dumps([{**rows[0], "pointcloud_timestamp": float("inf")}]))
    written, errors = _convert(tmp_path / "src", tmp_path / "out")
    assert len(written) == 1
    assert errors == [(str(path), "frame 001366: field pointcloud_timestamp: expected integer µs, got inf")]


@pytest.mark.parametrize(("text", "why"), [("[" * 100_000 + "]" * 100_000, "maximum recursion depth exceeded"),
                                           ("[" + "9" * 5000 + "]", "Exceeds the limit (4300 digits)")])
def test_json_nested_too_deep_or_with_a_5000_digit_number_is_one_line(tmp_path: Path, text: str, why: str) -> None:
    # A RecursionError / ValueError traceback from the json module.
    build_dair(tmp_path / "src", skew=0.0)
    path = _rewrite(tmp_path / "src" / "cooperative" / "label_world" / "017314.json", text)
    _, errors = _convert(tmp_path / "src", tmp_path / "out")
    assert len(errors) == 1 and errors[0][0] == str(path)
    assert errors[0][1].startswith("malformed JSON (") and why in errors[0][1] and "\n" not in errors[0][1]


@pytest.mark.parametrize(("rel", "group", "key"), [
    ("cooperative/label_world/017314.json", "3d_location", "x"),  # the writer refused the whole frame, naming no file
    ("cooperative/label_world/017314.json", "3d_dimensions", "l"),
    ("cooperative/label_world/017314.json", None, "rotation"),  # written as a box of arbitrary heading
    ("vehicle-side/label/lidar/017314.json", "3d_location", "y"),  # the hint was lost without a word
    ("infrastructure-side/label/virtuallidar/001366.json", "3d_dimensions", "h"),
])
def test_a_label_value_of_1e308_or_nan_costs_that_object(tmp_path: Path, rel: str, group: str | None, key: str) -> None:
    build_dair(tmp_path / "src", skew=0.0)
    path = tmp_path / "src" / rel
    entries = json.loads(path.read_text())
    (entries[0][group] if group else entries[0])[key] = 1e308 if key != "h" else float("nan")  # (JSON NaN)
    _rewrite(path, json.dumps(entries))
    written, errors = _convert(tmp_path / "src", tmp_path / "out")
    assert len(written) == 1 and len(errors) == 1 and errors[0][0] == str(path)
    assert errors[0][1].startswith("object [0]: expected finite values within 1e+07 m, dimensions in (0, 1000] m and a "
                                   "rotation within +-12.57 rad (two turns), got ")
    assert ("nan" if key == "h" else "1e+308") in errors[0][1]
    n_world = len(json.loads((tmp_path / "src" / "cooperative" / "label_world" / "017314.json").read_text()))
    objects = DatasetReader(tmp_path / "out").objects().num_rows
    assert objects == (n_world - 1 if rel.startswith("cooperative") else n_world)
