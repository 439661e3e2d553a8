"""Objects on a generated sea floor: meshes the user gives (rocks, pipes, wrecks), set on the floor
of a sea scene (:mod:`synth.scene.sea_write`) at drawn places and headings.

An object file is a PLY or OBJ mesh in millimetres with ``z`` up (the seabed frame's
convention), read by Mitsuba's own loaders (:func:`synth.scene.surface_scene.read_user_mesh`).
Each scene with objects holds 0–:data:`MAX_OBJECTS` of them (the count, which object, where and
which way drawn from the scene's *objects* seed stream): an object's footprint is centred on a
point of the middle of the floor patch (within :data:`PLACEMENT_SHARE` of its half sides around
the point the rig looks at), turned about the vertical, and sunk into the floor by
:data:`SINK_SHARE` of its height below the floor's height there. Objects are merged into the
floor's mesh — what the renderer sees is what the truth traces — and textured from a strip of
:data:`STRIP_TEXELS` rows appended to the floor's texture: a ``1/f`` texture of a drawn mean
reflectance, mapped by the object's own ``x`` and ``y + z`` (so that its sides are textured too).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from synth.scene.seabed import fractal_noise

#: Most objects on one floor, the share of the patch's half sides they are placed within, the
#: share of their height sunk into the floor, and the texture strip's rows.
MAX_OBJECTS, PLACEMENT_SHARE, SINK_SHARE, STRIP_TEXELS = 3, 0.5, 0.1, 256
#: Largest object, mm (its largest side).
MAX_OBJECT_MM = 5000.0


@dataclass(frozen=True)
class SeaObject:
    """An object mesh: ``vertices`` ``(V, 3)`` mm in its own frame (``z`` up, its footprint
    centred on ``x = y = 0``, its lowest point at ``z = 0``), ``triangles`` ``(T, 3)``."""

    name: str
    vertices: np.ndarray
    triangles: np.ndarray


def read_object(path: str) -> SeaObject:
    """The object of a PLY or OBJ file (module docs); ValueError naming ``--object FILE``."""
    from synth.scene.surface_scene import read_user_mesh

    try:
        vertices, triangles = read_user_mesh(path)
    except ValueError as exc:
        raise ValueError(str(exc).replace("--mesh", "--object", 1)) from None
    if not np.all(np.isfinite(vertices)):
        raise ValueError(f"--object {path}: vertices that are not finite")
    size = vertices.max(axis=0) - vertices.min(axis=0)
    if not (0 < size.max() <= MAX_OBJECT_MM):
        raise ValueError(f"--object {path}: {size.max():g} mm across: an object is 0-"
                         f"{MAX_OBJECT_MM:g} mm (mm, z up)")
    lower, upper = vertices.min(axis=0), vertices.max(axis=0)
    centre = np.array([(lower[0] + upper[0]) / 2, (lower[1] + upper[1]) / 2, lower[2]])
    return SeaObject(os.path.basename(path), vertices - centre, triangles)


def _heights_at(x, y, heights, points_xy) -> np.ndarray:
    """The floor's height at ``points_xy`` ``(N, 2)`` (bilinear on the grid ``x``, ``y``)."""
    fx = np.clip(np.interp(points_xy[:, 0], x, np.arange(x.size)), 0, x.size - 1.000001)
    fy = np.clip(np.interp(points_xy[:, 1], y, np.arange(y.size)), 0, y.size - 1.000001)
    i, j = np.floor(fy).astype(int), np.floor(fx).astype(int)
    a, b = fx - j, fy - i
    return ((1 - a) * (1 - b) * heights[i, j] + a * (1 - b) * heights[i, j + 1]
            + (1 - a) * b * heights[i + 1, j] + a * b * heights[i + 1, j + 1])


def place_objects(rng, objects, x, y, heights, look_xy):
    """The objects of one floor (module docs): ``[(vertices (V, 3) in the seabed frame,
    triangles, what was drawn)]`` — none when ``objects`` is empty."""
    if not objects:
        return []
    placed = []
    half = np.array([x[-1] - x[0], y[-1] - y[0]]) / 2
    centre = np.clip(np.asarray(look_xy, float), [x[0], y[0]], [x[-1], y[-1]])
    for _ in range(int(rng.integers(0, MAX_OBJECTS + 1))):
        item = objects[int(rng.integers(len(objects)))]
        heading = rng.uniform(0.0, 2 * np.pi)
        at = centre + rng.uniform(-PLACEMENT_SHARE, PLACEMENT_SHARE, 2) * half
        c, s = np.cos(heading), np.sin(heading)
        turned = item.vertices @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]).T
        footprint = turned[:, :2] + at
        floor = float(np.min(_heights_at(x, y, heights, footprint)))
        height = float(item.vertices[:, 2].max())
        vertices = turned + np.r_[at, floor - SINK_SHARE * height]
        placed.append((vertices, item.triangles, {
            "object": item.name, "at_mm": at.tolist(), "heading_deg": float(np.degrees(heading)),
            "sunk_mm": SINK_SHARE * height}))
    return placed


def object_uv(vertices_local: np.ndarray, lower_mm, width_mm: float, strip_mm: float):
    """Texture coordinates (mm of texture) of an object's vertices in the strip that starts at
    ``lower_mm`` (2-vector) and is ``width_mm`` × ``strip_mm``: ``x`` across, ``y + z`` along,
    each scaled to the strip with a 5 % margin."""
    a = vertices_local[:, 0]
    b = vertices_local[:, 1] + vertices_local[:, 2]
    span = max(float(np.ptp(a)), float(np.ptp(b)), 1e-9)  # one scale: no stretch
    u = 0.05 + 0.9 * (a - a.min()) / span
    v = 0.05 + 0.9 * (b - b.min()) / span
    return np.column_stack([lower_mm[0] + u * width_mm, lower_mm[1] + v * strip_mm])


def object_strip(rng, width: int) -> tuple[np.ndarray, float]:
    """The objects' texture strip ``(STRIP_TEXELS, width)`` (reflectance) and its mean."""
    mean = float(rng.uniform(0.12, 0.5))
    strip = mean * np.exp(0.3 * fractal_noise((STRIP_TEXELS, width), 2.0, rng))
    return np.clip(strip, 0.02, 0.95), mean


__all__ = ["MAX_OBJECTS", "SeaObject", "object_strip", "object_uv", "place_objects",
           "read_object"]
