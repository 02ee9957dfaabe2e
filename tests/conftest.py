"""Suite-wide: tests that need the real sample files are skipped, with one summary line, when they are absent.

A test needs them when its module mentions ``REALDATA`` or the ``realdata`` folder, or a fixture it uses
names ``REALDATA`` or a path under it. Under CI (``CI=true``) their absence fails the run at collection instead.
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path

import pytest

from tests.realdata import REALDATA, SOURCES

_MISSING = not REALDATA.is_dir()
_skipped: list[str] = []


@cache
def _mentions_realdata(module_file: str | None) -> bool:
    if not module_file:
        return False
    try:
        with open(module_file, encoding="utf-8") as handle:
            text = handle.read()
    except OSError:
        return False
    return "REALDATA" in text or "realdata" in text


def _uses_realdata(func: object) -> bool:
    """Whether a fixture's code names REALDATA or a module-level path under it (nested functions included)."""
    code = getattr(func, "__code__", None)
    module_globals = getattr(func, "__globals__", {})
    stack = [code] if code is not None else []
    while stack:
        current = stack.pop()
        for name in current.co_names:
            value = module_globals.get(name)
            if name == "REALDATA" or (isinstance(value, Path) and value.is_relative_to(REALDATA)):
                return True
        stack.extend(c for c in current.co_consts if hasattr(c, "co_names"))
    return False


def _needs_realdata(item: pytest.Item) -> bool:
    if _mentions_realdata(getattr(item, "fspath", None) and str(item.fspath)):
        return True
    info = getattr(item, "_fixtureinfo", None)
    for defs in (info.name2fixturedefs.values() if info else ()):
        if any(_uses_realdata(getattr(d, "func", None)) for d in defs):
            return True
    return False


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not _MISSING:
        return
    if os.environ.get("CI") == "true":
        raise pytest.UsageError(f"CI=true and the real sample files are missing at {REALDATA} (set AVDATA_REALDATA)")
    marker = pytest.mark.skip(reason=f"real sample files missing at {REALDATA}")
    for item in items:
        if _needs_realdata(item):
            item.add_marker(marker)
            _skipped.append(item.nodeid)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if _skipped:
        sources = "; ".join(f"{name}: {origin}" for name, origin in SOURCES.items())
        terminalreporter.write_line(
            f"{len(_skipped)} tests skipped: the real sample files are missing at {REALDATA} (set AVDATA_REALDATA to "
            f"their folder; README 'Real sample files' lists them). They come from {sources}.")


@pytest.fixture(scope="session")
def generated_v2i(tmp_path_factory: pytest.TempPathFactory):
    """A small generated V2I dataset shared by the tests that only read one: 3 frames, 20 vehicles, 10 pedestrians,
    an ego with a 64-beam lidar and a camera, 2 infrastructure lidars (v2i-intersection preset, seed 5)."""
    from avdata.generators.config import load_preset, scenario_from_dict
    from avdata.generators.scenario import generate

    config = load_preset("v2i-intersection").to_dict()
    config.update(frames=3, seed=5, scenes=1)
    config["traffic"].update(vehicles=20, pedestrians=10, crossing_pedestrians=0)
    config["infrastructure"]["count"] = 2
    out = tmp_path_factory.mktemp("generated_v2i") / "v2i"
    generate(scenario_from_dict(config, "test fixture"), out, progress=False)
    return out
