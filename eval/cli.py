"""The ``python -m eval`` dispatcher: argparse with one subparser per subcommand module.

Adding a subcommand: create its module — ``eval/<name>.py`` for a single-file command, or a
package ``eval/<name>/`` whose ``command.py`` is the command — exposing

* ``add_parser(subparsers)`` — ``subparsers.add_parser("<name>", …)`` and its arguments,
* ``main(args) -> int`` — run it; raise :class:`CLIError` for a user error,

and add the module to :data:`SUBCOMMANDS`. Keep heavy imports (Open3D, Mitsuba,
matplotlib, SciPy, Dask) inside ``main`` so that ``--help``, argument errors and the other
subcommands stay fast: every command module is imported to build the parser
(``tests/test_cli_startup.py`` checks what that loads).

Errors and exit codes follow :mod:`synth.infra.cli`, shared with ``python -m synth``: one line
``error: …`` and exit 2 for bad input, 1 for a check that fails, 130 when interrupted.
"""

from __future__ import annotations

import importlib

from synth.infra.cli import (CLIError, Parser, command_parser, non_negative_float, non_negative_int,
                       positive_float, positive_int, process_main, run_command)

#: The module of each subcommand, in the order ``--help`` lists them.
SUBCOMMANDS = ("eval.run.command", "eval.score", "eval.paper.command", "eval.sweep.command",
               "eval.calibrate.command", "eval.measure.command", "eval.bench",
               "eval.render_bench", "eval.rectify", "eval.track", "eval.interface")


def build_parser() -> Parser:
    """The parser of ``python -m eval``: one subparser per module of :data:`SUBCOMMANDS`."""
    return command_parser("python -m eval",
                          "Underwater refractive stereo: experiments, evaluation, reports.",
                          [importlib.import_module(name) for name in SUBCOMMANDS])


def main(argv=None) -> int:
    """Parse ``argv`` (default ``sys.argv[1:]``), run the subcommand, return the exit code."""
    return run_command(build_parser, argv)


def console_main() -> None:
    """Entry point of ``python -m eval`` and of the ``refstereo-eval`` console script."""
    process_main(main)


__all__ = ["CLIError", "SUBCOMMANDS", "build_parser", "main", "console_main", "positive_int",
           "non_negative_int", "positive_float", "non_negative_float"]
