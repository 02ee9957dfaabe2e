"""Bad-input corpus for the nuScenes converter, built from the real Lyft tables (nuScenes schema): each case
loses exactly the record it is in, names file, token and field, and writes the scene (Issue 16.2, 16.3, 16.7)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from avdata.converters import ConvertConfig, run_conversion
from avdata.converters.nuscenes import NuScenesConverter
from avdata.errors import InputError
from avdata.frames.rotations import SILENT_TOLERANCE, quaternion_message
from avdata.schema import DatasetReader
from avdata.schema.validate import validate_dataset
from tests.realdata import REALDATA

LYFT = REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train"
VERSION = "v1.01-train"


def lyft_copy(root: Path) -> Path:
    """The Lyft dataroot with its sensor folders symlinked and the tables copied (to be edited)."""
    root.mkdir()
    for entry in LYFT.iterdir():
        if entry.name != VERSION:
            (root / entry.name).symlink_to(entry)
    (root / VERSION).mkdir()
    for table in (LYFT / VERSION).iterdir():
        (root / VERSION / table.name).write_bytes(table.read_bytes())
    return root


def edit_table(root: Path, table: str, edit) -> list[dict]:
    path = root / VERSION / f"{table}.json"
    rows = json.loads(path.read_text())
    edit(rows)
    path.write_text(json.dumps(rows))
    return rows


def convert(root: Path, dst: Path):
    return valid(run_conversion(NuScenesConverter(ConvertConfig(src=root, dst=dst, quiet=True))), dst)


def valid(result, dst: Path):
    """``result``, after checking that what the conversion wrote passes ``avdata validate`` (issue 34)."""
    if (dst / "avdata.json").is_file():
        assert validate_dataset(dst) == []
    return result


def _set(index: int, field: str, value):
    def edit(rows: list[dict]) -> None:
        rows[index][field] = value
    return edit


def _drop(index: int, field: str):
    def edit(rows: list[dict]) -> None:
        del rows[index][field]
    return edit


def _duplicate(index: int, **changes):
    def edit(rows: list[dict]) -> None:
        rows.append({**rows[index], **changes})
    return edit


ANNOTATION_CASES = [
    ("translation-nan", _set(0, "translation", [float("nan"), 1.0, 2.0]),
     "field 'translation': expected 3 finite numbers within 1e+07 m, got [NaN, 1.0, 2.0]; dropped"),
    ("size-missing", _drop(0, "size"), "field 'size': expected 3 finite numbers in 0 .. 1000 m, got none; dropped"),
    ("rotation-mistyped", _set(0, "rotation", "1 0 0 0"),
     "field 'rotation': expected a unit quaternion (w, x, y, z) (| |q| - 1 | <= 0.01), got \"1 0 0 0\"; dropped"),
    ("rotation-zero", _set(0, "rotation", [0, 0, 0, 0]),
     "field 'rotation': expected a unit quaternion (w, x, y, z) (| |q| - 1 | <= 0.01), got [0, 0, 0, 0]; dropped"),
    ("instance-null", _set(0, "instance_token", None),
     "field 'instance_token': expected a non-empty string, got null; dropped"),
    ("duplicate-token", _duplicate(1),
     "expected unique tokens, got this token twice; the later row is dropped"),
    ("visibility-unknown", _set(0, "visibility_token", "no-such-level"), "dangling visibility_token no-such-level"),
    # A list is unhashable: looking it up among the visibility tokens was a TypeError traceback.
    ("visibility-list", _set(0, "visibility_token", ["4"]), "dangling visibility_token ['4']"),
    ("attribute-unknown", _set(0, "attribute_tokens", ["no-such-attribute"]), "dangling attribute_token no-such-attribute"),
]


@pytest.mark.parametrize("case", ANNOTATION_CASES, ids=[c[0] for c in ANNOTATION_CASES])
def test_bad_annotation_loses_only_that_annotation(tmp_path, case):
    _, edit, message = case
    root = lyft_copy(tmp_path / "src")
    rows = edit_table(root, "sample_annotation", edit)
    result = convert(root, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file == "sample_annotation.json"
    assert error.message == f"sample_annotation {rows[0 if case[0] != 'duplicate-token' else 1]['token']}: {message}"
    assert result.written and not result.failed
    objects = DatasetReader(tmp_path / "out").objects().num_rows
    # The 4 real annotations (all in the one sample), less the bad one; a repeated row adds nothing.
    assert objects == (4 if case[0] == "duplicate-token" else 3)


def test_slightly_off_quaternion_is_normalised_with_a_warning(tmp_path):
    root = lyft_copy(tmp_path / "src")
    rows = edit_table(root, "sample_annotation",
                      lambda rows: rows[2].update(rotation=[v * 1.001 for v in rows[2]["rotation"]]))
    result = convert(root, tmp_path / "out")
    assert result.n_errors == 0
    (warning,) = [p for p in result.problems if p.file == "sample_annotation.json" and "quaternion" in p.message]
    assert warning.message.startswith(f"sample_annotation {rows[2]['token']}: field 'rotation': quaternion [")
    assert "off unit norm by 0.001 (> 1e-06); normalised" in warning.message
    assert DatasetReader(tmp_path / "out").objects().num_rows == 4


@pytest.mark.filterwarnings("error::avdata.frames.RepairWarning")
@pytest.mark.parametrize(("table", "scale"), [("sample_annotation", 1.001), ("ego_pose", 1.002), ("calibrated_sensor", 0.997)])
def test_repaired_quaternion_is_one_warning_in_the_one_rules_words(tmp_path, table, scale):
    # The row check names the repair and the value is normalised there, by the rule of avdata.frames.rotations:
    # Boxes3D used to repair the annotation's quaternion a second time, with a second, file-less RepairWarning.
    root = lyft_copy(tmp_path / "src")
    rows = edit_table(root, table, lambda rows: rows[0].update(rotation=[v * scale for v in rows[0]["rotation"]]))
    result = convert(root, tmp_path / "out")
    assert result.n_errors == 0
    quaternion = np.asarray(rows[0]["rotation"], dtype=np.float64)
    (warning,) = [p for p in result.problems if "quaternion" in p.message]
    assert (warning.severity, warning.file, warning.message) == (
        "warning", f"{table}.json",
        f"{table} {rows[0]['token']}: field 'rotation': {quaternion_message(quaternion, rejected=False)}")
    assert f"off unit norm by {abs(scale - 1):.3g} (> {SILENT_TOLERANCE:g}); normalised" in warning.message
    assert DatasetReader(tmp_path / "out").objects().num_rows == 4


def test_bad_ego_pose_loses_the_sample_data_that_uses_it(tmp_path):
    root = lyft_copy(tmp_path / "src")
    poses = edit_table(root, "ego_pose", _set(0, "rotation", [float("nan"), 0, 0, 1]))
    result = convert(root, tmp_path / "out")
    errors = [p for p in result.problems if p.severity == "error"]
    assert errors[0].file == "ego_pose.json" and errors[0].message.startswith(
        f"ego_pose {poses[0]['token']}: field 'rotation': expected a unit quaternion")
    users = [sd for sd in json.loads((LYFT / VERSION / "sample_data.json").read_text())
             if sd["ego_pose_token"] == poses[0]["token"]]
    assert len(errors) == 1 + len(users) and users
    assert all("dangling ego_pose_token" in e.message for e in errors[1:])
    assert result.written and DatasetReader(tmp_path / "out").frames().num_rows == 1


def test_duplicate_calibrated_sensor_token_is_an_error_and_the_first_row_is_kept(tmp_path):
    root = lyft_copy(tmp_path / "src")
    rows = edit_table(root, "calibrated_sensor", _duplicate(0, translation=[9.0, 9.0, 9.0]))
    result = convert(root, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file == "calibrated_sensor.json"
    assert error.message == (f"calibrated_sensor {rows[0]['token']}: expected unique tokens, got this token twice; "
                             f"the later row is dropped")


def test_duplicate_scene_name_is_an_error(tmp_path):
    root = lyft_copy(tmp_path / "src")
    rows = edit_table(root, "scene", _duplicate(0, token="f" * 64))
    result = convert(root, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file == "scene.json"
    assert error.message == (f"scene {'f' * 64}: expected unique scene names, got {rows[0]['name']!r} again "
                             f"(first: scene {rows[0]['token']}); the later scene is not converted")
    assert DatasetReader(tmp_path / "out").scenes == [rows[0]["name"]]


def test_utf16_table_is_one_error_line(tmp_path):
    root = lyft_copy(tmp_path / "src")
    path = root / VERSION / "sample.json"
    path.write_bytes(path.read_text().encode("utf-16"))
    with pytest.raises(InputError, match=r"sample\.json: expected UTF-8 JSON .*a UTF-16 file\?\)$"):
        convert(root, tmp_path / "out")


def test_a_damaged_or_folder_sensor_file_is_an_error_a_missing_one_a_warning(tmp_path):
    # A folder where a sensor file belongs and a damaged file are errors (exit 1), not "missing" or warnings.
    root = lyft_copy(tmp_path / "src")
    (root / "lidar").mkdir()
    (root / "lidar" / "host-a101_lidar0_1240710385903083166.bin").mkdir()
    (root / "lidar" / "host-a101_lidar1_1240710385903083166.bin").write_bytes(b"\0" * 7)
    # A real nuScenes JPEG whole, and the same cut short (a torn download), which must not be stored as is.
    jpeg = (REALDATA / "nuscenes" / "samples" / "CAM_FRONT"
            / "n015-2018-07-24-11-22-45+0800__CAM_FRONT__1532402927612460.jpg").read_bytes()
    (root / "images").mkdir()
    (root / "images" / "host-a101_cam0_1240710385850000006.jpeg").write_bytes(jpeg)
    cut = root / "images" / "host-a101_cam1_1240710385866660006.jpeg"
    cut.write_bytes(jpeg[:100_000])

    def nuscenes_size(rows: list[dict]) -> None:  # the rows state the size of the image put in their place
        for row in rows:
            if row["filename"] == "images/host-a101_cam0_1240710385850000006.jpeg":
                row["width"], row["height"] = 1600, 900
    edit_table(root, "sample_data", nuscenes_size)
    result = convert(root, tmp_path / "out")
    errors = sorted((p.file, p.message.split(" (")[0]) for p in result.problems if p.severity == "error")
    assert errors == [
        ("images/host-a101_cam1_1240710385866660006.jpeg", "unreadable sensor file"),
        ("lidar/host-a101_lidar0_1240710385903083166.bin", "expected a sensor file, got Is a directory"),
        ("lidar/host-a101_lidar1_1240710385903083166.bin", "unreadable sensor file"),
    ]
    (cut_error,) = [p.message for p in result.problems if p.file.endswith("cam1_1240710385866660006.jpeg")]
    assert cut_error.endswith(f"{cut.relative_to(root)}: expected the file to end with the EOI marker ff d9, got "
                              f"{jpeg[99_998:100_000].hex(' ')} (truncated file?)")
    warned = {p.file for p in result.problems if p.severity == "warning" and "sensor file missing" in p.message}
    assert "lidar/host-a101_lidar2_1240710385903083166.bin" in warned and len(warned) == 6
    assert result.n_errors == 3 and len(result.written) == 1
    images = [topic for topic in DatasetReader(tmp_path / "out").scene(result.written[0]).topics if topic.endswith("/image")]
    assert len(images) == 1


def _repeat_key_in_text(root: Path, table: str, index: int, key: str, value) -> list[dict]:
    """Writes ``table`` with row ``index`` giving ``key`` a second time (``value``) at its end, as text."""
    path = root / VERSION / f"{table}.json"
    rows = json.loads(path.read_text())
    texts = [json.dumps(row) for row in rows]
    texts[index] = texts[index][:-1] + f", {json.dumps(key)}: {json.dumps(value)}}}"
    path.write_text("[" + ",\n".join(texts) + "]")
    return rows


def test_a_key_given_twice_with_different_values_loses_only_that_annotation(tmp_path):
    # json keeps the last value of a repeated key without a word: which translation the annotator meant is unknown.
    root = lyft_copy(tmp_path / "src")
    rows = _repeat_key_in_text(root, "sample_annotation", 2, "translation", [1.0, 2.0, 3.0])
    result = convert(root, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file == "sample_annotation.json"
    first = json.dumps(rows[2]["translation"])[:40]
    assert error.message == (f"sample_annotation {rows[2]['token']}: field 'translation': expected it once, got it "
                             f"twice with different values ({first} and [1.0, 2.0, 3.0]); dropped")
    assert result.written and DatasetReader(tmp_path / "out").objects().num_rows == 3


def test_a_key_given_twice_with_one_value_and_unusual_text_convert_unchanged(tmp_path):
    # The same value twice is not ambiguous; '":' inside a string and white space before a colon only send the
    # chunk through the slower exact decode. Each conversion equals the one of the untouched tables.
    reference = convert(lyft_copy(tmp_path / "src0"), tmp_path / "out0")
    assert reference.n_errors == 0
    expected = DatasetReader(tmp_path / "out0").objects()
    root = lyft_copy(tmp_path / "src1")
    rows = _repeat_key_in_text(root, "sample_annotation", 1, "size", None)
    path = root / VERSION / "sample_annotation.json"
    path.write_text(path.read_text().replace(', "size": null}', f', "size": {json.dumps(rows[1]["size"])}}}'))
    scene = root / VERSION / "scene.json"
    scenes = json.loads(scene.read_text())
    scenes[0]["description"] = 'says "x": 1'
    scene.write_text(json.dumps(scenes, separators=(",", " : ")))
    result = convert(root, tmp_path / "out1")
    assert result.n_errors == 0 and result.written
    got = DatasetReader(tmp_path / "out1").objects()
    assert got.column_names == expected.column_names
    for name in expected.column_names:  # NaN velocities (no neighbour): equal as numpy sees them
        assert expected[name].equals(got[name]) or np.array_equal(expected[name].to_numpy(), got[name].to_numpy(),
                                                                  equal_nan=True), name


def test_a_bad_map_row_is_an_error_not_a_traceback(tmp_path):
    root = lyft_copy(tmp_path / "src")
    rows = edit_table(root, "map", _set(0, "log_tokens", 5))
    result = convert(root, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file == "map.json"
    assert error.message == f"map {rows[0]['token']}: field 'log_tokens': expected a list of strings, got 5; dropped"
    assert result.written


@pytest.mark.parametrize("table", ["sample_data", "ego_pose"])
def test_duplicate_sample_data_and_ego_pose_tokens_are_errors(tmp_path, table):
    # README promises it for every table; these two were written (or looked up) twice without a word.
    root = lyft_copy(tmp_path / "src")
    rows = edit_table(root, table, _duplicate(0))
    result = convert(root, tmp_path / "out")
    errors = [p for p in result.problems if p.severity == "error"]
    assert [(e.file, e.message) for e in errors] == [
        (f"{table}.json", f"{table} {rows[0]['token']}: expected unique tokens, got this token twice; the later row "
                          "is dropped")]


def test_a_table_of_records_without_commas_is_one_error_line(tmp_path):
    # '[{...}{...}]' is not JSON (json.loads refuses it) but the chunked reader parsed it anyway.
    root = lyft_copy(tmp_path / "src")
    path = root / VERSION / "sample_data.json"
    rows = json.loads(path.read_text())
    path.write_text("[" + "".join(json.dumps(row) for row in rows) + "]")
    with pytest.raises(InputError, match=r"sample_data\.json: malformed JSON: expected ',' between records, got '\{"):
        convert(root, tmp_path / "out")


@pytest.mark.parametrize("table", ["sample_annotation", "sample_data"])
@pytest.mark.parametrize("token", [["4"], {"token": "4"}])
def test_a_sample_token_that_is_a_list_or_an_object_costs_that_row(tmp_path, table, token):
    # Looking it up among the sample tokens (to report the row with its scene) was a TypeError traceback.
    root = lyft_copy(tmp_path / "src")
    rows = edit_table(root, table, _set(0, "sample_token", token))
    result = convert(root, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file == f"{table}.json" and error.message == (
        f"{table} {rows[0]['token']}: field 'sample_token': expected a non-empty string, got {json.dumps(token)}; "
        f"dropped")
    assert result.written and not result.failed


@pytest.mark.parametrize(("table", "field"), [("log", "vehicle"), ("log", "date_captured"), ("scene", "description")])
def test_a_descriptive_field_that_is_no_string_costs_itself_not_the_scene(tmp_path, table, field):
    # A NaN there made the scene metadata unwritable (not JSON): the whole scene was lost, naming the source folder.
    root = lyft_copy(tmp_path / "src")
    rows = edit_table(root, table, _set(0, field, float("nan")))
    result = convert(root, tmp_path / "out")
    (error,) = [p for p in result.problems if p.severity == "error"]
    assert error.file == f"{table}.json" and error.message == (
        f"{table} {rows[0]['token']}: field '{field}': expected a string, got NaN; left empty in the scene metadata")
    reader = DatasetReader(tmp_path / "out")
    assert reader.frames().num_rows == 1 and reader.scene(reader.scenes[0]).metadata[field] == ""


@pytest.mark.parametrize(("version", "why"), [
    ("", "an empty name"),  # it chose the only version present without a word
    ("..", "the folder itself or its parent"),  # read the tables of SRC's parent
    ("/", "a path separator"),
    ("x" * 300, "more than 255 bytes"),  # a traceback (ENAMETOOLONG)
])
def test_version_is_one_folder_under_src(tmp_path: Path, version: str, why: str) -> None:
    with pytest.raises(InputError, match=rf"^--version: expected a name that stays inside its folder .*\({why}\)$"):
        NuScenesConverter(ConvertConfig(src=LYFT.parent, dst=tmp_path / "out", options={"version": version}))
    assert NuScenesConverter(ConvertConfig(src=LYFT.parent, dst=tmp_path / "out",
                                           options={"version": VERSION})).table_dir() == LYFT
