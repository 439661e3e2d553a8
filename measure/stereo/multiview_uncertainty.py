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

#: The step (px) of the central differences of :func:`view_point_covariances`.
STEP_PX = 1e-3


def view_pixel_sigmas(pixel_sigma, n: int, n_views: int) -> np.ndarray:
    """``(N, V)`` px: σ of each point's pixel in each view from one number, ``(N,)`` (per
    point) or ``(N, V)`` (per point and view); ValueError for another shape or a σ that is not
    positive (NaN allowed: a point without a σ gets no covariance)."""
    sigma = np.asarray(pixel_sigma, dtype=np.float64)
    if sigma.ndim == 1 and sigma.shape == (n,):
        sigma = sigma[:, None]
    try:
        sigma = np.broadcast_to(sigma, (n, n_views)).copy()
    except ValueError:
        raise ValueError(f"pixel_sigma must be a number, ({n},) or ({n}, {n_views}), got shape "
                         f"{sigma.shape}") from None
    finite = np.isfinite(sigma)
    if np.any(sigma[finite] <= 0):
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
    flat_g = G.reshape(G.shape[0], 3, -1)
    covariance = np.matmul(weighted.reshape(G.shape[0], 3, -1), np.swapaxes(flat_g, 1, 2))
    no_sigma = ~np.all(np.isfinite(sigma) | ~np.isfinite(pixels[..., 0]), axis=1)
    covariance[no_sigma] = np.nan
    return points, covariance


__all__ = ["STEP_PX", "point_jacobians", "view_pixel_sigmas", "view_point_covariances"]
