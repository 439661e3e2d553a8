"""Throughput of ``python -m synth learn``: pairs per hour, and where a scene's time goes.

    python tools/learn_throughput.py SET_DIR                     # a set already written
    python tools/learn_throughput.py --run DIR --scenes 20 [synth learn options …]

With ``--run`` the set is written first (``python -m synth learn --out DIR --scenes N …``, the
other options passed on), timed from outside: wall clock, the load average (``os.getloadavg``,
1 minute) before and after, and the CPU seconds of the run and every process it waited for
(``resource.getrusage(RUSAGE_CHILDREN)``: its Dask workers too). Then, from the set's
``learn.json`` (its runs: scenes rendered, seconds of compute) and its scenes' manifests (each
part's wall-clock ``seconds`` and ``cpu_seconds``), prints the pairs per hour of every run, the
CPU seconds of a pair and the pairs per hour two cores would give if nothing else ran
(``2 · 3600 / CPU seconds per pair``; on a loaded machine the wall clock is slower by what the
other processes take), and a table of the mean seconds per scene of each part (the scene files,
the truth, the render, the writing, the checks) by water. Nothing is asserted: a benchmark.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PARTS = ("scene", "truth", "render", "write", "checks", "total")


def _manifests(folder: str) -> list:
    """The manifests of the set's finished scene folders."""
    found = []
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name, "manifest.json")
        if name.startswith("scene_") and os.path.isfile(path):
            with open(path, encoding="utf-8") as handle:
                found.append(json.load(handle))
    return found


def _mean(manifests, key: str, part: str):
    values = [m[key][part] for m in manifests if part in m.get(key, {})]
    return sum(values) / len(values) if values else None


def summarize(folder: str, cores: int = 2) -> None:
    """Print the runs' pairs per hour and the per-part table of the set in ``folder``."""
    learn_path = os.path.join(folder, "learn.json")
    if os.path.isfile(learn_path):
        with open(learn_path, encoding="utf-8") as handle:
            learn = json.load(handle)
        for run in learn["runs"]:
            if run["scenes_rendered"] and run["compute_seconds"] > 0:
                rate = 3600 * run["scenes_rendered"] / run["compute_seconds"]
                print(f"run {run['run_id']}: {run['scenes_rendered']} scenes in "
                      f"{run['compute_seconds']:.0f} s on {run['where']}: {rate:.0f} pairs/hour")
    manifests = _manifests(folder)
    if not manifests:
        print("no finished scene")
        return
    timed = [m for m in manifests if "total" in m.get("cpu_seconds", {})]
    if timed:
        cpu = _mean(timed, "cpu_seconds", "total")
        print(f"{len(timed)} scenes with CPU seconds: {cpu:.1f} CPU s per pair; {cores} cores "
              f"with nothing else running: {cores * 3600 / cpu:.0f} pairs/hour")
    by_water = defaultdict(list)
    for manifest in manifests:
        by_water[manifest["generator"]["water"]].append(manifest)
    print("| water | scenes | " + " | ".join(f"{p} s (CPU s)" for p in PARTS) + " |")
    print("|---|---|" + "---|" * len(PARTS))
    for water, chosen in sorted(by_water.items()) + [("all", manifests)]:
        cells = []
        for part in PARTS:
            wall, cpu = _mean(chosen, "seconds", part), _mean(chosen, "cpu_seconds", part)
            cells.append(f"{wall:.1f}" + (f" ({cpu:.1f})" if cpu is not None else ""))
        print(f"| {water} | {len(chosen)} | " + " | ".join(cells) + " |")


def main() -> int:
    args = sys.argv[1:]
    if not args or args[0] in ("-h", "--help"):
        print(__doc__)
        return 0 if args else 2
    if args[0] == "--run":
        if len(args) < 2:
            print("error: --run needs a folder", file=sys.stderr)
            return 2
        folder = args[1]
        before, usage = os.getloadavg(), resource.getrusage(resource.RUSAGE_CHILDREN)
        started = time.perf_counter()
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        code = subprocess.call([sys.executable, "-m", "synth", "learn", "--out", folder,
                                "--no-progress", *args[2:]], env=env)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - usage.ru_utime) + (after.ru_stime - usage.ru_stime)
        print(f"wall {time.perf_counter() - started:.0f} s, exit {code}; CPU {cpu:.0f} s (the "
              f"run and its workers); load average before {before[0]:.2f}, after "
              f"{os.getloadavg()[0]:.2f}")
    else:
        folder = args[0]
    if not os.path.isdir(folder):
        print(f"error: {folder} is not a folder", file=sys.stderr)
        return 2
    summarize(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
