"""Suite-wide: tests that need the real sample files are skipped, with one summary line, when they are absent.

A test needs the samples when it depends on them, as pytest and Python resolve names (never by searching text):

- it uses the ``realdata`` fixture (directly or through its other fixtures), or carries the ``realdata`` marker
  (for a dependency no code shows, e.g. a subprocess given the folder through an environment variable); or
- its code reaches the folder: the test function, its fixtures, its parameters, and the test package's helper
  functions and classes they name (followed through module globals, closures and defaults, across modules: a
  module importing ``REAL_LOG`` from another test module is seen) name ``REALDATA`` or a module-level value
  derived from it (a path under it, or a tuple/list/dict holding one).

When samples are missing, such tests are found at collection, get the ``realdata`` marker, and are skipped before any
of their fixtures is set up; so no test module may read a sample at import time (``tests/test_without_samples.py``
collects the whole suite with an empty folder). Under CI (``CI=true``) missing samples fail the run at collection.
"""

from __future__ import annotations

import dis
import importlib
import importlib.util
import inspect
import os
import sys
import types
from pathlib import Path
from typing import Any

import pytest

from tests.realdata import MISSING, REALDATA, SOURCES

_skipped: set[str] = set()
_reaches_cache: dict[int, bool] = {}
_TESTS = Path(__file__).resolve().parent
#: Helper modules of the test folder (not test modules) by their bare names.
_HELPER_FILES = {p.stem: p for p in sorted(_TESTS.rglob("*.py")) if not p.stem.startswith(("test_", "_", "conftest"))}


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "realdata: needs the real sample files (tests/realdata.py); skipped without them")


@pytest.fixture(scope="session")
def realdata() -> Path:
    """The real sample folder; a test using this fixture (directly or through others) is skipped without it."""
    return REALDATA


def _derived(value: Any, depth: int = 0) -> bool:
    """Whether a module-level value is a path under REALDATA (or its text) or a (shallow) container holding one."""
    if isinstance(value, Path):
        return value.is_relative_to(REALDATA)
    if isinstance(value, str):
        return value.startswith(f"{REALDATA}{os.sep}")
    if depth < 2 and isinstance(value, tuple | list | frozenset | set) and len(value) < 10_000:
        return any(_derived(v, depth + 1) for v in value)
    if depth < 2 and isinstance(value, dict) and len(value) < 10_000:
        return any(_derived(v, depth + 1) for v in value.values())
    return False


def _ours(obj: Any) -> bool:
    """Whether a function, class or module is defined in a file of the test folder (the only code followed)."""
    if isinstance(obj, types.ModuleType):
        path = getattr(obj, "__file__", None)
    elif isinstance(obj, types.FunctionType):
        path = obj.__code__.co_filename
    else:
        path = getattr(sys.modules.get(getattr(obj, "__module__", "") or ""), "__file__", None)
    return bool(path) and Path(path).resolve().is_relative_to(_TESTS)


def _reaches(obj: Any) -> bool:
    """Whether calling ``obj`` (a function or class of the test package) can reach the real sample folder."""
    key = id(obj)
    if key not in _reaches_cache:
        _reaches_cache[key] = False  # recursion guard: a cycle adds nothing
        _reaches_cache[key] = _reaches_now(obj)
    return _reaches_cache[key]


def _reaches_now(obj: Any) -> bool:
    obj = inspect.unwrap(obj) if callable(obj) else obj
    obj = getattr(getattr(obj, "hypothesis", None), "inner_test", obj)  # a @given test: the function it wraps
    if isinstance(obj, type):
        return any(_reaches(v) for v in vars(obj).values() if isinstance(v, types.FunctionType))
    if isinstance(obj, types.MethodType):
        obj = obj.__func__
    if not isinstance(obj, types.FunctionType):
        return False
    module_globals = obj.__globals__
    values = [cell.cell_contents for cell in obj.__closure__ or () if _filled(cell)]
    values += list(obj.__defaults__ or ()) + list((obj.__kwdefaults__ or {}).values())
    names: set[str] = set()
    imported: set[str] = set()
    stack = [obj.__code__]
    while stack:
        code = stack.pop()
        names.update(code.co_names)
        imported.update(i.argval for i in dis.get_instructions(code) if i.opname == "IMPORT_NAME")
        stack.extend(c for c in code.co_consts if isinstance(c, types.CodeType))
    if "REALDATA" in names:
        return True
    values += [module_globals[name] for name in names if name in module_globals]
    # modules of the test folder imported inside the function (``from tests.x import helper``, or a helper module
    # such as tests/oracles/waymo_fixture.py imported by its bare name after a sys.path insert)
    values += [_helper_module(name) for name in imported if name.startswith("tests.") or name in _HELPER_FILES]
    # attributes of our own modules named in the code (``fixtures.REAL_LOG``)
    modules = [v for v in values if isinstance(v, types.ModuleType) and _ours(v)]
    values += [getattr(m, name) for m in modules for name in names if hasattr(m, name)]
    return any(_derived(v) or (callable(v) and not isinstance(v, types.ModuleType) and _ours(v) and _reaches(v))
               for v in values)


def _helper_module(name: str) -> types.ModuleType:
    if name in sys.modules or name.startswith("tests."):
        return importlib.import_module(name)
    spec = importlib.util.spec_from_file_location(name, _HELPER_FILES[name])
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # the test's own ``import`` later finds this one
    spec.loader.exec_module(module)
    return module


def _filled(cell: Any) -> bool:
    try:
        cell.cell_contents  # noqa: B018 (an unfilled cell raises)
    except ValueError:
        return False
    return True


def _needs_realdata(item: pytest.Item) -> bool:
    if item.get_closest_marker("realdata") or "realdata" in getattr(item, "fixturenames", ()):
        return True
    if isinstance(item, pytest.Function) and _reaches(item.obj):
        return True
    params = getattr(getattr(item, "callspec", None), "params", {})
    if any(_derived(v) or (callable(v) and _ours(v) and _reaches(v)) for v in params.values()):
        return True
    # a parameter naming a fixture the test requests by name (``request.getfixturevalue(name)``)
    manager = item.session._fixturemanager
    named = [manager.getfixturedefs(v, item) or () for v in params.values() if isinstance(v, str) and v.isidentifier()]
    if any(_reaches(d.func) for defs in named for d in defs):
        return True
    info = getattr(item, "_fixtureinfo", None)
    return any(_reaches(d.func) for defs in (info.name2fixturedefs.values() if info else ()) for d in defs)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    # The documentation's blocks are the suite's longest file (a fifth of the suite's time). Under README's `-n auto`
    # each worker takes whole files in collection order (pyproject.toml's xdist options), so that file goes first:
    # run last, it kept one worker busy minutes after the other had run out of work.
    items.sort(key=lambda item: item.path.name != "test_docs.py" or item.path.parent != _TESTS)
    if not MISSING:
        return
    needing = [item for item in items if _needs_realdata(item)]
    if needing and os.environ.get("CI") == "true":
        raise pytest.UsageError(f"CI=true and the real sample files are missing at {REALDATA}: {', '.join(MISSING)} "
                                f"(set AVDATA_REALDATA); {len(needing)} tests need them")
    for item in needing:
        item.add_marker(pytest.mark.realdata)
        _skipped.add(item.nodeid)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    """Skips, before any fixture is set up, a test that collection found to need the missing samples.

    Raised here rather than through a ``skip`` marker so that ``-ra`` folds every such skip into one line.
    """
    if item.nodeid in _skipped:
        pytest.skip(f"real sample files missing at {REALDATA}: {', '.join(MISSING)}")


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if _skipped:
        sources = "; ".join(f"{name}: {origin}" for name, origin in SOURCES.items())
        terminalreporter.write_line(
            f"{len(_skipped)} tests skipped: the real sample files are missing at {REALDATA} ({', '.join(MISSING)}; "
            f"set AVDATA_REALDATA to their folder; README 'Real sample files' lists them). They come from {sources}.")


@pytest.fixture(scope="session")
def generated_v2i(tmp_path_factory: pytest.TempPathFactory):
    """A small generated V2I dataset shared by the tests that only read one: 3 frames, 20 vehicles, 10 pedestrians,
    an ego with a 64-beam lidar and a camera, 2 infrastructure lidars (v2i-intersection preset, seed 5)."""
    from avdata.generators.config import load_preset, scenario_from_dict
    from avdata.generators.driver import generate

    config = load_preset("v2i-intersection").to_dict()
    config.update(frames=3, seed=5, scenes=1)
    config["traffic"].update(vehicles=20, pedestrians=10, crossing_pedestrians=0)
    config["infrastructure"]["count"] = 2
    out = tmp_path_factory.mktemp("generated_v2i") / "v2i"
    generate(scenario_from_dict(config, "test fixture"), out, progress=False)
    return out


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray instance on 2 CPUs for a test module; its workers import this tree as the test process does."""
    ray = pytest.importorskip("ray")
    root = Path(__file__).resolve().parents[1]
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}})
    yield
    ray.shutdown()
