"""One command-line vocabulary for ``python -m synth`` and ``python -m eval``: every subcommand's
parser is walked and its options checked against the house style of :mod:`synth.cli`."""

from __future__ import annotations

import argparse

import pytest

from synth.cli import DEFINE_HELP, JSON_HELP, NO_PROGRESS_HELP, SCENE_HELP

#: Subcommands that show progress (long work): each takes --no-progress.
WITH_PROGRESS = {("eval", "run"), ("eval", "paper"), ("eval", "sweep"), ("eval", "calibrate"),
                 ("eval", "bench"), ("eval", "render-bench"), ("synth", "render"),
                 ("synth", "dataset"), ("synth", "boards")}
#: Subcommands that read a scene file: each takes it as the positional ``scene``.
WITH_SCENE = {("eval", "run"), ("eval", "render-bench"), ("synth", "render"),
              ("synth", "dataset"), ("synth", "boards")}


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
    assert len(names) == 12


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
