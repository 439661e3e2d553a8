"""Where the cells of ``python -m eval sweep`` run: a local cluster of single-threaded worker
processes or the scheduler of ``--scheduler`` (:func:`connect`), render cells one per task and
analytic cells in batches (:func:`batches`), each finished record written at once and the
tables rebuilt every few seconds (:func:`execute`)."""

from __future__ import annotations

import os
import re
import sys
import time

from eval.cli import CLIError
from eval.sweep.directory import SweepDir
from eval.sweep.table import write_tables
from synth import interrupt

#: Seconds between two rebuilds of the tables while cells come in.
TABLE_INTERVAL_S = 10.0
#: Analytic cells per task when the spec does not say (and at most this many).
MAX_CELLS_PER_TASK = 250


def check_address(address: str) -> str:
    if not re.fullmatch(r"(tcp|tls|inproc|ucx|ws|wss)://[^\s/]+(:\d+)?", address or ""):
        raise CLIError(f"--scheduler {address!r}: expected an address like tcp://HOST:PORT")
    return address


#: Largest local cluster, in single-threaded workers per usable core (more only costs memory).
MAX_WORKERS_PER_CORE = 4


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


def connect(args):
    """``(client, cluster or None, description)``: the scheduler of ``--scheduler`` (CLIError
    when it does not answer within ``--connect-timeout``), or a new local cluster."""
    import logging

    for name in ("distributed", "distributed.client", "distributed.comm", "tornado", "asyncio"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    from distributed import Client, LocalCluster

    if args.scheduler:
        timeout = args.connect_timeout
        try:
            client = Client(args.scheduler, timeout=f"{timeout}s", set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise CLIError(f"--scheduler {args.scheduler}: no Dask scheduler answered within "
                           f"{timeout:g} s ({' '.join(str(exc).split())[:160]})") from None
        except (MemoryError, ValueError, TypeError, EOFError) as exc:
            # something answered, but not in Dask's protocol (its bytes read as a message
            # length ask for exabytes); the half-built client complains again when collected
            _ignore_client_finalizer_errors()
            raise CLIError(f"--scheduler {args.scheduler}: what answers there is not a Dask "
                           f"scheduler ({type(exc).__name__})") from None
        try:
            client.wait_for_workers(1, timeout=max(timeout, 30.0))
        except (OSError, TimeoutError):
            client.close()
            raise CLIError(f"--scheduler {args.scheduler}: the scheduler has no worker "
                           f"(start some with: dask worker {args.scheduler} --nthreads 1)") from None
        except KeyboardInterrupt:
            with interrupt.deferred():
                client.close()
            raise
        try:
            client.run(_probe_worker)
        except KeyboardInterrupt:
            with interrupt.deferred():
                client.close()
            raise
        except Exception as exc:
            client.close()
            raise CLIError(f"--scheduler {args.scheduler}: a worker cannot run sweep cells "
                           f"({type(exc).__name__}: {' '.join(str(exc).split())[:160]}); "
                           f"install this project where the workers run") from None
        n = len(client.scheduler_info(n_workers=-1)["workers"])
        return client, None, f"{n} worker(s) of {args.scheduler}"
    workers = args.workers or default_workers()
    if workers > MAX_WORKERS_PER_CORE * default_workers():
        raise CLIError(f"--workers {workers}: at most {MAX_WORKERS_PER_CORE} single-threaded "
                       f"workers per core ({MAX_WORKERS_PER_CORE * default_workers()} here); "
                       f"for more, run a cluster and pass --scheduler")
    # Started whole, SIGINT held back (synth.interrupt.deferred): Dask's threads and the worker
    # processes they spawn inherit SIGINT blocked, so a Ctrl-C in the terminal reaches this
    # process only, which closes them (their tracebacks, Mitsuba's "winding down" on stdout and a
    # render cut short are no longer possible).
    cluster = client = None
    try:
        with interrupt.deferred(processes=True):
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


def _probe_worker():
    from eval.sweep.cells import probe

    return probe()


def _cell_payload(spec, cell) -> dict:
    from eval.sweep.spec import scene_defines

    scene = spec.scenes[cell.scene]
    return {"key": cell.key, "kind": cell.kind, "scene": cell.scene, "scene_sha": scene.sha256,
            "scene_path": scene.path, "params": cell.params, "seed": cell.seed,
            "repeat": cell.repeat, "methods": list(cell.methods),
            "defines": scene_defines(cell.params, scene, cell.kind, spec.render_width)}


def batches(spec, cells: list, workers: int) -> list:
    """Tasks: each render cell alone, analytic cells in batches of ``cells_per_task`` (default:
    about eight tasks per worker, at most :data:`MAX_CELLS_PER_TASK` cells each)."""
    render = [c for c in cells if c.kind == "render"]
    analytic = [c for c in cells if c.kind == "analytic"]
    size = spec.cells_per_task or max(1, min(MAX_CELLS_PER_TASK,
                                             -(-len(analytic) // max(1, 8 * workers))))
    out = [[c] for c in render]
    out += [analytic[i:i + size] for i in range(0, len(analytic), size)]
    return out


def execute(client, spec, todo: list, out: SweepDir, records: dict, run_id: str, progress: bool,
            workers: int) -> int:
    """Run ``todo`` cells; write each record as it arrives. Returns ``(cells run, seconds from
    the first submission to the last result)``."""
    from distributed import as_completed
    from tqdm import tqdm

    tasks = batches(spec, todo, workers)
    started = time.perf_counter()
    futures = {}
    for batch in tasks:
        payload = [_cell_payload(spec, c) for c in batch]
        scenes = {spec.scenes[c.scene].sha256: spec.scenes[c.scene].data for c in batch}
        future = client.submit(_run_batch, payload, scenes, spec.save, pure=False)
        futures[future] = batch
    bar = tqdm(total=len(todo), unit="cell", desc="sweep", file=sys.stderr,
               disable=True if not progress else None, smoothing=0.05)
    ran, last_table, interval = 0, time.monotonic(), TABLE_INTERVAL_S
    try:
        for future in as_completed(futures, loop=client.loop):
            interrupt.check()  # an interrupt that Dask's machinery swallowed stops here
            batch = futures.pop(future)
            try:
                results = future.result()
            except Exception as exc:  # the task itself failed (a worker died, …)
                message = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
                results = [{"key": c.key, "status": "failed", "error": message, "report": None,
                            "metrics": {}, "seconds": None, "files": {}} for c in batch]
            for cell, result in zip(batch, results):
                files = result.pop("files", {})
                result.pop("worker_pid", None)
                record = {**result, "run_id": run_id, "kind": cell.kind, "scene": cell.scene,
                          "params": cell.params, "repeat": cell.repeat, "sample": cell.sample,
                          "seed": cell.seed, "methods": list(cell.methods)}
                with interrupt.deferred():  # the cell file and its log line, both or neither
                    out.write_record(record, files)
                records[cell.key] = record
                ran += 1
            bar.update(len(batch))
            failed = sum(r["status"] != "ok" for r in records.values())
            if failed:
                bar.set_postfix_str(f"{failed} failed")
            if time.monotonic() - last_table > interval:
                took = time.monotonic()
                write_tables(out.path, spec, records)
                last_table = time.monotonic()
                # rebuilding a large table costs seconds: keep it under a tenth of the time
                interval = max(TABLE_INTERVAL_S, 10 * (last_table - took))
    finally:
        bar.close()
        for future in futures:
            future.cancel()
    return ran, time.perf_counter() - started


def _run_batch(cells, scenes, save):
    from eval.sweep.cells import run_batch

    return run_batch(cells, scenes, save)


__all__ = ["MAX_CELLS_PER_TASK", "MAX_WORKERS_PER_CORE", "TABLE_INTERVAL_S", "batches",
           "check_address", "connect", "default_workers", "execute"]
