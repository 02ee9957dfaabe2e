"""A full disk is one line naming the path and what was kept, in every writer; nothing partial stays; a rerun completes.

The real thing where the machine allows it: a small tmpfs (``small_disk`` in conftest.py; mounting needs
root), filled up to a budget by a ballast file that the test then deletes to free the space. Everywhere:
``ENOSPC`` injected into the scene writer in this process.
"""

from __future__ import annotations

import errno
import os
import re
from pathlib import Path

import pytest

from avdata.cli import main
from avdata.schema.dataset import is_complete_scene
from tests.executors.conftest import SmallDisk
from tests.realdata import REALDATA

KITTI_OBJECT = REALDATA / "kitti" / "object"
_KEPT = re.compile(r"^avdata: error: (?P<path>\S+): cannot write(?: this file)? \(No space left on device\); the run "
                   r"stopped, keeping (?P<kept>\d+) (?P<what>.*) and nothing partial; free space and rerun: what is "
                   r"complete is skipped$")


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    status = main(argv)
    out, err = capsys.readouterr()
    return status, out, err


def _one_line(err: str) -> re.Match:
    assert "Traceback" not in err and err.count("\n") == 1, err
    match = _KEPT.match(err.strip())
    assert match, err
    return match


def _nothing_partial(root: Path) -> list[str]:
    """The scene files under ``root`` (all complete); no temporary file anywhere."""
    assert not [p for p in root.rglob("*") if p.name.endswith(".tmp")]
    scenes = sorted((root / "scenes").glob("*.mcap")) if (root / "scenes").is_dir() else []
    assert all(is_complete_scene(p) for p in scenes)
    return [p.stem for p in scenes]


@pytest.mark.parametrize("options", [["--workers", "1"], ["--workers", "2"]], ids=["local", "2-workers"])
def test_convert(small_disk: SmallDisk, capsys, options: list[str]) -> None:
    dst = small_disk.root / "ds"
    small_disk.fill(leave=4 << 20)  # one of the three ~2.7 MB scenes fits
    argv = ["convert", "kitti-object", str(KITTI_OBJECT), str(dst), "--quiet", "--scene-size", "1", *options]
    status, _, err = _run(argv, capsys)
    match = _one_line(err)
    assert status == 1 and match["path"].startswith(f"{dst}/scenes/training_0000")
    assert match["what"] == f"complete scene file(s) in {dst}/scenes"
    kept = _nothing_partial(dst)
    assert int(match["kept"]) == len(kept) <= 1
    small_disk.free()
    status, out, err = _run(argv, capsys)
    assert (status, err) == (0, "")
    assert f"{3 - len(kept)} scenes written, {len(kept)} already complete" in out
    assert _nothing_partial(dst) == ["training_000000", "training_000001", "training_000002"]
    assert _run(["validate", str(dst)], capsys)[0] == 0


def test_generate(small_disk: SmallDisk, tmp_path: Path, capsys) -> None:
    import yaml

    from avdata.generators.config import load_preset

    config = load_preset("v2i-intersection").to_dict()
    config.update(frames=2, seed=1, scenes=2)
    config["traffic"].update(vehicles=4, pedestrians=2, crossing_pedestrians=0)
    config["infrastructure"]["count"] = 1
    (tmp_path / "scenario.yaml").write_text(yaml.safe_dump(config))
    dst = small_disk.root / "gen"
    small_disk.fill(leave=64 << 10)
    argv = ["generate", str(tmp_path / "scenario.yaml"), str(dst), "--quiet"]
    status, _, err = _run(argv, capsys)
    match = _one_line(err)
    assert status == 1 and match["path"].startswith(f"{dst}/") and match["kept"] == "0"
    assert _nothing_partial(dst) == []
    small_disk.free()
    assert _run(argv, capsys)[0] == 0
    assert len(_nothing_partial(dst)) == 2


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from avdata.demo import write_demo

    return write_demo(tmp_path_factory.mktemp("demo") / "demo")


@pytest.mark.parametrize("fmt", ["nuscenes", "kitti-object"])
def test_export(small_disk: SmallDisk, demo: Path, capsys, fmt: str) -> None:
    dst = small_disk.root / "export"
    small_disk.fill(leave=200 << 10)
    argv = ["export", fmt, str(demo), str(dst), "--quiet"]
    status, _, err = _run(argv, capsys)
    match = _one_line(err)
    assert status == 1 and match["path"].startswith(f"{dst}/") and match["kept"] == "0"
    assert match["what"] == f"exported scene(s) (their markers in {dst}/.avdata-export/scenes)"
    files = [p for p in dst.rglob("*") if p.is_file() and ".avdata" not in p.as_posix()]
    assert files == []  # no file of the unfinished scene
    small_disk.free()
    assert _run(argv, capsys)[0] == 0


def test_index_and_eval_plots(small_disk: SmallDisk, demo: Path, capsys) -> None:
    import shutil

    dataset = small_disk.root / "demo"
    shutil.copytree(demo, dataset)
    index = {p.name: p.read_bytes() for p in (dataset / "index").iterdir()}
    small_disk.fill(leave=4 << 10)
    status, _, err = _run(["index", str(dataset), "--quiet"], capsys)
    match = _one_line(err)
    assert status == 1 and match["kept"] == "1"
    assert {p.name: p.read_bytes() for p in (dataset / "index").iterdir()} == index  # the old index stays whole
    _nothing_partial(dataset)
    # eval --plots: no lock, nothing kept; one line naming the plot.
    tracks = small_disk.root / "tracks.parquet"
    small_disk.free()
    import pyarrow.parquet as pq

    from avdata.schema import DatasetReader

    pq.write_table(DatasetReader(dataset).objects(), tracks)
    small_disk.fill(leave=4 << 10)
    status, _, err = _run(["eval", "tracking", str(dataset), str(tracks), "--protocol", "avdata", "--plots",
                           str(small_disk.root / "plots")], capsys)
    assert status == 1 and "Traceback" not in err
    assert re.fullmatch(rf"avdata: error: {small_disk.root}/plots/hota_\w+\.png: cannot write this file "
                        r"\(No space left on device\)\n", err), err
    assert not [p for p in (small_disk.root / "plots").iterdir()]
    small_disk.free()
    assert _run(["index", str(dataset), "--quiet"], capsys)[0] == 0


def test_injected_enospc_in_the_scene_writer_is_one_line(tmp_path: Path, capsys, monkeypatch) -> None:
    """Without root: the scene writer's ``os.writev`` fails as on a full disk after the first scene."""
    import avdata.schema.mcap.fileio as mcap_io

    calls = {"scenes": 0}
    real_writev = os.writev
    real_scene = mcap_io.os.replace

    def writev(fd: int, buffers):  # noqa: ANN001 - os.writev's own signature
        if calls["scenes"] >= 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_writev(fd, buffers)

    def replace(src, dst):  # noqa: ANN001
        calls["scenes"] += str(dst).endswith(".mcap")
        return real_scene(src, dst)

    monkeypatch.setattr(mcap_io.os, "writev", writev)
    monkeypatch.setattr(os, "replace", replace)
    dst = tmp_path / "ds"
    argv = ["convert", "kitti-object", str(KITTI_OBJECT), str(dst), "--quiet", "--scene-size", "1"]
    status, _, err = _run(argv, capsys)
    match = _one_line(err)
    assert status == 1 and match["path"] == f"{dst}/scenes/training_000001.mcap" and match["kept"] == "1"
    assert _nothing_partial(dst) == ["training_000000"]
    monkeypatch.undo()
    status, out, _ = _run(argv, capsys)
    assert status == 0 and "2 scenes written, 1 already complete" in out


def test_study_run(small_disk: SmallDisk, demo: Path, tmp_path: Path, capsys) -> None:
    import yaml

    study = tmp_path / "study.yaml"
    study.write_text(yaml.safe_dump({"name": "s", "dataset": str(demo), "cases": [
        {"name": "base", "comm_range_m": None}, {"name": "near", "comm_range_m": 50}]}))
    out = small_disk.root / "study"
    small_disk.fill(leave=12 << 10)  # the lock, study.yaml and one run result
    argv = ["study", "run", str(study), str(out), "--quiet"]
    status, _, err = _run(argv, capsys)
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert status == 1 and re.match(rf"avdata: error: {out}/runs/\w+__trial-0\.json: cannot write this file \(No space "
                                    rf"left on device\); the run stopped, keeping every file already under its final "
                                    rf"name in {out} and nothing partial", err), err
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
    small_disk.free()
    assert _run(argv, capsys)[0] == 0
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["base__trial-0.json", "near__trial-0.json"]
