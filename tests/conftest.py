"""Suite-wide: tests that need the real sample files are skipped, with one summary line, when they are absent.

A test needs them when its module, or the module of a fixture it uses, mentions ``REALDATA`` or the
``realdata`` folder. Under CI (``CI=true``) their absence fails the run at collection instead.
"""

from __future__ import annotations

import inspect
import os
from functools import cache

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


def _needs_realdata(item: pytest.Item) -> bool:
    if _mentions_realdata(getattr(item, "fspath", None) and str(item.fspath)):
        return True
    info = getattr(item, "_fixtureinfo", None)
    for defs in (info.name2fixturedefs.values() if info else ()):
        for fixturedef in defs:
            func = getattr(fixturedef, "func", None)
            if func is not None and _mentions_realdata(inspect.getsourcefile(func)):
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
