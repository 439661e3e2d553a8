"""synth.infra.cli: the house style of both command lines."""

from __future__ import annotations

import pytest

from synth.infra.cli import CLIError, Parser


def _parser():
    parser = Parser(prog="x")
    parser.add_argument("--range")
    parser.add_argument("--flag", action="store_true")
    return parser


@pytest.mark.parametrize("value", ["-100,2000", "-100", "-.5", "-1e9", "-1.5e-3,2", "-3,-2"])
def test_a_value_with_a_leading_minus_is_the_options_value(value):
    """argparse alone takes ``-100,2000`` and ``-1e9`` for options ("expected one argument")."""
    assert _parser().parse_args(["--range", value]).range == value


@pytest.mark.parametrize("argv", [["--range", "--flag"], ["--range", "-x"]])
def test_an_option_is_still_not_a_value(argv):
    with pytest.raises(CLIError, match="expected one argument"):
        _parser().parse_args(argv)
