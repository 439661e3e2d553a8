"""``python -m eval sweep SPEC.toml --out DIR [--scheduler ADDRESS] [--workers N]``: sweeps at
scale on ``dask.distributed``.

The spec (:mod:`eval.sweep.spec`) expands into cells; the workers run them
(:mod:`eval.sweep.cells`); this module owns the output directory, the execution and the tables.

Execution: a ``LocalCluster`` of ``--workers`` single-threaded worker processes (default: one
per core), or ``--scheduler tcp://HOST:PORT``, a scheduler someone runs (``dask scheduler`` /
``dask worker``, dask-jobqueue, Kubernetes) whose workers can import this project. Render cells
are one task each; analytic cells go in batches (``cells_per_task``). The client writes every
finished cell at once as ``DIR/cells/<key>.json`` (its record: parameters, seed, run id, status,
error, the full report, the row) and appends ``<key> <run id>`` to ``DIR/completions.log``.

Output: ``DIR`` is updated in place, cell by cell — unlike the other commands, whose outputs
appear whole or not at all (:class:`synth.fileio.OutputDir`): a sweep of hours must keep what
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
import re
import sys
import time
import uuid

from eval.cli import CLIError, positive_float, positive_int
from synth.cli import add_out_option, add_progress_option

COMMAND = "eval sweep"
#: What a sweep writes at the top of its directory (anything else makes it foreign).
TOP_LEVEL = ("sweep.json", "spec.toml", "cells", "files", "figures", "results.parquet",
             "results.csv", "completions.log", ".sweep.lock")
#: Seconds between two rebuilds of the tables while cells come in.
TABLE_INTERVAL_S = 10.0
#: Analytic cells per task when the spec does not say (and at most this many).
MAX_CELLS_PER_TASK = 250
#: Columns that differ from run to run of the same cell (left out when comparing tables).
TIMING_COLUMNS = re.compile(r"^(seconds$|timings_s\.)")
_KEY = re.compile(r"^[0-9a-f]{20}$")
_TMP = re.compile(r"^\..+\.tmp$")


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
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="submit to a running Dask scheduler (tcp://HOST:PORT) instead of "
                             "starting a local cluster")
    parser.add_argument("--workers", type=positive_int, default=None, metavar="N",
                        help="local cluster: N single-threaded worker processes (default: one "
                             "per core)")
    parser.add_argument("--connect-timeout", type=positive_float, default=5.0, metavar="S",
                        help="seconds to wait for --scheduler to answer (default 5)")
    parser.add_argument("--allow-changed-spec", action="store_true",
                        help="reuse an output written with another spec (its cells that the new "
                             "spec shares are kept; the tables hold the new spec's cells)")
    parser.add_argument("--retry-failed", action="store_true",
                        help="run again the cells that failed in an earlier run")
    parser.add_argument("--no-figures", action="store_true", help="do not draw the figures")
    add_progress_option(parser)


# ------------------------------------------------------------------------------------------------
# the output directory


class SweepDir:
    """The output directory of a sweep (see module docs): checked, locked, updated in place."""

    def __init__(self, path):
        self.display = os.fspath(path)
        self.path = os.path.abspath(self.display)
        self.cells = os.path.join(self.path, "cells")
        self._lock = None

    def _refuse(self, why: str):
        raise CLIError(f"--out {self.display} {why}")

    def check(self) -> dict | None:
        """The rule (no writes): returns the earlier sweep's ``sweep.json`` or None."""
        from synth.fileio import directory_problem, read_marker

        path = self.path
        problem = directory_problem(path)
        if problem:
            self._refuse(problem)
        if os.path.isdir(path) and not os.access(path, os.W_OK | os.X_OK):
            self._refuse(f"cannot be written: {path} is not writable")  # updated in place
        if not os.path.isdir(path) or not os.listdir(path):
            return None
        marker = read_marker(path)
        if marker is None or marker.get("command") != COMMAND:
            self._refuse("exists and holds files this command did not write")
        foreign = [name for name in self._entries() if not self._ours(name)]
        if foreign:
            self._refuse(f"exists and holds files this command did not write ({foreign[0]})")
        try:
            with open(os.path.join(path, "sweep.json"), encoding="utf-8") as handle:
                return json.load(handle)
        except (OSError, ValueError):
            return {}

    def _entries(self):
        for root, dirs, files in os.walk(self.path):
            rel = os.path.relpath(root, self.path)
            for name in dirs + files:
                yield os.path.normpath(os.path.join(rel, name))

    @staticmethod
    def _ours(rel: str) -> bool:
        from synth.fileio import MARKER_NAME

        parts = rel.split(os.sep)
        top = parts[0]
        if len(parts) == 1:
            return top in TOP_LEVEL or top == MARKER_NAME or bool(_TMP.match(top))
        if top == "cells":
            name = parts[1]
            return len(parts) == 2 and (bool(_KEY.match(name[:-5])) and name.endswith(".json")
                                        or bool(_TMP.match(name)))
        if top == "files":
            return bool(_KEY.match(parts[1])) and len(parts) <= 3
        if top == "figures":
            return len(parts) == 2
        return False

    def open(self, spec, allow_changed: bool, previous: dict | None) -> None:
        """Create or reuse the directory for ``spec``; lock it against a second sweep."""
        import fcntl

        from synth.fileio import MARKER_NAME, MARKER_SCHEMA, PROJECT_NAME, atomic_write_json

        if previous and previous.get("spec_hash") not in (None, spec.spec_hash()):
            if not allow_changed:
                self._refuse(f"holds a sweep of another spec ({previous.get('spec_path', '?')}, "
                             f"hash {str(previous.get('spec_hash'))[:12]}); use "
                             f"--allow-changed-spec to reuse the cells both specs share")
        os.makedirs(self.cells, exist_ok=True)
        self._lock = open(os.path.join(self.path, ".sweep.lock"), "a")
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._refuse("is being written by another sweep")
        for root in (self.path, self.cells):  # temporary files of a killed sweep
            for name in os.listdir(root):
                if _TMP.match(name):
                    os.unlink(os.path.join(root, name))
        atomic_write_json(os.path.join(self.path, MARKER_NAME),
                          {"project": PROJECT_NAME, "schema": MARKER_SCHEMA, "command": COMMAND,
                           "files": sorted(TOP_LEVEL),
                           "note": "updated in place cell by cell (eval sweep)"})
        from synth.fileio import atomic_write_text

        atomic_write_text(os.path.join(self.path, "spec.toml"), spec.text)

    def write_state(self, spec, runs: list) -> None:
        from synth.fileio import atomic_write_json

        atomic_write_json(os.path.join(self.path, "sweep.json"), {
            "spec_path": spec.path, "spec_hash": spec.spec_hash(), "name": spec.name,
            "cells": len(spec.cells), "spec": spec.canonical(), "runs": runs})

    def previous_runs(self) -> list:
        try:
            with open(os.path.join(self.path, "sweep.json"), encoding="utf-8") as handle:
                return list(json.load(handle).get("runs", []))
        except (OSError, ValueError):
            return []

    def load_records(self, keys) -> dict:
        """The finished cells among ``keys``: ``{key: record}`` (unreadable files are ignored:
        those cells run again)."""
        records = {}
        for key in keys:
            try:
                with open(os.path.join(self.cells, f"{key}.json"), encoding="utf-8") as handle:
                    record = json.load(handle)
            except (OSError, ValueError):
                continue
            if record.get("key") == key:
                records[key] = record
        return records

    def write_record(self, record: dict, files: dict, durable: bool = False) -> None:
        from synth.fileio import atomic_write_bytes

        for name, data in (files or {}).items():
            folder = os.path.join(self.path, "files", record["key"])
            os.makedirs(folder, exist_ok=True)
            atomic_write_bytes(os.path.join(folder, name), data)
        text = json.dumps(record, allow_nan=False, separators=(",", ":"))
        _write_atomic(os.path.join(self.cells, f"{record['key']}.json"), text.encode("utf-8"),
                      durable)
        with open(os.path.join(self.path, "completions.log"), "a", encoding="utf-8") as handle:
            handle.write(f"{record['key']} {record['run_id']}\n")


def _write_atomic(path: str, data: bytes, durable: bool) -> None:
    """Temporary file + rename: whole or absent after a ``kill -9``; ``durable`` also fsyncs
    (a cell file need not survive a power cut: its cell would simply run again)."""
    if durable:
        from synth.fileio import atomic_write_bytes

        atomic_write_bytes(path, data)
        return
    directory, name = os.path.split(path)
    tmp = os.path.join(directory, f".{name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as handle:
        handle.write(data)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


# ------------------------------------------------------------------------------------------------
# tables


def _param_columns(cells) -> list:
    return sorted({k for c in cells for k in c.params})


def table_rows(spec, records: dict) -> list:
    """One row per cell of the spec that has a record, in the spec's order."""
    rows = []
    for cell in spec.cells:
        record = records.get(cell.key)
        if record is None:
            continue
        row = {"key": cell.key, "kind": cell.kind, "scene": cell.scene, "repeat": cell.repeat,
               "sample": cell.sample, "seed": cell.seed}
        row.update({k: _cell_value(v) for k, v in cell.params.items()})
        row["status"] = record["status"]
        row["error"] = record["error"]
        row["seconds"] = record.get("seconds")
        row.update(record.get("metrics") or {})
        rows.append(row)
    return rows


def _cell_value(value):
    if isinstance(value, list):
        return " ".join(str(v) for v in value)
    return value


def table_columns(spec, rows: list) -> list:
    fixed = ["key", "kind", "scene", "repeat", "sample", "seed", *_param_columns(spec.cells),
             "status", "error", "seconds"]
    rest = sorted({k for row in rows for k in row} - set(fixed))
    return fixed + rest


def write_tables(directory: str, spec, records: dict) -> int:
    """``results.parquet`` and ``results.csv`` from the records; returns the number of rows."""
    import pyarrow as pa
    import pyarrow.csv as pa_csv
    import pyarrow.parquet as pq

    rows = table_rows(spec, records)
    columns = table_columns(spec, rows)
    arrays = {}
    for name in columns:
        values = [row.get(name) for row in rows]
        kinds = {type(v) for v in values if v is not None}
        if kinds <= {int, float} and int in kinds and float in kinds:
            values = [None if v is None else float(v) for v in values]
        elif len(kinds) > 1:
            values = [None if v is None else str(v) for v in values]
        arrays[name] = pa.array(values, type=None if kinds else pa.null())
    table = pa.table(arrays)
    for name, writer in (("results.parquet", pq.write_table), ("results.csv", pa_csv.write_csv)):
        tmp = os.path.join(directory, f".{name}.{os.getpid()}.tmp")
        writer(table, tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, os.path.join(directory, name))
    return len(rows)


# ------------------------------------------------------------------------------------------------
# execution


def _check_address(address: str) -> str:
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
        try:
            client.run(_probe_worker)
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
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=logging.CRITICAL)
    client = Client(cluster, set_as_default=False)
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


def main(args) -> int:
    from eval.sweep.spec import load_spec

    start = time.perf_counter()
    spec = load_spec(args.spec)
    if args.scheduler is not None:
        _check_address(args.scheduler)
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
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    rows = write_tables(out.path, spec, records)
    elapsed = time.perf_counter() - start
    runs[-1].update({"cells_ran": ran, "seconds": elapsed, "compute_seconds": compute})
    out.write_state(spec, runs)
    figures = []
    if not args.no_figures and rows:
        from eval.sweep.figures import write_figures

        figures = write_figures(os.path.join(out.path, "figures"), spec,
                                table_rows(spec, records))
    failed = sum(1 for c in spec.cells if records.get(c.key, {}).get("status") == "failed")
    per_cell = (f" ({compute:.1f} s from the first cell submitted to the last result, "
                f"{compute / ran:.3f} s per cell)" if ran else "")
    print(f"sweep {spec.name}: {len(spec.cells)} cells: {len(spec.cells) - len(todo)} done "
          f"before, {ran} ran now on {where} in {elapsed:.1f} s{per_cell}; {failed} failed"
          f"{' (see the error column)' if failed else ''}; wrote {out.display}/results.parquet, "
          f"results.csv, cells/ and {len(figures)} figure(s)")
    return 1 if failed else 0


__all__ = ["COMMAND", "SweepDir", "TIMING_COLUMNS", "add_parser", "batches", "connect",
           "execute", "main", "table_rows", "write_tables"]
