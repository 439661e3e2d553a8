"""Benchmark :func:`measure.stereo.pose.estimate_poses` (numbers for docs/speed.md and
docs/library.md; nothing asserted).

The 1 m docking frame (synth.scene.layouts.docking_frame, 12 markers) at random poses 1–5 m from
the paper's rig (full size, the paper's port), its pixels from the Fermat forward model with
Gaussian noise of ``--sigma`` px, only the markers inside each image. Printed: poses per second
from the left camera alone and from both cameras jointly (after detection: the pixels are
given), the position and rotation errors, how many poses came back, and the load average.
``--stress`` estimates 2400 poses from no guess over 0.5–5 m (log-uniform), the frame with and
without its posts, tilts up to 0.35 and 0.8 rad about each axis, σ 0 and 0.5 px, behind the
paper's port and a decentred dome, and counts the poses that came back and those in a wrong
minimum (position error above 10 σ of the reported covariance). ``--starts`` compares the
start the estimator uses (a central PnP, SQPnP, on the water rays) with a linear generalized
PnP on the rays' Plücker lines (``[d]× (R X + t) = [d]× o``, twelve unknowns, R projected onto
SO(3)).

    python tools/pose_bench.py [--frames 200] [--sigma 0.1] [--seed 0] [--starts] [--stress]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from measure.geometry.projection import project
from measure.stereo import pose as pose_module
from measure.stereo.multiview import View
from measure.stereo.pose import as_views, estimate_poses, rotation_error
from synth.scene.layouts import docking_frame
from synth.scene.rig import paper_rig


def _poses(rng, frames, near=1000.0, far=5000.0):
    Rs = Rotation.from_rotvec(rng.uniform(-0.35, 0.35, (frames, 3))).as_matrix()
    z = rng.uniform(near, far, frames)
    ts = np.column_stack([rng.uniform(-0.15, 0.15, frames) * z,
                          rng.uniform(-0.15, 0.15, frames) * z, z])
    return Rs, ts


def _pixels(views, obj, Rs, ts, sigma, rng):
    out = np.full((len(Rs), len(views), obj.shape[0], 2), np.nan)
    for f, (R, t) in enumerate(zip(Rs, ts)):
        X = obj @ R.T + t
        for v, view in enumerate(views):
            uv = project(view.camera, view.port, X) + rng.normal(scale=sigma, size=(len(X), 2))
            uv[~view.camera.in_image(uv)] = np.nan
            out[f, v] = uv
    return out


def _linear_gpnp(origins, directions, X):
    """The linear generalized PnP: ``[d]× (R X + t) = [d]× o`` in the 12 entries of (R, t),
    least squares, R projected onto SO(3)."""
    S = pose_module.skew(directions)
    A = np.zeros((X.shape[0], 3, 12))
    for j in range(3):
        A[:, :, 3 * j:3 * j + 3] = S[:, :, j:j + 1] * X[:, None, :]
    A[:, :, 9:] = S
    b = np.einsum("nij,nj->ni", S, origins)
    solution = np.linalg.lstsq(A.reshape(-1, 12), b.ravel(), rcond=None)[0]
    U, _, Vt = np.linalg.svd(solution[:9].reshape(3, 3))
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt, solution[9:]


def compare_starts(view, obj, rng, trials=20):
    for z in (1000.0, 2000.0):
        for sigma in (0.0, 0.1):
            linear, central = [], []
            Rs, ts = _poses(rng, trials, z, z)
            for R, t in zip(Rs, ts):
                uv = project(view.camera, view.port, obj @ R.T + t)
                uv = uv + rng.normal(scale=sigma, size=uv.shape)
                origins, directions, _ = view.water_rays(uv)
                linear.append(np.linalg.norm(_linear_gpnp(origins, directions, obj)[1] - t))
                problem = pose_module._Problem([view], obj, uv[None], np.ones((1, len(obj))))
                start = pose_module._start_candidates(problem, origins, directions, False)[0]
                central.append(np.linalg.norm(start[1] - t))
            print(f"start at {z:.0f} mm, sigma {sigma} px: linear GPnP |dt| median "
                  f"{np.median(linear):.3g} mm (max {np.max(linear):.3g}); central SQPnP "
                  f"median {np.median(central):.3g} mm (max {np.max(central):.3g})")


def stress(rng, frames=150):
    from synth.scene.dome import dome_pair
    from synth.scene.rig import paper_cameras

    rig = paper_rig()
    cameras = paper_cameras()
    dome = dome_pair(cameras, 50.0, 8.0, (2.0, -1.0, 1.5), (1.0, 1.54, 1.33))
    for label, view in (("flat", View(rig.left, rig.port)), ("dome", View(cameras[0],
                                                                          dome.view(0)))):
        for post in (100.0, 0.0):
            obj = docking_frame(post=post)
            for tilt in (0.35, 0.8):
                for sigma in (0.0, 0.5):
                    z = np.exp(rng.uniform(np.log(500.0), np.log(5000.0), frames))
                    Rs = Rotation.from_rotvec(rng.uniform(-tilt, tilt, (frames, 3))).as_matrix()
                    ts = np.column_stack([rng.uniform(-0.2, 0.2, frames) * z,
                                          rng.uniform(-0.2, 0.2, frames) * z, z])
                    pixels = _pixels([view], obj, Rs, ts, sigma, rng)[:, 0]
                    seen = np.sum(np.isfinite(pixels[..., 0]), axis=1) >= 4
                    poses = estimate_poses(view, obj, pixels, sigma if sigma else None)
                    dt = np.linalg.norm(poses.t - ts, axis=1)
                    sig = np.sqrt(np.trace(poses.covariance[:, 3:, 3:], axis1=1, axis2=2))
                    wrong = poses.valid & (dt > np.maximum(10 * sig, 1e-6))
                    print(f"stress {label}, posts {post:g} mm, tilt {tilt} rad, sigma {sigma} "
                          f"px: {seen.sum()} of {frames} see >= 4 markers, {poses.valid.sum()} "
                          f"poses, {wrong.sum()} in a wrong minimum, largest error "
                          f"{np.max(dt[poses.valid]):.3g} mm")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--sigma", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--starts", action="store_true")
    parser.add_argument("--stress", action="store_true")
    args = parser.parse_args(argv)
    rig = paper_rig()
    obj = docking_frame()
    rng = np.random.default_rng(args.seed)
    Rs, ts = _poses(rng, args.frames)
    views = as_views(rig)
    pixels = _pixels(views, obj, Rs, ts, args.sigma, rng)
    estimate_poses(views[0], obj, pixels[:2, 0], args.sigma)  # imports and first calls
    for name, target, px in (("left camera", views[0], pixels[:, 0]),
                             ("both cameras jointly", rig, pixels)):
        start = time.perf_counter()
        poses = estimate_poses(target, obj, px, args.sigma)
        elapsed = time.perf_counter() - start
        ok = poses.valid
        dt = np.linalg.norm(poses.t[ok] - ts[ok], axis=1)
        dr = rotation_error(poses.R[ok], Rs[ok])
        print(f"{name}: {args.frames} frames in {elapsed:.2f} s = "
              f"{args.frames / elapsed:.0f} poses/s; {ok.sum()} valid; |dt| median "
              f"{np.median(dt):.3g} mm, max {dt.max():.3g} mm; rotation median "
              f"{np.median(dr):.3g} rad, max {dr.max():.3g} rad; median observations "
              f"{np.median(poses.observations):.0f}")
    if args.starts:
        compare_starts(View(rig.left, rig.port), obj, rng)
    if args.stress:
        stress(rng)
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
