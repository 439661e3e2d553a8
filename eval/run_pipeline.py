"""The stages of ``python -m eval run``: images → detections → matches → 3D → scores.

Frames and units: the reference frame is the left camera's (OpenCV axes), millimetres, pixels
in the OpenCV convention. Ground truth is used only after matching, to score.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from measure import detect_targets, triangulate
from measure.matching import match_targets
from synth.dataset import match_detections, wholly_in_image
from synth.noise import add_pixel_noise
from synth.project import project

from .cloud_metrics import cloud_distances, flatness, rigid_alignment

#: Pixels between a detection and the simulator's pixel of a target for them to be associated.
ASSOCIATION_GATE_PX = 2.0
#: The default working range around the scene's ``target_z``: ``(near, far)`` factors.
DEPTH_WINDOW_FACTORS = (0.8, 1.25)


@dataclass
class RunInputs:
    """What the pipeline starts from: a rig, two linear images, and (for scoring) the truth."""

    scene: str
    rig: object
    has_port: bool
    targets: np.ndarray
    target_ids: np.ndarray
    target_radius: float
    left: np.ndarray
    right: np.ndarray
    params: dict
    variant: str
    spp: int
    render_seconds: float
    extra: dict = field(default_factory=dict)


def default_depth_window(params: dict):
    """``(near, far)`` along the port normal from the scene's ``target_z`` (mm), or no bound."""
    try:
        z = float(params["target_z"])
    except (KeyError, TypeError, ValueError):
        return (None, None)
    return (DEPTH_WINDOW_FACTORS[0] * z, DEPTH_WINDOW_FACTORS[1] * z)


def visible_targets(camera, port, targets, radius_mm):
    """Simulator pixels ``(N, 2)`` and whether each target lies wholly inside the image."""
    uv = project(camera, port, targets)
    return uv, wholly_in_image(camera, uv, targets, radius_mm)


def _error_stats(errors: np.ndarray) -> dict:
    if len(errors) == 0:
        nan = float("nan")
        return {"n": 0, "rms_dp_mm": nan, "max_dp_mm": nan, "mean_dx_mm": nan, "mean_dy_mm": nan,
                "mean_dz_mm": nan, "rms_dx_mm": nan, "rms_dy_mm": nan, "rms_dz_mm": nan}
    dp = np.linalg.norm(errors, axis=1)
    return {"n": int(len(errors)), "rms_dp_mm": float(np.sqrt(np.mean(dp ** 2))),
            "max_dp_mm": float(dp.max()),
            "mean_dx_mm": float(errors[:, 0].mean()), "mean_dy_mm": float(errors[:, 1].mean()),
            "mean_dz_mm": float(errors[:, 2].mean()),
            "rms_dx_mm": float(np.sqrt(np.mean(errors[:, 0] ** 2))),
            "rms_dy_mm": float(np.sqrt(np.mean(errors[:, 1] ** 2))),
            "rms_dz_mm": float(np.sqrt(np.mean(errors[:, 2] ** 2)))}


def run_pipeline(inputs: RunInputs, methods, noise_px: float = 0.0, seed: int = 0,
                 gate_mm: float = 0.5, depth_window=None, log=print):
    """Run detection, matching, triangulation and scoring. Returns ``(report, arrays)``.

    ``report`` is the JSON-ready dict (without versions and total timing); ``arrays`` holds what
    the figures and PLY files need.
    """
    timings = {"render": inputs.render_seconds}
    rig = inputs.rig

    log("detect targets in both views …")
    start = time.perf_counter()
    detections = {"left": detect_targets(inputs.left), "right": detect_targets(inputs.right)}
    timings["detect"] = time.perf_counter() - start
    centers = {name: np.array(d.centers, dtype=float) for name, d in detections.items()}
    if noise_px > 0:
        rng = np.random.default_rng(seed)
        for name in ("left", "right"):
            centers[name] = add_pixel_noise(centers[name], variance=noise_px ** 2, rng=rng)

    log("match left and right (refractive epipolar constraint) …")
    start = time.perf_counter()
    window = default_depth_window(inputs.params) if depth_window is None else tuple(depth_window)
    matches = match_targets(rig, centers["left"], centers["right"], gate_mm=gate_mm,
                            depth_range=window)
    timings["match"] = time.perf_counter() - start

    log(f"triangulate {len(matches.left)} pairs with {', '.join(methods)} …")
    start = time.perf_counter()
    uv_left = centers["left"][matches.left]
    uv_right = centers["right"][matches.right]
    results = {m: triangulate(rig, uv_left, uv_right, m) for m in methods}
    timings["triangulate"] = time.perf_counter() - start

    log("score against the ground truth (Open3D) …")
    start = time.perf_counter()
    # Association with the truth, for scoring only: nearest simulator pixel per view.
    simulated, inside, truth_of = {}, {}, {}
    crosscheck, distances = {}, []
    for name, camera in (("left", rig.left), ("right", rig.right)):
        simulated[name], inside[name] = visible_targets(camera, rig.port, inputs.targets,
                                                        inputs.target_radius)
        index, distance = match_detections(np.asarray(detections[name].centers),
                                           simulated[name], ASSOCIATION_GATE_PX)
        truth_of[name] = index
        d = distance[index >= 0]
        distances.append(d)
        crosscheck[name] = {"associated": int(d.size),
                            "rms_px": float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan"),
                            "max_px": float(d.max()) if d.size else float("nan")}
    all_d = np.concatenate(distances)
    crosscheck.update({"rms_px": float(np.sqrt(np.mean(all_d ** 2))) if all_d.size else float("nan"),
                       "max_px": float(all_d.max()) if all_d.size else float("nan")})

    pair_truth_left = truth_of["left"][matches.left]
    pair_truth_right = truth_of["right"][matches.right]
    correct = (pair_truth_left >= 0) & (pair_truth_left == pair_truth_right)
    found_both = np.intersect1d(truth_of["left"][truth_of["left"] >= 0],
                                truth_of["right"][truth_of["right"] >= 0])
    visible_both = np.flatnonzero(inside["left"] & inside["right"])
    matched_ids = pair_truth_left[correct]
    matching = {"pairs": int(len(matches.left)), "correct": int(correct.sum()),
                "wrong": int((~correct).sum()), "ambiguous_dropped": int(matches.n_ambiguous),
                "candidates": int(matches.n_candidates),
                "visible_in_both": int(len(visible_both)),
                "detected_in_both": int(len(found_both)),
                "visible_in_both_matched": int(np.isin(visible_both, matched_ids).sum()),
                "gate_mm": gate_mm,
                "depth_window_mm": [None if v is None else float(v) for v in window]}
    visibility = {"in_both": int(len(visible_both)),
                  "left_only": int((inside["left"] & ~inside["right"]).sum()),
                  "right_only": int((~inside["left"] & inside["right"]).sum()),
                  "in_neither": int((~inside["left"] & ~inside["right"]).sum())}

    truth_visible = inputs.targets[visible_both]
    method_reports, per_method = {}, {}
    for method, result in results.items():
        ok = correct & result.valid
        truth = inputs.targets[pair_truth_left[ok]]
        errors = result.points[ok] - truth
        stats = _error_stats(errors)
        measured_all = result.points[result.valid]
        stats.update(cloud_distances(measured_all, truth_visible))
        stats.update(rigid_alignment(result.points[ok], truth))
        stats.update(flatness(measured_all, seed=seed))
        stats["invalid"] = int((~result.valid).sum())
        method_reports[method] = stats
        per_method[method] = {"points": result.points[ok], "truth": truth, "errors": errors,
                              "all_points": measured_all}
    timings["evaluate"] = time.perf_counter() - start

    report = {
        "scene": inputs.scene, "targets": int(len(inputs.targets)),
        "visibility": visibility,
        "detection": {name: {"found": int(d.n_found), "rejected": int(d.n_rejected),
                             "rejected_by_reason": {k: int(v) for k, v in d.rejected.items()}}
                      for name, d in detections.items()},
        "crosscheck": crosscheck,
        "matching": matching,
        "methods": method_reports,
        "noise_px": noise_px, "seed": seed,
        "timings_s": timings,
        "variant": inputs.variant, "spp": inputs.spp,
    }
    arrays = {"detections": detections, "centers": centers, "matches": matches,
              "correct": correct, "per_method": per_method, "simulated": simulated}
    return report, arrays
