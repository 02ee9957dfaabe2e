"""Progress without a terminal: one line per finished task with its count, name and elapsed time."""

from __future__ import annotations

import re
from pathlib import Path

from avdata.cli import main
from avdata.progress import Progress
from tests.realdata import REALDATA


def test_a_line_per_task_and_nothing_when_quiet(capsys) -> None:
    with Progress(3, "convert toy", "scene") as progress:
        for name in ("a", "b", "c"):
            progress.update(name)
    with Progress(2, "convert toy", "scene", quiet=True) as progress:
        progress.update("a")
    lines = capsys.readouterr().err.splitlines()
    assert [re.sub(r"\d+\.\d s", "T s", line) for line in lines] == [
        "convert toy: 1/3 scenes (a finished, T s)", "convert toy: 2/3 scenes (b finished, T s)",
        "convert toy: 3/3 scenes (c finished, T s)"]


def test_convert_says_each_scene_in_a_log(tmp_path: Path, capsys) -> None:
    assert main(["convert", "kitti-object", str(REALDATA / "kitti" / "object"), str(tmp_path / "out"), "--scene-size", "1"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert [re.sub(r" \d+\.\d s\)$", ")", line) for line in err] == [
        f"convert kitti-object: {i}/3 scenes (training_00000{i - 1} finished,)" for i in (1, 2, 3)]
