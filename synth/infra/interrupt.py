"""Ctrl-C, the same way everywhere: one line ``error: interrupted``, exit 130, nothing committed.

A SIGINT reaches Python as a ``KeyboardInterrupt`` raised wherever the main thread happens to
be, and there are places where it is lost or disguised: inside a finalizer or a weakref callback
Python prints ``Exception ignored in …`` and carries on (a sweep then finished with exit 0),
libraries catch it and raise something else (matplotlib: ``Invalid affine transformation
matrix``), and Dask's worker processes, in the terminal's process group, get the same signal and
print their own tracebacks. So:

* :func:`handling` (installed by :func:`synth.infra.cli.run_command` for one command) records every
  SIGINT before raising ``KeyboardInterrupt``; whatever the command then returns or raises,
  :func:`requested` says it was interrupted, and the command line prints ``error: interrupted``
  and exits 130. :func:`check` raises it again where a command can stop cleanly (between cells,
  passes, figures), so a swallowed interrupt still stops the work, and
  :meth:`synth.infra.fileio.OutputDir.staged` never commits an output once it is set. An
  interrupt lost in a finalizer or weakref callback is not printed (``Exception ignored in …``):
  it is recorded, and that is what counts.
* :func:`deferred` holds SIGINT back for a block that must not be cut in half (starting or
  closing a Dask cluster, writing a sweep's record and its log line): the signal is blocked in
  this thread and recorded, and raised as ``KeyboardInterrupt`` when the block ends. Threads and
  processes started inside it inherit the blocked signal: the workers of a local cluster never
  see the terminal's Ctrl-C — the command closes them.

Only the main thread can install handlers; elsewhere (a Dask worker thread) these do nothing.
"""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager

#: ``interrupted``: a SIGINT arrived; ``handling``: inside :func:`handling` (a command runs).
_STATE = {"interrupted": False, "handling": False}


def _raise(signum, frame):
    _STATE["interrupted"] = True
    raise KeyboardInterrupt


def _record(signum, frame):
    _STATE["interrupted"] = True


def _quiet_lost_interrupts(previous_hook):
    """An unraisable-exception hook that drops a ``KeyboardInterrupt`` Python could not raise
    (it landed in a finalizer or a weakref callback: ``Exception ignored in …``) — it is already
    recorded, and :func:`check` raises it where the work can stop — and passes anything else to
    ``previous_hook``."""
    def hook(unraisable):
        if isinstance(unraisable.exc_value, KeyboardInterrupt) and _STATE["interrupted"]:
            return
        previous_hook(unraisable)
    return hook


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def install() -> None:
    """Make SIGINT record itself, then raise ``KeyboardInterrupt`` (main thread only)."""
    if _main_thread():
        signal.signal(signal.SIGINT, _raise)


@contextmanager
def handling():
    """Within the block a SIGINT is recorded (:func:`requested`) and raised; the flag starts
    clear and the previous handler comes back afterwards."""
    if not _main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, _raise)
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_lost_interrupts(previous_hook)
    _STATE.update(interrupted=False, handling=True)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)
        sys.unraisablehook = previous_hook
        _STATE.update(interrupted=False, handling=False)


def requested() -> bool:
    """Whether a SIGINT arrived since :func:`handling` began (even if it was swallowed); read
    it inside the block."""
    return _STATE["interrupted"]


def check() -> None:
    """Raise ``KeyboardInterrupt`` if a SIGINT arrived: a point where the work may stop."""
    if _STATE["interrupted"]:
        raise KeyboardInterrupt


@contextmanager
def deferred(processes: bool = False):
    """Hold SIGINT back during the block (see the module): blocked in this thread and in the
    threads and processes started inside, recorded, and raised as ``KeyboardInterrupt`` when the
    block ends without an exception of its own. ``processes``: the block starts processes with
    ``multiprocessing`` (a Dask ``LocalCluster``); its resource tracker is started first, since
    starting it unblocks SIGINT in the thread that does (which would then pass SIGINT on to the
    processes it starts)."""
    if not _main_thread():
        yield
        return
    if processes:
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()
    previous = signal.signal(signal.SIGINT, _record)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a held SIGINT is recorded now
        signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)
    if _STATE["interrupted"] and not _STATE["handling"]:  # used as a library: raise it once
        _STATE["interrupted"] = False
        raise KeyboardInterrupt
    check()


__all__ = ["check", "deferred", "handling", "install", "requested"]
