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


def facing_cameras(points) -> np.ndarray:
    """Unit normals ``(N, 3)`` of targets that face the cameras squarely: ``(0, 0, -1)``."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    return np.tile([0.0, 0.0, -1.0], (points.shape[0], 1))


def tilted_plane(z: float = 1000.0, tilt_deg=(0.0, 30.0)) -> tuple[np.ndarray, np.ndarray]:
    """The paper's 496 targets on a plane through ``(0, 0, z)`` tilted by ``tilt_deg`` =
    (about x, about y) degrees (first about y, then about x); ``(points, normals)``, mm.

    The normals are the plane's, pointing back towards the cameras (−z before the tilt).
    """
    from scipy.spatial.transform import Rotation

    ax, ay = np.radians(np.asarray(tilt_deg, dtype=float))
    rotation = Rotation.from_rotvec([ax, 0.0, 0.0]) * Rotation.from_rotvec([0.0, ay, 0.0])
    flat = paper_plane(0.0)
    points = rotation.apply(flat) + [0.0, 0.0, float(z)]
    normals = np.tile(rotation.apply([0.0, 0.0, -1.0]), (points.shape[0], 1))
    return points, normals


def cylinder(z: float = 1000.0, radius: float = 400.0, half_angle_deg: float = 60.0,
             height: float = 800.0, spacing: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """Targets on a vertical cylinder (axis parallel to y, convex towards the cameras, like a
    pipe seen from the side) whose nearest line is at depth ``z``; ``(points, normals)``, mm.

    Columns every ``spacing`` mm of arc length within ``±half_angle_deg`` of the line facing
    the cameras, rows every ``spacing`` mm over ``height``; normals point outwards (towards the
    cameras' side).
    """
    if not 0 < half_angle_deg < 90:
        raise ValueError(f"half_angle_deg must lie in (0, 90), got {half_angle_deg}")
    n_arc = int(np.floor(np.radians(half_angle_deg) * radius / spacing))
    theta = np.arange(-n_arc, n_arc + 1) * spacing / radius
    rows = np.arange(-np.floor(height / 2 / spacing), np.floor(height / 2 / spacing) + 1) * spacing
    tt, yy = np.meshgrid(theta, rows)
    tt, yy = tt.ravel(), yy.ravel()
    normals = np.column_stack([np.sin(tt), np.zeros_like(tt), -np.cos(tt)])
    axis_z = float(z) + radius
    points = np.column_stack([radius * np.sin(tt), yy, axis_z - radius * np.cos(tt)])
    return points, normals


def sphere_cap(z: float = 1000.0, radius: float = 400.0, half_angle_deg: float = 60.0,
               spacing: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """Targets on the cap of a sphere (convex towards the cameras) whose nearest point is at
    depth ``z``: rings every ``spacing`` mm of arc length around the point facing the cameras,
    up to ``half_angle_deg`` from it, each ring with as many targets as fit ``spacing`` apart;
    ``(points, normals)``, mm, normals outwards."""
    if not 0 < half_angle_deg < 90:
        raise ValueError(f"half_angle_deg must lie in (0, 90), got {half_angle_deg}")
    centre = np.array([0.0, 0.0, float(z) + radius])
    directions = [np.array([[0.0, 0.0, -1.0]])]
    for polar in np.arange(1, int(np.floor(np.radians(half_angle_deg) * radius / spacing)) + 1) \
            * spacing / radius:
        count = max(int(np.floor(2 * np.pi * radius * np.sin(polar) / spacing)), 1)
        azimuth = 2 * np.pi * np.arange(count) / count
        directions.append(np.column_stack([np.sin(polar) * np.cos(azimuth),
                                           np.sin(polar) * np.sin(azimuth),
                                           np.full(count, -np.cos(polar))]))
    normals = np.concatenate(directions)
    return centre + radius * normals, normals


def docking_frame(size: float = 1000.0, post: float = 100.0) -> np.ndarray:
    """A docking frame's 12 markers ``(12, 3)`` mm in its own frame (origin at its centre, z
    away from the cameras when it faces them): the corners and side midpoints of a square of
    side ``size`` in the plane z = 0, and four markers on posts ``post`` mm towards the cameras
    at ``(±size/5, ±size/5, −post)`` (``post = 0``: all in one plane)."""
    h, q = size / 2.0, size / 5.0
    rim = [(-h, -h), (0.0, -h), (h, -h), (h, 0.0), (h, h), (0.0, h), (-h, h), (-h, 0.0)]
    inner = [(-q, -q), (q, -q), (q, q), (-q, q)]
    return np.array([(x, y, 0.0) for x, y in rim] + [(x, y, -float(post)) for x, y in inner])
