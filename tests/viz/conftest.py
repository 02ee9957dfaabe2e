"""Datasets for the viz tests: the real KITTI object samples converted, and a small generated V2I scene."""

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
def generated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from avdata.generators.config import load_preset, scenario_from_dict
    from avdata.generators.scenario import generate

    config = load_preset("v2i-intersection").to_dict()
    config.update(frames=3, seed=5, scenes=1)
    config["traffic"].update(vehicles=20, pedestrians=10, crossing_pedestrians=0)
    out = tmp_path_factory.mktemp("gen") / "v2i"
    generate(scenario_from_dict(config, "test"), out, progress=False)
    return out
