"""Every ```bash and ```python block of README.md and docs/*.md runs, so no documented command goes stale.

One test per file. A file's blocks run in order in one fresh temporary folder (the folder is the only state
they share): bash blocks as scripts with ``set -euo pipefail`` (each line a command; the first failure stops
the block), python blocks with this interpreter. ``avdata`` on their PATH runs this checkout's code, the
environment variable ``REALDATA`` names the real sample folder, and links to the checkout's ``studies/`` and
``examples/`` make commands written for the project root work. A block preceded by the line
``<!-- docs-test: skip (reason) -->`` is not run; the reason is required. Other languages (```text,
```yaml, ```console) are never run.
"""

from __future__ import annotations

import os
import re
import stat
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.realdata import REALDATA

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RUNNABLE = ("bash", "python")
SKIP = re.compile(r"^<!-- docs-test: skip(?: \((?P<reason>.*)\))? -->$")
FENCE = re.compile(r"^```(?P<language>\S*)\s*$")


@dataclass(frozen=True)
class Block:
    """A fenced code block: its language, first line number (1-based, the fence), code and skip reason."""

    language: str
    line: int
    code: str
    skip: str | None


def blocks(path: Path) -> list[Block]:
    """Every fenced block of a Markdown file, with the skip marker of the line just before its fence."""
    lines = path.read_text().splitlines()
    found = []
    i = 0
    while i < len(lines):
        opening = FENCE.match(lines[i])
        if not opening:
            i += 1
            continue
        end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")), None)
        assert end is not None, f"{path.name}:{i + 1}: a code block without its closing fence"
        marker = SKIP.match(lines[i - 1].strip()) if i else None
        if marker:
            assert (marker["reason"] or "").strip(), f"{path.name}:{i}: docs-test skip without a reason"
        found.append(Block(opening["language"], i + 1, "\n".join(lines[i + 1:end]) + "\n",
                           marker["reason"] if marker else None))
        i = end + 1
    return found


def _environment(tmp_path: Path) -> dict[str, str]:
    shim = tmp_path / ".bin"
    shim.mkdir()
    avdata = shim / "avdata"
    avdata.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m avdata.cli "$@"\n')
    avdata.chmod(avdata.stat().st_mode | stat.S_IEXEC)
    env = dict(os.environ)
    env.update(PATH=f"{shim}{os.pathsep}{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}",
               PYTHONPATH=f"{ROOT}{os.pathsep}{env.get('PYTHONPATH', '')}".rstrip(os.pathsep),
               REALDATA=str(REALDATA), MPLBACKEND="Agg")
    return env


def test_the_parser_finds_blocks_and_requires_a_reason(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("text\n```bash\necho a\n```\n<!-- docs-test: skip (needs a cluster) -->\n```python\nx\n```\n"
                    "```text\nnot run\n```\n")
    assert [(b.language, b.line, b.code, b.skip) for b in blocks(page)] == [
        ("bash", 2, "echo a\n", None), ("python", 6, "x\n", "needs a cluster"), ("text", 9, "not run\n", None)]
    page.write_text("<!-- docs-test: skip -->\n```bash\necho a\n```\n")
    with pytest.raises(AssertionError, match="skip without a reason"):
        blocks(page)


@pytest.mark.parametrize("doc", DOCS, ids=[p.relative_to(ROOT).as_posix() for p in DOCS])
def test_every_block_runs(doc: Path, tmp_path: Path) -> None:
    runnable = [b for b in blocks(doc) if b.language in RUNNABLE and b.skip is None]
    if not runnable:
        pytest.skip(f"{doc.name}: no runnable block")
    work = tmp_path / "work"
    work.mkdir()
    for folder in ("studies", "examples"):
        (work / folder).symlink_to(ROOT / folder, target_is_directory=True)
    env = _environment(tmp_path)
    for block in runnable:
        if block.language == "bash":
            argv = ["bash", "-euo", "pipefail", "-c", block.code]
        else:
            script = tmp_path / f"block_{block.line}.py"
            script.write_text(block.code)
            argv = [sys.executable, str(script)]
        result = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, (f"{doc.relative_to(ROOT)}:{block.line}: the {block.language} block "
                                        f"failed (exit {result.returncode}):\n{block.code}\n--- stderr:\n"
                                        f"{result.stderr[-3000:]}\n--- stdout:\n{result.stdout[-1000:]}")
