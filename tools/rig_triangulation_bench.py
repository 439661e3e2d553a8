"""Benchmark :func:`measure.triangulate_rig`: the N-view reprojection against the N-view optical
path, and the pair's reprojection for scale (numbers for docs/library.md; nothing asserted).

The rig of tools/multiview_bench.py (cameras 2448 x 2048 px, f = 1100 px, on an arc of radius
700 mm 0.3 rad apart, behind one flat port: air, 8 mm glass, water, 520 mm away) with OpenCV's
Brown–Conrady distortion; ``--points`` targets 1.1–2 m away, projected into every view by the
Fermat forward model and given Gaussian pixel noise of ``--sigma`` px (seeded). Printed per
method: the best wall time of ``--repeat`` runs, points per second, the process CPU time of that
run, the RMS distance from the true points (mm) and the load average before and after.

    python tools/rig_triangulation_bench.py [--points 1e5] [--views 4] [--sigma 0.2] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from measure import Rig, triangulate, triangulate_rig
from measure.geometry.projection import project
from tools.multiview_bench import BENCH_PORT, bench_targets, cameras


def _best(run, repeat: int):
    """``(wall s, cpu s, result)`` of the fastest of ``repeat`` calls of ``run``."""
    best = None
    for _ in range(repeat):
        wall, cpu = time.perf_counter(), time.process_time()
        result = run()
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        if best is None or wall < best[0]:
            best = (wall, cpu, result)
    return best


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--points", type=float, default=1e5)
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--sigma", type=float, default=0.2)
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args(argv)
    n = int(args.points)
    rng = np.random.default_rng(0)
    port, truth = BENCH_PORT, bench_targets(n, rng)
    ring = cameras(args.views, "brown_conrady")
    rig = Rig(ring, [port] * len(ring))
    pixels = np.stack([project(c, port, truth) for c in ring], axis=1)
    pixels += rng.normal(0.0, args.sigma, pixels.shape)
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; load average "
          f"before {os.getloadavg()[0]:.2f}; {n} points, {args.views} views, σ {args.sigma} px")
    triangulate_rig(rig, pixels[:1000], "reprojection")  # imports and first calls
    cases = [(f"{args.views} views {method}", lambda m=method: triangulate_rig(rig, pixels, m))
             for method in ("optical_path", "reprojection")]
    two = rig.pair(0, 1)
    cases.append(("pair (views 0, 1) reprojection",
                  lambda: triangulate(two, pixels[:, 0], pixels[:, 1], "reprojection")))
    for name, run in cases:
        wall, cpu, result = _best(run, args.repeat)
        error = np.linalg.norm(result.points - truth, axis=1)
        print(f"{name:34s} {wall:7.3f} s  {n / wall / 1e3:8.1f} k points/s  cpu {cpu:7.3f} s  "
              f"RMS error {np.sqrt(np.nanmean(error ** 2)):.4f} mm  "
              f"valid {np.mean(result.reason == 0):.4f}")
    print(f"load average after {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
