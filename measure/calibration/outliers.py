"""The rules that say a board view does not belong with the others: its reprojection RMS far
above theirs (a photo turned or mirrored, blurred, of another board, or of another moment), and,
for two cameras that found the board in the same poses, a pose whose own relative pose of the
two cameras disagrees with the others' (:func:`relative_pose_check`: a photo of another moment,
swapped or turned) — the one check of every pair of cameras, whatever the rig's count.

:func:`outlier_threshold` of the views' RMS: max(:data:`OUTLIER_FACTOR` × median, median +
:data:`OUTLIER_MADS` × 1.4826 × MAD, median + :data:`OUTLIER_FLOOR_PX`) — MAD the median
absolute deviation (1.4826 × MAD is σ for Gaussian scatter); the floor keeps a set of nearly
equal, very small residuals from shedding views. Units: px; relative poses mm and degrees.
"""

from __future__ import annotations

import numpy as np

#: A pose whose own stereo pose (from the two cameras' board poses) lies farther than
#: max(:data:`STEREO_OUTLIER_FACTOR` × the median distance, :data:`STEREO_FLOOR_FRACTION` ×
#: the baseline) or turned by more than max(factor × the median angle,
#: :data:`STEREO_FLOOR_DEG`) from the poses' median stereo pose is left out of the stereo fit
#: (:func:`stereo_pose_outliers`): a swapped, turned or mirrored photo, or a pair not taken at
#: one moment.
STEREO_OUTLIER_FACTOR, STEREO_FLOOR_FRACTION, STEREO_FLOOR_DEG = 5.0, 0.02, 0.5

#: The outlier rule (module docs).
OUTLIER_FACTOR, OUTLIER_MADS, OUTLIER_FLOOR_PX = 3.0, 5.0, 0.1


def outlier_threshold(rms_values) -> float:
    """The RMS (px) above which a view is an outlier (module docs); inf for no views."""
    values = np.asarray(list(rms_values), dtype=np.float64)
    if values.size == 0:
        return float("inf")
    median = float(np.median(values))
    mad = float(np.median(np.abs(values - median)))
    return max(OUTLIER_FACTOR * median, median + OUTLIER_MADS * 1.4826 * mad,
               median + OUTLIER_FLOOR_PX)


def relative_poses(left_extrinsics, right_extrinsics):
    """Per pose the stereo pose seen through that pose alone, in OpenCV's stereo convention
    (``X_right = R X_left + T``): ``(R (P, 3, 3), T (P, 3) mm)`` from each camera's
    board-to-camera ``(R, t)`` pairs."""
    R_l = np.stack([R for R, _ in left_extrinsics])
    R_r = np.stack([R for R, _ in right_extrinsics])
    t_l = np.stack([t for _, t in left_extrinsics])
    t_r = np.stack([t for _, t in right_extrinsics])
    R = R_r @ np.transpose(R_l, (0, 2, 1))
    return R, t_r - np.einsum("pij,pj->pi", R, t_l)


def stereo_pose_outliers(R, T) -> dict:
    """The poses whose own stereo pose ``(R (P, 3, 3), T (P, 3))`` disagrees with the others
    (module constants): the median pose is the component-wise median of ``T`` and the medoid
    of the rotations; returns ``{"deviation_mm" (P,), "deviation_deg" (P,),
    "threshold_mm", "threshold_deg", "outliers" [indices], "baseline_mm" (P,)}``."""
    from scipy.spatial.transform import Rotation
    T = np.asarray(T, dtype=np.float64)
    angles = np.degrees(Rotation.from_matrix(
        np.einsum("pij,qkj->pqik", R, R).reshape(-1, 3, 3)).magnitude()).reshape(len(R), len(R))
    medoid = int(np.argmin(np.median(angles, axis=1)))
    deviation_deg = angles[:, medoid]
    deviation_mm = np.linalg.norm(T - np.median(T, axis=0), axis=1)
    baseline = float(np.linalg.norm(np.median(T, axis=0)))
    threshold_mm = max(STEREO_OUTLIER_FACTOR * float(np.median(deviation_mm)),
                       STEREO_FLOOR_FRACTION * baseline)
    threshold_deg = max(STEREO_OUTLIER_FACTOR * float(np.median(deviation_deg)), STEREO_FLOOR_DEG)
    bad = (deviation_mm > threshold_mm) | (deviation_deg > threshold_deg)
    return {"deviation_mm": deviation_mm, "deviation_deg": deviation_deg,
            "threshold_mm": threshold_mm, "threshold_deg": threshold_deg,
            "outliers": [int(i) for i in np.flatnonzero(bad)],
            "baseline_mm": np.linalg.norm(T, axis=1)}


def relative_pose_check(own_a: dict, own_b: dict, poses) -> tuple[dict, tuple]:
    """The pair's per-pose check of cameras a and b (``own_*`` ``{pose: (R, t)}`` board →
    camera) over ``poses`` both found (at least :data:`MIN_POSES`): ``({pose: {baseline_mm,
    deviation_mm, deviation_deg, threshold_mm, threshold_deg}}, poses left out)`` — each
    pose's own relative pose against the poses' median (:func:`stereo_pose_outliers`)."""
    R_k, T_k = relative_poses([own_a[k] for k in poses], [own_b[k] for k in poses])
    check = stereo_pose_outliers(R_k, T_k)
    checked = {k: {"baseline_mm": float(check["baseline_mm"][i]),
                   "deviation_mm": float(check["deviation_mm"][i]),
                   "deviation_deg": float(check["deviation_deg"][i]),
                   "threshold_mm": check["threshold_mm"],
                   "threshold_deg": check["threshold_deg"]}
               for i, k in enumerate(poses)}
    return checked, tuple(poses[i] for i in check["outliers"])


__all__ = ["OUTLIER_FACTOR", "OUTLIER_FLOOR_PX", "OUTLIER_MADS", "STEREO_FLOOR_DEG",
           "STEREO_FLOOR_FRACTION", "STEREO_OUTLIER_FACTOR", "outlier_threshold",
           "relative_pose_check", "relative_poses", "stereo_pose_outliers"]
