"""The house style's mechanical part: ruff and mypy report nothing on the package.

Both run with the repository's configuration (pyproject.toml) over the whole package, so CI is green only if
every module passes ``mypy --strict``; there are no per-module exceptions to keep in step.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: mypy's own TOML reader
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
# A `# type: ignore[code]` that stays says why on the same line: `# type: ignore[code]  # reason`.
_IGNORE = re.compile(r"#\s*type:\s*ignore")
_EXPLAINED_IGNORE = re.compile(r"#\s*type:\s*ignore\[[\w, -]+\]\s+#\s*\S")


def test_ruff_is_clean() -> None:
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "avdata", "tests", "benchmarks", "examples"],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr


def test_mypy_configuration_is_strict_for_the_whole_package() -> None:
    mypy = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["mypy"]
    assert mypy.get("strict") is True, mypy
    assert "overrides" not in mypy, "per-module mypy settings: the package is checked by one configuration"


def test_mypy_is_clean() -> None:
    # No flags: `mypy avdata` reads [tool.mypy] from pyproject.toml, as a developer's run does.
    result = subprocess.run([sys.executable, "-m", "mypy", "avdata"], cwd=ROOT, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr


def test_every_type_ignore_names_its_code_and_says_why() -> None:
    unexplained = [f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
                   for path in sorted((ROOT / "avdata").rglob("*.py"))
                   for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1)
                   if _IGNORE.search(line) and not _EXPLAINED_IGNORE.search(line)]
    assert not unexplained, "\n".join(unexplained)
