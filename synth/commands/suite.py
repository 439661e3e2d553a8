"""``python -m synth suite SPEC.toml --out DIR [--workers N | --scheduler tcp://HOST:PORT]``:
render a benchmark suite — one dataset per entry of the spec — on Dask workers
(:mod:`synth.products.suite`, the grammar of :mod:`synth.infra.grid`, the cluster of
:mod:`synth.infra.cluster`).

Resumable: a rerun does only the entries without a whole dataset; each dataset appears whole
(written by :func:`synth.products.dataset.write_dataset`). A spec with ``render = "learn"`` is a
learning set of generated sea scenes instead (:mod:`synth.products.learn_run`, what
``python -m synth learn`` writes). A write that fails (a full disk) or an
unreachable scheduler ends with one ``error:`` line; the datasets finished are kept."""

from __future__ import annotations

import sys
import time
import uuid

from synth.infra import interrupt
from synth.infra.cli import (CLIError, add_cluster_options, add_out_option, add_progress_option, refuse_given)


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "suite", help="render a benchmark suite: one dataset per entry of a spec, on Dask",
        description="Expand SPEC.toml (the grammar of eval sweep: grid, zip, seeded random "
                    "samples over scenes and their -D parameters, spp, sensor) into entries and "
                    "render one dataset per entry into DIR/<folder>/ on dask.distributed; write "
                    "DIR/index.parquet, index.csv, suite.json and README.md. Resumable.")
    p.add_argument("spec", help="suite spec (TOML; see suites/ and docs/suites.md)")
    add_out_option(p, "synth suite", rule="updated in place dataset by dataset, so that a killed "
                   "suite keeps what it finished; an existing one is used only if it is an "
                   "earlier output of synth suite with the same spec")
    add_cluster_options(p)
    p.add_argument("--retry-failed", action="store_true",
                   help="render again the entries that failed in an earlier run")
    add_progress_option(p)


def main(args) -> int:
    from synth.infra.cluster import connect
    from synth.products.suite import load_suite_spec
    from synth.products.suite_folder import (SuiteDir, probe, write_index, write_readme,
                                             write_suite_json)

    start = time.perf_counter()
    _check_cluster_options(args)
    learn = _learn_request(args)
    if learn is not None:  # a learning set (render = "learn"): synth learn's runner
        from synth.products.learn_run import run_learn

        return run_learn(learn, args.scheduler, args.workers, args.connect_timeout,
                         not args.no_progress)
    spec = load_suite_spec(args.spec)
    out = SuiteDir(args.out)
    previous = out.check()
    if previous and previous.get("spec_hash") not in (None, spec.spec_hash()):
        out.open(spec, previous, "")  # refuses, one line
    records = out.finished(spec) if previous is not None else {}
    todo = [e for e in spec.entries if e.key not in records
            or (args.retry_failed and records[e.key].get("status") != "ok")]
    if not args.no_progress:
        _announce(spec, todo)
    token = uuid.uuid4().hex
    client = cluster = None
    where, ran, compute = "nothing to render", 0, 0.0
    runs = list((previous or {}).get("runs", []))
    try:
        if todo:
            client, cluster, where = connect(args.scheduler, args.workers, args.connect_timeout,
                                             probe, "suite datasets")
        out.open(spec, previous, token)
        out.write_scenes(spec)
        runs.append({"run_id": token[:12], "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
                     "datasets_to_render": len(todo), "where": where})
        if todo:
            try:
                ran, compute = _execute(client, spec, todo, out, records, token,
                                        not args.no_progress)
            except OSError as exc:  # a full disk, a folder that vanished: what finished stays
                done = sum(1 for r in records.values() if r.get("status") == "ok")
                raise CLIError(f"--out {args.out}: cannot write "
                               f"({exc.strerror or exc}{': ' + exc.filename if exc.filename else ''}"
                               f"); the {done} dataset(s) finished are kept: rerun to resume"
                               ) from None
    finally:
        with interrupt.deferred():
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()
    interrupt.check()
    rows = write_index(out.path, spec, records)
    runs[-1].update({"datasets_rendered": ran, "seconds": time.perf_counter() - start,
                     "compute_seconds": compute})
    write_suite_json(out.path, spec, records, runs)
    write_readme(out.path, spec, rows)
    failed = [r for r in rows if r["status"] != "ok"]
    elapsed = time.perf_counter() - start
    per = f" ({compute / ran:.2f} s per dataset)" if ran else ""
    print(f"suite {spec.name}: {len(spec.entries)} datasets: {len(spec.entries) - len(todo)} "
          f"done before, {ran} rendered now on {where} in {elapsed:.1f} s{per}; {len(failed)} "
          f"failed{' (see the error column of index.csv)' if failed else ''}; wrote "
          f"{out.display}/index.parquet, index.csv, suite.json, README.md")
    for row in failed[:5]:
        print(f"  {row['folder']}: {row['error']}", file=sys.stderr)
    return 1 if failed else 0


def _check_cluster_options(args) -> None:
    """CLIError for ``--connect-timeout`` without ``--scheduler``, a bad scheduler address, or
    ``--workers`` with one (the cluster's own workers render)."""
    from synth.infra.cluster import check_address

    if args.scheduler is None:
        refuse_given(args, ["connect_timeout"], "without --scheduler (the local cluster is "
                                                "started here, nothing is connected to)")
        return
    check_address(args.scheduler)
    if args.workers is not None:
        raise CLIError("--workers sets the size of the local cluster; with --scheduler the "
                       "cluster's workers render the datasets")


def _announce(spec, todo) -> None:
    """What the run will render, on stderr; a warning for a suite of many hours."""
    print(f"suite {spec.name}: {len(spec.entries)} datasets, {len(todo)} to render now "
          f"({len(spec.entries) - len(todo)} done before)", file=sys.stderr, flush=True)
    if len(todo) > LARGE_SUITE:
        print(f"warning: {len(todo)} datasets to render: at 5–60 s each on a 2-core machine "
              f"(docs/suites.md) that is {len(todo) * 5 / 3600:.0f}–"
              f"{len(todo) * 60 / 3600:.0f} hours; Ctrl-C stops it and a rerun resumes",
              file=sys.stderr, flush=True)


def _learn_request(args):
    """The learning set of a spec with ``render = "learn"`` (:mod:`synth.products.learn_run`),
    or None for any other spec."""
    from synth.infra.grid import read_toml
    from synth.products.learn_run import is_learn_spec, read_learn_spec

    data, _, label = read_toml(args.spec)
    if not is_learn_spec(data):
        return None
    if args.retry_failed:
        raise CLIError("--retry-failed does not apply to a learning suite (render = \"learn\"): "
                       "every scene without a whole folder is rendered again by a rerun")
    return read_learn_spec(data, label, args.out)


#: Datasets to render above which the suite warns of the hours it will take; progress lines
#: printed without a terminal (tqdm draws none there).
LARGE_SUITE, PROGRESS_LINES = 10_000, 20


def _execute(client, spec, todo, out, records, token, progress) -> tuple[int, float]:
    import os

    from distributed import as_completed
    from tqdm import tqdm

    from synth.products.suite_folder import render_task

    started = time.perf_counter()
    futures = {}
    for entry in todo:
        scene = spec.scene_files[entry.scene_id]
        made = spec.generated.get(entry.scene_id)
        if made is not None:  # written into DIR/scenes/ by out.write_scenes
            scene = made.placed(out.path)
        task = {"key": entry.key, "render": entry.render, "scene_sha": scene.sha256,
                "scene_data": scene.data, "scene_path": scene.path, "params": entry.params,
                "defines": entry.defines, "design": entry.design, "seed": entry.seed,
                "out": os.path.join(out.path, entry.folder), "token": token}
        futures[client.submit(render_task, task, pure=False, key=f"suite-{entry.key}")] = entry
    bar = tqdm(total=len(todo), unit="dataset", desc="suite", file=sys.stderr,
               disable=True if not progress else None)
    # without a terminal tqdm draws nothing: a line every twentieth of the suite instead
    lines = progress and bar.disable
    every = max(1, len(todo) // PROGRESS_LINES)
    ran = failed = 0
    try:
        for future in as_completed(futures, loop=client.loop):
            interrupt.check()
            entry = futures.pop(future)
            try:
                result = future.result()
            except Exception as exc:  # the task itself failed (a worker died, …)
                result = {"key": entry.key, "status": "failed",
                          "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"}
            if result.get("write_error"):  # a full disk: stop, keep what finished
                raise OSError(f"{entry.folder}: {result['error']}")
            files = result.pop("files", None)
            if result["status"] == "ok" and files is not None:
                out.write_dataset_files(entry.folder, files, result["request_key"], entry.render)
            record = {**result, "folder": entry.folder}
            with interrupt.deferred():
                out.write_record(record)
            records[entry.key] = record
            ran += 1
            failed += record.get("status") != "ok"
            bar.update(1)
            if lines and (ran % every == 0 or ran == len(todo)):
                print(f"suite: {ran}/{len(todo)} datasets ({100 * ran / len(todo):.0f} %), "
                      f"{failed} failed, {time.perf_counter() - started:.0f} s", file=sys.stderr,
                      flush=True)
    finally:
        bar.close()
        for future in futures:
            future.cancel()
    return ran, time.perf_counter() - started


__all__ = ["add_parser", "main"]
