"""One command-line vocabulary for ``python -m synth`` and ``python -m eval``: every subcommand's
parser is walked and its options checked against the house style of :mod:`synth.infra.cli`."""

from __future__ import annotations

import argparse

import pytest

from synth.infra.cli import DEFINE_HELP, JSON_HELP, NO_PROGRESS_HELP, SCENE_HELP

#: Subcommands that show progress (long work): each takes --no-progress.
WITH_PROGRESS = {("eval", "run"), ("eval", "paper"), ("eval", "sweep"), ("eval", "calibrate"),
                 ("eval", "bench"), ("eval", "render-bench"), ("eval", "measure"),
                 ("synth", "render"),
                 ("synth", "dataset"), ("synth", "suite"), ("synth", "learn"), ("synth", "boards"),
                 ("synth", "sequence"), ("eval", "track"), ("eval", "interface")}
#: Subcommands that read a scene file: each takes it as the positional ``scene``.
WITH_SCENE = {("eval", "run"), ("eval", "render-bench"), ("synth", "render"),
              ("synth", "dataset"), ("synth", "boards"), ("synth", "sequence")}


def _synth_parser():
    try:
        from synth.commands import build_parser
    except ImportError:
        from synth.__main__ import build_parser
    return build_parser()


def _subcommands():
    from eval.cli import build_parser as eval_parser

    for prog, parser in (("eval", eval_parser()), ("synth", _synth_parser())):
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        for name, subparser in sub.choices.items():
            yield prog, name, subparser


SUBCOMMANDS = list(_subcommands())


def test_every_subcommand_is_walked():
    names = {(prog, name) for prog, name, _ in SUBCOMMANDS}
    assert WITH_PROGRESS <= names and WITH_SCENE <= names
    assert len(names) == 20


@pytest.mark.parametrize("prog, name, parser", SUBCOMMANDS,
                         ids=[f"{p}-{n}" for p, n, _ in SUBCOMMANDS])
def test_vocabulary(prog, name, parser):
    options = {s: a for a in parser._actions for s in a.option_strings}
    positionals = [a for a in parser._actions if not a.option_strings]
    where = f"python -m {prog} {name}"
    # the scene is the positional `scene`, never an option
    assert "--scene" not in options, where
    scene = [a for a in positionals if a.dest == "scene"]
    if (prog, name) in WITH_SCENE:
        assert scene and scene[0].help.startswith(SCENE_HELP), where
    # -D NAME=VALUE, the same words everywhere
    if "-D" in options:
        assert options["-D"].metavar == "NAME=VALUE" and options["-D"].help == DEFINE_HELP, where
        assert options["-D"].dest == "defines", where
    # --no-progress (alias --quiet) where there is progress; --quiet only as that alias
    if (prog, name) in WITH_PROGRESS:
        assert "--no-progress" in options, where
    if "--no-progress" in options or "--quiet" in options:
        action = options.get("--no-progress")
        assert action is not None and options.get("--quiet") is action, where
        assert action.help == NO_PROGRESS_HELP and action.dest == "no_progress", where
    # --json is a flag printing the report to stdout
    if "--json" in options:
        action = options["--json"]
        assert action.nargs == 0 and action.help == JSON_HELP, where
    # --out says what it writes and its rule
    if "--out" in options:
        action = options["--out"]
        assert action.metavar in ("DIR", "FILE"), where
        assert action.help.startswith("output "), where
        assert "earlier output of" in action.help or "wrote it" in action.help, where


# --- --version and a bare command --------------------------------------------------------------
def _main(prog):
    if prog == "eval":
        from eval.cli import main
    else:
        from synth.commands import main
    return main


def _pyproject_version() -> str:
    import re

    from tests.conftest import REPO

    text = (REPO / "pyproject.toml").read_text(encoding="utf-8")
    return re.search(r'(?m)^version\s*=\s*"([^"]+)"', text).group(1)


@pytest.mark.parametrize("prog", ["eval", "synth"])
def test_version(prog, capsys):
    """``--version``: ``refractive-stereo X.Y.Z`` on stdout, exit 0 (the version of the installed
    distribution, which is pyproject's)."""
    assert _main(prog)(["--version"]) == 0
    out, err = capsys.readouterr()
    assert out == f"refractive-stereo {_pyproject_version()}\n" and err == ""


def test_version_falls_back_to_pyproject(monkeypatch, capsys):
    """Not installed (no distribution metadata): the version in pyproject.toml."""
    import importlib.metadata

    def missing(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", missing)
    from synth.infra.cli import package_version

    assert package_version() == _pyproject_version()
    assert _main("synth")(["--version"]) == 0
    assert capsys.readouterr().out == f"refractive-stereo {_pyproject_version()}\n"


def _commands_listed(prog, text):
    from eval.cli import build_parser as eval_parser

    parser = eval_parser() if prog == "eval" else _synth_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return all(name in text for name in sub.choices) and "usage:" in text


@pytest.mark.parametrize("prog", ["eval", "synth"])
def test_bare_command_prints_the_commands(prog, capsys):
    """No command: the help (its list of commands) on stdout, exit 0 — a question, not bad
    input (docs/architecture.md, "The command lines")."""
    assert _main(prog)([]) == 0
    out, err = capsys.readouterr()
    assert _commands_listed(prog, out) and err == ""


@pytest.mark.parametrize("argv", [["-m", "eval"], ["-m", "synth"], ["refstereo-eval"],
                                  ["refstereo-synth"], ["-m", "eval", "--version"],
                                  ["refstereo-synth", "--version"]],
                         ids=lambda argv: " ".join(argv))
def test_bare_command_and_version_in_a_process(argv, tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path

    from tests.conftest import REPO

    if argv[0] == "-m":
        command = [sys.executable, *argv]
    else:
        script = Path(sys.executable).parent / argv[0]
        if not script.exists():
            pytest.skip(f"{argv[0]} is not installed in this environment (pip install -e .)")
        command = [str(script), *argv[1:]]
    env = dict(os.environ, PYTHONPATH=str(REPO))  # this checkout, not another editable one
    proc = subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    prog = "eval" if "eval" in " ".join(argv) else "synth"
    if "--version" in argv:
        assert proc.stdout == f"refractive-stereo {_pyproject_version()}\n"
    else:
        assert _commands_listed(prog, proc.stdout)
    assert list(tmp_path.iterdir()) == []


def test_help_imports_no_heavy_library():
    """Building both parsers (what --help does) imports neither Open3D, Mitsuba nor matplotlib:
    heavy imports stay inside the commands' main (eval --help took 1.3 s more with Open3D)."""
    import subprocess
    import sys

    code = ("import sys; from eval.cli import build_parser; build_parser(); "
            "from synth.commands import build_parser as b; b(); "
            "print(','.join(m for m in ('open3d', 'mitsuba', 'matplotlib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"--help imports {out.stdout.strip()}"
