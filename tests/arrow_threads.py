"""How many threads a piece of code starts, counted in a fresh interpreter (Linux: ``/proc/self/task``).

Arrow starts its thread pools' workers on their first task, so a fresh interpreter that runs ``setup`` and then
``code`` starts pool threads during ``code`` exactly when ``code`` gave the pool work. Tests use it to check that
reads of Python-owned bytes stay off the pool: a worker dropping the last reference to such bytes after the read
returned takes the GIL, which aborts the process when that happens during interpreter exit (docs/decisions.md).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

_COUNT = "__import__('os').listdir('/proc/self/task').__len__()"


def threads_started(setup: str, code: str) -> int:
    """Threads alive after ``code`` minus those alive after ``setup`` (both run in one new interpreter)."""
    if not Path("/proc/self/task").is_dir():
        pytest.skip("counting threads needs Linux's /proc/self/task")
    script = f"{setup}\nbefore = {_COUNT}\n{code}\nprint({_COUNT} - before)\n"
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    return int(result.stdout.split()[-1])
