"""Datasets for the viz tests: the real KITTI object samples converted, and the suite's small generated V2I scene."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.realdata import REALDATA

REAL_KITTI = REALDATA / "kitti" / "object"


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


#: Each real sample the suite converts, its convert command, and what the converted dataset lacks (README's table).
REAL_SAMPLES = {
    "kitti-object": ("kitti-object", REALDATA / "kitti" / "object"),
    "kitti-tracking": ("kitti-tracking", REALDATA / "kitti" / "tracking"),
    "kitti-raw": ("kitti-raw", REALDATA / "kitti" / "raw"),  # no lidar, no camera, no labels
    "lyft": ("nuscenes", REALDATA / "nuscenes_schema" / "lyft" / "v1.01-train"),
    "argoverse2": ("argoverse2", REALDATA / "argoverse2" / "sensor"),  # no camera images
    "waymo-v2": ("waymo", REALDATA / "waymo_v2"),  # ego poses only: no lidar, camera or boxes
    "v2xset": ("opv2v", REALDATA / "v2xset"),  # labels only, a single frame
}


@pytest.fixture(scope="session")
def real_datasets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Every real sample converted (in-process: no interpreter start per sample). Partial samples convert with
    errors about what they lack (exit 1) but still write their scene."""
    from avdata.cli import main

    root = tmp_path_factory.mktemp("real")
    out = {}
    for name, (converter, src) in REAL_SAMPLES.items():
        main(["convert", converter, str(src), str(root / name), "--quiet"])
        assert (root / name / "avdata.json").is_file(), name
        out[name] = root / name
    return out


@pytest.fixture(scope="session")
def demo_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from avdata.demo import write_demo

    return write_demo(tmp_path_factory.mktemp("demo") / "demo")


@pytest.fixture(scope="session")
def chromium() -> str:
    from tests.viz.browser import chromium_or_skip

    return chromium_or_skip()
