"""Does the housing calibration's σ cover its error? The in-air → housing chain over many seeds.

For every seed S the folder DATA holds three ``python -m synth boards`` folders: ``air_S``
(``--air``), ``straight_S`` (``scenes/paper_plane.xml``) and ``tilt_S``
(``scenes/paper_plane_port_tilt1.xml``), e.g.::

    for S in $(seq 1 30); do
      python -m synth boards scenes/paper_plane.xml --air --poses 12 --seed $S \\
          -D width=1224 -D height=1024 --out DATA/air_$S
      python -m synth boards scenes/paper_plane.xml --poses 12 --seed $S \\
          -D width=1224 -D height=1024 --out DATA/straight_$S
      python -m synth boards scenes/paper_plane_port_tilt1.xml --poses 12 --seed $S \\
          -D width=1224 -D height=1024 --out DATA/tilt_$S
    done
    python tools/calibration_coverage.py DATA --out OUT [--seeds 1-30] [--modes propagate,prior]

Per seed it runs the chain as a user does — ``eval calibrate air_S`` (OpenCV, its calib.yaml
with the in-air covariance), then ``eval calibrate straight_S`` and ``tilt_S`` with
``--intrinsics`` that calib.yaml and each ``--air-uncertainty`` of ``--modes`` — and reads the
reports (``OUT/air_S``, ``OUT/straight_S_MODE``, …; a run whose ``report.json`` exists is not
run again). The normalized errors z = (estimate − truth) / σ of the port distance D and of the
normal's two tilts are collected with the σ of each mode and with the conditional σ (the
housing's own, the in-air calibration taken as exact: "before"). Printed per port, parameter
and σ: the fraction of |z| ≤ 2, the largest |z|, and the RMS of the reported σ over the RMS
of the errors over the seeds (1 when σ is the spread); and the in-air calibration's error
against its full covariance (χ² over the 22 parameters, expected 22 on average; the RMS of
each parameter's z). ``OUT/coverage.json`` holds every number.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

PORTS = ("straight", "tilt")
PARAMETERS = ("D", "tilt[0]", "tilt[1]")


def seeds_argument(text: str) -> list[int]:
    """``1-30`` or ``1,2,5``."""
    out = []
    for part in text.split(","):
        first, _, last = part.partition("-")
        out += list(range(int(first), int(last or first) + 1))
    return out


def calibrate(argv: list[str]) -> None:
    """One ``python -m eval calibrate`` run in this process; exits on failure."""
    from eval.cli import main

    code = main(["calibrate", *argv, "--no-progress"])
    if code:
        raise SystemExit(f"eval calibrate {' '.join(argv)}: exit code {code}")


def errors_and_sigmas(report: dict) -> dict:
    """``{"error": [D, t0, t1], "sigma": […], "sigma_conditional": […]}`` from a housing
    report (mm, rad)."""
    p = report["housing"]["parameters"]
    d, n = p["distance"], p["normal"]
    return {"error": [d["error"], *n["tilt_error_rad"]],
            "sigma": [d["sigma"], *np.radians(n["sigma_deg"]).tolist()],
            "sigma_conditional": [d["sigma_conditional"],
                                  *np.radians(n["sigma_conditional_deg"]).tolist()]}


def coverage(errors, sigmas, names=PARAMETERS) -> dict:
    """Per parameter of ``names`` (the columns of ``errors`` and ``sigmas``, one row per seed):
    n, fraction of |z| ≤ 2, max |z|, counts beyond 3 and 4 σ, mean and RMS z, RMS σ / RMS error,
    the RMS and mean error, the RMS σ (the parameters' units)."""
    errors, sigmas = np.asarray(errors, float), np.asarray(sigmas, float)
    z = errors / sigmas
    out = {}
    for j, name in enumerate(names):
        rms_error = float(np.sqrt(np.mean(errors[:, j] ** 2)))
        out[name] = {"n": int(len(z)), "within_2_sigma": float(np.mean(np.abs(z[:, j]) <= 2)),
                     "max_abs_z": float(np.max(np.abs(z[:, j]))),
                     "beyond_3_sigma": int(np.sum(np.abs(z[:, j]) > 3)),
                     "beyond_4_sigma": int(np.sum(np.abs(z[:, j]) > 4)),
                     "mean_z": float(np.mean(z[:, j])), "rms_z": float(np.sqrt(np.mean(z[:, j] ** 2))),
                     "sigma_over_spread": float(np.sqrt(np.mean(sigmas[:, j] ** 2)) / rms_error),
                     "rms_error": rms_error, "mean_error": float(np.mean(errors[:, j])),
                     "rms_sigma": float(np.sqrt(np.mean(sigmas[:, j] ** 2)))}
    return out


def air_errors(calib_path, truth_path) -> tuple:
    """The in-air calibration's error (estimate − truth) in its covariance's names and that
    covariance (``measure.calibration.covariance.AIR_NAMES`` order)."""
    from scipy.spatial.transform import Rotation

    from synth.products.dataset import read_calib

    calib, truth = read_calib(calib_path), read_calib(truth_path)["rig"]
    errors = []
    for name in ("left", "right"):
        a, b = getattr(calib["rig"], name), getattr(truth, name)
        errors += [a.K[0, 0] - b.K[0, 0], a.K[1, 1] - b.K[1, 1], a.K[0, 2] - b.K[0, 2],
                   a.K[1, 2] - b.K[1, 2]]
        dist = [np.zeros(5) if c.dist is None else np.resize(np.ravel(c.dist), 5) for c in (a, b)]
        errors += list((dist[0] - dist[1])[:4])
    errors += list(Rotation.from_matrix(calib["rig"].right.R @ truth.right.R.T).as_rotvec())
    errors += list(calib["rig"].right.t - truth.right.t)
    return np.asarray(errors), calib["covariance"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="folder with air_S, straight_S, tilt_S boards folders")
    parser.add_argument("--out", required=True, help="folder for the calibrations and "
                                                     "coverage.json")
    parser.add_argument("--seeds", type=seeds_argument, default=seeds_argument("1-30"))
    parser.add_argument("--modes", default="propagate,prior",
                        help="--air-uncertainty values to run (comma list)")
    args = parser.parse_args(argv)
    modes = [m for m in args.modes.split(",") if m]
    os.makedirs(args.out, exist_ok=True)
    rows, air_rows = [], []
    for seed in args.seeds:
        air = os.path.join(args.out, f"air_{seed}")
        if not os.path.isfile(os.path.join(air, "report.json")):
            calibrate([os.path.join(args.data, f"air_{seed}"), "--out", air])
        errors, cov = air_errors(os.path.join(air, "calib.yaml"),
                                 os.path.join(args.data, f"air_{seed}", "calib.yaml"))
        air_rows.append({"seed": seed, "chi2": float(errors @ np.linalg.solve(cov.matrix, errors)),
                         "z": (errors / np.sqrt(np.diag(cov.matrix))).tolist()})
        for port in PORTS:
            for mode in modes:
                out = os.path.join(args.out, f"{port}_{seed}_{mode}")
                if not os.path.isfile(os.path.join(out, "report.json")):
                    calibrate([os.path.join(args.data, f"{port}_{seed}"), "--intrinsics",
                               os.path.join(air, "calib.yaml"), "--air-uncertainty", mode,
                               "--out", out])
                with open(os.path.join(out, "report.json")) as f:
                    rows.append({"seed": seed, "port": port, "mode": mode,
                                 **errors_and_sigmas(json.load(f))})
        print(f"seed {seed} done", file=sys.stderr, flush=True)
    table = {}
    print("| port | σ | parameter | n | within 2σ | max |z| | beyond 4σ | σ / spread | "
          "RMS error | RMS σ |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for port in PORTS:
        plain = "propagate" if "propagate" in modes else modes[0]  # the estimate of the fit
        kinds = [("conditional", plain, "sigma_conditional")] + [
            (mode, mode, "sigma") for mode in modes]
        for label, mode, key in kinds:
            chosen = [r for r in rows if r["port"] == port and r["mode"] == mode]
            if not chosen:
                continue
            stats = coverage([r["error"] for r in chosen], [r[key] for r in chosen])
            table[f"{port}/{label}"] = stats
            for name, s in stats.items():
                unit, scale = ("mm", 1.0) if name == "D" else ("″", np.degrees(1) * 3600)
                print(f"| {port} | {label} | {name} | {s['n']} | {100 * s['within_2_sigma']:.0f} % "
                      f"| {s['max_abs_z']:.2f} | {s['beyond_4_sigma']} | "
                      f"{s['sigma_over_spread']:.2f} | {s['rms_error'] * scale:.4g} {unit} | "
                      f"{s['rms_sigma'] * scale:.4g} {unit} |")
    z = np.array([r["z"] for r in air_rows])
    chi2 = np.array([r["chi2"] for r in air_rows])
    print(f"\nin air: χ² of the error with the full covariance ({z.shape[1]} parameters), mean "
          f"{chi2.mean():.1f} over {len(chi2)} seeds (expected {z.shape[1]}), max {chi2.max():.1f}; "
          f"RMS z per parameter {np.round(np.sqrt(np.mean(z ** 2, axis=0)), 2).tolist()}")
    with open(os.path.join(args.out, "coverage.json"), "w") as f:
        json.dump({"rows": rows, "air": air_rows, "table": table}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
