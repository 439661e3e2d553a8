"""Does the dome calibration's σ cover its error? Each camera's decentring over many seeds.

For every seed S the folder DATA holds two ``python -m synth boards`` folders of
``scenes/dome_decentred.xml``: ``air_S`` (``--air``) and ``water_S`` (behind the domes), e.g.::

    for S in $(seq 1 20); do
      python -m synth boards scenes/dome_decentred.xml --air --poses 15 --seed $S \\
          -D width=1224 -D height=1024 --out DATA/air_$S
      python -m synth boards scenes/dome_decentred.xml --poses 15 --seed $S \\
          -D width=1224 -D height=1024 --out DATA/water_$S
    done
    python tools/dome_coverage.py DATA --out OUT [--seeds 1-20] [--modes exact,propagate,prior]

Per seed it runs ``eval calibrate`` as a user does: ``exact`` — ``water_S`` with
``--intrinsics water_S/calib.yaml`` (the true cameras: no in-air error, σ conditional);
``propagate`` / ``prior`` — ``air_S`` first (OpenCV, its calib.yaml with the in-air
covariance), then ``water_S`` with ``--intrinsics`` that calib.yaml and that
``--air-uncertainty``. The reports land in ``OUT/air_S``, ``OUT/water_S_MODE`` (a run whose
``report.json`` exists is not run again). Printed per mode, σ and component (left x, y, z,
right x, y, z; mm, each camera's frame): the fraction of |z| ≤ 2 with z = (estimate − truth) /
σ, the largest |z|, how many beyond 3 σ, the mean z, σ / spread (RMS of σ over the RMS error;
1 when σ is the spread), the RMS error and the mean error. "conditional" is the σ of the
chain's estimate without the in-air calibration. ``OUT/dome_coverage.json`` holds every number.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration_coverage import calibrate, coverage, seeds_argument

COMPONENTS = tuple(f"{cam}_dome_{axis}" for cam in ("left", "right") for axis in "xyz")
MODES = ("exact", "propagate", "prior")


def components(report: dict) -> dict:
    """``{"error", "sigma", "sigma_conditional"}`` (mm, :data:`COMPONENTS` order) of a dome
    housing report."""
    p = report["housing"]["parameters"]
    return {"error": [p[c]["error"] for c in COMPONENTS],
            "sigma": [p[c]["sigma"] for c in COMPONENTS],
            "sigma_conditional": [p[c].get("sigma_conditional", p[c]["sigma"])
                                  for c in COMPONENTS],
            "rms_px": report["housing"]["rms_px"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="folder with air_S and water_S boards folders")
    parser.add_argument("--out", required=True, help="folder for the calibrations and "
                                                     "dome_coverage.json")
    parser.add_argument("--seeds", type=seeds_argument, default=seeds_argument("1-20"))
    parser.add_argument("--modes", default=",".join(MODES),
                        help=f"comma list of {', '.join(MODES)}")
    args = parser.parse_args(argv)
    modes = [m for m in args.modes.split(",") if m]
    bad = [m for m in modes if m not in MODES]
    if bad:
        parser.error(f"--modes: unknown {bad}")
    os.makedirs(args.out, exist_ok=True)
    rows = []
    for seed in args.seeds:
        water = os.path.join(args.data, f"water_{seed}")
        air = os.path.join(args.out, f"air_{seed}")
        for mode in modes:
            out = os.path.join(args.out, f"water_{seed}_{mode}")
            if not os.path.isfile(os.path.join(out, "report.json")):
                if mode == "exact":
                    calibrate([water, "--intrinsics", os.path.join(water, "calib.yaml"),
                               "--out", out])
                else:
                    if not os.path.isfile(os.path.join(air, "report.json")):
                        calibrate([os.path.join(args.data, f"air_{seed}"), "--out", air])
                    calibrate([water, "--intrinsics", os.path.join(air, "calib.yaml"),
                               "--air-uncertainty", mode, "--out", out])
            with open(os.path.join(out, "report.json")) as f:
                rows.append({"seed": seed, "mode": mode, **components(json.load(f))})
        print(f"seed {seed} done", file=sys.stderr, flush=True)
    table = {}
    print("| intrinsics | σ | component | n | within 2σ | max \\|z\\| | beyond 3σ | mean z | "
          "RMS z | σ / spread | RMS error | mean error | RMS σ |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    kinds = [("exact", "exact", "sigma")]
    chain = [m for m in modes if m != "exact"]
    if chain:
        kinds.append(("in-air chain", "propagate" if "propagate" in chain else chain[0],
                      "sigma_conditional"))
        kinds += [("in-air chain", m, "sigma") for m in chain]
    for source, mode, key in kinds:
        chosen = [r for r in rows if r["mode"] == mode]
        if not chosen:
            continue
        label = "conditional" if key == "sigma_conditional" or mode == "exact" else mode
        stats = coverage([r["error"] for r in chosen], [r[key] for r in chosen], COMPONENTS)
        table[f"{mode}/{label}"] = stats
        for name, s in stats.items():
            print(f"| {source} | {label} | {name} | {s['n']} | {100 * s['within_2_sigma']:.0f} % "
                  f"| {s['max_abs_z']:.2f} | {s['beyond_3_sigma']} | {s['mean_z']:+.2f} | "
                  f"{s['rms_z']:.2f} | {s['sigma_over_spread']:.2f} | {s['rms_error']:.4f} mm | "
                  f"{s['mean_error']:+.4f} mm | {s['rms_sigma']:.4f} mm |")
    with open(os.path.join(args.out, "dome_coverage.json"), "w") as f:
        json.dump({"rows": rows, "table": table}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
