"""Plane-sweep warps for dense stereo through a flat port or two domes: left pixel → right pixel
via a plane.

A depth plane is ``N · (X − C_left) = d`` (N the rig's :attr:`~measure.Rig.depth_axis`:
the port normal, or the left optical axis for domes; C_left the left camera centre, d in mm).
For one plane the warp map sends every left pixel along its water ray (``Camera.rays`` →
:meth:`~measure.Rig.trace`) to the plane and projects the point into the right camera
through its port (:func:`project`, the exact Fermat forward model). The map is smooth, so it is computed
exactly on a coarse grid of left pixels and interpolated to full resolution (``cv2.resize``,
bilinear: OpenCV's bicubic kernel (a = −0.75) does not even reproduce a linear ramp and misses
by ~0.07 px per grid step, bilinear's error falls as step² / f); ``model="pinhole"`` runs the
same code with straight rays and pinhole projection (the port ignored).

Units mm; reference frame = left camera frame; OpenCV pixels ``(u, v)``, integer = pixel centre.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..geometry.port import index_matched_port
from ..geometry.projection import project
from ..stereo.rig import Rig

MODELS = ("refractive", "pinhole")
#: Bilinear interpolation error of the warp map (px) is about ``WARP_CURVATURE · step² / f``
#: (f in px): measured on the paper's rig, max 0.0020 px at step 8, f = 1100 px, both models.
WARP_CURVATURE = 0.034
#: The largest interpolation error (px) the default grid step aims at (see :func:`grid_step_for`);
#: tests/measure/dense/test_dense.py measures the actual error against the exact map.
WARP_ERROR_BUDGET_PX = 0.002
#: Coarse nodes added beyond every image edge, so that interpolation never reaches a
#: replicated border value inside the image.
GRID_PAD_NODES = 2
#: Coarse nodes (about) on which :meth:`PlaneWarp.sweep_depths` measures the epipolar speed.
SPEED_SAMPLE_NODES = 4000


def grid_step_for(focal_px: float) -> int:
    """The coarse-grid spacing (px, 2 … 16) whose bilinear warp error stays within
    :data:`WARP_ERROR_BUDGET_PX` for a camera of focal length ``focal_px``."""
    step = math.floor(math.sqrt(WARP_ERROR_BUDGET_PX * focal_px / WARP_CURVATURE))
    return int(min(16, max(2, step)))


class PlaneWarp:
    """Left pixel → right pixel through depth planes, for ``model`` ``"refractive"`` (through
    ``rig.port``) or ``"pinhole"`` (straight rays, the port ignored)."""

    def __init__(self, rig: Rig, model: str = "refractive",
                 grid_step_px: int | None = None):
        if model not in MODELS:
            raise ValueError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
        self.rig = rig
        self.model = model
        self.normal = rig.depth_axis
        self.depth_origin = float(self.normal @ rig.left.center)
        self.projection_port = rig.view_port(1) if model == "refractive" else index_matched_port(
            self.normal, np.stack([rig.left.center, rig.right.center]))
        if grid_step_px is None:
            grid_step_px = grid_step_for(min(rig.left.K[0, 0], rig.left.K[1, 1]))
        self.grid_step = int(grid_step_px)
        width, height = rig.left.size
        step, pad = self.grid_step, GRID_PAD_NODES
        self.grid_shape = (math.ceil(height / step) + 2 * pad, math.ceil(width / step) + 2 * pad)
        us = np.arange(self.grid_shape[1]) * step + (step - 1) / 2 - pad * step
        vs = np.arange(self.grid_shape[0]) * step + (step - 1) / 2 - pad * step
        grid = np.stack(np.meshgrid(us, vs), axis=-1).reshape(-1, 2)
        self.grid_pixels = grid
        self.grid_origins, self.grid_directions = self.water_rays(grid)

    # --- exact geometry ---------------------------------------------------------------------
    def water_rays(self, uv_left: np.ndarray):
        """Rays of left pixels ``(N, 2)`` in the water (refractive) or in air (pinhole):
        origins and unit directions ``(N, 3)``, NaN where a ray has no path."""
        uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
        directions = self.rig.left.rays(uv_left)
        if self.model == "pinhole":
            return np.broadcast_to(self.rig.left.center, directions.shape), directions
        water = self.rig.trace(0, directions)
        return water.origins, water.directions

    def points_at_depth(self, origins, directions, depth):
        """Points ``(N, 3)`` where rays meet the planes ``N·(X − C_left) = depth`` (scalar or
        ``(N,)``, mm), and ``dX/d depth`` ``(N, 3)``."""
        with np.errstate(invalid="ignore", divide="ignore"):
            along = directions / (directions @ self.normal)[:, None]
            offset = np.asarray(depth, dtype=np.float64) + self.depth_origin - origins @ self.normal
            return origins + offset[..., None] * along, along

    def right_pixels(self, points, jacobian: bool = False):
        """Right-camera pixels ``(N, 2)`` of points ``(N, 3)`` (and ``d pixel / d point``)."""
        return project(self.rig.right, self.projection_port, points, jacobian=jacobian)

    def right_pixels_at_depth(self, origins, directions, depth):
        """Right pixels ``(N, 2)`` of the rays at ``depth`` and their derivative along the
        epipolar curve ``d pixel / d depth`` ``(N, 2)`` (px/mm)."""
        points, along = self.points_at_depth(origins, directions, depth)
        pixels, d_points = self.right_pixels(points, jacobian=True)
        return pixels, np.einsum("nij,nj->ni", d_points, along)

    # --- maps ---------------------------------------------------------------------------------
    def grid_right_pixels(self, depth: float) -> np.ndarray:
        """Exact right pixels of the coarse grid at one depth, ``(rows, cols, 2)``."""
        points, _ = self.points_at_depth(self.grid_origins, self.grid_directions, depth)
        return self.right_pixels(points).reshape(*self.grid_shape, 2)

    def right_map(self, depth: float):
        """Full-resolution warp map at one depth plane: ``(map_u, map_v)``, each ``(H, W)``
        float32 (the right pixel of every left pixel), for ``cv2.remap``."""
        full = self.right_map_rows(self.grid_right_pixels(depth), 0, self.rig.left.size[1])
        return np.ascontiguousarray(full[..., 0]), np.ascontiguousarray(full[..., 1])

    def right_map_rows(self, coarse: np.ndarray, lo: int, hi: int) -> np.ndarray:
        """Rows ``[lo, hi)`` of the full-resolution warp map interpolated from the coarse grid's
        right pixels ``coarse`` (:meth:`grid_right_pixels`): ``(hi − lo, W, 2)`` float32, a
        two-channel map for ``cv2.remap``. Only the coarse rows these rows need are resized (one
        more on each side, so the band's rows get the same weights as in the whole map)."""
        step, pad = self.grid_step, GRID_PAD_NODES
        rows, cols = self.grid_shape
        top, bottom = lo + pad * step, hi + pad * step  # rows of the padded fine grid
        first = max(top // step - 1, 0)
        last = min(-(-bottom // step) + 1, rows)
        fine = cv2.resize(np.asarray(coarse[first:last], dtype=np.float32),
                          (cols * step, (last - first) * step), interpolation=cv2.INTER_LINEAR)
        width = self.rig.left.size[0]
        return fine[top - first * step:bottom - first * step, pad * step:pad * step + width]

    def sweep_depths(self, near: float, far: float, step_px: float) -> np.ndarray:
        """Depth planes from ``near`` to ``far`` (mm), spaced so that no in-image left pixel's
        right pixel moves more than about ``step_px`` between consecutive planes."""
        inside = np.flatnonzero(self.rig.left.in_image(self.grid_pixels))
        inside = inside[::max(1, inside.size // SPEED_SAMPLE_NODES)]
        origins, directions = self.grid_origins[inside], self.grid_directions[inside]
        depths = [float(near)]
        while depths[-1] < far:
            _, rate = self.right_pixels_at_depth(origins, directions, depths[-1])
            speed = np.nanmax(np.hypot(rate[:, 0], rate[:, 1]))
            if not np.isfinite(speed) or speed <= 0:
                raise ValueError("no left pixel sees the depth range through the right camera")
            # the rate falls with depth: the next plane's step stays at most step_px
            depths.append(depths[-1] + step_px / speed)
        depths[-1] = float(far)
        return np.asarray(depths)
