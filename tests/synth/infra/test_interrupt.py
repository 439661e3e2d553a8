"""synth.infra.interrupt and synth.infra.cli.run_command under SIGINT, in this process: an interrupt that a
library swallows or disguises is still reported as one line ``error: interrupted``, exit 130,
and an interrupted command never commits its output. (The real processes, the sweep's Dask
workers included: tests/test_cli_interrupt.py.)"""

from __future__ import annotations

import os
import signal
import time

import pytest

from synth.infra import interrupt
from synth.infra.cli import Parser, run_command


def _sigint():
    """Send this process a SIGINT and give the handler the chance to run."""
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.05)


def _parser(body):
    parser = Parser(prog="test")
    parser.set_defaults(_main=lambda args: body())
    return parser


def _swallowed():
    try:
        _sigint()
    except KeyboardInterrupt:  # e.g. raised inside a finalizer: "Exception ignored in …"
        pass
    return 0


def _disguised():
    try:
        _sigint()
    except KeyboardInterrupt:  # e.g. matplotlib: "Invalid affine transformation matrix"
        raise ValueError("Invalid affine transformation matrix") from None
    return 0


def _raised():
    _sigint()
    return 0


@pytest.mark.parametrize("body", [_raised, _swallowed, _disguised],
                         ids=["raised", "swallowed", "disguised"])
def test_an_interrupt_is_reported_however_the_command_ends(body, capsys):
    """Before: a swallowed interrupt finished with exit 0, a disguised one was ``error: Invalid
    affine transformation matrix`` with exit 2."""
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN where the suite runs in the background
    assert run_command(_parser(body), []) == 130
    captured = capsys.readouterr()
    assert captured.err == "error: interrupted\n" and captured.out == ""
    # the handler is put back and the next command starts clear
    assert signal.getsignal(signal.SIGINT) is before
    assert run_command(_parser(lambda: 0), []) == 0


def test_building_the_parser_is_covered(capsys):
    def build():
        _sigint()  # e.g. while the command modules are imported
        return _parser(lambda: 0)

    assert run_command(build, []) == 130
    assert capsys.readouterr().err == "error: interrupted\n"


def test_an_interrupted_command_commits_no_output(tmp_path):
    from synth.infra.fileio import OutputDir

    out = OutputDir(tmp_path / "out", "test")
    with interrupt.handling():
        with pytest.raises(KeyboardInterrupt):
            with out.staged() as staging:
                (tmp_path / "marker").write_text("")
                _swallowed()
                with open(os.path.join(staging, "result.txt"), "w") as handle:
                    handle.write("computed after the interrupt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["marker"]


def test_deferred_holds_the_signal_until_the_block_ends():
    with interrupt.handling():
        steps = []
        with pytest.raises(KeyboardInterrupt):
            with interrupt.deferred():
                _sigint()
                steps.append("the block went on")
        assert steps == ["the block went on"] and interrupt.requested()
        # SIGINT is unblocked again
        assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())


def test_an_interrupt_lost_in_a_weakref_callback_is_not_printed(capsys, monkeypatch):
    """Before: ``Exception ignored in: <function WeakSet…_remove>`` and a traceback above
    ``error: interrupted`` when the SIGINT landed in a weakref callback (seen in a sweep). Other
    unraisable exceptions still reach the hook that was there."""
    import gc
    import sys
    import weakref

    seen = []
    monkeypatch.setattr(sys, "unraisablehook", lambda unraisable: seen.append(unraisable.exc_type))

    class Thing:
        pass

    def lost(callback):
        thing = Thing()
        ref = weakref.ref(thing, callback)
        del thing
        gc.collect()
        assert ref() is None

    def body():
        lost(lambda _ref: _sigint())
        lost(lambda _ref: 1 / 0)
        return 0

    assert run_command(_parser(body), []) == 130
    assert seen == [ZeroDivisionError]
    assert capsys.readouterr().err == "error: interrupted\n"
