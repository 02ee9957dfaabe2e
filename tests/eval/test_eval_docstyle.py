"""avdata.eval's public modules keep Google-style docstrings (ruff ``D``, Google convention)."""

import subprocess
import sys
from pathlib import Path

EVAL = Path(__file__).resolve().parents[2] / "avdata" / "eval"


def test_ruff_docstring_rules_pass_on_eval():
    proc = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--select", "D", "--config", 'lint.pydocstyle.convention="google"',
         str(EVAL)],
        capture_output=True, text=True,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
