"""An export writes only into an empty folder or its own earlier export (as convert refuses another source's folder)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from avdata.cli import main
from avdata.demo import write_demo


@pytest.fixture(scope="module")
def demos(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("demos")
    return write_demo(root / "a"), write_demo(root / "b")


def _export(fmt: str, dataset: Path, dst: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    status = main(["export", fmt, str(dataset), str(dst), "--quiet"])
    return status, capsys.readouterr().err


@pytest.mark.parametrize("fmt", ["nuscenes", "kitti-object"])
def test_another_datasets_export_is_refused_and_left_alone(fmt, demos, tmp_path, capsys) -> None:
    # Was (S36): the second export silently replaced the first one's tables (and pruned its files).
    a, b = demos
    dst = tmp_path / "dst"
    assert _export(fmt, a, dst, capsys)[0] == 0
    before = {p: p.read_bytes() for p in dst.rglob("*") if p.is_file()}
    status, err = _export(fmt, b, dst, capsys)
    assert (status, err) == (1, f"avdata: error: {dst}: expected an empty folder or an export of {b.resolve()}, got "
                                f"an export of {a.resolve()} (write into another folder)\n")
    assert {p: p.read_bytes() for p in dst.rglob("*") if p.is_file()} == before
    assert _export(fmt, a, dst, capsys)[0] == 0  # its own export is resumed


def test_a_folder_holding_other_files_is_refused_and_left_alone(demos, tmp_path, capsys) -> None:
    # A real nuScenes dataroot: its tables would have been replaced and its samples pruned.
    dst = tmp_path / "nuscenes"
    (dst / "v1.0-avdata").mkdir(parents=True)
    (dst / "v1.0-avdata" / "scene.json").write_text("[]")
    (dst / "samples").mkdir()
    status, err = _export("nuscenes", demos[0], dst, capsys)
    assert (status, err) == (1, f"avdata: error: {dst}: expected an empty folder or an earlier avdata export, got a "
                                f"folder holding samples, v1.0-avdata (write into another folder)\n")
    assert sorted(p.relative_to(dst).as_posix() for p in dst.rglob("*")) == [
        ".avdata.lock", "samples", "v1.0-avdata", "v1.0-avdata/scene.json"]
    assert json.loads((dst / "v1.0-avdata" / "scene.json").read_text()) == []
