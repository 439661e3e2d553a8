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


def test_an_internal_error_has_its_own_exit_code(capsys, monkeypatch):
    """A bug is one line ``error: internal error: …`` and exit 3 — not 1, which says that a
    check failed, nor 2 (bad input)."""
    from synth.infra.cli import (EXIT_BAD_INPUT, EXIT_CHECK_FAILED, EXIT_INTERNAL_ERROR,
                                 run_command)

    monkeypatch.delenv("REFSTEREO_TRACEBACK", raising=False)

    def parser():
        p = Parser(prog="x")
        p.set_defaults(_main=lambda args: {}["missing"])
        return p

    code = run_command(parser, [])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == EXIT_INTERNAL_ERROR == 3 and code not in (EXIT_CHECK_FAILED, EXIT_BAD_INPUT)
    assert len(err) == 1 and err[0].startswith("error: internal error: KeyError: 'missing'")


@pytest.mark.parametrize("value, text", [(1e9, "1e9"), (0.5, "0.5"), (2.5e-5, "2.5e-5"),
                                         (1000.0, "1000"), (123456.75, "123456.75"), (1e6, "1e6"),
                                         (-1e-12, "-1e-12")])
def test_option_number_reads_as_typed(value, text):
    from synth.infra.cli import option_number

    assert option_number(value) == text
    assert float(option_number(value)) == value


@pytest.mark.parametrize("module, code, fragment", [
    ("cv2_not_installed_here", 2, "error: the Python module 'cv2_not_installed_here' is not "
                                  "installed in this Python"),
    ("measure.no_such_module", 3, "error: internal error: ModuleNotFoundError")])
def test_a_missing_dependency_says_to_use_the_projects_environment(capsys, module, code,
                                                                   fragment):
    """``python -m eval …`` with a Python that lacks the dependencies (the system's) was
    "internal error: ModuleNotFoundError: cv2"; a missing module of the project is still a bug."""
    import importlib

    from synth.infra.cli import run_command

    def parser():
        p = Parser(prog="x")
        p.set_defaults(_main=lambda args: importlib.import_module(module))
        return p

    assert run_command(parser, []) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(fragment), err
    if code == 2:
        assert ".venv/bin/activate" in err[0] and "make setup" in err[0]
