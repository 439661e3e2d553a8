"""Reprojection-optimal triangulation through the port: the point whose images (the exact
forward model, :func:`measure.projection.project`) lie nearest the two detected pixels — the
maximum-likelihood point for Gaussian pixel noise. Units mm, pixels in the OpenCV convention."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from .projection import project


def reprojection_points(rig, uv_left, uv_right, start):
    """Reprojection-optimal points ``(N, 3)`` mm: each point minimizes its 4 reprojection
    residuals through ``rig.port`` (``least_squares``, a block-diagonal sparse Jacobian),
    starting from ``start`` ``(N, 3)`` (e.g. the optical-path triangulation). Also returns the
    per-point reprojection RMS ``(N,)`` px and whether the fit converged. Rows with non-finite
    input or start stay NaN."""
    uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
    uv_right = np.asarray(uv_right, dtype=np.float64).reshape(-1, 2)
    start = np.asarray(start, dtype=np.float64).reshape(-1, 3)
    points = np.full_like(start, np.nan)
    rms = np.full(start.shape[0], np.nan)
    keep = np.all(np.isfinite(start), axis=1) & np.all(np.isfinite(uv_left), axis=1) & np.all(
        np.isfinite(uv_right), axis=1)
    n = int(keep.sum())
    if n == 0:
        return points, rms, True
    observed = np.concatenate([uv_left[keep], uv_right[keep]], axis=1).ravel()

    def residuals(x):
        pts = x.reshape(n, 3)
        predicted = np.concatenate([project(rig.left, rig.port, pts),
                                    project(rig.right, rig.port, pts)], axis=1).ravel()
        r = predicted - observed
        return np.where(np.isfinite(r), r, 1e3)

    sparsity = lil_matrix((4 * n, 3 * n), dtype=np.int8)
    rows = np.arange(4 * n).reshape(n, 4)
    for j in range(3):
        for k in range(4):
            sparsity[rows[:, k], 3 * np.arange(n) + j] = 1
    fit = least_squares(residuals, start[keep].ravel(), jac_sparsity=sparsity, method="trf",
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=100,
                        tr_options={"atol": 1e-14, "btol": 1e-14})
    points[keep] = fit.x.reshape(n, 3)
    rms[keep] = np.sqrt(np.mean(fit.fun.reshape(n, 4) ** 2, axis=1))
    return points, rms, bool(fit.success)


__all__ = ["reprojection_points"]
