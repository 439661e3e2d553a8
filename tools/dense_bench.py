"""Benchmark :func:`measure.dense.match.match_dense` on a full-size analytic pair (numbers for the
report; nothing asserted).

The paper's rig (2448 x 2048 px, f = 1100 px) behind the paper's port looks at a speckled plane
at 1 m facing the cameras (synth.products.dense_pairs, 3 x 3 supersampled). Both models match the pair
over the depth range 900-1100 mm (the pinhole model over its own apparent range, which lies
nearer: straight rays see the plane at ~780 mm). Printed: matched fraction of the overlap (left
pixels whose true surface point is in the right image, both 7 px inside the borders), the
right-pixel error against the exact Fermat projection of the true point (RMS, max), the RMS
distance of the triangulated points to the plane, the time per stage (the matching σ's
included), the time of the refractive points' covariances and the load average.

    python tools/dense_bench.py [--size 2448 2048] [--supersample 3] [--seed 0] [--cache [DIR]]

``--cache`` keeps the rendered pair as .npy files (default directory: ``dense_bench`` under the
system's temporary directory) and reuses them on the next run with the same size, supersampling
and seed, so that timing runs skip the ~1 min render.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from measure import triangulate
from measure.dense.match import match_dense
from measure.geometry.projection import project
from measure.stereo.uncertainty import dense_point_covariances
from synth.products.dense_pairs import PlaneSurface, SpeckleTexture, render_pair, surface_points
from synth.scene.rig import PAPER_FOCAL_PX, PAPER_IMAGE_SIZE, paper_rig

#: Speckle diameter in pixels of the left image at 1 m (the texture scales with the image).
SPECKLE_PX = 2.5
#: Footprint of one left pixel on the plane at 1 m behind the paper's port (mm per px at f = 1100).
FOOTPRINT_MM_AT_F1100 = 0.70


def _load() -> str:
    try:
        return Path("/proc/loadavg").read_text().strip()
    except OSError:
        return "n/a"


def _rendered_pair(rig, surface, texture, args):
    """The rendered pair, from the ``--cache`` directory when it holds one for these arguments."""
    if args.cache is None:
        return render_pair(rig, surface, texture, args.supersample)
    directory = Path(args.cache)
    stem = f"plane1000_{args.size[0]}x{args.size[1]}_ss{args.supersample}_seed{args.seed}"
    files = [directory / f"{stem}_{side}.npy" for side in ("left", "right")]
    if all(f.is_file() for f in files):
        print(f"pair read from {directory}")
        return tuple(np.load(f) for f in files)
    pair = render_pair(rig, surface, texture, args.supersample)
    directory.mkdir(parents=True, exist_ok=True)
    for f, image in zip(files, pair):
        np.save(f, image)
    print(f"pair cached in {directory}")
    return pair


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, nargs=2, default=PAPER_IMAGE_SIZE)
    parser.add_argument("--supersample", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--models", nargs="+", default=["refractive", "pinhole"])
    parser.add_argument("--cache", nargs="?",
                        const=str(Path(tempfile.gettempdir()) / "dense_bench"),
                        default=None, metavar="DIR",
                        help="keep/reuse the rendered pair as .npy in DIR")
    args = parser.parse_args(argv)
    size = tuple(args.size)
    rig = paper_rig(size=size)
    focal = PAPER_FOCAL_PX * size[0] / PAPER_IMAGE_SIZE[0]
    speckle_mm = SPECKLE_PX * FOOTPRINT_MM_AT_F1100 * PAPER_FOCAL_PX / focal
    surface = PlaneSurface.create((0.0, 0.0, 1000.0), (0.0, 0.0, 1.0))
    texture = SpeckleTexture.random((-900, 1100, -800, 800), speckle_mm, seed=args.seed)
    print(f"pair {size[0]}x{size[1]} px, f = {focal:g} px, plane z = 1000 mm, speckle "
          f"{speckle_mm:.2f} mm, supersample {args.supersample}^2, cores {os.cpu_count()}")
    t0 = time.perf_counter()
    left, right = _rendered_pair(rig, surface, texture, args)
    print(f"render: {time.perf_counter() - t0:.1f} s   load {_load()}")

    width, height = size
    us, vs = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    pixels = np.stack([us.ravel(), vs.ravel()], axis=1)
    truth = project(rig.right, rig.port, surface_points(rig.left, rig.port, surface, pixels))
    overlap = rig.left.in_image(pixels, 7) & rig.right.in_image(truth, 7)
    ranges = {"refractive": (900.0, 1100.0), "pinhole": (700.0, 900.0)}
    for model in args.models:
        t0 = time.perf_counter()
        matches = match_dense(rig, left, right, ranges[model], model=model)
        total = time.perf_counter() - t0
        index = (matches.uv_left[:, 1] * width + matches.uv_left[:, 0]).astype(np.int64)
        in_overlap = overlap[index]
        error = np.hypot(*(matches.uv_right - truth[index]).T)
        method = "optical_path" if model == "refractive" else "regular"
        points = triangulate(rig, matches.uv_left, matches.uv_right, method).points
        distance = surface.distance(points)
        print(f"\n[{model}] depth range {ranges[model]} mm, {matches.n_planes} planes")
        print(f"  matched {in_overlap.sum()} of {overlap.sum()} overlap pixels "
              f"({100.0 * in_overlap.sum() / overlap.sum():.2f} %), {matches.score.size} in all")
        print(f"  right pixel error vs truth: RMS {np.sqrt(np.mean(error ** 2)):.4f} px, "
              f"max {error.max():.4f} px, 99.9 % {np.percentile(error, 99.9):.4f} px")
        print(f"  triangulated ({method}) point-to-plane: RMS "
              f"{np.sqrt(np.nanmean(distance ** 2)):.4f} mm, max {np.nanmax(distance):.4f} mm")
        stages = ", ".join(f"{k} {v:.1f} s" for k, v in matches.timings.items())
        print(f"  time {total:.1f} s: {stages}")
        if model == "refractive":  # the points' covariances (eval run's chunks)
            t0 = time.perf_counter()
            chunk = 1 << 16
            sigma_z = np.concatenate([np.sqrt(dense_point_covariances(
                rig, points[k:k + chunk], matches.sigma_px[k:k + chunk],
                matches.curve_direction[k:k + chunk]).total[:, 2, 2])
                for k in range(0, len(points), chunk)])
            print(f"  covariances: {time.perf_counter() - t0:.1f} s; matching σ median "
                  f"{np.nanmedian(matches.sigma_px):.4f} px ({matches.noise_source}, σ_n "
                  f"{matches.noise_sigma:.4f}), σz median {np.nanmedian(sigma_z):.4f} mm")
        print(f"  load {_load()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
