"""``require_file`` names what is at a path instead of a file, one line each."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from avdata.errors import InputError
from avdata.inputs import require_file


def test_a_regular_file_and_a_link_to_one_pass(tmp_path: Path) -> None:
    (tmp_path / "calib.txt").write_text("x")
    (tmp_path / "link.txt").symlink_to(tmp_path / "calib.txt")
    require_file(tmp_path / "calib.txt", "calibration file")
    require_file(tmp_path / "link.txt", "calibration file")


def _folder(path: Path) -> None:
    path.mkdir()


def _fifo(path: Path) -> None:
    os.mkfifo(path)


def _broken_link(path: Path) -> None:
    path.symlink_to(path.parent / "nowhere")


def _loop(path: Path) -> None:
    path.symlink_to(path)


@pytest.mark.parametrize(("make", "message"), [
    (None, "calibration file missing"),
    (_folder, "expected a calibration file, got a folder"),
    (_fifo, "expected a regular file, got a FIFO"),
    (_broken_link, "expected a calibration file, got a broken symbolic link"),
    (_loop, "expected a calibration file, got Too many levels of symbolic links"),
])
def test_anything_else_is_named(tmp_path: Path, make, message: str) -> None:
    path = tmp_path / "calib.txt"
    if make is not None:
        make(path)
    with pytest.raises(InputError) as raised:
        require_file(path, "calibration file")
    assert str(raised.value) == f"{path}: {message}"


def test_a_path_through_a_file_is_missing_with_the_callers_hint(tmp_path: Path) -> None:
    (tmp_path / "not_a_folder").write_text("x")
    path = tmp_path / "not_a_folder" / "calib.txt"
    with pytest.raises(InputError, match=r"calib.txt: no calibration \(pass --calib\)$"):
        require_file(path, "calibration file", missing="no calibration (pass --calib)")
