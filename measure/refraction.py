"""Ray tracing through a flat port: the vector form of Snell's law (paper equations 3-10).

All arrays are vectorized over N rays: points and directions ``(N, 3)`` in the reference frame
(mm); directions are unit vectors. Rows with no answer are NaN with a :class:`Reason` code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .port import FlatPort
from .reasons import Reason


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of ``(N, 3)`` arrays (or an ``(N, 3)`` array and a 3-vector)."""
    if b.ndim == 1:
        return a @ b
    return np.einsum("ij,ij->i", a, b)


def refract(directions: np.ndarray, normal: np.ndarray, n_from: float, n_to: float):
    """Refract unit ``directions (N, 3)`` at a plane with unit ``normal`` (along propagation).

    The paper's equation 7: ``ζ2 = (n1/n2) ζ1 − ((n1/n2) cos α1 − cos α2) N`` with
    ``cos α1 = ζ1·N`` and Snell's law ``n1 sin α1 = n2 sin α2``. Returns the refracted unit
    directions ``(N, 3)`` and a boolean mask of rows with total internal reflection (NaN rows).
    """
    eta = n_from / n_to
    cos_in = directions @ normal
    sin2_out = eta * eta * (1.0 - cos_in * cos_in)
    tir = sin2_out > 1.0
    cos_out = np.sqrt(np.where(tir, np.nan, 1.0 - sin2_out))
    out = eta * directions - ((eta * cos_in - cos_out)[:, None]) * normal
    return out, tir


def intersect_plane(origins: np.ndarray, directions: np.ndarray, normal: np.ndarray,
                    offset: float):
    """Intersect rays with the plane ``normal · X = offset`` (the paper's equation 4).

    Returns the points ``(N, 3)`` and the ray parameters ``h (N,)``; rows where the ray runs
    parallel to the plane or away from it (``h <= 0``) are NaN.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        h = (offset - origins @ normal) / (directions @ normal)
    h = np.where(h > 0, h, np.nan)
    return origins + h[:, None] * directions, h


@dataclass(frozen=True)
class WaterRays:
    """Rays in the last medium: they start on the port's last interface.

    ``origins`` and ``directions`` are ``(N, 3)`` (mm, reference frame, unit directions);
    ``interface_points`` is ``(K, N, 3)``, the refraction points on each interface (A1, A2 …);
    ``reason`` ``(N,)`` holds :class:`Reason` codes (``OK`` where the ray reached the water).
    """

    origins: np.ndarray
    directions: np.ndarray
    interface_points: np.ndarray
    reason: np.ndarray


def trace_through_port(origins: np.ndarray, directions: np.ndarray, port: FlatPort) -> WaterRays:
    """Trace rays from the camera side through every interface of ``port`` into the water.

    ``origins`` may be ``(N, 3)`` or a single 3-vector (a camera centre). At each interface the
    ray is intersected with the plane (equation 4) and refracted (equations 5-7, 9-10).
    """
    directions = np.asarray(directions, dtype=np.float64)
    n_rays = directions.shape[0]
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), (n_rays, 3))
    reason = np.full(n_rays, Reason.OK, dtype=np.int8)
    reason[~np.all(np.isfinite(directions), axis=1)] = Reason.INVALID_INPUT
    normal = port.normal
    points = np.empty((port.n_interfaces, n_rays, 3))
    position, direction = origins, directions
    for k, offset in enumerate(port.offsets):
        position, h = intersect_plane(position, direction, normal, offset)
        reason[(reason == Reason.OK) & np.isnan(h)] = Reason.MISSES_PORT
        points[k] = position
        direction, tir = refract(direction, normal, port.indices[k], port.indices[k + 1])
        reason[(reason == Reason.OK) & tir] = Reason.TOTAL_INTERNAL_REFLECTION
    bad = reason != Reason.OK
    if bad.any():
        position = np.where(bad[:, None], np.nan, position)
        direction = np.where(bad[:, None], np.nan, direction)
    return WaterRays(position, direction, points, reason)
