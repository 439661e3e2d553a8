"""Reprojection-optimal triangulation through the port: the point whose images (the exact
forward model, :func:`measure.projection.project`) lie nearest the two detected pixels — the
maximum-likelihood point for Gaussian pixel noise. Units mm, pixels in the OpenCV convention."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from .projection import project


def stereo_residuals(rig, port, points, observed) -> np.ndarray:
    """Reprojection residuals ``(4N,)`` px of ``points`` ``(N, 3)`` through ``port`` against
    ``observed`` = rows ``(u_left, v_left, u_right, v_right)`` flattened; a point with no image
    gets a large residual (1e3 px) instead of NaN, so the optimizer steers away from it."""
    predicted = np.concatenate([project(rig.left, port, points),
                                project(rig.right, port, points)], axis=1).ravel()
    r = predicted - observed
    return np.where(np.isfinite(r), r, 1e3)


def point_block_sparsity(n: int, n_params: int = 0):
    """Jacobian structure of :func:`stereo_residuals` over ``n_params`` shared parameters (all
    rows) followed by the points' coordinates (each point's 3 columns touch its 4 rows)."""
    sparsity = lil_matrix((4 * n, n_params + 3 * n), dtype=np.int8)
    if n_params:
        sparsity[:, :n_params] = 1
    rows = np.repeat(np.arange(4 * n), 3)
    cols = n_params + 3 * np.repeat(np.arange(n), 12) + np.tile(np.arange(3), 4 * n)
    sparsity[rows, cols] = 1
    return sparsity


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
        return stereo_residuals(rig, rig.port, x.reshape(n, 3), observed)

    sparsity = point_block_sparsity(n)
    fit = least_squares(residuals, start[keep].ravel(), jac_sparsity=sparsity, method="trf",
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=100,
                        tr_options={"atol": 1e-14, "btol": 1e-14})
    points[keep] = fit.x.reshape(n, 3)
    rms[keep] = np.sqrt(np.mean(fit.fun.reshape(n, 4) ** 2, axis=1))
    return points, rms, bool(fit.success)


__all__ = ["point_block_sparsity", "reprojection_points", "stereo_residuals"]
