"""Point-cloud comparison of a measured target cloud with the ground truth, with Open3D.

All distances in mm, both clouds in the reference frame (the left camera's).

* cloud-to-cloud distances (``PointCloud.compute_point_cloud_distance``) both ways, their means
  summed as the Chamfer distance, and precision / recall / F-score at distance thresholds in the
  style of the Tanks and Temples benchmark (precision: share of measured points within τ of the
  truth; recall: share of true points within τ of the measurement; F = 2PR / (P + R));
* the best rigid alignment of the measured points onto their true counterparts with known
  correspondences (``TransformationEstimationPointToPoint``): the error left after it is the
  shape error, what it removed the pose error;
* the flatness of the measured cloud: RMS distance to its plane (a seeded, vectorized RANSAC
  refined by least squares: reproducible, unlike the multi-threaded ``segment_plane``);
* the length error of target pairs (:func:`length_errors`): what a scale bar or a fish-length
  measurement sees, independent of the frame the points are in.
"""

from __future__ import annotations

import os

import numpy as np
import open3d as o3d
from scipy.spatial.distance import pdist


def point_cloud(points: np.ndarray, colors: np.ndarray | None = None) -> o3d.geometry.PointCloud:
    """An Open3D cloud from ``(N, 3)`` points (mm) and optional ``(N, 3)`` colours in [0, 1]."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    if colors is not None:
        cloud.colors = o3d.utility.Vector3dVector(np.asarray(colors, dtype=np.float64))
    return cloud


def cloud_distances(measured: np.ndarray, truth: np.ndarray, thresholds=(1.0, 5.0)) -> dict:
    """Chamfer distance and precision / recall / F-score at each threshold (mm)."""
    if len(measured) == 0 or len(truth) == 0:
        nan = float("nan")
        out = {"chamfer_mm": nan, "mean_measured_to_truth_mm": nan, "mean_truth_to_measured_mm": nan}
        for tau in thresholds:
            out.update({f"precision_{tau:g}mm": nan, f"recall_{tau:g}mm": nan, f"fscore_{tau:g}mm": nan})
        return out
    cloud_m, cloud_t = point_cloud(measured), point_cloud(truth)
    m_to_t = np.asarray(cloud_m.compute_point_cloud_distance(cloud_t))
    t_to_m = np.asarray(cloud_t.compute_point_cloud_distance(cloud_m))
    out = {"chamfer_mm": float(m_to_t.mean() + t_to_m.mean()),
           "mean_measured_to_truth_mm": float(m_to_t.mean()),
           "mean_truth_to_measured_mm": float(t_to_m.mean())}
    for tau in thresholds:
        precision = float(np.mean(m_to_t < tau))
        recall = float(np.mean(t_to_m < tau))
        fscore = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
        out.update({f"precision_{tau:g}mm": precision, f"recall_{tau:g}mm": recall,
                    f"fscore_{tau:g}mm": fscore})
    return out


def rigid_alignment(measured: np.ndarray, truth: np.ndarray) -> dict:
    """Best rigid transform of ``measured`` onto ``truth`` (row i ↔ row i) and the errors after it."""
    if len(measured) < 3:
        return {"rms_dp_aligned_mm": float("nan"), "rotation_deg": float("nan"),
                "translation_mm": [float("nan")] * 3}
    correspondences = o3d.utility.Vector2iVector(np.column_stack([np.arange(len(measured))] * 2))
    estimator = o3d.pipelines.registration.TransformationEstimationPointToPoint(False)
    transform = estimator.compute_transformation(point_cloud(measured), point_cloud(truth),
                                                 correspondences)
    aligned = measured @ transform[:3, :3].T + transform[:3, 3]
    residual = np.linalg.norm(aligned - truth, axis=1)
    angle = np.degrees(np.arccos(np.clip((np.trace(transform[:3, :3]) - 1) / 2, -1.0, 1.0)))
    return {"rms_dp_aligned_mm": float(np.sqrt(np.mean(residual ** 2))),
            "max_dp_aligned_mm": float(residual.max()),
            "rotation_deg": float(angle), "translation_mm": transform[:3, 3].tolist()}


#: Pairs of targets whose true distance is shorter than this are left out of the length errors
#: (mm): a length is measured between things apart, and a short one's relative error is noise.
MIN_LENGTH_MM = 100.0
#: At most this many points enter the length errors (every k-th point beyond it): the pairs grow
#: with the square of the points.
MAX_LENGTH_POINTS = 3000


def length_errors(measured: np.ndarray, truth: np.ndarray,
                  min_length_mm: float = MIN_LENGTH_MM) -> dict:
    """Relative errors of the distances between every two points (row i ↔ row i of
    ``measured`` and ``truth``, mm) whose true distance is at least ``min_length_mm``:
    ``length_median_pct`` (signed: negative = too short), ``length_median_abs_pct``,
    ``length_p95_abs_pct``, ``length_worst_pct`` (the largest in magnitude, signed) and
    ``length_pairs``. A rigid motion of the measured points changes none of them."""
    measured = np.asarray(measured, dtype=np.float64).reshape(-1, 3)
    truth = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
    step = max(1, -(-len(truth) // MAX_LENGTH_POINTS))
    measured, truth = measured[::step], truth[::step]
    true_lengths = pdist(truth)
    keep = true_lengths >= min_length_mm
    relative = 100.0 * (pdist(measured)[keep] / true_lengths[keep] - 1.0)
    relative = relative[np.isfinite(relative)]
    nan = float("nan")
    if len(relative) == 0:
        return {"length_median_pct": nan, "length_median_abs_pct": nan,
                "length_p95_abs_pct": nan, "length_worst_pct": nan, "length_pairs": 0}
    size = np.abs(relative)
    return {"length_median_pct": float(np.median(relative)),
            "length_median_abs_pct": float(np.median(size)),
            "length_p95_abs_pct": float(np.percentile(size, 95)),
            "length_worst_pct": float(relative[np.argmax(size)]),
            "length_pairs": int(len(relative))}


def flatness(points: np.ndarray, seed: int = 0, threshold_mm: float = 5.0,
             hypotheses: int = 1000) -> dict:
    """RMS and peak-to-valley distance (mm) of ``points`` to their plane.

    The plane: RANSAC over ``hypotheses`` random triples (``numpy.random.default_rng(seed)``,
    vectorized), the one with the most points within ``threshold_mm``, refined by a least-squares
    (SVD) fit to those inliers. Not Open3D's ``segment_plane``: it runs on several threads and
    gave different planes for the same seed (1 run in 5 differed by 0.06 mm of flatness); this
    one is the same for the same arguments, always.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) < 3:
        return {"flatness_mm": float("nan"), "flatness_pv_mm": float("nan"), "plane": None}
    rng = np.random.default_rng(seed)
    triples = points[rng.integers(0, len(points), size=(hypotheses, 3))]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    length = np.linalg.norm(normals, axis=1)
    usable = length > 1e-12
    if not usable.any():
        return {"flatness_mm": float("nan"), "flatness_pv_mm": float("nan"), "plane": None}
    normals = normals[usable] / length[usable, None]
    offsets = -np.einsum("ij,ij->i", normals, triples[usable, 0])
    inliers = np.abs(points @ normals.T + offsets) <= threshold_mm  # (N, hypotheses)
    best = inliers[:, int(np.argmax(inliers.sum(axis=0)))]
    centroid = points[best].mean(axis=0)
    # only V: the thin SVD (the full one also built an N x N U, 15 ms at 496 points)
    normal = np.linalg.svd(points[best] - centroid, full_matrices=False)[2][-1]
    if normal[np.argmax(np.abs(normal))] < 0:
        normal = -normal  # a deterministic sign
    d = -float(normal @ centroid)
    signed = points @ normal + d
    return {"flatness_mm": float(np.sqrt(np.mean(signed ** 2))),
            "flatness_pv_mm": float(signed.max() - signed.min()),
            "plane": [float(v) for v in (*normal, d)]}


def write_colored_ply(path: str, points: np.ndarray, values: np.ndarray, vmax: float,
                      colormap: str = "viridis") -> None:
    """Write points coloured by ``values`` on ``colormap`` over [0, vmax] (clipped) as PLY."""
    from matplotlib import colormaps

    if len(points) == 0:  # Open3D refuses to write an empty cloud; an empty PLY is still valid
        with open(path, "w") as fh:
            fh.write("ply\nformat ascii 1.0\ncomment no points\nelement vertex 0\n"
                     "property double x\nproperty double y\nproperty double z\n"
                     "property uchar red\nproperty uchar green\nproperty uchar blue\n"
                     "end_header\n")
        return
    values = np.asarray(values, dtype=float)
    fraction = np.clip(values / vmax if vmax > 0 else np.zeros_like(values), 0.0, 1.0)
    colors = colormaps[colormap](fraction)[:, :3]
    if not o3d.io.write_point_cloud(str(path), point_cloud(points, colors), write_ascii=False):
        raise OSError(f"Open3D could not write {path}")


#: Colour map of the PLY files of measured points (dP, mm).
PLY_COLORMAP = "viridis"


def write_error_ply(directory: str, name: str, points, errors) -> dict:
    """``points`` ``(N, 3)`` coloured by their dP (norm of ``errors`` ``(N, 3)``, mm) on
    :data:`PLY_COLORMAP` from 0 to the largest, as ``directory/name``; returns the report entry."""
    dp = np.linalg.norm(errors, axis=1)
    vmax = float(dp.max()) if dp.size else 1.0
    write_colored_ply(os.path.join(directory, name), points, dp, vmax, PLY_COLORMAP)
    return {"file": name, "colormap": PLY_COLORMAP, "vmin_mm": 0.0, "vmax_mm": vmax,
            "points": int(dp.size)}
