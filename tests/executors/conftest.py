"""The executors' tests share a small disk: a tmpfs that a ballast file fills up to a budget."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest


class SmallDisk:
    """A 24 MB tmpfs; ``fill(leave)`` takes all but ``leave`` bytes of it, ``free()`` gives them back."""

    def __init__(self, root: Path):
        self.root = root
        self._ballast = root / "ballast"

    def fill(self, leave: int) -> None:
        stat = os.statvfs(self.root)
        size = stat.f_bavail * stat.f_frsize - leave
        with open(self._ballast, "wb") as stream:
            stream.truncate(0)
            os.posix_fallocate(stream.fileno(), 0, size)

    def free(self) -> None:
        self._ballast.unlink()


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[SmallDisk]:
    root = tmp_path / "disk"
    root.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=24m", "tmpfs", str(root)],
                                           capture_output=True).returncode:
        pytest.skip("mounting a small tmpfs needs root (the ENOSPC injection tests run anyway)")
    try:
        yield SmallDisk(root)
    finally:
        subprocess.run(["umount", "-l", str(root)], check=True)
