"""What refraction does to a learner's inputs: OpenCV's StereoSGBM on the scenes of a learning set
(``python -m synth learn``) rectified three ways — the raw pair as pinholes (the port ignored),
the absorbed pinhole calibration's rectification, the port-exact rectification — each scored
against the truth of its own frame (:mod:`eval.core.learn_sgbm`): EPE, D1-all, density, and the
depth error by distance, pooled over the scenes, overall and per kind of port.

    python tools/learn_sgbm.py SET_DIR [--split test] [--limit N] [--out DIR]

Prints a Markdown table (for docs/learning.md) and writes ``DIR/learn_sgbm.json`` and each
scene's scores and depths (``DIR/scenes/scene_<seed>.npz``, kept: a rerun — the set grown by
then — scores only the scenes it has not). Nothing is asserted: a benchmark.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from eval.core.disparity_scores import depth_errors_by_distance, pooled
from eval.core.learn_sgbm import METHODS as ROWS
from eval.core.learn_sgbm import load_scene, score_scene

BINS = (0.0, 1000.0, 1500.0, 2000.0, np.inf)


def absorbed_rig(item):
    """The absorbed calibration of the scene's cameras (15 boards through its port at 0.7–1.3 ×
    its median distance, squares scaled with it; OpenCV's k1 k2 p1 p2, the usual model),
    or None when it cannot be had."""
    from eval.core.absorbed import analytic_absorbed_calibration
    from measure.calibration.board import Board

    distance = item.manifest["rectified"]["distance_mm"]
    board = Board("chessboard", (11, 8), 40.0 * distance / 1000.0)
    try:
        return analytic_absorbed_calibration(item.scene.rig, seed=item.scene.seed, board=board,
                                             distance_range=(0.7 * distance, 1.3 * distance),
                                             lens_model="standard")
    except ValueError as exc:
        print(f"  {os.path.basename(item.folder)}: no absorbed calibration ({exc})",
              file=sys.stderr)
        return None


def _table(results: dict, label: str) -> list:
    lines = [f"**{label}**", "",
             "| rectification | pixels with truth | density | EPE (px) | D1-all | "
             + " | ".join(f"depth {lo / 1000:g}–{hi / 1000:g} m: median abs (rel)"
                          if np.isfinite(hi) else f"depth ≥ {lo / 1000:g} m: median abs (rel)"
                          for lo, hi in zip(BINS[:-1], BINS[1:])) + " |",
             "|---" * (5 + len(BINS) - 1) + "|"]
    for method in ROWS:
        if method not in results:
            continue
        r = results[method]
        s = r["scores"]
        cells = [f"{d['median_abs_mm']:.1f} mm ({d['median_rel_percent']:.2f} %)"
                 if d["pixels"] else "–" for d in r["depth"]]
        lines.append(f"| {method} | {s['pixels']:,} | {100 * s['density']:.1f} % | "
                     f"{s['epe_px']:.3f} | {100 * s['d1']:.2f} % | " + " | ".join(cells) + " |")
    return lines + [""]


def _pool(per_scene: list) -> dict:
    out = {}
    for method in ROWS:
        got = [s[method] for s in per_scene if method in s]
        if not got:
            continue
        z_pred = np.concatenate([g["z"][0] for g in got])
        z_true = np.concatenate([g["z"][1] for g in got])
        out[method] = {"scores": pooled(g["scores"] for g in got),
                       "depth": depth_errors_by_distance(z_pred, z_true, BINS),
                       "scenes": len(got)}
    return out


def _split_seeds(folder: str, split: str) -> list:
    """The seeds of the finished scenes of ``split``: the scene folders that hold a manifest
    (a folder is renamed into place whole, so a set still being written is scored from what it
    finished), their split by seed with the shares of ``learn.json`` (the default shares
    without one)."""
    from synth.products.learn_set import DEFAULT_FRACTIONS, split_of

    fractions, path = DEFAULT_FRACTIONS, os.path.join(folder, "learn.json")
    if os.path.isfile(path):
        with open(path, encoding="utf-8") as handle:
            fractions = tuple(json.load(handle)["options"]["split"]["fractions"])
    seeds = sorted(int(name[6:]) for name in os.listdir(folder) if name.startswith("scene_")
                   and os.path.isfile(os.path.join(folder, name, "manifest.json")))
    return [s for s in seeds if split_of(s, fractions) == split]


def _manifest_sha(folder: str) -> str:
    with open(os.path.join(folder, "manifest.json"), "rb") as handle:
        return hashlib.sha256(handle.read()).hexdigest()


def _cached(path, folder):
    """``(result, port, water)`` of a scene scored before into ``path`` (an ``.npz`` beside
    ``learn_sgbm.json``), or Nones when there is none or its scene's manifest changed since."""
    if not path or not os.path.isfile(path):
        return None, None, None
    with np.load(path) as data:
        meta = json.loads(str(data["meta"]))
        if meta["manifest_sha256"] != _manifest_sha(folder):
            return None, None, None
        result = {m: {"scores": meta["scores"][m], "z": (data[f"z{k}_pred"], data[f"z{k}_true"])}
                  for k, m in enumerate(ROWS) if m in meta["scores"]}
    return result, meta["port"], meta["water"]


def _cache(path, folder, result, port, water) -> None:
    """Keep a scene's scores and depths in ``path`` (written whole: a temporary file renamed)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    meta = {"manifest_sha256": _manifest_sha(folder), "port": port, "water": water,
            "scores": {m: r["scores"] for m, r in result.items()}}
    arrays = {}
    for k, method in enumerate(ROWS):
        if method in result:
            arrays[f"z{k}_pred"], arrays[f"z{k}_true"] = result[method]["z"]
    tmp = path + ".tmp.npz"
    np.savez(tmp, meta=np.array(json.dumps(meta)), **arrays)
    os.replace(tmp, path)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("set", help="a learning set (python -m synth learn --out DIR)")
    parser.add_argument("--split", default="test", help="the split to score (default test)")
    parser.add_argument("--limit", type=int, default=None, help="at most this many scenes")
    parser.add_argument("--out", default=None,
                        help="folder for learn_sgbm.json and each scene's scores (scenes/: a "
                             "rerun scores only the scenes it has not, or whose manifest "
                             "changed)")
    args = parser.parse_args()
    seeds = _split_seeds(args.set, args.split)[:args.limit]
    started, per_scene, ports = time.perf_counter(), [], []
    for seed in seeds:
        t = time.perf_counter()
        folder = os.path.join(args.set, f"scene_{seed:06d}")
        cache = args.out and os.path.join(args.out, "scenes", f"scene_{seed:06d}.npz")
        result, port, water = _cached(cache, folder)
        if result is None:
            item = load_scene(folder)
            absorbed = absorbed_rig(item)
            result = score_scene(item, None if absorbed is None else absorbed.rig)
            port, water = item.scene.port_kind, item.scene.water
            if cache:
                _cache(cache, folder, result, port, water)
        per_scene.append(result)
        ports.append(port)
        print(f"  scene {seed} ({port}, {water}): {time.perf_counter() - t:.1f} s",
              file=sys.stderr, flush=True)
    report = {"set": os.path.abspath(args.set), "split": args.split, "scenes": seeds,
              "all": _pool(per_scene)}
    lines = _table(report["all"], f"all {len(seeds)} {args.split} scenes")
    for kind in sorted(set(ports)):
        chosen = [s for s, p in zip(per_scene, ports) if p == kind]
        report[kind] = _pool(chosen)
        lines += _table(report[kind], f"{kind} ports ({len(chosen)} scenes)")
    print("\n".join(lines))
    print(f"({time.perf_counter() - started:.0f} s; load average "
          f"{', '.join(f'{v:.1f}' for v in os.getloadavg())})")
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "learn_sgbm.json"), "w", encoding="utf-8") as handle:
            json.dump(report, handle, indent=1, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
