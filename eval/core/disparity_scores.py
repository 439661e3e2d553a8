"""Scores of a disparity map against its truth, as the stereo benchmarks define them, and depth
errors by distance.

* EPE — the mean end-point error ``|d − d*|`` (px) over the pixels scored;
* D1 (KITTI 2015's ``D1-all``) — the share of those pixels whose error exceeds both 3 px and
  5 % of the true disparity;
* density — the share of the pixels with truth where the method gave a disparity (KITTI fills
  the holes before scoring; here the holes are left out of EPE and D1 and counted here);
* depth errors by distance — per bin of the true distance (mm): the pixels, the median of
  ``|z − z*|`` (mm) and of ``|z − z*| / z*`` (%).

Disparities in px (``u_left − u_right`` on a row-aligned pair), NaN (or a ``valid`` mask) where
a map has none; depths in mm.
"""

from __future__ import annotations

import numpy as np

#: KITTI 2015's outlier rule: an error above both of these is bad.
D1_PIXELS, D1_FRACTION = 3.0, 0.05
#: Default bins of true distance (mm) for :func:`depth_errors_by_distance`.
DISTANCE_BINS_MM = (0.0, 1000.0, 1500.0, 2000.0, 3000.0, np.inf)


def disparity_scores(predicted: np.ndarray, truth: np.ndarray) -> dict:
    """``{pixels, scored, density, epe_px, d1}`` of ``predicted`` against ``truth`` (same
    shape; NaN where none): ``pixels`` with truth, ``scored`` of those with a prediction."""
    predicted = np.asarray(predicted, np.float64)
    truth = np.asarray(truth, np.float64)
    has_truth = np.isfinite(truth)
    scored = has_truth & np.isfinite(predicted)
    error = np.abs(predicted[scored] - truth[scored])
    bad = (error > D1_PIXELS) & (error > D1_FRACTION * np.abs(truth[scored]))
    n = int(scored.sum())
    return {"pixels": int(has_truth.sum()), "scored": n,
            "density": n / max(int(has_truth.sum()), 1),
            "epe_px": float(error.mean()) if n else float("nan"),
            "d1": float(bad.mean()) if n else float("nan"),
            "sum_error_px": float(error.sum()), "bad": int(bad.sum())}


def pooled(scores) -> dict:
    """:func:`disparity_scores` of many maps pooled pixel by pixel (not a mean of means)."""
    scores = list(scores)
    pixels = sum(s["pixels"] for s in scores)
    n = sum(s["scored"] for s in scores)
    return {"pixels": pixels, "scored": n, "density": n / max(pixels, 1),
            "epe_px": sum(s["sum_error_px"] for s in scores) / n if n else float("nan"),
            "d1": sum(s["bad"] for s in scores) / n if n else float("nan")}


def depth_errors_by_distance(z_predicted, z_true, bins=DISTANCE_BINS_MM) -> list:
    """Per bin ``[lo, hi)`` of the true depth: ``{"from_mm", "to_mm", "pixels",
    "median_abs_mm", "median_rel_percent"}`` over the pixels where both depths are finite."""
    z_predicted = np.ravel(np.asarray(z_predicted, np.float64))
    z_true = np.ravel(np.asarray(z_true, np.float64))
    both = np.isfinite(z_predicted) & np.isfinite(z_true) & (z_true > 0)
    error = np.abs(z_predicted[both] - z_true[both])
    truth = z_true[both]
    rows = []
    for lo, hi in zip(bins[:-1], bins[1:]):
        inside = (truth >= lo) & (truth < hi)
        n = int(inside.sum())
        rows.append({"from_mm": float(lo), "to_mm": float(hi), "pixels": n,
                     "median_abs_mm": float(np.median(error[inside])) if n else float("nan"),
                     "median_rel_percent": (float(np.median(100 * error[inside] / truth[inside]))
                                            if n else float("nan"))})
    return rows


__all__ = ["D1_FRACTION", "D1_PIXELS", "DISTANCE_BINS_MM", "depth_errors_by_distance",
           "disparity_scores", "pooled"]
