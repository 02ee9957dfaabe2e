"""The package's shape: modules a reader does not page through, layers that only point down.

Measured with ``ast`` over every module of ``avdata``:
- no module over 600 lines and no function (or method) over 80 lines, from its ``def`` to its last line;
- no import cycle between modules (every import counts, also those inside functions: an import deferred
  to run time still ties the two modules together);
- a private module (``_name.py``) is imported only inside the package that holds it.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "avdata"
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80

# Private modules imported from outside their package, each with the reason (none today).
PRIVATE_IMPORTS_ALLOWED: dict[tuple[str, str], str] = {}


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package."""
    modules = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


MODULES = _modules()


def _imported_modules(name: str, path: Path) -> Iterator[tuple[str, int]]:
    """(avdata module, line) of each import in the module, resolved to the most specific module imported."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join([*package[:len(package) - node.level + 1], *([node.module] if node.module else [])])
            targets = [f"{base}.{alias.name}" for alias in node.names]  # the name may be a sub-module
        else:
            continue
        for target in targets:
            while target and target not in MODULES:
                target = target.rpartition(".")[0]
            if target and target != name:
                yield target, node.lineno


def _import_graph() -> dict[str, dict[str, int]]:
    """Module -> {imported avdata module: first line importing it}."""
    graph: dict[str, dict[str, int]] = {}
    for name, path in MODULES.items():
        edges: dict[str, int] = {}
        for target, line in _imported_modules(name, path):
            edges.setdefault(target, line)
        graph[name] = edges
    return graph


def _cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each as a list of modules."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return components


def _functions(path: Path) -> Iterator[tuple[str, int, int]]:
    """(qualified name, first line, length in lines) of every function and method in the file."""

    def walk(node: ast.AST, prefix: str) -> Iterator[tuple[str, int, int]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                assert child.end_lineno is not None
                yield f"{prefix}{child.name}", child.lineno, child.end_lineno - child.lineno + 1
                yield from walk(child, f"{prefix}{child.name}.")
            elif isinstance(child, ast.ClassDef):
                yield from walk(child, f"{prefix}{child.name}.")
            else:
                yield from walk(child, prefix)

    yield from walk(ast.parse(path.read_text(encoding="utf-8")), "")


def test_the_checks_see_the_whole_package() -> None:
    assert len(MODULES) > 150
    assert {"avdata", "avdata.cli", "avdata.schema.mcap", "avdata.generators.scenario"} <= set(MODULES)


def test_no_module_over_600_lines() -> None:
    long = {f"{path.relative_to(ROOT)}: {n} lines" for path in MODULES.values()
            if (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert not long, "\n".join(sorted(long))


def test_no_function_over_80_lines() -> None:
    long = [f"{path.relative_to(ROOT)}:{line}: {name} has {length} lines"
            for path in MODULES.values() for name, line, length in _functions(path) if length > MAX_FUNCTION_LINES]
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(sorted(long))


def test_no_import_cycle_between_modules() -> None:
    graph = _import_graph()
    cycles = _cycles(graph)
    described = ["  " + ", ".join(f"{m} imports {t} (line {graph[m][t]})" for m in c for t in graph[m] if t in c)
                 for c in cycles]
    assert not cycles, "modules importing each other:\n" + "\n".join(described)


def test_private_modules_are_imported_only_inside_their_package() -> None:
    crossings = []
    for name, edges in _import_graph().items():
        for target, line in edges.items():
            parts = target.split(".")
            private = next((i for i, part in enumerate(parts) if part.startswith("_")), None)
            if private is None:
                continue
            owner = ".".join(parts[:private])  # the package holding the private module
            inside = name == owner or name.startswith(owner + ".")
            if not inside and (name, target) not in PRIVATE_IMPORTS_ALLOWED:
                crossings.append(f"{MODULES[name].relative_to(ROOT)}:{line}: imports the private {target}")
    assert not crossings, "\n".join(crossings)


def test_the_checks_find_what_they_look_for(tmp_path: Path) -> None:
    """The measures themselves, on small made-up cases (a check that finds nothing must be able to)."""
    assert _cycles({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b": 1}, "b": {}}) == []
    source = tmp_path / "example.py"
    source.write_text("from . import config\n"
                      "class A:\n"
                      "    def method(self) -> None:\n"
                      "        from avdata.schema.limits import MAX_TIME_NS\n"
                      "        import numpy\n"
                      "\n"
                      "        return None\n", encoding="utf-8")
    assert list(_imported_modules("avdata.generators.example", source)) == [
        ("avdata.generators.config", 1), ("avdata.schema.limits", 4)]
    assert list(_functions(source)) == [("A.method", 3, 5)]
