"""The structure the project promises: dependencies point one way (subpackages included), no
package has an import cycle, measure imports neither Mitsuba nor Open3D, no private name crosses a
module boundary, one import style per package, no command imports another command, the tests
mirror the package tree, no module points at files outside the repository."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from eval.cli import SUBCOMMANDS

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("measure", "synth", "eval")
#: Modules holding a command of ``python -m eval`` (its parser and main); only the dispatcher
#: ``eval.cli`` imports them.
EVAL_COMMANDS = SUBCOMMANDS


def _module_name(path: Path) -> str:
    """``eval/run/command.py`` → ``eval.run.command``; ``eval/run/__init__.py`` → ``eval.run``."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _files(top: str):
    """Every Python file of ``top`` (a package or ``tests``/``tools``), subfolders included."""
    return sorted((ROOT / top).rglob("*.py"))


def _import_nodes(path: Path):
    """``(node, absolute module)`` for every import of a file, at module level or inside
    functions; a relative import is resolved against the file's package."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node, alias.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[:len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            yield node, base


def _imports(path: Path) -> set[str]:
    """Every module a file imports, and every ``module.name`` it imports from one."""
    found = set()
    for node, base in _import_nodes(path):
        found.add(base)
        if isinstance(node, ast.ImportFrom):
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


def _graph(package: str) -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in _files(package)}
    graph = {}
    for name, path in modules.items():
        targets = set()
        for imported in _imports(path):
            # an import of a subpackage's name depends on that subpackage's __init__ only
            while imported and imported not in modules:
                imported = imported.rpartition(".")[0]
            if imported and imported != name and not name.startswith(imported + "."):
                targets.add(imported)
        graph[name] = targets
    return graph


def test_subpackages_are_seen():
    """The walk below reaches into subpackages (a flat glob would let them slip past)."""
    assert "eval.run.pipeline" in _graph("eval")
    assert "eval.run.config" in _graph("eval")["eval.run.pipeline"]


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
    for path in _files(package):
        bad = {m for m in _imports(path) if m.split(".")[0] in forbidden}
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


@pytest.mark.parametrize("top", PACKAGES + ("tests", "tools"))
def test_no_private_name_crosses_a_module(top):
    """``from x import _y`` (or ``import x._y``) of a project module is refused: what two
    modules share is public."""
    bad = []
    for path in _files(top):
        for node, base in _import_nodes(path):
            if base.split(".")[0] not in PACKAGES:
                continue
            names = ([a.name for a in node.names] if isinstance(node, ast.ImportFrom) else [])
            parts = base.split(".") + names
            if any(p.startswith("_") and not p.startswith("__") for p in parts):
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno} imports "
                           f"{base}{':' + ','.join(names) if names else ''}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("package", PACKAGES)
def test_one_import_style_per_package(package):
    """Inside a package its own modules are imported either all relatively or all absolutely."""
    styles = {}
    for path in _files(package):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                styles.setdefault("relative", path.relative_to(ROOT))
            elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == package:
                styles.setdefault("absolute", path.relative_to(ROOT))
            elif isinstance(node, ast.Import) and any(a.name.split(".")[0] == package
                                                      for a in node.names):
                styles.setdefault("absolute", path.relative_to(ROOT))
    assert len(styles) <= 1, f"{package} mixes import styles: {styles}"


def test_no_command_imports_another_command():
    """Commands share code through ``eval.core`` and the library parts of other command
    packages (``eval.run.config``, ``eval.run.pipeline``), never through a command module: only
    the dispatcher ``eval.cli`` imports them."""
    for path in _files("eval"):
        name = _module_name(path)
        if name == "eval.cli":
            continue
        for imported in _imports(path):
            for command in EVAL_COMMANDS:
                if (imported == command or imported.startswith(command + ".")) and name != command:
                    raise AssertionError(f"{name} imports the command module {command}")
    cells = _imports(ROOT / "eval" / "sweep" / "cells.py")
    assert not {m for m in cells if m.startswith("eval.cli")}, "a sweep cell parses no argv"


def test_tests_mirror_the_package_tree():
    """Every test module lives in ``tests/<package>/`` (or ``tests/`` for the whole project) and
    every folder of tests names a package or subpackage that exists."""
    for path in _files("tests"):
        folder = path.parent.relative_to(ROOT / "tests")
        if folder.parts:
            assert (ROOT / folder).is_dir() and (ROOT / folder / "__init__.py").exists(), (
                f"{path.relative_to(ROOT)}: no package {folder.as_posix()} to mirror")


def test_no_pointers_outside_the_repository():
    for top in PACKAGES + ("tests", "tools"):
        for path in _files(top):
            text = path.read_text()
            assert "DESIGN" + ".md" not in text and "../" + "shared" not in text, path.name


#: The rooms of ``measure`` and ``synth`` (docs/architecture.md, "rooms by concept"): at most this
#: many entries at a package's top level, each subfolder a package that says what it holds.
MAX_TOP_LEVEL_ENTRIES = 10


@pytest.mark.parametrize("package", ("measure", "synth"))
def test_packages_are_rooms(package):
    entries = sorted(p.name for p in (ROOT / package).iterdir()
                     if not p.name.startswith((".", "__pycache__")))
    assert len(entries) <= MAX_TOP_LEVEL_ENTRIES, f"{package}/ has {len(entries)} entries: {entries}"
    for room in (ROOT / package).iterdir():
        if room.is_dir() and not room.name.startswith((".", "__pycache__")):
            init = room / "__init__.py"
            assert init.exists(), f"{package}/{room.name} is not a package"
            assert ast.get_docstring(ast.parse(init.read_text())), (
                f"{package}/{room.name}/__init__.py does not say what the room holds")


#: The modules that implement the kinds of port (docs/architecture.md, "The port interface").
PORT_MODULES = {f"measure/geometry/{name}.py" for name in (
    "port", "dome", "flat_pair", "refraction", "projection", "plane_path", "dome_projection",
    "flatport_format")}
#: What asks which kind of port it holds (the issue's count: 80 lines in 31 files before the port
#: interface).
PORT_KIND = re.compile(r"isinstance\([^)]*(DomePair|DomePort|FlatPort)|is_dome|port_of\(")
#: Lines outside the port modules that still branch on the port's kind, and the places (files)
#: they are in, each listed with its reason in docs/architecture.md (the goals: at most 5
#: places, then at most 3 lines; 3 lines in 2 places since the port is asked for its one water
#: plane and its closed-form apparent depths).
MAX_PORT_KIND_BRANCHES, MAX_PORT_KIND_PLACES = 3, 2


def _port_kind_branches():
    found = []
    for package in PACKAGES:
        for path in _files(package):
            rel = path.relative_to(ROOT).as_posix()
            if rel in PORT_MODULES:
                continue
            for number, line in enumerate(path.read_text().splitlines(), 1):
                if PORT_KIND.search(line):
                    found.append((rel, number, line.strip()))
    return found


def test_code_asks_the_port_not_its_kind():
    """Outside the port modules the code calls the port interface (``RigPort``) instead of asking
    which kind of port it holds; the few places that still branch are listed, with their reasons,
    in docs/architecture.md."""
    found = _port_kind_branches()
    assert len(found) <= MAX_PORT_KIND_BRANCHES, "\n".join(f"{r}:{n}: {s}" for r, n, s in found)
    assert len({rel for rel, _, _ in found}) <= MAX_PORT_KIND_PLACES, sorted({r for r, _, _ in found})
    documented = (ROOT / "docs" / "architecture.md").read_text()
    missing = sorted({rel for rel, _, _ in found if f"`{rel}`" not in documented})
    assert not missing, f"port-kind branches not listed in docs/architecture.md: {missing}"


def test_measure_rooms_point_one_way():
    """``measure``'s rooms form no cycle (``calibration`` → ``stereo`` → ``geometry``; ``dense``
    and ``images`` → ``stereo``, ``geometry``): a reader can take them bottom up."""
    graph = {}
    for module, targets in _graph("measure").items():
        room = module.split(".")[1] if "." in module else ""
        for target in targets:
            other = target.split(".")[1] if "." in target else ""
            if room and other and room != other:
                graph.setdefault(room, set()).add(other)
    state = {}

    def visit(node, stack):
        state[node] = "open"
        for child in sorted(graph.get(node, ())):
            assert state.get(child) != "open", f"rooms import each other: {stack + [node, child]}"
            if child not in state:
                visit(child, stack + [node])
        state[node] = "done"

    for room in sorted(graph):
        if room not in state:
            visit(room, [])
