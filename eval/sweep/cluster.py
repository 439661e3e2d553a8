"""Where the cells of ``python -m eval sweep`` run: a local cluster of single-threaded worker
processes or the scheduler of ``--scheduler`` (:func:`connect`), render cells one per task and
analytic cells in batches (:func:`batches`), each finished record written at once and the
tables rebuilt every few seconds (:func:`execute`)."""

from __future__ import annotations

import sys
import time

from eval.sweep.directory import SweepDir
from eval.sweep.table import write_tables
from synth.infra import interrupt
from synth.infra.cluster import MAX_WORKERS_PER_CORE, check_address, default_workers
from synth.infra.cluster import connect as cluster_connect

#: Seconds between two rebuilds of the tables while cells come in.
TABLE_INTERVAL_S = 10.0
#: Analytic cells per task when the spec does not say (and at most this many).
MAX_CELLS_PER_TASK = 250

def connect(args):
    """``(client, cluster or None, description)``: the scheduler of ``--scheduler`` (CLIError
    when it does not answer within ``--connect-timeout``, has no worker, or its workers cannot
    run sweep cells), or a new local cluster (:func:`synth.infra.cluster.connect`)."""
    return cluster_connect(args.scheduler, args.workers, args.connect_timeout, _probe_worker,
                           "sweep cells")


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
