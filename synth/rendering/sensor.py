"""One conversion between a :class:`measure.Camera` and Mitsuba's ``perspective`` sensor, and
its inverse (used to write scenes, to read them back and to build the renderer's pinhole
sensors).

Mitsuba's sensor looks along its local +z with x to the left and y up; OpenCV's camera has x to
the right and y down, so ``to_world = [R · diag(−1, −1, 1) | t]`` for the pose
``X_ref = R · X_cam + t``. Mitsuba's film pixel i covers [i, i + 1), OpenCV's pixel i is centred
on i, so a centred principal point is ``c = W/2 − 0.5``:
``f = (W/2) / tan(fov/2)`` (fov along x), ``cx = W/2 − 0.5 − ppx·W``, ``cy = H/2 − 0.5 − ppy·H``.
Mitsuba's sensor has square pixels and no skew.
"""

from __future__ import annotations

import math

import numpy as np

#: OpenCV camera axes → Mitsuba sensor axes.
MITSUBA_AXES = np.diag([-1.0, -1.0, 1.0])


def sensor_parameters(K, size, R, t) -> dict:
    """Mitsuba ``perspective`` properties of a camera with intrinsics ``K`` (px), film ``size``
    (w, h) and pose ``R``, ``t`` (camera-to-reference, mm): ``fov`` (degrees, along x),
    ``principal_point_offset_x/y`` (fractions of the film) and ``to_world`` (4 × 4)."""
    K = np.asarray(K, dtype=np.float64)
    w, h = size
    if abs(K[0, 0] - K[1, 1]) > 1e-9 * K[0, 0] or K[0, 1] != 0:
        raise ValueError(f"Mitsuba's perspective sensor needs square pixels and no skew "
                         f"(fx = fy, s = 0), got fx={K[0, 0]}, fy={K[1, 1]}, s={K[0, 1]}")
    to_world = np.eye(4)
    to_world[:3, :3] = np.asarray(R, dtype=np.float64) @ MITSUBA_AXES
    to_world[:3, 3] = t
    return {"fov": math.degrees(2.0 * math.atan(w / (2.0 * K[0, 0]))),
            "principal_point_offset_x": (w / 2.0 - 0.5 - K[0, 2]) / w,
            "principal_point_offset_y": (h / 2.0 - 0.5 - K[1, 2]) / h,
            "to_world": to_world}


def intrinsics_from_sensor(fov_deg: float, fov_axis: str, ppx: float, ppy: float,
                           size) -> np.ndarray:
    """The inverse of :func:`sensor_parameters` for the intrinsics: ``K`` (px)."""
    w, h = size
    extent = {"x": w, "y": h}[fov_axis]
    f = (extent / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[f, 0.0, w / 2.0 - 0.5 - ppx * w], [0.0, f, h / 2.0 - 0.5 - ppy * h],
                     [0.0, 0.0, 1.0]])


def pose_from_to_world(to_world) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`sensor_parameters` for the pose: ``(R, t)`` (R not yet checked)."""
    M = np.asarray(to_world, dtype=np.float64).reshape(4, 4)
    return M[:3, :3] @ MITSUBA_AXES, M[:3, 3].copy()
