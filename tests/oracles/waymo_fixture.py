"""The real-data Waymo v2 fixture, built once per machine by Waymo's own code and cached in a tmp dir.

``waymo_v2_fixture()`` runs ``waymo_v2_fixture.py`` (compat_v1 on the real v1 frame, plus Waymo's points)
with the waymo oracle venv into ``<tmp>/avdata-waymo-v2-<hash>/``; the hash covers the script and the
real frame, so an edited script rebuilds. Built under a temporary name and renamed, so concurrent test
runs never see a half-built folder. Used by every Waymo test module (host Python).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
REALDATA = REPO.parent / "shared" / "realdata"
V1_FRAME = REALDATA / "waymo_v1" / "pvps_data_one_frame.tfrecord"
REAL_POSES = REALDATA / "waymo_v2" / "vehicle_pose"
PYTHON = REPO / ".oracle-envs" / "waymo" / "bin" / "python"
SCRIPT = Path(__file__).resolve().parent / "waymo_v2_fixture.py"


@functools.lru_cache(maxsize=1)
def waymo_v2_fixture() -> tuple[Path, dict]:
    """(folder of ``<component>/<context>.parquet`` and ``points_<laser>.npz``, {context, lasers})."""
    if not PYTHON.exists():
        raise AssertionError(f"oracle env waymo missing at {PYTHON}; run tests/oracles/make_envs.sh")
    digest = hashlib.sha256(SCRIPT.read_bytes() + V1_FRAME.read_bytes()).hexdigest()[:16]
    final = Path(tempfile.gettempdir()) / f"avdata-waymo-v2-{digest}"
    if not (final / "info.json").is_file():
        building = Path(tempfile.mkdtemp(prefix=f"{final.name}.building-"))
        proc = subprocess.run([str(PYTHON), str(SCRIPT), str(V1_FRAME), str(building)],
                              capture_output=True, text=True, timeout=900)
        if proc.returncode != 0:
            shutil.rmtree(building, ignore_errors=True)
            raise AssertionError(proc.stderr[-3000:])
        (building / "info.json").write_text(proc.stdout.strip().splitlines()[-1])
        try:
            os.rename(building, final)
        except OSError:  # another run finished first
            shutil.rmtree(building, ignore_errors=True)
    return final, json.loads((final / "info.json").read_text())
