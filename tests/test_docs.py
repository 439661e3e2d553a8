"""The documentation stays true to the repository: links, paths, commands, README length.

Checked files: ``README.md`` and every ``docs/*.md``.

Rules (each test names the file and the offending text):

* **Links.** Every relative Markdown link ``[text](target)``, image ``![alt](target)`` and
  reference definition ``[label]: target`` outside code must point to an existing file or folder,
  resolved from the folder of the page that holds it. A ``#anchor`` is stripped; a target that is
  only an anchor, and ``http://``, ``https://`` and ``mailto:`` targets are skipped.
* **Paths in backticks.** Every whitespace-separated token of an inline code span (``...``,
  outside fenced blocks) that starts with ``scenes/``, ``sweeps/``, ``tools/``, ``docs/``,
  ``tests/``, ``measure/``, ``synth/`` or ``eval/``, or that is ``Makefile`` or
  ``pyproject.toml``, is a repository path (relative to the repository root) and must exist.
  Quotes, brackets and trailing punctuation (``,;:.)``) around the token are stripped, and so
  are a ``::test`` suffix and a ``:LINE`` suffix. A token is a *pattern or placeholder*, and is
  skipped, when it contains any of ``* ? [ ] { } < > … |`` or ``...``, or when one of the parts
  of its name (split at ``/ . _ -``) is an upper-case word such as ``X``, ``NAME`` or ``DIR``
  (``scenes/speckle_X.xml``, ``sweeps/<name>.toml``, ``scenes/*.xml``). Paths under ``out/``
  and other generated folders are not checked.
* **Commands.** Every ``python -m eval NAME``, ``python -m synth NAME`` (also
  ``refstereo-eval NAME`` / ``refstereo-synth NAME``) in an inline code span or a fenced code
  block names a subcommand of that command line's argparse parser (``eval.cli.build_parser``;
  ``synth.commands.build_parser``, else ``synth.__main__.build_parser``). A ``NAME`` that starts
  with ``-`` or is a placeholder by the rule above (``COMMAND``, ``…``) is skipped. Likewise every
  ``make TARGET`` (options ``-x`` and assignments ``VAR=value`` skipped, up to ``#``, ``&&``,
  ``;`` or ``|``) names a target of the Makefile.
* ``README.md`` has at most 300 lines.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PAGE_IDS = [str(p.relative_to(ROOT)) for p in PAGES]

README_MAX_LINES = 300
PATH_PREFIXES = ("scenes/", "sweeps/", "suites/", "tools/", "docs/", "tests/", "measure/", "synth/", "eval/")
PATH_NAMES = ("Makefile", "pyproject.toml")
PLACEHOLDER_CHARS = set("*?[]{}<>…|")

FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})[^\n]*\n(.*?)^ {0,3}\1[ \t]*$", re.S | re.M)
CODE_SPAN = re.compile(r"(?<!`)(`+)(?!`)(.+?)(?<!`)\1(?!`)", re.S)
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]*)>?(?:\s+[\"'(][^)]*)?\)")
REF_DEF = re.compile(r"^ {0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s.*)?$", re.M)
COMMAND = re.compile(r"(?:python3?\s+-m\s+|refstereo-)(eval|synth)\s+(\S+)")
MAKE = re.compile(r"(?<![\w./-])make\s+([^\n#&;|`]*)")


def split_markdown(text: str) -> tuple[str, list[str], list[str]]:
    """(prose with code removed, inline code spans, fenced code blocks) of a Markdown page."""
    blocks = [m.group(2) for m in FENCE.finditer(text)]
    prose = FENCE.sub("\n", text)
    spans = [m.group(2).strip() for m in CODE_SPAN.finditer(prose)]
    prose = CODE_SPAN.sub("CODE", prose)
    return prose, spans, blocks


@functools.cache
def parsed(page: Path) -> tuple[str, list[str], list[str]]:
    return split_markdown(page.read_text(encoding="utf-8"))


def is_placeholder(token: str) -> bool:
    if any(c in PLACEHOLDER_CHARS for c in token) or "..." in token:
        return True
    return any(re.fullmatch(r"[A-Z]+", part) for part in re.split(r"[/._-]", token) if part)


def repo_paths(span: str) -> list[str]:
    """The repository paths named in one inline code span (see the module docstring)."""
    found = []
    for token in span.split():
        token = token.strip("\"'`()[],;")
        token = re.sub(r"::.*$", "", token)
        token = re.sub(r":\d+$", "", token)
        token = token.rstrip(".:")
        if not (token.startswith(PATH_PREFIXES) or token in PATH_NAMES):
            continue
        if not is_placeholder(token):
            found.append(token)
    return found


@functools.cache
def subcommands(cli: str) -> frozenset[str]:
    """The subcommand names of ``python -m eval`` or ``python -m synth``, from their parsers."""
    candidates = {"eval": ["eval.cli"], "synth": ["synth.commands", "synth.__main__"]}[cli]
    for name in candidates:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as error:
            if error.name is not None and name.startswith(error.name):
                continue  # that module does not exist (any more): try the next one
            raise
        if hasattr(module, "build_parser"):
            parser = module.build_parser()
            break
    else:
        raise AssertionError(f"no build_parser in any of {candidates}")
    names = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            names.update(action.choices)
    assert names, f"the {cli} parser has no subcommands"
    return frozenset(names)


@functools.cache
def make_targets() -> frozenset[str]:
    targets = set()
    for line in (ROOT / "Makefile").read_text(encoding="utf-8").splitlines():
        m = re.match(r"^([A-Za-z0-9_.%/-]+(?:[ \t]+[A-Za-z0-9_.%/-]+)*)[ \t]*:(?![=:])", line)
        if m:
            targets.update(t for t in m.group(1).split() if not t.startswith("."))
    return frozenset(targets)


def code_texts(page: Path) -> list[str]:
    _, spans, blocks = parsed(page)
    return spans + blocks


@pytest.mark.parametrize("page", PAGES, ids=PAGE_IDS)
def test_relative_links_exist(page):
    prose, _, _ = parsed(page)
    missing = []
    for target in LINK.findall(prose) + REF_DEF.findall(prose):
        if not target or target.startswith(("#", "http://", "https://", "mailto:")):
            continue
        path = target.split("#", 1)[0]
        if path and not (page.parent / path).exists():
            missing.append(target)
    assert not missing, f"{page.relative_to(ROOT)}: links to nothing: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=PAGE_IDS)
def test_paths_in_backticks_exist(page):
    _, spans, _ = parsed(page)
    missing = sorted({p for span in spans for p in repo_paths(span) if not (ROOT / p).exists()})
    assert not missing, f"{page.relative_to(ROOT)}: paths that do not exist: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=PAGE_IDS)
def test_commands_exist(page):
    unknown = []
    for text in code_texts(page):
        for cli, name in COMMAND.findall(text):
            name = name.strip("`'\",;)")
            if not name or name.startswith("-") or is_placeholder(name):
                continue
            if name not in subcommands(cli):
                unknown.append(f"python -m {cli} {name}")
    assert not unknown, f"{page.relative_to(ROOT)}: unknown subcommands: {sorted(set(unknown))}"


@pytest.mark.parametrize("page", PAGES, ids=PAGE_IDS)
def test_make_targets_exist(page):
    unknown = []
    for text in code_texts(page):
        for rest in MAKE.findall(text):
            for token in rest.split():
                if token.startswith("-") or re.match(r"[A-Za-z_][A-Za-z0-9_]*=", token):
                    continue
                if not re.fullmatch(r"[A-Za-z0-9_.-]+", token):
                    break  # prose after the command in a code span
                if token not in make_targets():
                    unknown.append(f"make {token}")
    assert not unknown, f"{page.relative_to(ROOT)}: unknown Makefile targets: {sorted(set(unknown))}"


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").count("\n")
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines (at most {README_MAX_LINES})"


# The checkers check themselves on small examples, so that a rule that matches nothing fails.

def test_rules_on_examples():
    text = ("See [a](docs/a.md#x), ![b](img/b.png \"t\") and [c](https://x.org).\n"
            "Run `python -m eval run scenes/paper_plane.xml --out out/run`, `make test`.\n"
            "```sh\npython -m synth dataset scenes/speckle_X.xml  # make paper\n```\n"
            "`scenes/*.xml`, `sweeps/<name>.toml`, `tests/test_docs.py::test_x`, `Makefile`.\n")
    prose, spans, blocks = split_markdown(text)
    assert LINK.findall(prose) == ["docs/a.md#x", "img/b.png", "https://x.org"]
    assert [p for s in spans for p in repo_paths(s)] == [
        "scenes/paper_plane.xml", "tests/test_docs.py", "Makefile"]
    assert COMMAND.findall(" ".join(spans + blocks)) == [("eval", "run"), ("synth", "dataset")]
    assert [m.split()[0] for m in MAKE.findall("\n".join(spans + blocks))] == ["test", "paper"]
    assert {"run", "score", "paper", "sweep", "calibrate", "bench", "render-bench"} <= subcommands("eval")
    assert {"scene", "render", "dataset", "boards", "check"} <= subcommands("synth")
    assert {"setup", "test", "run", "paper", "bench", "clean"} <= make_targets()
