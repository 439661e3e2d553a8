"""``python -m synth`` -- write scenes, render them, write and check benchmark datasets.

Subcommands::

    python -m synth scene   --layout paper --z 1000 --out scenes/paper_plane.xml [options]
    python -m synth render  SCENE --out DIR [--spp N] [--variant V] [--exr] [-D name=value ...]
    python -m synth dataset SCENE --out DIR [--spp N] [--variant V] [--exr] [-D name=value ...]
    python -m synth suite   SPEC.toml --out DIR [--workers N | --scheduler tcp://HOST:PORT]
    python -m synth learn   --out DIR --scenes N [--seed S] [--size WxH] [--spp N] [--ports …]
    python -m synth boards  SCENE --out DIR [--poses 15] [--board chessboard|charuco]
                            [--squares 11x8] [--square-mm 40] [--seed S] [--air]
    python -m synth sequence SCENE --approach FROM,TO --frames N --out DIR [--yaw DEG]
    python -m synth check   DIR [--rms PX] [--max PX] [--json]

Bad input (missing or malformed scene, wrong structure, unknown ``-D``, bad option, an ``--out``
holding files this command did not write) prints one line ``error: ...`` and exits with code 2;
``check`` exits with 1 when the dataset is outside the bounds; 130 when interrupted
(:mod:`synth.infra.cli`, shared with ``python -m eval``). Output directories follow
:class:`synth.infra.fileio.OutputDir`: whole or not at all, never over someone else's files.

One module per command (``synth/commands/<name>.py``, listed in ``--help`` order in
:data:`COMMANDS`), with the convention of :mod:`eval.cli`: each exposes

* ``add_parser(subparsers)`` -- ``subparsers.add_parser("<name>", …)`` and its arguments,
* ``main(args) -> int`` -- run it; raise :class:`synth.infra.cli.CLIError` for a user error.

What several commands share is in :mod:`synth.commands.common`; the cameras and port of
``scene``'s options are in :mod:`synth.commands.scene_rig`. Heavy imports (Mitsuba, Open3D,
matplotlib, SciPy) stay inside the functions so that ``--help`` stays fast.
"""

from __future__ import annotations

from synth.infra.cli import Parser, command_parser, process_main, run_command
from synth.commands import (boards, check, dataset, learn, photos, render, scene, sequence,
                            suite)

PROG = "python -m synth"
#: The command modules, in the order ``--help`` lists them.
COMMANDS = (scene, render, dataset, suite, learn, boards, sequence, photos, check)


def build_parser() -> Parser:
    """The parser of ``python -m synth``: one subparser per module of :data:`COMMANDS`, whose
    ``main`` it runs."""
    return command_parser(PROG, "Mitsuba scenes and datasets of a stereo rig behind a flat port "
                                "(units mm).", COMMANDS)


def main(argv=None) -> int:
    """Run the CLI; returns the exit code (:mod:`synth.infra.cli`: 2 on bad input, with one line
    ``error: …`` on stderr; 1 when ``check`` fails; 130 when interrupted)."""
    return run_command(build_parser, argv)


def console_main() -> None:
    """Entry point of ``python -m synth`` and of the ``refstereo-synth`` console script."""
    process_main(main)


__all__ = ["COMMANDS", "PROG", "build_parser", "console_main", "main"]
