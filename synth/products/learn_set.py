"""A learning set: many sea scenes (:mod:`synth.products.learn_scene`), their split and the file
lists and folder layouts learned tools read; ``python -m synth learn``'s output.

``DIR`` holds one folder per scene, ``scene_<seed:06d>/`` (written whole on a Dask worker —
the cluster of :mod:`synth.infra.cluster`, as ``synth suite`` uses it — straight into ``DIR``:
the workers must see it), and, rebuilt after every run from the scenes' manifests:

* ``learn.json`` — the generator's options (seeds, ranges, spp, split), their hash (another
  set of options for the same ``DIR`` is refused), every scene's split, status and manifest
  SHA-256, and each run;
* ``index.csv`` — one row per scene: seed, split, port, water, light, distance, what was drawn,
  the checks, the timings (wall clock and CPU seconds);
* ``lists/<split>_sceneflow.txt`` (``left right disparity.pfm`` per line) and
  ``lists/<split>_kitti.txt`` (``left right disp_occ disp_noc``), paths relative to ``DIR``, of
  the rectified pairs; ``lists/<split>_raw.txt`` (``left right flow occlusion``) of the raw pairs;
* ``kitti/<split>/{image_2,image_3,disp_occ_0,disp_noc_0}/<seed:06d>_10.png`` — hard links (or
  copies, across file systems) to the scenes' rectified files, KITTI 2015's layout;
* ``README.md`` — what is where, for a stranger.

The split is a function of the scene's seed alone (:func:`split_of`): adding scenes never moves
one from train to test.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil

from synth.scene.sea_draw import SeaRanges

#: The splits, in order.
SPLITS = ("train", "val", "test")
DEFAULT_FRACTIONS = (0.8, 0.1, 0.1)
LEARN_JSON = "learn.json"
#: What ``DIR`` holds besides the scene folders.
TOP_LEVEL = (LEARN_JSON, "index.csv", "lists", "kitti", "README.md")


def split_of(seed: int, fractions=DEFAULT_FRACTIONS) -> str:
    """The split of the scene of ``seed``: the SHA-256 of ``"sea-scene-<seed>"`` read as a
    number in [0, 1) falls in the train, val or test share of ``fractions``."""
    digest = hashlib.sha256(f"sea-scene-{int(seed)}".encode()).digest()
    x = int.from_bytes(digest[:8], "big") / 2.0 ** 64
    edges = [sum(fractions[:k + 1]) / sum(fractions) for k in range(len(SPLITS))]
    return next(s for s, edge in zip(SPLITS, edges) if x < edge)


def scene_folder(seed: int) -> str:
    return f"scene_{int(seed):06d}"


def options_of(seeds, ranges: SeaRanges, spp: int, fractions) -> dict:
    """The generator's options of a set (what :data:`LEARN_JSON` holds and hashes)."""
    from synth.products.learn_scene import object_digests

    described = ranges.describe()
    if ranges.objects:
        described["objects"] = object_digests(ranges)
    return {"seeds": [int(s) for s in seeds], "ranges": described, "spp": int(spp),
            "split": {"names": list(SPLITS), "fractions": [float(f) for f in fractions]}}


def options_hash(options: dict) -> str:
    return hashlib.sha256(json.dumps(options, sort_keys=True).encode()).hexdigest()


def render_scene_task(task: dict) -> dict:
    """One scene on a Dask worker (never raises): ``{"seed", "status", "error", "seconds"}``."""
    import time

    from synth.infra.cluster import setup_worker

    started = time.perf_counter()
    try:
        setup_worker()
        from synth.products.learn_scene import write_learn_scene

        ranges = SeaRanges(**{k: tuple(v) for k, v in task["ranges"].items()})  # paths
        manifest = write_learn_scene(task["out"], task["seed"], ranges, task["spp"])
        return {"seed": task["seed"], "status": "ok", "error": None,
                "passed": manifest["checks"]["passed"],
                "seconds": time.perf_counter() - started}
    except Exception as exc:  # recorded, never raised: the set goes on
        return {"seed": task["seed"], "status": "failed",
                "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}",
                "seconds": time.perf_counter() - started}


def probe() -> bool:
    """What a worker must import to render scenes (``--scheduler``'s check)."""
    import synth.products.learn_scene  # noqa: F401

    return True


def scene_done(directory: str, seed: int, ranges: SeaRanges, spp: int) -> bool:
    """Whether ``directory/scene_<seed>`` is a whole scene of these options (its marker's
    request key, every file as written)."""
    from synth.infra.fileio import OutputDir, read_marker
    from synth.products.learn_scene import COMMAND, request_key

    path = os.path.join(directory, scene_folder(seed))
    marker = read_marker(path)
    if not marker or marker.get("request_key") != request_key(seed, ranges, spp):
        return False
    return OutputDir(path, COMMAND).damage() is None


def read_manifests(directory: str, seeds) -> dict:
    """``{seed: manifest}`` of the scenes of ``seeds`` that are in ``directory``."""
    found = {}
    for seed in seeds:
        path = os.path.join(directory, scene_folder(seed), "manifest.json")
        if os.path.isfile(path):
            with open(path, encoding="utf-8") as handle:
                found[int(seed)] = json.load(handle)
    return found


INDEX_COLUMNS = ("seed", "split", "folder", "port", "water", "light", "distance_mm",
                 "baseline_mm", "convergence_deg", "hfov_air_deg", "pitch_deg",
                 "rectified_distance_mm", "disparity_min_px", "disparity_max_px",
                 "residual_max_px", "exact_fraction", "occluded_left", "round_trip_max_px",
                 "rectified_vs_flow_max_px", "exact_pixels_compared",
                 "exact_rectified_vs_flow_max_px", "passed", "render_seconds", "total_seconds",
                 "render_cpu_seconds", "total_cpu_seconds")


def index_row(seed: int, manifest: dict, fractions) -> dict:
    g, r, c = manifest["generator"], manifest["rectified"], manifest["checks"]
    drawn, seconds, cpu = g["drawn"], manifest["seconds"], manifest.get("cpu_seconds", {})
    span = r["disparity_px"] or [None, None]
    return {"seed": seed, "split": split_of(seed, fractions), "folder": scene_folder(seed),
            "port": g["port"], "water": g["water"], "light": g["light"],
            "distance_mm": g["distance_mm"], "baseline_mm": drawn["baseline_mm"],
            "convergence_deg": drawn["convergence_deg"], "hfov_air_deg": drawn["hfov_air_deg"],
            "pitch_deg": drawn["pitch_deg"], "rectified_distance_mm": r["distance_mm"],
            "disparity_min_px": span[0], "disparity_max_px": span[1],
            "residual_max_px": r["residual_max_px"], "exact_fraction": r["exact_fraction"],
            "occluded_left": manifest["pixels"]["occluded_left"],
            "round_trip_max_px": max(c["left_round_trip_max_px"], c["right_round_trip_max_px"]),
            "rectified_vs_flow_max_px": c["rectified_vs_flow_max_px"],
            "exact_pixels_compared": c["exact_pixels_compared"],
            "exact_rectified_vs_flow_max_px": c["exact_rectified_vs_flow_max_px"],
            "passed": c["passed"],
            "render_seconds": seconds["render"], "total_seconds": seconds["total"],
            "render_cpu_seconds": cpu.get("render"), "total_cpu_seconds": cpu.get("total")}


def _link(source: str, target: str) -> None:
    os.makedirs(os.path.dirname(target), exist_ok=True)
    if os.path.lexists(target):
        os.unlink(target)
    try:
        os.link(source, target)
    except OSError:
        shutil.copyfile(source, target)


def write_lists(directory: str, manifests: dict, fractions) -> dict:
    """``lists/`` and ``kitti/`` (module docs), rebuilt from the finished scenes; returns the
    number of scenes per split."""
    for name in ("lists", "kitti"):
        shutil.rmtree(os.path.join(directory, name), ignore_errors=True)
    os.makedirs(os.path.join(directory, "lists"))
    lines = {(split, kind): [] for split in SPLITS for kind in ("sceneflow", "kitti", "raw")}
    for seed in sorted(manifests):
        split, folder = split_of(seed, fractions), scene_folder(seed)
        rect = f"{folder}/rectified"
        lines[split, "sceneflow"].append(f"{rect}/left.png {rect}/right.png {rect}/disparity.pfm")
        lines[split, "kitti"].append(f"{rect}/left.png {rect}/right.png "
                                     f"{rect}/disparity_occ.png {rect}/disparity_noc.png")
        lines[split, "raw"].append(f"{folder}/left.png {folder}/right.png "
                                   f"{folder}/truth/flow_left_to_right.flo "
                                   f"{folder}/truth/occlusion_left.png")
        for sub, name in (("image_2", "left.png"), ("image_3", "right.png"),
                          ("disp_occ_0", "disparity_occ.png"), ("disp_noc_0", "disparity_noc.png")):
            _link(os.path.join(directory, rect, name),
                  os.path.join(directory, "kitti", split, sub, f"{seed:06d}_10.png"))
    for (split, kind), entries in lines.items():
        with open(os.path.join(directory, "lists", f"{split}_{kind}.txt"), "w",
                  encoding="utf-8") as handle:
            handle.write("".join(line + "\n" for line in entries))
    return {split: len(lines[split, "raw"]) for split in SPLITS}


def write_index(directory: str, manifests: dict, fractions) -> list:
    rows = [index_row(seed, manifests[seed], fractions) for seed in sorted(manifests)]
    with open(os.path.join(directory, "index.csv"), "w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=INDEX_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return rows


def readme_text(options: dict, counts: dict, rows: list) -> str:
    """``README.md`` of a learning set."""
    ports = sorted({r["port"] for r in rows})
    waters = sorted({r["water"] for r in rows})
    size = options["ranges"]["size"]
    return f"""# Refracted sea scenes for learned stereo and MVS

{len(rows)} scenes ({', '.join(f'{counts[s]} {s}' for s in SPLITS)}), {size[0]} x {size[1]} px,
{options['spp']} samples per pixel, written by `python -m synth learn` (refractive-stereo).
Every scene is a stereo pair seen through a real housing ({', '.join(ports)}) in
{', '.join(waters)} water; its truth comes from the exact forward model through the port.

- `scene_<seed>/` — one scene: `left.png`, `right.png` (8-bit); `truth/` (per view depth `z` and
  range as PFM in mm, points and normals as float32 `.npy` in the left camera's frame, the
  left-to-right flow `.flo` and its occlusion mask); `rectified/` (the port-exact row-aligned pair,
  exact at the scene's median distance: `disparity.pfm`, KITTI `disparity_occ.png` /
  `disparity_noc.png`, the warp's `residual.pfm` and `row_error.pfm` in px, `calib.yaml`);
  `calib.yaml`, `cameras.json`, `colmap/` (the refractive COLMAP fork's FLATPORT / DOMEPORT model
  with depth maps), `colmap_pinhole/` (the rectified pair for upstream COLMAP); `scene/` (the
  Mitsuba scene that renders the images); `manifest.json` (every file's SHA-256, the generator's
  parameters, the checks).
- `lists/<split>_sceneflow.txt`, `lists/<split>_kitti.txt`, `lists/<split>_raw.txt` — file lists.
- `kitti/<split>/image_2|image_3|disp_occ_0|disp_noc_0/` — the rectified pairs in KITTI's layout.
- `index.csv` — one row per scene; `learn.json` — the generator's options.

The rectified pair is a pinhole pair only where `residual.pfm` is 0: a port makes each camera
non-central, so the warp is exact at one distance. Depth from disparity with the virtual pair's
`f · B / d` is exact there; elsewhere use `truth/` (or the refractive model in `calib.yaml`).
"""


__all__ = ["DEFAULT_FRACTIONS", "INDEX_COLUMNS", "LEARN_JSON", "SPLITS", "TOP_LEVEL",
           "index_row", "options_hash", "options_of", "probe", "read_manifests",
           "readme_text", "render_scene_task", "scene_done", "scene_folder", "split_of",
           "write_index", "write_lists"]
