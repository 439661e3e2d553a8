"""Detected target centres against the simulator's pixels: association and statistics.

Used by ``python -m synth check`` (a dataset against its ``pixels.csv``) and by
``python -m eval run`` (to score, after matching without ground truth). Pixels follow OpenCV's
convention (integer coordinates are pixel centres); distances are in pixels.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from measure import Camera
from measure.images.detect import FLOOR_FRACTION

#: Pixels between a detection and the simulator's pixel of a target for them to be associated.
ASSOCIATION_GATE_PX = 2.0


def associate_detections(detected, expected, gate_px: float = ASSOCIATION_GATE_PX):
    """Mutual nearest neighbours within ``gate_px``.

    ``detected`` ``(M, 2)`` and ``expected`` ``(N, 2)`` px (NaN rows of ``expected`` never match).
    Returns ``(index, distance)``, both ``(M,)``: the index into ``expected`` of each detection's
    partner and their distance in px (``-1`` and ``inf`` where it has none).
    """
    detected = np.asarray(detected, float).reshape(-1, 2)
    expected = np.asarray(expected, float).reshape(-1, 2)
    index = np.full(detected.shape[0], -1)
    distance = np.full(detected.shape[0], np.inf)
    finite = np.all(np.isfinite(expected), axis=1)
    if detected.shape[0] == 0 or not finite.any():
        return index, distance
    finite_rows = np.flatnonzero(finite)
    d1, j = cKDTree(expected[finite]).query(detected)
    _, back = cKDTree(detected).query(expected[finite])
    ok = (d1 <= gate_px) & (back[j] == np.arange(detected.shape[0]))
    index[ok], distance[ok] = finite_rows[j[ok]], d1[ok]
    return index, distance


def target_image_margin_px(camera: Camera, points, radius_mm: float) -> np.ndarray:
    """How far (px) each target's image may reach from its centre's pixel, ``(N,)``.

    The port magnifies a target, so its image may reach twice its pinhole radius
    (``f · radius / z``) plus 2 px from its centre. ``points`` ``(N, 3)`` mm, reference frame.
    """
    z = camera.to_camera(np.asarray(points, float).reshape(-1, 3))[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        radius_px = camera.K[0, 0] * radius_mm / np.where(z > 0, z, np.nan)
    return 2.0 * np.nan_to_num(radius_px, nan=0.0) + 2.0


def wholly_in_image(camera: Camera, uv, points, radius_mm: float) -> np.ndarray:
    """Whether each target's image lies wholly inside the image, ``(N,)`` bool.

    ``uv`` ``(N, 2)`` the simulator's pixels of the centres ``points`` (NaN where none)."""
    return camera.in_image(uv, target_image_margin_px(camera, points, radius_mm))


def crosscheck_view(camera, port, targets, centers, simulated):
    """One view's cross-check: ``(index, distances, outline distances)`` — the target of each
    detected centre ``centers`` ``(M, 2)`` px (−1 none: mutual nearest neighbours of the
    simulator's pixels ``simulated`` within :data:`ASSOCIATION_GATE_PX`), and for the
    associated ones their distance (px) to the simulator's pixel of the target's centre and to
    the area centroid of the image of its outline. ``targets`` ``(centres (N, 3) mm, normals
    (N, 3) or one (3,), radius mm)``."""
    from measure.images.eccentricity import outline_centroid_offsets

    points, normals, radius = targets
    index, distance = associate_detections(centers, simulated, ASSOCIATION_GATE_PX)
    found = index >= 0
    offsets = outline_centroid_offsets(camera, port, points[index[found]],
                                       np.broadcast_to(normals, points.shape)[index[found]],
                                       radius)
    d_outline = np.linalg.norm(centers[found] - simulated[index[found]] - offsets, axis=1)
    return index, distance[found], d_outline


def distance_stats(distances) -> dict:
    """``{"n", "rms_px", "max_px"}`` of distances in px (NaN when there are none)."""
    d = np.asarray(distances, float).ravel()
    if d.size == 0:
        return {"n": 0, "rms_px": float("nan"), "max_px": float("nan")}
    return {"n": int(d.size), "rms_px": float(np.sqrt(np.mean(d ** 2))), "max_px": float(d.max())}


__all__ = ["ASSOCIATION_GATE_PX", "CHECK_MAX_PX", "CHECK_RMS_PX", "associate_detections",
           "check_dataset", "check_view", "crosscheck_summary", "crosscheck_view",
           "distance_stats",
           "target_image_margin_px", "wholly_in_image"]


# ---------------------------------------------------------------------------------------------
# python -m synth check
# ---------------------------------------------------------------------------------------------
#: Bounds of ``python -m synth check``: RMS and max centre distance, px.
CHECK_RMS_PX = 0.05
CHECK_MAX_PX = 0.15


def crosscheck_summary(distances: dict) -> dict:
    """A run's cross-check: per view ``name`` (``distances[name]``: the centres' and the
    outlines' distances from the simulator, px, :func:`crosscheck_view`) the associated count
    and the RMS and largest distance of both; then the same over every view."""
    summary = {}
    for name, (d, d_outline) in distances.items():
        stats, outline = distance_stats(d), distance_stats(d_outline)
        summary[name] = {"associated": stats["n"], "rms_px": stats["rms_px"],
                         "max_px": stats["max_px"], "rms_px_outline": outline["rms_px"],
                         "max_px_outline": outline["max_px"]}
    every = distance_stats(np.concatenate([d for d, _ in distances.values()]))
    every_outline = distance_stats(np.concatenate([d for _, d in distances.values()]))
    summary.update({"rms_px": every["rms_px"], "max_px": every["max_px"],
                    "rms_px_outline": every_outline["rms_px"],
                    "max_px_outline": every_outline["max_px"]})
    return summary


def check_view(image, camera: Camera, expected, targets, ids, radius_mm: float,
               gate_px: float = ASSOCIATION_GATE_PX) -> tuple[dict, np.ndarray]:
    """One view of :func:`check_dataset`: detect the targets of ``image`` (linear, ``(H, W)``)
    and compare them with ``expected`` ``(T, 2)`` px, the simulator's pixels of the targets
    ``targets`` ``(T, 3)`` mm (reference frame) numbered ``ids``, seen by ``camera``.
    Returns ``(entry, distances)``: the view's report entry (``in_image``, ``found``,
    ``missed``, ``detected``, ``unmatched_detections``, ``rejected``, ``rms_px``, ``max_px``,
    ``mean_px``) and the associated detections' distances in px."""
    from measure.images.detect import detect_targets

    det = detect_targets(image, floor_fraction=FLOOR_FRACTION)
    inside = wholly_in_image(camera, expected, targets, radius_mm)
    idx, dist = associate_detections(det.centers, expected, gate_px)
    matched = idx >= 0
    found = np.isin(np.flatnonzero(inside), idx[matched])
    missed = np.asarray(ids)[np.flatnonzero(inside)[~found]].tolist()
    d = dist[matched]
    offsets = det.centers[matched] - expected[idx[matched]]
    stats = distance_stats(d)
    entry = {
        "in_image": int(inside.sum()), "found": int(found.sum()), "missed": missed,
        "detected": det.n_found, "unmatched_detections": int((~matched).sum()),
        "rejected": {k: int(v) for k, v in det.rejected.items()},
        "rms_px": stats["rms_px"], "max_px": stats["max_px"],
        "mean_px": offsets.mean(axis=0).tolist() if d.size else [float("nan")] * 2,
    }
    return entry, d


def check_dataset(path, rms_px: float = CHECK_RMS_PX, max_px: float = CHECK_MAX_PX,
                  gate_px: float = ASSOCIATION_GATE_PX) -> dict:
    """Detect the targets in every image of a dataset and compare them with ``pixels.csv``.

    A target is *in the image* when its simulated pixel lies farther inside the image than its
    image can reach (:func:`target_image_margin_px`): those must all be found. Detections are
    paired with simulated pixels by :func:`associate_detections`. Returns a dict: ``views``
    (the views' names: ``left``, ``right``, or ``cam0``, ``cam1``, … of a dataset of N cameras,
    :mod:`synth.products.dataset_layout`) and per view (:func:`check_view`) ``in_image``,
    ``found``, ``missed`` (ids), ``detected``, ``unmatched_detections``, ``rejected``
    {reason: count}, ``rms_px``, ``max_px``, ``mean_px`` (mean offset detected − simulated,
    (du, dv)); over all views ``rms_px``, ``max_px``; the bounds and ``passed``.
    """
    from synth.products.dataset import read_dataset

    data = read_dataset(path)
    views = data.views
    radius = float(data.manifest.get("scene", {}).get("target_radius_mm", 0.0))
    report = {"path": str(path), "views": [v[0] for v in views],
              "bounds": {"rms_px": rms_px, "max_px": max_px}}
    all_d = []
    for name, image, camera, expected in views:
        report[name], d = check_view(image, camera, expected, data.targets, data.ids, radius,
                                     gate_px)
        all_d.append(d)
    all_found = not any(report[name]["missed"] for name, *_ in views)
    both = distance_stats(np.concatenate(all_d))
    report["rms_px"], report["max_px"] = both["rms_px"], both["max_px"]
    report["all_found"] = bool(all_found)
    report["passed"] = bool(all_found and both["n"] and report["rms_px"] <= rms_px
                            and report["max_px"] <= max_px)
    return report
