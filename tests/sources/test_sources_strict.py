"""The sources layer of KITTI and nuScenes passes ``mypy --strict`` and ruff's Google docstring rules (Issue 10.6)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PATHS = ["avdata/sources/kitti", "avdata/sources/nuscenes", "avdata/sources/_checks.py"]


def test_mypy_strict_on_kitti_and_nuscenes_sources() -> None:
    # follow-imports=silent: modules below (avdata.frames) are checked by their own owners' settings.
    result = subprocess.run([sys.executable, "-m", "mypy", "--strict", "--follow-imports=silent", *PATHS],
                            cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_google_docstrings_on_kitti_and_nuscenes_sources() -> None:
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--select", "D", "--config",
                             'lint.pydocstyle.convention="google"', *PATHS],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
