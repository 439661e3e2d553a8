"""The structure the project promises: dependencies point one way, eval has no import cycle,
measure imports neither Mitsuba nor Open3D, no module points at files outside the repository."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("measure", "synth", "eval")


def _imports(path: Path) -> set[str]:
    """Every module a file imports, at module level or inside functions (absolute names)."""
    package = path.parent.name
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = f"{package}.{base}" if base else package
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


def _graph(package: str) -> dict[str, set[str]]:
    modules = {f"{package}.{p.stem}": p for p in (ROOT / package).glob("*.py")}
    return {name: {m for m in _imports(path) if m in modules and m != name}
            for name, path in modules.items()}


@pytest.mark.parametrize("package", PACKAGES)
def test_no_import_cycle(package):
    graph = _graph(package)
    state = {}

    def visit(node, stack):
        state[node] = "open"
        for child in sorted(graph[node]):
            if state.get(child) == "open":
                raise AssertionError(f"import cycle: {' -> '.join(stack + [node, child])}")
            if child not in state:
                visit(child, stack + [node])
        state[node] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [])


@pytest.mark.parametrize("package, forbidden", [
    ("measure", ("mitsuba", "drjit", "open3d", "synth", "eval")),
    ("synth", ("eval",)),
])
def test_dependencies_point_one_way(package, forbidden):
    for path in (ROOT / package).glob("*.py"):
        bad = {m for m in _imports(path) if m.split(".")[0] in forbidden}
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def test_no_pointers_outside_the_repository():
    for package in PACKAGES + ("tests",):
        for path in (ROOT / package).glob("*.py"):
            text = path.read_text()
            assert "DESIGN" + ".md" not in text and "../" + "shared" not in text, path.name
