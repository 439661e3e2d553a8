"""The covariance of every point of N views from its pixels' noise, first order.

A point of :func:`measure.stereo.multiview.triangulate_views` is a function ``X = g(m)`` of the
pixels ``m = (u_1, v_1, …, u_V, v_V)`` of the views that saw it: each pixel is back-projected,
traced through its view's port and the point is the one nearest to all the water rays. With
``G = ∂g/∂m`` ``(3, 2V)`` at the measured pixels and independent noise of σ per coordinate,

    ``Σ_X = G diag(σ²) Gᵀ``

— the covariance of the point as it is triangulated (the least-squares point of the rays),
not the maximum-likelihood bound ``(JᵀWJ)⁻¹`` of :mod:`measure.stereo.uncertainty` (for two
views they differ only in how they spread the noise that makes the rays skew: within 1 %,
tested; for more views the rays' point weighs each view by distances in the water, not by
its pixels, and its covariance is at least the bound).
``G`` is taken by central differences of the triangulation itself (each pixel coordinate moved
by ±:data:`STEP_PX`, all points at once): the derivative through every refraction of every
kind of port without writing it out; the error of the difference is of order ``STEP_PX²``
times the curvature of the rays' point in the pixels, far below the noise.

A view that did not see a point (NaN pixels) contributes nothing to it; a point whose
triangulation is not valid, or becomes invalid when a pixel is moved (a ray at the edge of
its port), has a NaN covariance. Only the pixels' part: the rig is taken as exact.

Units: mm (points), mm² (covariances), px (pixels, σ); frame: the reference frame.
"""

from __future__ import annotations

import numpy as np

from .multiview import triangulate_views
from .rig_triangulation import reprojection_normal_equations

#: The step (px) of the central differences of :func:`view_point_covariances`.
STEP_PX = 1e-3


def view_pixel_sigmas(pixel_sigma, n: int, n_views: int, allow_zero: bool = False) -> np.ndarray:
    """``(N, V)`` px: σ of each point's pixel in each view from one number, ``(N,)`` (per
    point) or ``(N, V)`` (per point and view); ValueError for another shape or a σ that is not
    positive (0 too unless ``allow_zero``; NaN allowed: a point without a σ gets no
    covariance)."""
    sigma = np.asarray(pixel_sigma, dtype=np.float64)
    if sigma.ndim == 1 and sigma.shape == (n,):
        sigma = sigma[:, None]
    try:
        sigma = np.broadcast_to(sigma, (n, n_views)).copy()
    except ValueError:
        raise ValueError(f"pixel_sigma must be a number, ({n},) or ({n}, {n_views}), got shape "
                         f"{sigma.shape}") from None
    finite = sigma[np.isfinite(sigma)]
    if np.any(finite < 0) or (not allow_zero and np.any(finite == 0)):
        raise ValueError("pixel_sigma must be positive")
    return sigma


def point_jacobians(views, pixels) -> tuple[np.ndarray, np.ndarray]:
    """``(points (N, 3) mm, G (N, 3, V, 2) mm/px)``: the triangulated points of ``pixels``
    ``(N, V, 2)`` and the derivative of each point with respect to each of its pixels (zero for
    a view that did not see it; NaN rows where the point is not valid or a moved pixel makes it
    invalid)."""
    views = list(views)
    pixels = np.asarray(pixels, dtype=np.float64)
    base = triangulate_views(views, pixels)
    n, n_views = pixels.shape[0], len(views)
    G = np.zeros((n, 3, n_views, 2))
    broken = ~base.valid
    for v in range(n_views):
        seen = base.used[:, v]
        for c in range(2):
            moved = []
            for step in (STEP_PX, -STEP_PX):
                shifted = pixels.copy()
                shifted[:, v, c] += step
                moved.append(triangulate_views(views, shifted))
            changed = ~moved[0].valid | ~moved[1].valid
            changed |= (moved[0].used != base.used).any(axis=1)
            changed |= (moved[1].used != base.used).any(axis=1)
            broken |= seen & changed
            column = (moved[0].points - moved[1].points) / (2 * STEP_PX)
            G[:, :, v, c] = np.where(seen[:, None], column, 0.0)
    G[broken] = np.nan
    points = base.points.copy()
    points[broken] = np.nan
    return points, G


def view_point_covariances(views, pixels, pixel_sigma) -> tuple[np.ndarray, np.ndarray]:
    """``(points (N, 3) mm, covariances (N, 3, 3) mm²)`` of the points triangulated from
    ``pixels`` ``(N, V, 2)`` in ``views`` (:class:`measure.stereo.multiview.View`, e.g.
    ``Rig.views()``), each pixel coordinate with independent noise of ``pixel_sigma`` px (see
    :func:`view_pixel_sigmas`). Module docs for what is and is not included."""
    views = list(views)
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim != 3 or pixels.shape[1:] != (len(views), 2):
        raise ValueError(f"pixels must have shape (N, {len(views)}, 2) for {len(views)} views, "
                         f"got {pixels.shape}")
    sigma = view_pixel_sigmas(pixel_sigma, pixels.shape[0], len(views))
    points, G = point_jacobians(views, pixels)
    variance = np.where(np.isfinite(pixels[..., 0]), sigma * sigma, 0.0)  # (N, V)
    weighted = G * variance[:, None, :, None]
    flat_g = G.reshape(G.shape[0], 3, 2 * len(views))
    covariance = np.matmul(weighted.reshape(G.shape[0], 3, 2 * len(views)),
                           np.swapaxes(flat_g, 1, 2))
    no_sigma = ~np.all(np.isfinite(sigma) | ~np.isfinite(pixels[..., 0]), axis=1)
    covariance[no_sigma] = np.nan
    return points, covariance


#: A point's residual per degree of freedom beyond this many times the robust level (the
#: median's) is an outlier (a wrong match) for :func:`view_residual_sigma`.
OUTLIER_FACTOR = 20.0


def view_residuals(views, pixels, points) -> tuple[np.ndarray, np.ndarray]:
    """``(q (N,) px², dof (N,))``: each point's squared first-order maximum-likelihood residual
    over the pixels of the views that saw it — ``e = m − f(X)`` (``f`` the Fermat forward model
    of each view, :func:`measure.geometry.projection.project`), ``r = (I − J (JᵀJ)⁻¹ Jᵀ) e``
    with ``J`` its point Jacobian, ``q = |r|²`` — and its degrees of freedom ``2k − 3`` for k
    views (``q ~ σ² χ²(2k − 3)`` for a pixel noise of σ per coordinate); NaN where the point or
    a projection is not finite. ``|r|² = |e|² − (Jᵀe)ᵀ (JᵀJ)⁻¹ Jᵀe``, from the reprojection's
    normal equations (:func:`measure.stereo.rig_triangulation.reprojection_normal_equations`)."""
    pixels = np.asarray(pixels, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    seen = np.all(np.isfinite(pixels), axis=2)
    dof = 2 * seen.sum(axis=1) - 3
    ok = (dof > 0) & np.all(np.isfinite(points), axis=1)
    q = np.full(points.shape[0], np.nan)
    cost, normal, gradient = reprojection_normal_equations(views, pixels[ok], seen[ok], points[ok])
    fits = np.isfinite(cost) & np.all(np.isfinite(normal), axis=(1, 2))
    explained = np.einsum("ni,ni->n", gradient[fits],
                          np.linalg.solve(normal[fits], gradient[fits][..., None])[..., 0])
    q[np.flatnonzero(ok)[fits]] = np.maximum(cost[fits] - explained, 0.0)
    ok = np.isfinite(q)
    return q, np.where(ok, dof, 0)


def view_residual_sigma(views, pixels, points, pixel_sigma=0.0) -> dict:
    """The pixel noise the points' residuals show beyond the stated ``pixel_sigma`` (px: a
    number, ``(N,)`` or ``(N, V)``; 0 allowed), no truth needed: with ``q`` and ``dof`` of
    :func:`view_residuals` and ``s²`` each point's mean stated variance over its views, the
    extra σ₀ of every detection is ``σ₀² = max(0, mean(q / dof − s²))`` over the points whose
    ``q / dof`` lies within :data:`OUTLIER_FACTOR` times the robust level (``s²`` plus the
    median of ``q / dof − s²``): a wrong match does not inflate it. What it cannot see: an
    error every view of a target shares (the disks' eccentricity, a calibration error along
    the rays). Returns ``{"sigma0_px", "rms_residual_px", "n"}`` (``rms_residual_px`` the RMS of
    ``q / dof``'s root)."""
    pixels = np.asarray(pixels, dtype=np.float64)
    q, dof = view_residuals(views, pixels, points)
    ok = np.isfinite(q) & (dof > 0)
    if not ok.any():
        return {"sigma0_px": None, "rms_residual_px": None, "n": 0}
    stated = np.nan_to_num(view_pixel_sigmas(pixel_sigma, *pixels.shape[:2], allow_zero=True))
    seen = np.all(np.isfinite(pixels), axis=2)
    known = (np.sum(np.where(seen, stated ** 2, 0.0), axis=1)
             / np.maximum(seen.sum(axis=1), 1))[ok]
    per_dof = q[ok] / dof[ok]
    robust = max(float(np.median(per_dof - known)), 0.0)
    inliers = per_dof <= OUTLIER_FACTOR * (known + robust)
    variance = max(float(np.mean(per_dof[inliers] - known[inliers])), 0.0)
    return {"sigma0_px": float(np.sqrt(variance)),
            "rms_residual_px": float(np.sqrt(np.mean(per_dof))), "n": int(ok.sum())}


__all__ = ["OUTLIER_FACTOR", "STEP_PX", "point_jacobians", "view_pixel_sigmas",
           "view_point_covariances", "view_residual_sigma", "view_residuals"]
