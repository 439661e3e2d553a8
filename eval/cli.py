"""The ``python -m eval`` dispatcher: argparse with one subparser per subcommand module.

Adding a subcommand: create ``eval/<name>.py`` exposing

* ``add_parser(subparsers)`` — ``subparsers.add_parser("<name>", …)`` and its arguments,
* ``main(args) -> int`` — run it; raise :class:`CLIError` for a user error,

and add the module name to :data:`SUBCOMMANDS`. Keep heavy imports (Open3D, Mitsuba,
matplotlib) inside ``main`` so that ``--help`` and the other subcommands stay fast.

Errors: bad arguments and :class:`CLIError` print one line ``error: …`` on stderr and exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import tempfile
from pathlib import Path

#: Subcommand modules, in the order ``--help`` lists them: ``eval.<name>``.
SUBCOMMANDS = ("run", "paper", "bench")


class CLIError(Exception):
    """A user error: printed as one line ``error: <message>`` with exit code 2."""


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line ``error: …`` (no usage dump) and exit 2."""

    def error(self, message):  # noqa: D401 - argparse API
        raise CLIError(message)


def int_at_least(minimum: int, description: str):
    """An argparse type: an integer >= ``minimum``; the error says ``description``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"expected a {description} integer, got {text!r}")
        return value

    return parse


positive_int = int_at_least(1, "positive")
non_negative_int = int_at_least(0, "non-negative")


def prepare_output_dir(path) -> Path:
    """Create ``path`` (and parents) and check that files can be written there.

    Raises :class:`CLIError` if it cannot be created or written.
    """
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out, prefix=".write-test-"):
            pass
    except OSError as exc:
        reason = exc.strerror or exc.__class__.__name__
        raise CLIError(f"cannot write to output directory {str(out)!r}: {reason}") from None
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="python -m eval",
                     description="Underwater refractive stereo: experiments, evaluation, reports.")
    subparsers = parser.add_subparsers(dest="command", metavar="command", required=True)
    for name in SUBCOMMANDS:
        module = importlib.import_module(f"eval.{name}")
        before = set(subparsers.choices)
        module.add_parser(subparsers)
        for added in set(subparsers.choices) - before:
            subparsers.choices[added].set_defaults(_main=module.main)
    return parser


def main(argv=None) -> int:
    """Parse ``argv`` (default ``sys.argv[1:]``), run the subcommand, return the exit code."""
    try:
        args = build_parser().parse_args(argv)
        return int(args._main(args) or 0)
    except CLIError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


__all__ = ["CLIError", "SUBCOMMANDS", "build_parser", "main", "positive_int",
           "non_negative_int", "prepare_output_dir"]
