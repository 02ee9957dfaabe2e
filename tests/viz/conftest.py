"""Datasets for the viz tests: the real KITTI object samples converted, and the suite's small generated V2I scene."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REAL_KITTI = Path(__file__).resolve().parents[2].parent / "shared" / "realdata" / "kitti" / "object"


@pytest.fixture(scope="session")
def kitti_object(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("kitti") / "kitti-object"
    proc = subprocess.run([sys.executable, "-m", "avdata.cli", "convert", "kitti-object", str(REAL_KITTI), str(out), "--quiet"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return out


@pytest.fixture(scope="session")
def generated(generated_v2i: Path) -> Path:
    return generated_v2i
