"""``python -m eval sweep SPEC.toml --out DIR [--scheduler ADDRESS] [--workers N]``: sweeps at
scale on ``dask.distributed``.

The spec (:mod:`eval.sweep.spec`) expands into cells; the workers run them
(:mod:`eval.sweep.cells`) where :mod:`eval.sweep.cluster` sends them; :mod:`eval.sweep.directory`
owns the output directory and :mod:`eval.sweep.table` the tables; this module is the command.

Execution: a ``LocalCluster`` of ``--workers`` single-threaded worker processes (default: one
per core), or ``--scheduler tcp://HOST:PORT``, a scheduler someone runs (``dask scheduler`` /
``dask worker``, dask-jobqueue, Kubernetes) whose workers can import this project. Render cells
are one task each; analytic cells go in batches (``cells_per_task``). The client writes every
finished cell at once as ``DIR/cells/<key>.json`` (its record: parameters, seed, run id, status,
error, the full report, the row) and appends ``<key> <run id>`` to ``DIR/completions.log``.

Output: ``DIR`` is updated in place, cell by cell — unlike the other commands, whose outputs
appear whole or not at all (:class:`synth.infra.fileio.OutputDir`): a sweep of hours must keep what
it finished when it is killed. The same rule guards it: ``DIR`` must not exist, be empty, or be
an earlier output of ``eval sweep`` (its marker) holding only what a sweep writes; every file
is written atomically (temporary file + rename). ``DIR/sweep.json`` records the spec's hash: a
rerun with the same spec does only the missing cells; another spec is refused unless
``--allow-changed-spec`` (the cells both specs share are then reused). The tables
``results.parquet`` and ``results.csv`` (one row per cell of the spec, in the spec's order) are
rebuilt from the cell files every few seconds and at the end; figures go into ``DIR/figures``.
"""

from __future__ import annotations

import json
import os
import time
import uuid

from eval.cli import CLIError
from eval.sweep.cluster import check_address, connect, execute
from eval.sweep.directory import COMMAND, SweepDir
from eval.sweep.table import table_rows, write_tables
from synth.infra import interrupt
from synth.infra.cli import add_cluster_options, add_out_option, add_progress_option, refuse_given


def add_parser(subparsers):
    parser = subparsers.add_parser(
        "sweep", help="run a grid or random sample of cells (eval run or analytic) on Dask",
        description="Expand SPEC.toml into cells (scene x parameters x repeats), run them on "
                    "dask.distributed (a local cluster, or --scheduler) and write one row per "
                    "cell to DIR/results.parquet and DIR/results.csv, the per-cell reports and "
                    "figures. Resumable: a rerun does only the missing cells.")
    parser.add_argument("spec", help="sweep spec (TOML; see sweeps/ and the README)")
    add_out_option(parser, COMMAND, rule="updated in place cell by cell, so that a killed sweep "
                   "keeps what it finished; an existing one is used only if it is an earlier "
                   "output of eval sweep")
    add_cluster_options(parser)
    parser.add_argument("--allow-changed-spec", action="store_true",
                        help="reuse an output written with another spec (its cells that the new "
                             "spec shares are kept; the tables hold the new spec's cells)")
    parser.add_argument("--retry-failed", action="store_true",
                        help="run again the cells that failed in an earlier run")
    parser.add_argument("--no-figures", action="store_true", help="do not draw the figures")
    add_progress_option(parser)


# ------------------------------------------------------------------------------------------------
# the output directory


def _figures_digest(spec, table: list) -> str:
    """What the figures are drawn from: the spec and the table's rows."""
    import hashlib

    text = json.dumps([spec.spec_hash(), table], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def main(args) -> int:
    from eval.sweep.spec import load_spec

    start = time.perf_counter()
    if args.scheduler is None:
        refuse_given(args, ["connect_timeout"], "without --scheduler (the local cluster is "
                                                "started here, nothing is connected to)")
    spec = load_spec(args.spec)
    if args.scheduler is not None:
        check_address(args.scheduler)
        if args.workers is not None:
            raise CLIError("--workers sets the size of the local cluster; with --scheduler the "
                           "cluster's workers run the cells")
    out = SweepDir(args.out)
    previous = out.check()
    if previous and previous.get("spec_hash") not in (None, spec.spec_hash()) and \
            not args.allow_changed_spec:
        out.open(spec, False, previous)  # refuses, one line
    on_disk = out.load_records([c.key for c in spec.cells]) if previous is not None else {}
    todo = [c for c in spec.cells if c.key not in on_disk
            or (args.retry_failed and on_disk[c.key].get("status") != "ok")]
    client = cluster = None
    progress = not args.no_progress
    try:
        where, workers = "nothing to run", 0
        if todo:
            client, cluster, where = connect(args)
            workers = len(client.scheduler_info(n_workers=-1)["workers"]) or 1
        out.open(spec, args.allow_changed_spec, previous)
        runs = out.previous_runs()
        run_id = uuid.uuid4().hex[:12]
        runs.append({"run_id": run_id, "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
                     "cells_to_run": len(todo), "where": where})
        out.write_state(spec, runs)
        records = dict(on_disk)
        ran, compute = 0, 0.0
        if todo:
            try:
                ran, compute = execute(client, spec, todo, out, records, run_id, progress, workers)
            except ValueError as exc:  # from Dask: a bug, not bad input (exit 1, not 2)
                raise RuntimeError(f"{type(exc).__name__}: {exc}") from exc
    finally:
        with interrupt.deferred():  # closed whole even when Ctrl-C is pressed again
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()
    interrupt.check()
    rows = write_tables(out.path, spec, records)
    elapsed = time.perf_counter() - start
    runs[-1].update({"cells_ran": ran, "seconds": elapsed, "compute_seconds": compute})
    out.write_state(spec, runs)
    figures, drawn = [], None
    if not args.no_figures and rows:
        from eval.sweep.figures import write_figures

        interrupt.check()
        table = table_rows(spec, records)
        digest = _figures_digest(spec, table)
        # nothing new (a rerun of a finished sweep): the figures drawn from this table are kept
        # (drawing them took ~20 s of a rerun that had nothing to do)
        figures = out.drawn_figures(digest)
        if figures is None:
            figures = write_figures(os.path.join(out.path, "figures"), spec, table)
        drawn = {"digest": digest, "files": [os.path.basename(p) for p in figures]}
    elapsed = time.perf_counter() - start  # the whole command, the figures included
    runs[-1]["seconds"] = elapsed
    out.write_state(spec, runs, drawn)
    failed = sum(1 for c in spec.cells if records.get(c.key, {}).get("status") == "failed")
    per_cell = (f" ({compute:.1f} s from the first cell submitted to the last result, "
                f"{compute / ran:.3f} s per cell)" if ran else "")
    print(f"sweep {spec.name}: {len(spec.cells)} cells: {len(spec.cells) - len(todo)} done "
          f"before, {ran} ran now on {where} in {elapsed:.1f} s{per_cell}; {failed} failed"
          f"{' (see the error column)' if failed else ''}; wrote {out.display}/results.parquet, "
          f"results.csv, cells/ and {len(figures)} figure(s)")
    return 1 if failed else 0


__all__ = ["add_parser", "main"]
