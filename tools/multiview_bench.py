"""Benchmark :func:`measure.stereo.multiview.triangulate_views`: N views of points behind flat
ports (numbers for docs/speed.md; nothing asserted).

Four cameras (2448 x 2048 px, f = 1100 px) on an arc of radius 700 mm, 0.3 rad apart, each
turned towards a point 1.5 m ahead, behind one flat port (air, 8 mm glass, water; 520 mm from
the first camera); ``--points`` targets 1.1–2 m away, projected into every view by the Fermat
forward model (:func:`measure.geometry.projection.project`) and triangulated back from those
pixels. Lens distortion: none, OpenCV's Brown–Conrady (k1 0.05, k2 −0.02, p1, p2 5e-4) and
OpenCV's fisheye model (k1…k4 0.05, −0.02, 0.005, −0.002). Printed per case and thread count:
the best wall time of ``--repeat`` runs, points per second, the process CPU time of that run,
the largest distance from the true points (mm) and the load average before and after.

    python tools/multiview_bench.py [--points 1e6] [--views 4] [--workers 1,2] [--repeat 3]
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

from measure.geometry.camera import BROWN_CONRADY, FISHEYE, Camera
from measure.geometry.port import FlatPort
from measure.geometry.projection import project
from measure.stereo.multiview import View, triangulate_views

SIZE, FOCAL = (2448, 2048), 1100.0
K = np.array([[FOCAL, 0, 1223.5], [0, FOCAL, 1023.5], [0, 0, 1.0]])
LENSES = {"none": (BROWN_CONRADY, None),
          "brown_conrady": (BROWN_CONRADY, (0.05, -0.02, 5e-4, -5e-4)),
          "fisheye": (FISHEYE, (0.05, -0.02, 0.005, -0.002))}


def cameras(count: int, lens: str) -> list[Camera]:
    model, dist = LENSES[lens]
    out = []
    for k in range(count):
        angle = (k - (count - 1) / 2) * min(0.3, 1.2 / max(count - 1, 1))
        centre = np.array([700 * np.sin(angle), 30 * np.cos(2 * angle),
                           700 * (1 - np.cos(angle))])
        z = np.array([0, 0, 1500.0]) - centre
        z /= np.linalg.norm(z)
        x = np.cross([0, 1, 0], z)
        x /= np.linalg.norm(x)
        out.append(Camera(K, SIZE, dist, np.column_stack([x, np.cross(z, x), z]), centre,
                          model))
    return out


#: The port of the benchmarks: the paper's flat port (520 mm, 8 mm of glass).
BENCH_PORT = FlatPort([0.0, 0.0, 1.0], 520.0, (8.0,), (1.0, 1.54, 1.33))


def bench_targets(n: int, rng=None) -> np.ndarray:
    """``n`` points (mm) in a box 700 × 600 mm wide, 1.1–2 m ahead of the cameras, drawn from
    ``rng`` (default: seeded with 0)."""
    rng = np.random.default_rng(0) if rng is None else rng
    return np.column_stack([rng.uniform(-350, 350, n), rng.uniform(-300, 300, n),
                            rng.uniform(1100, 2000, n)])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--points", type=float, default=1e6)
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--workers", default="1,2")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--lenses", default=",".join(LENSES))
    args = p.parse_args(argv)
    n = int(args.points)
    port, truth = BENCH_PORT, bench_targets(n)
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; "
          f"load average before {os.getloadavg()[0]:.2f}; {n} points, {args.views} views")
    for lens in args.lenses.split(","):
        views = [View(c, port) for c in cameras(args.views, lens)]
        pixels = np.stack([project(v.camera, port, truth) for v in views], axis=1)
        triangulate_views(views, pixels[:1000])  # imports and first calls
        for workers in (int(w) for w in args.workers.split(",")):
            best = None
            for _ in range(args.repeat):
                wall, cpu = time.perf_counter(), time.process_time()
                result = triangulate_views(views, pixels, workers=workers)
                wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
                if best is None or wall < best[0]:
                    best = (wall, cpu)
            error = np.nanmax(np.linalg.norm(result.points - truth, axis=1))
            print(f"{lens:14s} {workers} thread(s): {best[0]:.3f} s, {n / best[0] / 1e6:.2f} M "
                  f"points/s (CPU {best[1]:.2f} s); {result.valid.mean():.1%} valid, max error "
                  f"{error:.1e} mm")
    print(f"load average after {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
