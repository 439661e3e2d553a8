"""``python -m eval bench``: speed of the vectorized geometry on this machine.

Measures (best of ``--repeat`` runs, wall clock):

* on ``--points`` points behind the paper's port: ``triangulate`` with each method and
  ``measure.geometry.projection.project`` with the Fermat and the Snell solver (points per second);
* for every batch size of ``--sizes`` (default 10^3 … 10^6; 10^7 on request) and both ports —
  the paper's air–glass–water and a bare air–water interface: ``project`` (Fermat), ``project``
  with ``jacobian=True`` (d pixel / d point) and with ``parameters=True`` (also the port and
  camera parameters), and ``triangulate`` (``optical_path``);
* the per-point SciPy minimization of the same travel time (:mod:`eval.core.fermat_reference`) on a
  subset of the same points, and the speed-up of the vectorized Fermat solver over it.

Everything is pure NumPy (no just-in-time compilation: the first call costs nothing extra; it is
timed anyway, as ``first_call_seconds``). The machine (CPU model, cores, load average before and
after) is printed: other work on the machine slows every number. Speeds are measurements,
printed and optionally written as JSON; nothing is asserted.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from eval.cli import non_negative_int, positive_int
from synth.infra.cli import add_json_option, add_out_option, add_progress_option

COMMAND = "eval bench"

#: Issue 12's targets: (measurement, port, batch size) → points per second (the Jacobian: at
#: most this many times the projection's time).
ISSUE_TARGETS = {
    ("triangulate_optical_path", "air-glass-water", 10**6): 12e6,
    ("project_fermat", "air-glass-water", 10**6): 7e6,
    ("project_fermat", "air-water", 10**4): 10e6,
}
JACOBIAN_TIME_RATIO_TARGET = 2.0
DEFAULT_SIZES = (10**3, 10**4, 10**5, 10**6)
MAX_SIZE = 10**7


def batch_sizes(text: str) -> tuple[int, ...]:
    """An argparse type: comma-separated batch sizes (``1000,1e6`` or ``10^4``), 1 … 10^7."""
    sizes = []
    for part in text.split(","):
        part = part.strip().replace("10^", "1e")
        try:
            value = float(part)
        except ValueError:
            value = float("nan")
        if not (np.isfinite(value) and value == int(value) and 1 <= value <= MAX_SIZE):
            raise argparse.ArgumentTypeError(
                f"expected comma-separated batch sizes from 1 to 1e7, got {text!r}")
        sizes.append(int(value))
    return tuple(dict.fromkeys(sizes))


def add_parser(subparsers):
    parser = subparsers.add_parser("bench", help="measure the speed of triangulation and projection")
    parser.add_argument("--points", type=positive_int, default=1_000_000,
                        help="batch size of the per-method table (default 10^6)")
    parser.add_argument("--sizes", type=batch_sizes, default=DEFAULT_SIZES,
                        help="batch sizes of the per-size table, e.g. 1e3,1e4,1e5,1e6,1e7 "
                             "(default 10^3 to 10^6)")
    parser.add_argument("--reference-points", type=positive_int, default=2000,
                        help="points solved one by one with scipy.optimize (default 2000)")
    parser.add_argument("--repeat", type=positive_int, default=3, help="runs per measurement; best counts")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="seed of the random points")
    add_out_option(parser, COMMAND, what="file", required=False,
                   rule="the results as JSON; an existing file is replaced only if it is an "
                        "earlier output of eval bench")
    add_json_option(parser)
    add_progress_option(parser)


def _best_time(function, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def machine() -> dict:
    """CPU model, cores, platform and the load average (what else the machine is doing)."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    try:
        load = [round(v, 2) for v in os.getloadavg()]
    except (AttributeError, OSError):
        load = None
    return {"cpu": model, "cpu_count": os.cpu_count(), "usable_cores": usable,
            "machine": platform.machine(), "system": platform.platform(),
            "python": platform.python_version(), "numpy": np.__version__, "load_average": load}


def _ports():
    from measure import FlatPort
    from synth.scene.rig import paper_port

    paper = paper_port()
    return {"air-glass-water": paper,
            "air-water": FlatPort(paper.normal, paper.distance, (), (paper.indices[0], paper.n_water))}


def run_bench(n_points: int, n_reference: int, repeat: int, seed: int, progress=print,
              sizes=DEFAULT_SIZES) -> dict:
    """Run the measurements; returns a dict of seconds and points per second."""
    from eval.core.fermat_reference import fermat_pixel_scipy
    from measure import StereoRig, triangulate
    from measure.geometry.projection import project
    from synth.scene.layouts import random_volume
    from synth.scene.rig import paper_rig

    rig = paper_rig()
    results = {"points": n_points, **machine(), "timings": {}, "per_size": []}
    start = time.perf_counter()
    project(rig.left, rig.port, np.array([[10.0, 20.0, 1000.0]]), jacobian=True)
    results["first_call_seconds"] = time.perf_counter() - start
    points = random_volume(n_points, seed, z_range=(500.0, 2500.0), half_angle_deg=30.0)
    uv_left = project(rig.left, rig.port, points)
    uv_right = project(rig.right, rig.port, points)
    timings = results["timings"]

    for method in ("optical_path", "su", "regular"):
        progress(f"triangulate {method} …")
        seconds = _best_time(lambda: triangulate(rig, uv_left, uv_right, method), repeat)
        timings[f"triangulate_{method}"] = {"seconds": seconds, "points_per_s": n_points / seconds}
    for solver in ("fermat", "snell"):
        progress(f"project {solver} …")
        seconds = _best_time(lambda: project(rig.left, rig.port, points, solver), repeat)
        timings[f"project_{solver}"] = {"seconds": seconds, "points_per_s": n_points / seconds}

    for port_name, port in _ports().items():
        pair = StereoRig(rig.left, rig.right, port)
        for size in sizes:
            progress(f"{port_name}, {size} points …")
            batch = random_volume(size, seed, z_range=(500.0, 2500.0), half_angle_deg=30.0)
            left, right = project(rig.left, port, batch), project(rig.right, port, batch)
            runs = max(repeat, min(30, int(3e6 // size)))  # small batches: more runs
            measured = {
                "project_fermat": lambda: project(rig.left, port, batch),
                "project_fermat_jacobian": lambda: project(rig.left, port, batch, jacobian=True),
                "project_fermat_parameters": lambda: project(rig.left, port, batch,
                                                             parameters=True),
                "triangulate_optical_path": lambda: triangulate(pair, left, right),
            }
            best = {name: np.inf for name in measured}
            for _ in range(runs):  # interleaved, so that a busy moment hits all alike
                for name, function in measured.items():
                    best[name] = min(best[name], _best_time(function, 1))
            for name, seconds in best.items():
                row = {"measurement": name, "port": port_name, "points": size,
                       "seconds": seconds, "points_per_s": size / seconds}
                if name.startswith("project_fermat_"):
                    row["time_ratio_to_project"] = seconds / best["project_fermat"]
                results["per_size"].append(row)

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
    rows = {(r["measurement"], r["port"], r["points"]): r for r in results["per_size"]}
    results["issue_targets"] = [
        {"measurement": name, "port": port_name, "points": size, "target_points_per_s": target,
         "points_per_s": rows[name, port_name, size]["points_per_s"],
         "met": rows[name, port_name, size]["points_per_s"] >= target}
        for (name, port_name, size), target in ISSUE_TARGETS.items()
        if (name, port_name, size) in rows]
    ratios = [r["time_ratio_to_project"] for r in results["per_size"]
              if r["measurement"] == "project_fermat_jacobian"]
    if ratios:
        results["jacobian_time_ratio_max"] = max(ratios)
    results["load_average_after"] = machine()["load_average"]
    return results


def format_table(results: dict) -> str:
    lines = [f"{'measurement':<34} {'points':>9} {'seconds':>9} {'points/s':>12}"]
    for name, row in results["timings"].items():
        points = row.get("points", results["points"])
        lines.append(f"{name:<34} {points:>9d} {row['seconds']:>9.3f} {row['points_per_s']:>12,.0f}")
    lines.append(f"vectorized Fermat speed-up over per-point scipy: "
                 f"{results['fermat_speedup_over_scipy']:,.0f}x "
                 f"(max pixel difference {results['scipy_vs_vectorized_max_px']:.1e} px)")
    if results["per_size"]:
        lines.append("")
        lines.append(f"{'measurement':<28} {'port':<16} {'points':>9} {'seconds':>10} "
                     f"{'points/s':>13} {'× project':>10}")
        for row in results["per_size"]:
            ratio = row.get("time_ratio_to_project")
            lines.append(f"{row['measurement']:<28} {row['port']:<16} {row['points']:>9d} "
                         f"{row['seconds']:>10.5f} {row['points_per_s']:>13,.0f} "
                         f"{'' if ratio is None else f'{ratio:.2f}':>10}")
    for target in results.get("issue_targets", []):
        lines.append(f"target {target['measurement']} ({target['port']}, {target['points']:,} "
                     f"points) >= {target['target_points_per_s']:,.0f}/s: "
                     f"{'yes' if target['met'] else 'NO'} ({target['points_per_s']:,.0f}/s)")
    if "jacobian_time_ratio_max" in results:
        ratio = results["jacobian_time_ratio_max"]
        lines.append(f"target project with jacobian=True <= {JACOBIAN_TIME_RATIO_TARGET:g} × "
                     f"project: {'yes' if ratio <= JACOBIAN_TIME_RATIO_TARGET else 'NO'} "
                     f"(at most {ratio:.2f} ×)")
    lines.append(f"first call (nothing compiled): {results['first_call_seconds'] * 1e3:.1f} ms")
    lines.append(f"machine: {results['cpu']}, {results['cpu_count']} cores "
                 f"({results['usable_cores']} usable), {results['machine']}, "
                 f"Python {results['python']}, NumPy {results['numpy']}; load average "
                 f"{results['load_average']} before, {results['load_average_after']} after "
                 f"(other work on the machine slows every number)")
    return "\n".join(lines)


def is_bench_output(path: str) -> bool:
    """Whether ``path`` is a JSON file that ``eval bench --out`` wrote (its ``command`` key)."""
    import json

    try:
        with open(path, encoding="utf-8") as handle:
            return json.load(handle).get("command") == COMMAND
    except (OSError, ValueError, AttributeError):
        return False


def main(args) -> int:
    import json
    import sys

    from synth.infra.fileio import atomic_write_json, check_file_output

    if args.out:  # before the benchmark, not after
        check_file_output(args.out, "--out", may_replace=is_bench_output)
    progress = ((lambda text: None) if args.no_progress
                else (lambda text: print(text, file=sys.stderr, flush=True)))
    results = run_bench(args.points, args.reference_points, args.repeat, args.seed,
                        progress=progress, sizes=args.sizes)
    results = {"command": COMMAND, **results}
    print(format_table(results), file=sys.stderr if args.json else sys.stdout)
    if args.out:
        atomic_write_json(args.out, results)
    if args.json:
        print(json.dumps(results, indent=2))
    return 0
