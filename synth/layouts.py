"""Target layouts (reference frame, mm): the paper's concentric circles, grids, random volumes."""

from __future__ import annotations

import numpy as np


def paper_plane(z: float = 1000.0, n_circles: int = 15, points_per_circle: int = 33,
                radius_step: float = 40.0) -> np.ndarray:
    """The paper's 496 targets (section 3.1) on the plane ``Z = z`` mm, shape ``(496, 3)``.

    Target 0 is the centre; then circle c = 1 … 15 of radius ``40·c`` mm with 33 points evenly
    spaced, the first at angle 0 (on +X), angles increasing from +X towards +Y.
    """
    angles = 2 * np.pi * np.arange(points_per_circle) / points_per_circle
    radii = radius_step * np.arange(1, n_circles + 1)
    x = (radii[:, None] * np.cos(angles)).ravel()
    y = (radii[:, None] * np.sin(angles)).ravel()
    points = np.column_stack([np.r_[0.0, x], np.r_[0.0, y], np.full(x.size + 1, float(z))])
    return points


def grid_plane(z: float = 1000.0, half_width: float = 500.0, spacing: float = 50.0) -> np.ndarray:
    """A square grid of targets on the plane ``Z = z``, centred on the Z axis, ``(N, 3)`` mm."""
    ticks = np.arange(-half_width, half_width + 0.5 * spacing, spacing)
    xx, yy = np.meshgrid(ticks, ticks)
    return np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, float(z))])


def random_volume(n: int, rng, z_range=(600.0, 2000.0), half_angle_deg: float = 35.0) -> np.ndarray:
    """``n`` random targets in a viewing cone around the Z axis between two depths, ``(n, 3)`` mm.

    ``rng`` is a ``numpy.random.Generator`` or a seed.
    """
    rng = np.random.default_rng(rng)
    z = rng.uniform(*z_range, size=n)
    radius = z * np.tan(np.deg2rad(half_angle_deg)) * np.sqrt(rng.uniform(size=n))
    angle = rng.uniform(0, 2 * np.pi, size=n)
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), z])
