"""``write_atomically``: whole files or none, and one line for a path that cannot be written."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pyarrow as pa
import pytest

from avdata.errors import InputError, OutputError
from avdata.outputs import checked_name, write_atomically


def test_text_and_bytes_are_written_whole_with_the_usual_permissions(tmp_path: Path) -> None:
    umask = os.umask(0o022)
    try:
        write_atomically(tmp_path / "a" / "b" / "report.md", "ünïcode\n")
        write_atomically(tmp_path / "points.bin", memoryview(bytes(range(256))))
        write_atomically(tmp_path / "points.bin", b"again")  # replaced, not appended
    finally:
        os.umask(umask)
    assert (tmp_path / "a" / "b" / "report.md").read_text(encoding="utf-8") == "ünïcode\n"
    assert (tmp_path / "points.bin").read_bytes() == b"again"
    assert stat.S_IMODE((tmp_path / "points.bin").stat().st_mode) == 0o644
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "points.bin"]  # no temporary file left


def test_a_path_that_cannot_be_written_is_one_line_and_leaves_nothing(tmp_path: Path) -> None:
    (tmp_path / "taken").mkdir()
    (tmp_path / "a_file").write_text("x")
    for path, why in ((tmp_path / "taken", "Is a directory"),
                      (tmp_path / "a_file" / "out.json", "a file is where its folder should be"),
                      (tmp_path / "a_file" / "deeper" / "out.json", "a file is where its folder should be")):
        with pytest.raises(OutputError) as raised:
            write_atomically(path, "{}")
        assert str(raised.value) == f"{path}: cannot write this file ({why})"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "taken"]
    assert not list((tmp_path / "taken").iterdir())


def test_a_fifo_or_device_at_the_path_is_not_replaced(tmp_path: Path) -> None:
    # The rename replaced a FIFO with a file, exit 0 (eval --json FIFO): its reader waited forever.
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "null").symlink_to("/dev/null")
    for name, kind in (("fifo", "FIFO"), ("null", "character device")):
        with pytest.raises(OutputError, match=f"^{tmp_path / name}: cannot write this file \\(a {kind} is in its place\\)$"):
            write_atomically(tmp_path / name, "{}")
    assert stat.S_ISFIFO(os.lstat(tmp_path / "fifo").st_mode) and os.readlink(tmp_path / "null") == "/dev/null"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo", "null"]


# --------------------------------------------------------------------------- the path rule of every output name

#: Names that would leave their folder, name the folder itself, or be hidden; each with the reason the rule gives.
BAD_NAMES = {
    "": "an empty name",
    ".": "the folder itself or its parent",
    "..": "the folder itself or its parent",
    "../../evil": "a path separator",
    "/tmp/evil-absolute": "a path separator",
    "a/b": "a path separator",
    "a\\b": "a path separator",
    "a\0b": "a control character",
    "a\nb": "a control character",
    ".hidden": "a leading '.'",
    "x" * 256: "more than 255 bytes",
}


@pytest.mark.parametrize("name", list(BAD_NAMES), ids=[repr(n)[:20] for n in BAD_NAMES])
def test_checked_name_refuses_every_name_that_leaves_its_folder(name: str) -> None:
    with pytest.raises(InputError) as raised:
        checked_name(name, "--version")
    message = str(raised.value)
    assert message.startswith("--version: expected a name that stays inside its folder")
    assert message.endswith(f"got {name!r} ({BAD_NAMES[name]})")
    assert "\n" not in message


def test_checked_name_keeps_ordinary_names() -> None:
    for name in ("v1.0-trainval", "C1-Ideal", "demo-0000", "case with spaces", "ünï", "a..b", "x" * 255):
        assert checked_name(name, "name") == name
    with pytest.raises(InputError, match="expected a name, got int 3"):
        checked_name(3, "name")


def _no_file_outside(root: Path, before: set[Path]) -> None:
    """Nothing new beside ``root`` (every bad name would have written one level or two above it)."""
    assert set(root.parent.parent.rglob("*")) - set(root.rglob("*")) - {root} <= before


@pytest.mark.parametrize("name", list(BAD_NAMES)[:9], ids=[repr(n)[:20] for n in list(BAD_NAMES)[:9]])
def test_scene_names_go_through_the_rule(tmp_path: Path, name: str) -> None:
    from avdata.errors import AvdataError
    from avdata.schema import DatasetWriter, scene_path

    with pytest.raises(AvdataError, match="scene name: expected a name that stays inside its folder"):
        scene_path(tmp_path, name)
    with pytest.raises(AvdataError, match="scene name: expected"):
        DatasetWriter(tmp_path / "ds", source="test").scene(name, {})
    assert not list(tmp_path.rglob("*.mcap*"))


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from avdata.demo import write_demo

    return write_demo(tmp_path_factory.mktemp("demo") / "demo")


@pytest.mark.parametrize("version", [".", "..", "../../evil", "ABSOLUTE", "v1/v2", "a\\b", "a\0b"])  # '': the parser refuses it
def test_export_nuscenes_version_goes_through_the_rule(demo: Path, tmp_path: Path, version: str,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    from avdata.cli import main

    base = tmp_path / "a" / "b"
    base.mkdir(parents=True)
    version = str(tmp_path / "evil") if version == "ABSOLUTE" else version
    assert main(["export", "nuscenes", str(demo), str(base / "dst"), "--version", version, "--quiet"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"avdata: error: --version: expected a name that stays inside its folder (no '/', '..', " \
                  f"leading '.', control character or empty name), got {version!r} ({_reason(version)})"
    assert [p.relative_to(tmp_path).as_posix() for p in sorted(tmp_path.rglob("*"))] == ["a", "a/b"]  # not even DST


def _reason(name: str) -> str:
    return BAD_NAMES.get(name) or ("a path separator" if "/" in name or "\\" in name else "a control character")


@pytest.mark.parametrize("case", ["..", "../../evil", "/tmp/evil-absolute-case", "a\0b", ""])
def test_study_case_names_go_through_the_rule(demo: Path, tmp_path: Path, case: str) -> None:
    import yaml

    from avdata.studies import load_study, run_study

    study_file = tmp_path / "study.yaml"
    study_file.write_text(yaml.safe_dump({"name": "s", "dataset": str(demo), "cases": [{"name": case, "comm_range_m": None}]}))
    out = tmp_path / "a" / "out"
    with pytest.raises(InputError, match=r"study case name: expected a name that stays inside its folder"):
        run_study(load_study(study_file), out, progress=False)
    assert not [p for p in tmp_path.rglob("*.json")]
    assert not os.path.exists("/tmp/evil-absolute-case__trial-0.json")


def test_plot_names_from_a_class_column_go_through_the_rule(demo: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """``eval tracking --plots``: a tracker's class column names the plot files, so ``../x`` must not leave --plots."""
    import pyarrow.parquet as pq

    from avdata.cli import main
    from avdata.schema import DatasetReader

    objects = DatasetReader(demo).objects()
    tracks = objects.select(["scene", "frame_index", "object_id", "class", "x_world_m", "y_world_m", "z_world_m",
                             "length_m", "width_m", "height_m", "yaw_world_rad"])
    classes = ["../../evil" if c == "pedestrian" else c for c in tracks["class"].to_pylist()]
    tracks = tracks.set_column(3, "class", pa.array(classes))
    pq.write_table(tracks, tmp_path / "tracks.parquet")
    plots = tmp_path / "p" / "plots"
    status = main(["eval", "tracking", str(demo), str(tmp_path / "tracks.parquet"), "--protocol", "avdata",
                   "--plots", str(plots)])
    assert status == 1
    assert "plot file name: expected a name that stays inside its folder" in capsys.readouterr().err
    assert not list(tmp_path.rglob("*evil*"))


def test_an_output_folder_in_an_input_folder_is_refused(tmp_path: Path) -> None:
    from avdata.outputs import refuse_output_in_input

    data = tmp_path / "data"
    data.mkdir()
    (tmp_path / "link").symlink_to(data)
    with pytest.raises(InputError, match=f"^{tmp_path / 'link'}: expected an output outside DATASET, got DATASET "
                                         "itself$"):
        refuse_output_in_input(tmp_path / "link", [tmp_path / "other", data], "DATASET")
    with pytest.raises(InputError, match=f"got a path inside DATASET {data}$"):
        refuse_output_in_input(data / "x" / ".." / "sub", [tmp_path / "other", data], "DATASET")
    refuse_output_in_input(tmp_path / "data2", [data], "DATASET")  # a sibling sharing the name's start
    refuse_output_in_input(tmp_path, [data], "DATASET")  # an input inside the output is the writer's to refuse
