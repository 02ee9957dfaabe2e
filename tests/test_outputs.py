"""``write_atomically``: whole files or none, and one line for a path that cannot be written."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from avdata.errors import OutputError
from avdata.outputs import write_atomically


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
