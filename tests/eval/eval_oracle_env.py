"""Locating and running the reference implementations' virtual environments (tests/oracles/make_envs.sh)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ORACLES = REPO / "tests" / "oracles"


def run_oracle(env: str, script: str, *args: str, timeout_s: float = 600) -> dict:
    """Runs ``tests/oracles/<script>`` with the python of ``.oracle-envs/<env>`` and parses its JSON output.

    Fails (never skips) when the environment is missing: CI creates it before running the tests.
    """
    python = REPO / ".oracle-envs" / env / "bin" / "python"
    assert python.exists(), f"oracle env {env} missing at {python}; run tests/oracles/make_envs.sh"
    proc = subprocess.run(
        [str(python), str(ORACLES / script), *args], capture_output=True, text=True, timeout=timeout_s
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout)
