"""The optical path of N views: a target seen by any k ≥ 2 cameras, each behind its own port.

A :class:`View` is a camera and the port it looks through — any port that traces camera rays
into the water (the port interface, :class:`measure.geometry.port.RigPort`'s ``view(v)``: a flat
port shared by several cameras, a flat port per camera, a dome per camera, or
:func:`measure.geometry.port.index_matched_port` for a camera in air). Each view's pixel is
back-projected (lens distortion inverted) and traced through its port into the water (the
paper's equations 3–10 at every interface); the point is the one nearest to all k water rays
in the least-squares sense — the solution of ``Σ (I − d dᵀ) X = Σ (I − d dᵀ) o`` over the
rays (origin ``o`` on the last interface, unit direction ``d``), solved in closed form (the
adjugate of the symmetric 3 × 3 matrix, column arithmetic over all points). For k = 2 it is
the midpoint of the two rays' common perpendicular, the paper's optical-path point. ``gap`` is
the RMS distance of the point from its k rays (for k = 2 half the common perpendicular's length).

Arrays: ``pixels`` ``(N, V, 2)`` for V views, NaN where a view did not see the target; points
``(N, 3)`` mm in the reference frame; a row seen by fewer than two views is NaN with
:attr:`Reason.TOO_FEW_VIEWS` and never triangulated. Vectorized over N: one 3 × 3 solve per
point, written out.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera
from ..reasons import Reason

#: A point's normal matrix Σ (I − d dᵀ) whose determinant is below this times the cube of its
#: mean eigenvalue has (nearly) parallel rays: no point is determined along them.
PARALLEL_LIMIT = 1e-14
#: Points per piece of :func:`triangulate_views`: every intermediate column of a piece stays in
#: the processor's cache (4 views, 10^6 points, one thread on a loaded 2-core machine: 5.1 s in
#: one piece, 2.9 s in pieces of 131 072, 2.2 s of 32 768, 2.5 s of 8 192).
CHUNK_ROWS = 32_768


@dataclass(frozen=True)
class View:
    """A camera and the port it looks through (anything with ``trace(origin, directions,
    keep_interface_points)`` returning :class:`measure.WaterRays`)."""

    camera: Camera
    port: object

    def water_rays(self, uv: np.ndarray):
        """``(origins (N, 3), directions (N, 3), reason (N,))`` of pixels ``uv`` ``(N, 2)``:
        the rays in the water (NaN rows with their reason)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        directions, reason = self.camera.rays_with_reason(uv)
        water = self.port.trace(self.camera.center, directions, keep_interface_points=False)
        reason = np.where(reason == Reason.OK, water.reason, reason).astype(np.int8)
        bad = reason != Reason.OK
        origins, dirs = water.origins, water.directions
        if bad.any():
            origins, dirs = origins.copy(), dirs.copy()
            origins[bad] = np.nan
            dirs[bad] = np.nan
        return origins, dirs, reason


@dataclass(frozen=True)
class MultiViewTriangulation:
    """Result of :func:`triangulate_views`: ``points`` ``(N, 3)`` mm; ``gap`` ``(N,)`` the RMS
    distance of each point from its rays (mm); ``views`` ``(N,)`` how many views it was
    triangulated from; ``used`` ``(N, V)`` which; ``reason`` ``(N,)``."""

    points: np.ndarray
    gap: np.ndarray
    views: np.ndarray
    used: np.ndarray
    reason: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.reason == Reason.OK


def triangulate_views(views, pixels, workers: int | None = None) -> MultiViewTriangulation:
    """:func:`triangulate_rows` over pieces of :data:`CHUNK_ROWS` points on ``workers``
    threads (default one per CPU: NumPy's array arithmetic releases the GIL); the rows are
    independent, so the result does not depend on the pieces."""
    pixels = np.asarray(pixels, dtype=np.float64)
    n = pixels.shape[0] if pixels.ndim == 3 else 0
    if n <= CHUNK_ROWS:
        return triangulate_rows(views, pixels)
    views = list(views)
    out = MultiViewTriangulation(np.empty((n, 3)), np.empty(n), np.empty(n, np.int64),
                                 np.empty((n, len(views)), bool), np.empty(n, np.int8))
    starts = range(0, n, CHUNK_ROWS)

    def piece(start):
        part = triangulate_rows(views, pixels[start:start + CHUNK_ROWS])
        for name in ("points", "gap", "views", "used", "reason"):
            getattr(out, name)[start:start + CHUNK_ROWS] = getattr(part, name)

    workers = max(1, min(workers or os.cpu_count() or 1, len(starts)))
    if workers == 1:
        for start in starts:
            piece(start)
    else:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(piece, starts))
    return out


def triangulate_rows(views, pixels) -> MultiViewTriangulation:
    """The optical-path point of every target from its pixels in ``views`` (module docs).

    ``pixels`` ``(N, V, 2)``, one column per view in the order of ``views``; NaN where a view
    did not see the target. A view whose ray cannot be traced (it misses the port, total
    internal reflection, a distortion that cannot be inverted there) is left out of that
    point; a point with fewer than two rays left is NaN with ``TOO_FEW_VIEWS``; rays (nearly)
    parallel give ``PARALLEL_RAYS``; a point behind one of its rays' origins
    ``BEHIND_CAMERA``."""
    views = list(views)
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim != 3 or pixels.shape[1:] != (len(views), 2):
        raise ValueError(f"pixels must have shape (N, {len(views)}, 2) for {len(views)} views, "
                         f"got {pixels.shape}")
    n = pixels.shape[0]
    # the normal equations Σ (I − d dᵀ) X = Σ (I − d dᵀ) o, their six distinct entries and the
    # right-hand side accumulated as columns (no (N, 3, 3) arrays)
    a = np.zeros((6, n))  # xx, yy, zz, xy, xz, yz
    rhs = np.zeros((3, n))
    used = np.zeros((n, len(views)), bool)
    rays = []
    for v, view in enumerate(views):
        o, d, used[:, v] = _view_rays(view, pixels[:, v])
        _add_ray(a, rhs, o, d, used[:, v])
        rays.append((o, d))
    count = used.sum(axis=1)
    reason = np.full(n, Reason.OK, dtype=np.int8)
    reason[count < 2] = Reason.TOO_FEW_VIEWS
    points, parallel = _solve_normal_equations(a, rhs)
    reason[(reason == Reason.OK) & parallel] = Reason.PARALLEL_RAYS
    ok = reason == Reason.OK
    points[~ok] = np.nan
    squared, behind = _ray_residuals(np.where(ok, points.T, 0.0), rays, used)
    reason[ok & behind] = Reason.BEHIND_CAMERA
    ok = reason == Reason.OK
    with np.errstate(invalid="ignore", divide="ignore"):
        gap = np.sqrt(np.maximum(squared, 0.0) / np.maximum(count, 1))
    points[~ok] = np.nan
    gap[~ok] = np.nan
    return MultiViewTriangulation(points, gap, count, used, reason)


def _view_rays(view, pixels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(origins (3, N), directions (3, N), used (N,))``: the water rays of one view's
    ``pixels`` ``(N, 2)`` (NaN: not seen), as columns; the rows without a traced ray (not seen,
    or tracing failed) a zero ray, ``used`` False."""
    n = pixels.shape[0]
    seen = np.isfinite(pixels[:, 0]) & np.isfinite(pixels[:, 1])
    if seen.all():
        origins, dirs, reason = view.water_rays(pixels)
        used = reason == Reason.OK
    else:
        origins = np.full((n, 3), np.nan)
        dirs = np.full((n, 3), np.nan)
        used = np.zeros(n, bool)
        if seen.any():
            o, d, reason = view.water_rays(pixels[seen])
            origins[seen], dirs[seen] = o, d
            used[np.flatnonzero(seen)[reason == Reason.OK]] = True
    if used.all():  # every row: the rays as they are
        return origins.T, dirs.T, used
    return np.where(used, origins.T, 0.0), np.where(used, dirs.T, 0.0), used


def _add_ray(a, rhs, o, d, used) -> None:
    """Add one view's rays (columns ``o``, ``d``; rows not ``used`` zero rays of weight 0) to
    the normal equations' entries ``a`` (6, N) and right-hand side ``rhs`` (3, N), in place,
    column by column (each intermediate one column of the piece)."""
    weight = 1.0 if used.all() else used.astype(np.float64)
    along = d[0] * o[0]
    along += d[1] * o[1]
    along += d[2] * o[2]
    for j, (p, q) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
        a[j] -= d[p] * d[q]
    a[:3] += weight
    for j in range(3):
        rhs[j] += o[j]
        rhs[j] -= d[j] * along


def _solve_normal_equations(a, rhs) -> tuple[np.ndarray, np.ndarray]:
    """``(points (N, 3) mm, parallel (N,))``: the symmetric 3 × 3 systems solved by their
    adjugate; ``parallel`` where the determinant is below :data:`PARALLEL_LIMIT` × the
    trace's cube (rays nearly parallel, or none)."""
    xx, yy, zz, xy, xz, yz = a
    # the adjugate of the symmetric matrix, and its determinant
    c_xx, c_yy, c_zz = yy * zz - yz * yz, xx * zz - xz * xz, xx * yy - xy * xy
    c_xy, c_xz, c_yz = xz * yz - xy * zz, xy * yz - xz * yy, xy * xz - xx * yz
    det = xx * c_xx + xy * c_xy + xz * c_xz
    scale = (xx + yy + zz) / 3
    points = np.full((a.shape[1], 3), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        parallel = ~(det > PARALLEL_LIMIT * scale ** 3)
        bx, by, bz = rhs
        points[:, 0] = (c_xx * bx + c_xy * by + c_xz * bz) / det
        points[:, 1] = (c_xy * bx + c_yy * by + c_yz * bz) / det
        points[:, 2] = (c_xz * bx + c_yz * by + c_zz * bz) / det
    return points, parallel


def _ray_residuals(X, rays, used) -> tuple[np.ndarray, np.ndarray]:
    """``(squared (N,) mm², behind (N,))``: the sum over the used rays of each point's squared
    distance to the ray, and whether the point lies behind a used ray's origin; ``X`` (3, N)
    the points as columns (0 where none)."""
    n = X.shape[1]
    squared = np.zeros(n)
    behind = np.zeros(n, bool)
    for v, (o, d) in enumerate(rays):  # unused rows: zero rays, masked below
        offset = X - o
        along = d[0] * offset[0]
        along += d[1] * offset[1]
        along += d[2] * offset[2]
        behind |= used[:, v] & (along < 0)
        # |offset − along d|², not |offset|² − along²: that cancels
        square = np.zeros(n)
        for j in range(3):
            perpendicular = d[j] * along
            np.subtract(offset[j], perpendicular, out=perpendicular)
            perpendicular *= perpendicular
            square += perpendicular
        if used[:, v].all():
            squared += square
        else:
            squared += np.where(used[:, v], square, 0.0)
    return squared, behind


__all__ = ["CHUNK_ROWS", "MultiViewTriangulation", "PARALLEL_LIMIT", "View", "triangulate_rows",
           "triangulate_views"]
