"""Analytic speckle stereo pairs through a flat port (or a dome per camera), for testing and
benchmarking dense matching.

A surface (plane or cylinder) carries a band-limited speckle texture defined in surface
coordinates (mm). Each view is rendered by tracing every pixel's refracted ray
(``Camera.rays`` → :func:`measure.trace_through_port`, or
:func:`measure.geometry.dome.trace_through_dome` for a dome) to the surface and evaluating the
texture there, averaging ``supersample²`` sub-pixel rays per pixel (a box pixel footprint).
No Mitsuba: the images are exact up to the texture interpolation and the supersampling.

Units mm; reference frame = left camera frame; OpenCV pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from measure import Camera, FlatPort
from measure.geometry.dome import DomePort


@dataclass(frozen=True)
class SpeckleTexture:
    """Gaussian-filtered white noise on a grid over ``extent`` = (s0, s1, t0, t1) mm of
    surface coordinates; ``speckle_mm`` is about the blobs' diameter. Values ~ 0.5 ± 0.15
    (clipped to [0.02, 0.98])."""

    extent: tuple
    speckle_mm: float
    values: np.ndarray
    cell_mm: float

    @classmethod
    def random(cls, extent, speckle_mm: float, seed: int = 0) -> SpeckleTexture:
        cell = speckle_mm / 5.0
        s0, s1, t0, t1 = extent
        shape = (int(np.ceil((t1 - t0) / cell)) + 1, int(np.ceil((s1 - s0) / cell)) + 1)
        noise = np.random.default_rng(seed).standard_normal(shape).astype(np.float32)
        smooth = ndimage.gaussian_filter(noise, sigma=1.2, mode="wrap")
        smooth = 0.5 + 0.15 * smooth / smooth.std()
        return cls(tuple(float(v) for v in extent), float(speckle_mm),
                   np.clip(smooth, 0.02, 0.98), cell)

    def __call__(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Texture values at surface coordinates ``s, t`` (mm, same shape); cubic spline
        interpolation of the grid."""
        rows = (t - self.extent[2]) / self.cell_mm
        cols = (s - self.extent[0]) / self.cell_mm
        out = ndimage.map_coordinates(self.values, [rows.ravel(), cols.ravel()], order=3,
                                      mode="nearest", prefilter=False)
        return out.reshape(np.shape(s))


@dataclass(frozen=True)
class PlaneSurface:
    """The plane through ``point`` with unit ``normal`` (towards the cameras or away: either);
    surface coordinates along two in-plane axes."""

    point: np.ndarray
    normal: np.ndarray

    @classmethod
    def create(cls, point, normal) -> PlaneSurface:
        normal = np.asarray(normal, float)
        return cls(np.asarray(point, float), normal / np.linalg.norm(normal))

    def _axes(self):
        e1 = np.cross([0.0, 1.0, 0.0], self.normal)
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(self.normal, e1)

    def intersect(self, origins, directions):
        with np.errstate(invalid="ignore", divide="ignore"):
            h = ((self.point - origins) @ self.normal) / (directions @ self.normal)
        h = np.where(h > 0, h, np.nan)
        return origins + h[:, None] * directions

    def coordinates(self, points):
        e1, e2 = self._axes()
        rel = points - self.point
        return rel @ e1, rel @ e2

    def distance(self, points):
        """Unsigned distance of points ``(N, 3)`` to the surface (mm)."""
        return np.abs((points - self.point) @ self.normal)


@dataclass(frozen=True)
class CylinderSurface:
    """A cylinder of ``radius`` about the vertical axis (0, 1, 0) through ``axis_point``; the
    cameras see its near side (the first hit). Coordinates: arc length, height."""

    axis_point: np.ndarray
    radius: float

    @classmethod
    def create(cls, axis_point, radius) -> CylinderSurface:
        return cls(np.asarray(axis_point, float), float(radius))

    def intersect(self, origins, directions):
        o = origins - self.axis_point
        a = directions[:, 0] ** 2 + directions[:, 2] ** 2
        b = 2 * (o[..., 0] * directions[:, 0] + o[..., 2] * directions[:, 2])
        c = o[..., 0] ** 2 + o[..., 2] ** 2 - self.radius ** 2
        with np.errstate(invalid="ignore"):
            h = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)
        h = np.where(h > 0, h, np.nan)
        return origins + h[:, None] * directions

    def coordinates(self, points):
        rel = points - self.axis_point
        return self.radius * np.arctan2(rel[:, 0], -rel[:, 2]), rel[:, 1]

    def distance(self, points):
        rel = points - self.axis_point
        return np.abs(np.hypot(rel[:, 0], rel[:, 2]) - self.radius)


def surface_points(camera: Camera, port: FlatPort | DomePort, surface,
                   uv: np.ndarray) -> np.ndarray:
    """Where the refracted rays of pixels ``uv`` ``(N, 2)`` meet ``surface`` ``(N, 3)``
    (NaN where they miss); ``port`` a flat port or the camera's dome."""
    water = port.trace(camera.center, camera.rays(uv), keep_interface_points=False)
    return surface.intersect(water.origins, water.directions)


def render_view(camera: Camera, port: FlatPort | DomePort, surface, texture: SpeckleTexture,
                supersample: int = 4, background: float = 0.0, rows_per_chunk: int = 256):
    """The camera's float32 image of the textured surface: the mean texture over
    ``supersample × supersample`` sub-pixel rays per pixel; ``background`` where rays miss."""
    width, height = camera.size
    image = np.zeros((height, width), np.float32)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    us = np.arange(width, dtype=np.float64)
    for r0 in range(0, height, rows_per_chunk):
        vs = np.arange(r0, min(height, r0 + rows_per_chunk), dtype=np.float64)
        total = np.zeros((vs.size, width))
        for dv in offsets:
            for du in offsets:
                uu, vv = np.meshgrid(us + du, vs + dv)
                points = surface_points(camera, port, surface,
                                        np.stack([uu.ravel(), vv.ravel()], axis=1))
                s, t = surface.coordinates(points)
                value = texture(np.nan_to_num(s), np.nan_to_num(t))
                value[~np.isfinite(s)] = background
                total += value.reshape(vs.size, width)
        image[r0:r0 + vs.size] = total / supersample ** 2
    return image


def render_pair(rig, surface, texture, supersample: int = 4):
    """Left and right images of ``surface`` through ``rig.port`` (each camera's dome for a
    :class:`measure.geometry.dome.DomePair`)."""
    return (render_view(rig.left, rig.view_port(0), surface, texture, supersample),
            render_view(rig.right, rig.view_port(1), surface, texture, supersample))
