"""Throughput of ``python -m synth learn``: pairs per hour, and where a scene's time goes.

    python tools/learn_throughput.py SET_DIR                     # a set already written
    python tools/learn_throughput.py --run DIR --scenes 20 [synth learn options …]

With ``--run`` the set is written first (``python -m synth learn --out DIR --scenes N …``, the
other options passed on), timed from outside with the load average before and after. Then, from
the set's ``learn.json`` (its runs: scenes rendered, seconds of compute) and ``index.csv`` (each
scene's seconds), prints the pairs per hour of every run and, per water, the scenes, the mean
seconds of a scene on its worker and of its render, and the share of the time rendering took.
Nothing is asserted: a benchmark.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def summarize(folder: str) -> None:
    with open(os.path.join(folder, "learn.json"), encoding="utf-8") as handle:
        learn = json.load(handle)
    for run in learn["runs"]:
        if run["scenes_rendered"] and run["compute_seconds"] > 0:
            rate = 3600 * run["scenes_rendered"] / run["compute_seconds"]
            print(f"run {run['run_id']}: {run['scenes_rendered']} scenes in "
                  f"{run['compute_seconds']:.0f} s on {run['where']}: {rate:.0f} pairs/hour")
    with open(os.path.join(folder, "index.csv"), encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    by_water = defaultdict(list)
    for row in rows:
        by_water[row["water"]].append(row)
    print("| water | scenes | seconds per scene (on its worker) | of which rendering | render share |")
    print("|---|---|---|---|---|")
    for water, chosen in sorted(by_water.items()) + [("all", rows)]:
        total = sum(float(r["total_seconds"]) for r in chosen) / len(chosen)
        render = sum(float(r["render_seconds"]) for r in chosen) / len(chosen)
        print(f"| {water} | {len(chosen)} | {total:.1f} | {render:.1f} | "
              f"{100 * render / total:.0f} % |")


def main() -> int:
    args = sys.argv[1:]
    if args and args[0] == "--run":
        folder = args[1]
        before = os.getloadavg()
        started = time.perf_counter()
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        code = subprocess.call([sys.executable, "-m", "synth", "learn", "--out", folder,
                                "--no-progress", *args[2:]], env=env)
        print(f"wall {time.perf_counter() - started:.0f} s, exit {code}; load average before "
              f"{before[0]:.1f}, after {os.getloadavg()[0]:.1f}")
    else:
        folder = args[0]
    summarize(folder)
    return 0


if __name__ == "__main__":
    sys.exit(main())
