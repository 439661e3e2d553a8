"""The figures of docs/absorbed.md: the absorbed baseline against the port model, by distance
and over the field, on analytic pixels (the Fermat forward model; no noise unless ``--noise-px``).

    python tools/absorbed_figures.py --out docs/img [--noise-px 0.1] [--seed 0]

Writes ``absorbed_vs_distance.png`` (median and 95th percentile of the length errors of target
pairs ≥ 100 mm apart, and the error left after the best rigid alignment, against the distance
of the paper's target layout scaled to the field, with the absorbed calibration's range of board
distances shaded) and ``absorbed_field.png`` (each target's error after the best rigid alignment
over the field at 1 m and 2 m, both methods), and prints the numbers.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

DISTANCES_MM = (500, 750, 1000, 1250, 1500, 2000, 2500, 3000)


def main() -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from eval.core.absorbed import analytic_absorbed_calibration
    from eval.core.cloud_metrics import length_errors, rigid_alignment
    from measure import triangulate
    from measure.geometry.projection import project
    from synth.scene.layouts import paper_plane
    from synth.scene.rig import paper_rig

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--noise-px", type=float, default=0.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    rig = paper_rig()
    absorbed = analytic_absorbed_calibration(rig, seed=args.seed)
    near, far = absorbed.summary["distance_range_mm"]
    print(f"absorbed calibration: {absorbed.summary['lens_model']} model, stereo RMS "
          f"{absorbed.summary['stereo_rms_px']:.3f} px")
    rng = np.random.default_rng(args.seed)
    rows, fields = [], {}
    for z in DISTANCES_MM:
        points = paper_plane(float(z)) * np.array([z / 1000.0, z / 1000.0, 1.0])
        uv = [project(c, rig.port, points) for c in rig.cameras]
        seen = rig.left.in_image(uv[0]) & rig.right.in_image(uv[1])
        uv = [u[seen] + rng.normal(0, args.noise_px, u[seen].shape) for u in uv]
        truth = points[seen]
        row = {"z": z}
        for name, measuring in (("optical_path", rig), ("absorbed", absorbed.rig)):
            measured = triangulate(measuring, uv[0], uv[1], "optical_path").points
            lengths = length_errors(measured, truth)
            aligned = rigid_alignment(measured, truth)
            row[name] = {"median": lengths["length_median_abs_pct"],
                         "p95": lengths["length_p95_abs_pct"],
                         "aligned": aligned["rms_dp_aligned_mm"]}
            if z in (1000, 2000):
                from scipy.spatial.transform import Rotation

                # the per-target residual after the best rigid alignment
                centre_m, centre_t = measured.mean(axis=0), truth.mean(axis=0)
                rotation, _ = Rotation.align_vectors(truth - centre_t, measured - centre_m)
                residual = rotation.apply(measured - centre_m) + centre_t - truth
                fields[(z, name)] = (truth, np.linalg.norm(residual, axis=1))
        rows.append(row)
        print(f"{z:5d} mm: {seen.sum()} targets; length error median / p95 (%): optical path "
              f"{row['optical_path']['median']:.4f} / {row['optical_path']['p95']:.4f}, absorbed "
              f"{row['absorbed']['median']:.4f} / {row['absorbed']['p95']:.4f}; aligned RMS: "
              f"{row['optical_path']['aligned']:.4f} / {row['absorbed']['aligned']:.3f} mm")

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    z = [r["z"] for r in rows]
    for name, colour in (("optical_path", "tab:blue"), ("absorbed", "tab:red")):
        axes[0].plot(z, [r[name]["median"] for r in rows], "o-", color=colour,
                     label=f"{name}: median")
        axes[0].plot(z, [r[name]["p95"] for r in rows], "s--", color=colour,
                     label=f"{name}: 95th percentile")
        axes[1].plot(z, [r[name]["aligned"] for r in rows], "o-", color=colour, label=name)
    for ax in axes:
        ax.axvspan(near, far, color="0.85", label="boards of the absorbed calibration")
        ax.set_xlabel("distance of the targets (mm)")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("length error of target pairs ≥ 100 mm apart (%)")
    axes[1].set_ylabel("RMS error after the best rigid alignment (mm)")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"the paper's rig and port, the paper's layout scaled to the field, "
                 f"{args.noise_px:g} px noise")
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "absorbed_vs_distance.png"), dpi=90)
    plt.close(fig)

    fig, axes = plt.subplots(2, 2, figsize=(10, 8))
    for row_axes, zz in zip(axes, (1000, 2000)):
        for ax, name in zip(row_axes, ("optical_path", "absorbed")):
            truth, error = fields[(zz, name)]
            image = ax.scatter(truth[:, 0], truth[:, 1], c=error, s=8, cmap="viridis")
            ax.set_aspect("equal")
            ax.invert_yaxis()
            ax.set_title(f"{name} at {zz} mm: error after alignment (mm)", fontsize=9)
            fig.colorbar(image, ax=ax, fraction=0.046)
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "absorbed_field.png"), dpi=90)
    plt.close(fig)
    print(f"wrote {args.out}/absorbed_vs_distance.png, absorbed_field.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
