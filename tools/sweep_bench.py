"""Measure ``python -m eval sweep`` on this machine (numbers for the README; nothing asserted).

1. The same 16-cell render sweep (scenes/small_grid.xml, 320 x 268, 16 spp) with 1 and with 2
   single-threaded workers: cells per second, and the ratio.
2. The same 16 cells as a plain loop of ``python -m eval run`` processes (each pays Python
   start-up, imports and Mitsuba's JIT, and writes eval run's figures and PLY files): seconds
   per cell, against the sweep's.
3. The 10,000-cell analytic sweep (sweeps/analytic_10k.toml) on 2 workers: wall time.

    python tools/sweep_bench.py [--skip-loop] [--skip-10k] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def eval_run_arguments(cell: dict, scene_path: str) -> list:
    """The ``python -m eval run`` arguments of one cell of :data:`RENDER_SPEC` (its parameters:
    ``spp``, ``noise_px``, ``assume.n_water``), without ``--out``."""
    p = cell["params"]
    argv = [scene_path, "--no-progress", "--seed", str(cell["seed"]),
            "--methods", ",".join(cell["methods"]), "--spp", str(p["spp"]),
            "--noise-px", repr(float(p["noise_px"])),
            "--assume", f"n_water={float(p['assume.n_water'])!r}"]
    for name, value in sorted(cell["defines"].items()):
        argv += ["-D", f"{name}={value}"]
    return argv
RENDER_SPEC = """
name = "render16"
seed = 0
repeats = 4
scenes = ["{scene}"]
methods = ["optical_path", "su", "regular"]

[fixed]
kind = "render"
spp = 16

[grid]
noise_px = [0.0, 0.1]
"assume.n_water" = [1.33, 1.331995]
"""


def sweep(spec: Path, out: Path, *extra) -> float:
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "eval", "sweep", str(spec), "--out", str(out),
                             "--no-progress", "--no-figures", *extra], cwd=REPO,
                            capture_output=True, text=True)
    seconds = time.perf_counter() - start
    print(result.stdout.strip() or result.stderr.strip(), flush=True)
    state = json.loads((out / "sweep.json").read_text())
    return seconds, state["runs"][-1]["compute_seconds"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="scratch folder (default: a temporary one)")
    parser.add_argument("--skip-loop", action="store_true")
    parser.add_argument("--skip-10k", action="store_true")
    args = parser.parse_args()
    scratch = Path(args.out or tempfile.mkdtemp(prefix="sweep-bench-"))
    scratch.mkdir(parents=True, exist_ok=True)
    spec = scratch / "render16.toml"
    spec.write_text(RENDER_SPEC.replace("{scene}", str(REPO / "scenes" / "small_grid.xml")))
    results = {"load_average_before": os.getloadavg()}
    for workers in (1, 2):
        seconds, compute = sweep(spec, scratch / f"render-{workers}", "--workers", str(workers))
        results[f"render16_workers{workers}_s"] = seconds
        results[f"render16_workers{workers}_compute_s"] = compute
        print(f"16 render cells, {workers} worker(s): {seconds:.1f} s wall ({16 / seconds:.3f} "
              f"cells/s); {compute:.1f} s from the first submission to the last result", flush=True)
    results["throughput_ratio_2_vs_1"] = (results["render16_workers1_s"]
                                          / results["render16_workers2_s"])
    results["throughput_ratio_2_vs_1_compute"] = (results["render16_workers1_compute_s"]
                                                  / results["render16_workers2_compute_s"])
    print(f"throughput ratio 2 vs 1 worker: {results['throughput_ratio_2_vs_1']:.2f}x wall, "
          f"{results['throughput_ratio_2_vs_1_compute']:.2f}x without the cluster's start-up")
    if not args.skip_loop:
        sys.path.insert(0, str(REPO))
        from eval.sweep.spec import load_spec, scene_defines

        loaded = load_spec(spec)
        start = time.perf_counter()
        for k, cell in enumerate(loaded.cells):
            scene = loaded.scenes[cell.scene]
            payload = {"params": cell.params, "seed": cell.seed, "methods": list(cell.methods),
                       "defines": scene_defines(cell.params, scene, cell.kind,
                                                loaded.render_width)}
            argv = eval_run_arguments(payload, scene.path)
            subprocess.run([sys.executable, "-m", "eval", "run", *argv, "--out",
                            str(scratch / "loop" / f"cell{k}")], cwd=REPO, check=True,
                           capture_output=True)
        loop = time.perf_counter() - start
        results["eval_run_loop_s"] = loop
        per_sweep = results["render16_workers1_s"] / 16
        print(f"plain loop of 16 eval run processes: {loop:.1f} s ({loop / 16:.2f} s per cell); "
              f"sweep on 1 worker: {per_sweep:.2f} s per cell (start-up included); overhead of "
              f"the loop per cell: {loop / 16 - per_sweep:.2f} s")
    if not args.skip_10k:
        seconds, _ = sweep(REPO / "sweeps" / "analytic_10k.toml", scratch / "analytic10k",
                           "--workers", "2")
        results["analytic_10k_workers2_s"] = seconds
        print(f"10,000 analytic cells, 2 workers: {seconds:.1f} s wall", flush=True)
    results["load_average_after"] = os.getloadavg()
    print(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
