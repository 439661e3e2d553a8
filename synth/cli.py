"""The house style of both command lines (``python -m synth``, ``python -m eval``).

* One argument parser class whose errors are one line ``error: …`` (no usage dump).
* The same argument validators (integers with a lower bound, finite floats with bounds).
* The same exit codes: 0 ok, 1 a check that fails, 2 bad input (one line ``error: …`` on
  stderr), 130 interrupted. An unexpected exception (a bug) prints one line
  ``error: internal error: …`` and exits with 1; set ``REFSTEREO_TRACEBACK=1`` to see the traceback.
* The same ``--out`` rule (:mod:`synth.fileio`).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import traceback

EXIT_OK, EXIT_CHECK_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


class CLIError(Exception):
    """A user error: printed as one line ``error: <message>`` with exit code 2."""


class Parser(argparse.ArgumentParser):
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


def finite_float(minimum: float = -math.inf, *, strict: bool = False, description: str = "finite"):
    """An argparse type: a finite float >= ``minimum`` (> when ``strict``); NaN and ±inf refused."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        ok = math.isfinite(value) and (value > minimum if strict else value >= minimum)
        if not ok:
            raise argparse.ArgumentTypeError(f"expected a {description} number, got {text!r}")
        return value

    return parse


any_float = finite_float(description="finite")
positive_float = finite_float(0.0, strict=True, description="positive finite")
non_negative_float = finite_float(0.0, description="non-negative finite")


def one_line(message) -> str:
    """``message`` as one line (whitespace, including newlines, collapsed)."""
    return " ".join(str(message).split())


def run_command(parser: argparse.ArgumentParser, argv=None) -> int:
    """Parse ``argv`` with ``parser`` (whose subparsers set ``_main``), run it, return the exit
    code. Bad input of any kind — :class:`CLIError`, ``ValueError`` and its subclasses (scene,
    dataset, output errors), ``OSError`` — is one line ``error: …`` and exit 2."""
    try:
        args = parser.parse_args(argv)
        return int(args._main(args) or 0)
    except (CLIError, ValueError) as exc:
        print(f"error: {one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        where = f" {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"error: {one_line(exc.strerror or exc)}{':' if where else ''}{where}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except MemoryError:
        print("error: out of memory (try a smaller image, fewer samples per pixel or fewer "
              "targets)", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # a bug: one line, the traceback on request
        if os.environ.get("REFSTEREO_TRACEBACK"):
            traceback.print_exc()
        print(f"error: internal error: {type(exc).__name__}: {one_line(exc)} "
              f"(set REFSTEREO_TRACEBACK=1 for the traceback)", file=sys.stderr)
        return EXIT_CHECK_FAILED


__all__ = ["CLIError", "EXIT_BAD_INPUT", "EXIT_CHECK_FAILED", "EXIT_INTERRUPTED", "EXIT_OK",
           "Parser", "any_float", "finite_float", "int_at_least", "non_negative_float",
           "non_negative_int", "one_line", "positive_float", "positive_int", "run_command"]
