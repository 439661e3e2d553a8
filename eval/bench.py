"""``python -m eval bench``: speed of the vectorized geometry on this machine.

Measures, on 10^6 points behind the paper's port (best of ``--repeat`` runs, wall clock):

* ``triangulate`` with each method (points per second),
* ``synth.project`` with the Fermat and the Snell solver (points per second),
* the per-point SciPy minimization of the same travel time (:mod:`eval.fermat_reference`) on a
  subset of the same points, and the speed-up of the vectorized Fermat solver over it.

Speeds are measurements, printed and optionally written as JSON; nothing is asserted.
"""

from __future__ import annotations

import os
import platform
import time

import numpy as np

from eval.cli import non_negative_int, positive_int

ISSUE_TARGETS = {"triangulate_optical_path": 5e6, "project_fermat": 1e6}


def add_parser(subparsers):
    parser = subparsers.add_parser("bench", help="measure the speed of triangulation and projection")
    parser.add_argument("--points", type=positive_int, default=1_000_000,
                        help="batch size for the vectorized functions (default 10^6)")
    parser.add_argument("--reference-points", type=positive_int, default=2000,
                        help="points solved one by one with scipy.optimize (default 2000)")
    parser.add_argument("--repeat", type=positive_int, default=3, help="runs per measurement; best counts")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="seed of the random points")
    parser.add_argument("--json", metavar="FILE", help="also write the results to FILE")


def _best_time(function, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def run_bench(n_points: int, n_reference: int, repeat: int, seed: int, progress=print) -> dict:
    """Run the measurements; returns a dict of seconds and points per second."""
    from eval.fermat_reference import fermat_pixel_scipy
    from measure import triangulate
    from synth.layouts import random_volume
    from measure.projection import project
    from synth.rig import paper_rig

    rig = paper_rig()
    points = random_volume(n_points, seed, z_range=(500.0, 2500.0), half_angle_deg=30.0)
    uv_left = project(rig.left, rig.port, points)
    uv_right = project(rig.right, rig.port, points)
    results = {"points": n_points, "cpu_count": os.cpu_count(), "machine": platform.machine(),
               "python": platform.python_version(), "numpy": np.__version__, "timings": {}}
    timings = results["timings"]

    for method in ("optical_path", "su", "regular"):
        progress(f"triangulate {method} …")
        seconds = _best_time(lambda: triangulate(rig, uv_left, uv_right, method), repeat)
        timings[f"triangulate_{method}"] = {"seconds": seconds, "points_per_s": n_points / seconds}
    for solver in ("fermat", "snell"):
        progress(f"project {solver} …")
        seconds = _best_time(lambda: project(rig.left, rig.port, points, solver), repeat)
        timings[f"project_{solver}"] = {"seconds": seconds, "points_per_s": n_points / seconds}

    n_reference = min(n_reference, n_points)
    progress(f"per-point scipy.optimize Fermat on {n_reference} of the same points …")
    subset = points[:n_reference]
    start = time.perf_counter()
    reference = np.array([fermat_pixel_scipy(rig.left, rig.port, p) for p in subset])
    seconds = time.perf_counter() - start
    timings["project_fermat_scipy_per_point"] = {"seconds": seconds, "points": n_reference,
                                                 "points_per_s": n_reference / seconds}
    vectorized = project(rig.left, rig.port, subset)
    results["scipy_vs_vectorized_max_px"] = float(np.max(np.abs(reference - vectorized)))
    results["fermat_speedup_over_scipy"] = (timings["project_fermat"]["points_per_s"]
                                            / timings["project_fermat_scipy_per_point"]["points_per_s"])
    results["meets_issue_targets"] = {name: timings[name]["points_per_s"] >= target
                                      for name, target in ISSUE_TARGETS.items()}
    return results


def format_table(results: dict) -> str:
    lines = [f"{'measurement':<34} {'points':>9} {'seconds':>9} {'points/s':>12}"]
    for name, row in results["timings"].items():
        points = row.get("points", results["points"])
        lines.append(f"{name:<34} {points:>9d} {row['seconds']:>9.3f} {row['points_per_s']:>12,.0f}")
    lines.append(f"vectorized Fermat speed-up over per-point scipy: {results['fermat_speedup_over_scipy']:,.0f}x "
                 f"(max pixel difference {results['scipy_vs_vectorized_max_px']:.1e} px)")
    for name, ok in results["meets_issue_targets"].items():
        lines.append(f"target {name} >= {ISSUE_TARGETS[name]:,.0f}/s: {'yes' if ok else 'NO'}")
    lines.append(f"machine: {results['machine']}, {results['cpu_count']} cores, "
                 f"Python {results['python']}, NumPy {results['numpy']}")
    return "\n".join(lines)


def main(args) -> int:
    from synth.fileio import atomic_write_json, check_file_output

    if args.json:
        check_file_output(args.json, "--json")  # before the benchmark, not after
    results = run_bench(args.points, args.reference_points, args.repeat, args.seed,
                        progress=lambda text: print(text, flush=True))
    print(format_table(results))
    if args.json:
        atomic_write_json(args.json, results)
    return 0
