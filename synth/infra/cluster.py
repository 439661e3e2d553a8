"""The Dask cluster that ``python -m eval sweep`` and ``python -m synth suite`` run their tasks on:
a local cluster of single-threaded worker processes, started with SIGINT held back, or the
scheduler someone runs (``--scheduler tcp://HOST:PORT``), checked for an answer, a worker and
workers that can import the project (:func:`connect`). Errors are :class:`synth.infra.cli.CLIError`:
one ``error:`` line."""

from __future__ import annotations

import hashlib
import os
import re
import sys
import tempfile

from synth.infra import interrupt
from synth.infra.cli import CLIError


def check_address(address: str) -> str:
    if not re.fullmatch(r"(tcp|tls|inproc|ucx|ws|wss)://[^\s/]+(:\d+)?", address or ""):
        raise CLIError(f"--scheduler {address!r}: expected an address like tcp://HOST:PORT")
    return address


#: Largest local cluster, in single-threaded workers per usable core (more only costs memory).
MAX_WORKERS_PER_CORE = 4
#: Dask configuration the local cluster's workers start under: without the
#: ``MALLOC_TRIM_THRESHOLD_`` Dask's nanny sets for them (65536). Set, it turns off glibc's
#: dynamic mmap threshold, so that every NumPy array of 128 KiB or more is mapped and unmapped
#: afresh and its pages faulted in each time: a 960 x 768 scene of ``synth learn`` took 13.7
#: CPU seconds for its truth and 12.5 for its render with it, 5.8 and 11.5 without (the same
#: process, one thread). The numbers computed do not change.
LOCAL_WORKER_ENVIRON = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}


def _ignore_client_finalizer_errors() -> None:
    """Silence the 'Exception ignored in Client.__del__' report of a client whose connection
    failed half-way (the command is about to exit with its one error line)."""
    previous = sys.unraisablehook

    def hook(unraisable):
        if "Client.__del__" not in getattr(getattr(unraisable, "object", None), "__qualname__", ""):
            previous(unraisable)

    sys.unraisablehook = hook


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def _probe(client, run, probe, message) -> None:
    """``run(probe)`` (``client.run`` on the workers or ``client.run_on_scheduler``); on failure
    the client is closed and :class:`CLIError` ``message(why)`` raised (Ctrl-C closes it and is
    raised again)."""
    try:
        run(probe)
    except KeyboardInterrupt:
        with interrupt.deferred():
            client.close()
        raise
    except Exception as exc:
        client.close()
        raise CLIError(message(f"{type(exc).__name__}: {' '.join(str(exc).split())[:160]}")) \
            from None


def connect(scheduler: str | None, workers: int | None, timeout: float, probe, what: str):
    """``(client, cluster or None, description)``: the scheduler at ``scheduler`` (CLIError
    when it does not answer within ``timeout`` seconds, has no worker after
    ``max(timeout, 30)`` s, or a worker cannot run ``probe`` — a function of no arguments
    that imports what the tasks need; ``what`` names the tasks in the message), or a new local
    cluster of ``workers`` (default: one per core) single-threaded worker processes."""
    import logging

    for name in ("distributed", "distributed.client", "distributed.comm", "tornado", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    import dask
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout=f"{timeout}s", set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise CLIError(f"--scheduler {scheduler}: no Dask scheduler answered within "
                           f"{timeout:g} s ({' '.join(str(exc).split())[:160]})") from None
        except (MemoryError, ValueError, TypeError, EOFError) as exc:
            # something answered, but not in Dask's protocol (its bytes read as a message
            # length ask for exabytes); the half-built client complains again when collected
            _ignore_client_finalizer_errors()
            raise CLIError(f"--scheduler {scheduler}: what answers there is not a Dask "
                           f"scheduler ({type(exc).__name__})") from None
        try:
            client.wait_for_workers(1, timeout=max(timeout, 30.0))
        except (OSError, TimeoutError):
            client.close()
            raise CLIError(f"--scheduler {scheduler}: the scheduler has no worker "
                           f"(start some with: dask worker {scheduler} --nthreads 1)") from None
        except KeyboardInterrupt:
            with interrupt.deferred():
                client.close()
            raise
        _probe(client, client.run, probe,
               lambda why: f"--scheduler {scheduler}: a worker cannot run {what} ({why}); "
                           f"install this project where the workers run")
        # the scheduler unpickles the tasks too: it needs the project as well
        _probe(client, client.run_on_scheduler, probe,
               lambda why: f"--scheduler {scheduler}: the scheduler cannot import what the "
                           f"{what} need ({why}); install this project where the scheduler "
                           f"runs too")
        n = len(client.scheduler_info(n_workers=-1)["workers"])
        return client, None, f"{n} worker(s) of {scheduler}"
    workers = workers or default_workers()
    if workers > MAX_WORKERS_PER_CORE * default_workers():
        raise CLIError(f"--workers {workers}: at most {MAX_WORKERS_PER_CORE} single-threaded "
                       f"workers per core ({MAX_WORKERS_PER_CORE * default_workers()} here); "
                       f"for more, run a cluster and pass --scheduler")
    # Started whole, SIGINT held back (synth.infra.interrupt.deferred): Dask's threads and the worker
    # processes they spawn inherit SIGINT blocked, so a Ctrl-C in the terminal reaches this
    # process only, which closes them (their tracebacks, Mitsuba's "winding down" on stdout and a
    # render cut short are no longer possible).
    cluster = client = None
    try:
        with interrupt.deferred(processes=True), dask.config.set(LOCAL_WORKER_ENVIRON):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", silence_logs=logging.CRITICAL)
            client = Client(cluster, set_as_default=False)
    except BaseException:  # Ctrl-C held back until the cluster stood: close it again
        with interrupt.deferred():
            for started in (client, cluster):
                if started is not None:
                    started.close()
        raise
    return client, cluster, f"{workers} local single-threaded worker(s)"


# ------------------------------------------------------------------------------------------------
# on the workers

#: Per worker process: the scene files written (by SHA-256).
_FILES: dict = {}
_SETUP_DONE = False


def setup_worker() -> None:
    """Once per process: as many Dr.Jit and OpenCV threads as the Dask worker has (1 in the
    local cluster: one single-threaded worker process per core, no oversubscription)."""
    global _SETUP_DONE
    if _SETUP_DONE:
        return
    threads = 1
    try:
        from distributed import get_worker

        threads = max(1, int(get_worker().state.nthreads))
    except (ImportError, ValueError, AttributeError):
        pass
    import cv2

    cv2.setNumThreads(threads)
    try:
        from synth.rendering.mitsuba_setup import import_mitsuba

        import_mitsuba()
        import drjit

        drjit.set_thread_count(threads)
    except Exception:  # no Mitsuba here: analytic cells still run (scene parsing will say why)
        pass
    _SETUP_DONE = True


def scene_file(sha: str, data: bytes, original: str) -> str:
    """A path on this machine holding the scene bytes: the original path when it holds the same
    bytes, else a copy in the temporary directory named by the hash."""
    cached = _FILES.get(sha)
    if cached:
        return cached
    path = original
    try:
        with open(original, "rb") as handle:
            same = hashlib.sha256(handle.read()).hexdigest() == sha
    except OSError:
        same = False
    if not same:
        directory = os.path.join(tempfile.gettempdir(), "refstereo-sweep-scenes")
        os.makedirs(directory, exist_ok=True)
        path = os.path.join(directory, f"{sha}.xml")
        if not os.path.exists(path):
            fd, tmp = tempfile.mkstemp(dir=directory, suffix=".tmp")
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
            os.replace(tmp, path)
    _FILES[sha] = path
    return path


__all__ = ["MAX_WORKERS_PER_CORE", "check_address", "connect", "default_workers", "scene_file",
           "setup_worker"]
