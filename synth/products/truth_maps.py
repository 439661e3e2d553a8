"""Per-pixel ground truth of a surface scene: where each pixel's refracted ray meets the mesh.

For every pixel centre of a view (OpenCV convention), the ray of the *model* — the camera's ray
(:meth:`measure.Camera.rays`, lens distortion removed exactly) traced through the port
(:func:`measure.geometry.refraction.trace_through_port`, float64) — is intersected with the scene's
triangle mesh. Mitsuba's ``ray_intersect_preliminary`` finds the first triangle hit (float32);
the intersection is then recomputed in float64 against that triangle's plane, so every truth
point lies on its pixel's float64 ray (its Fermat projection returns to the pixel centre to
~1e-9 px) and on the mesh the renderer sees (the PLY's float32 vertices) to float64 rounding.
This is independent of the renderer's sampling: no image is involved.

Maps (``(H, W)`` in the view's pixel grid, NaN where the ray misses the surface):

* ``points`` ``(H, W, 3)`` float64 mm, reference frame;
* ``depth`` ``(H, W)`` mm: ``N·X`` along the port normal ``N`` from the left camera centre;
* ``valid`` ``(H, W)`` bool: the ray meets the surface;
* ``overlap`` ``(H, W)`` bool: valid, and the point is seen by the *other* camera too — its
  Fermat projection lies inside the other image and the other camera's ray through that
  (sub-pixel) position meets the mesh first at the same point (within
  :data:`VISIBILITY_TOLERANCE_MM`; otherwise something occludes it). These are the pixels a
  stereo method can measure.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from measure import Camera, FlatPort
from measure.geometry.projection import project
from measure.geometry.refraction import trace_through_port
from synth.infra.images import imread

#: A point seen by the other camera is the first hit of that camera's ray within this, mm
#: (float32 hit search, float64 refinement: agreement is ~1e-9 mm; occluders are mm away).
VISIBILITY_TOLERANCE_MM = 1e-3
#: Rays per call to Mitsuba (bounded memory).
CHUNK_RAYS = 1 << 20


@dataclass(frozen=True)
class TruthMaps:
    """The truth maps of one view (see the module docstring)."""

    points: np.ndarray
    depth: np.ndarray
    valid: np.ndarray
    overlap: np.ndarray


class MeshTracer:
    """First hits of float64 rays on a triangle mesh (Mitsuba for the search, float64 for the
    point). ``vertices`` ``(V, 3)`` mm as the renderer sees them, ``triangles`` ``(T, 3)``."""

    def __init__(self, mesh_path: str, vertices: np.ndarray, triangles: np.ndarray):
        from synth.rendering.mitsuba_setup import import_mitsuba

        self.mi, _ = import_mitsuba()
        self.scene = self.mi.load_dict({"type": "scene",
                                        "surface": {"type": "ply", "filename": mesh_path}})
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)

    def first_hits(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Points ``(N, 3)`` where rays ``origin + s·direction`` (s > 0) first meet the mesh;
        NaN for rays that miss it or are NaN."""
        out = np.full(origins.shape, np.nan)
        for start in range(0, origins.shape[0], CHUNK_RAYS):
            rows = slice(start, start + CHUNK_RAYS)
            out[rows] = self._chunk(origins[rows], directions[rows])
        return out

    def first_triangles(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Index of the triangle each ray first meets, ``(N,)``; -1 where it misses."""
        out = np.full(origins.shape[0], -1, dtype=np.int64)
        for start in range(0, origins.shape[0], CHUNK_RAYS):
            rows = slice(start, start + CHUNK_RAYS)
            valid, prim = self._triangles(origins[rows], directions[rows])
            out[rows] = np.where(valid, prim, -1)
        return out

    def _triangles(self, origins, directions):
        mi = self.mi
        finite = np.all(np.isfinite(origins), axis=1) & np.all(np.isfinite(directions), axis=1)
        o = np.where(finite[:, None], origins, 0.0).astype(np.float32)
        d = np.where(finite[:, None], directions, [0.0, 0.0, 1.0]).astype(np.float32)
        ray = mi.Ray3f(mi.Point3f(o[:, 0], o[:, 1], o[:, 2]),
                       mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
        hit = self.scene.ray_intersect_preliminary(ray)
        return np.array(hit.is_valid(), dtype=bool) & finite, np.array(hit.prim_index,
                                                                        dtype=np.int64)

    def _chunk(self, origins, directions):
        valid, prim = self._triangles(origins, directions)
        points = np.full(origins.shape, np.nan)
        if not valid.any():
            return points
        o, d, tri = origins[valid], directions[valid], self.triangles[prim[valid]]
        v0 = self.vertices[tri[:, 0]]
        normal = np.cross(self.vertices[tri[:, 1]] - v0, self.vertices[tri[:, 2]] - v0)
        s = np.einsum("ij,ij->i", v0 - o, normal) / np.einsum("ij,ij->i", d, normal)
        points[valid] = o + s[:, None] * d
        return points


def pixel_grid(size, step: int = 1) -> np.ndarray:
    """Every ``step``-th pixel centre of an image of ``size`` = (W, H) in both directions, row
    by row: ``(N, 2)`` (u, v)."""
    w, h = size
    uu, vv = np.meshgrid(np.arange(0, w, step, dtype=np.float64),
                         np.arange(0, h, step, dtype=np.float64))
    return np.column_stack([uu.ravel(), vv.ravel()])


def hits_of_pixels(tracer: MeshTracer, camera: Camera, port: FlatPort, uv: np.ndarray) -> np.ndarray:
    """Where the refracted rays of pixels ``uv`` ``(N, 2)`` first meet the mesh, ``(N, 3)``."""
    water = trace_through_port(camera.center, camera.rays(uv), port, keep_interface_points=False)
    return tracer.first_hits(water.origins, water.directions)


def seen_by(tracer: MeshTracer, camera: Camera, port: FlatPort, points: np.ndarray) -> np.ndarray:
    """Whether each point ``(N, 3)`` (NaN: no) is inside ``camera``'s image and the first thing
    its ray there meets (see :data:`VISIBILITY_TOLERANCE_MM`)."""
    seen = np.zeros(points.shape[0], dtype=bool)
    finite = np.all(np.isfinite(points), axis=1)
    uv = project(camera, port, points[finite])
    inside = camera.in_image(uv)
    rows = np.flatnonzero(finite)[inside]
    if rows.size:
        first = hits_of_pixels(tracer, camera, port, uv[inside])
        with np.errstate(invalid="ignore"):
            seen[rows] = np.linalg.norm(first - points[rows], axis=1) <= VISIBILITY_TOLERANCE_MM
    return seen


def truth_maps(tracer: MeshTracer, camera: Camera, other: Camera, port: FlatPort) -> TruthMaps:
    """The truth maps of ``camera``'s view; ``other`` is the second camera of the pair."""
    w, h = camera.size
    points = hits_of_pixels(tracer, camera, port, pixel_grid(camera.size))
    valid = np.all(np.isfinite(points), axis=1)
    overlap = seen_by(tracer, other, port, points)
    return TruthMaps(points.reshape(h, w, 3), (points @ port.normal).reshape(h, w),
                     valid.reshape(h, w), overlap.reshape(h, w))


# ---------------------------------------------------------------------------------------------
# files of a dataset
# ---------------------------------------------------------------------------------------------
#: Files of the truth maps of one view in a dataset (``{view}`` is left or right).
TRUTH_FILES = {"points": "{view}_truth_points.npy", "depth": "{view}_truth_depth.npy",
               "valid": "{view}_truth_valid.png", "overlap": "{view}_truth_overlap.png"}
#: The mesh of a surface dataset (a copy of the scene's).
SURFACE_FILE = "surface.ply"


def write_truth_maps(directory: str, rig, mesh_path: str, vertices, triangles) -> dict:
    """Write both views' truth maps and a copy of the mesh into ``directory``; returns counts
    for the manifest. ``points`` float64 ``.npy`` (the exact truth), ``depth`` float32 ``.npy``
    (a convenience: ``N·X``), ``valid`` / ``overlap`` 8-bit PNG masks (255 = true)."""
    import shutil

    import cv2

    tracer = MeshTracer(mesh_path, vertices, triangles)
    counts = {}
    for view, camera, other in (("left", rig.left, rig.right), ("right", rig.right, rig.left)):
        maps = truth_maps(tracer, camera, other, rig.port)
        np.save(os.path.join(directory, TRUTH_FILES["points"].format(view=view)), maps.points)
        np.save(os.path.join(directory, TRUTH_FILES["depth"].format(view=view)),
                maps.depth.astype(np.float32))
        for name in ("valid", "overlap"):
            mask = getattr(maps, name).astype(np.uint8) * 255
            if not cv2.imwrite(os.path.join(directory, TRUTH_FILES[name].format(view=view)), mask):
                raise OSError(f"cannot write the {view} {name} mask")
        counts[view] = {"valid_pixels": int(maps.valid.sum()),
                        "overlap_pixels": int(maps.overlap.sum())}
    shutil.copyfile(mesh_path, os.path.join(directory, SURFACE_FILE))
    return counts


def read_truth_maps(directory: str, view: str, size) -> TruthMaps:
    """The truth maps of ``view`` (left or right) of a surface dataset; ValueError naming the
    file when one is missing or does not match the image ``size`` = (W, H)."""
    import cv2

    w, h = size
    arrays = {}
    for name, pattern in TRUTH_FILES.items():
        path = os.path.join(directory, pattern.format(view=view))
        if not os.path.isfile(path):
            raise ValueError(f"{path}: no such file (not a surface dataset?)")
        if path.endswith(".npy"):
            try:
                value = np.load(path, allow_pickle=False)
            except ValueError as exc:
                raise ValueError(f"{path}: not a NumPy array file ({exc})") from None
        else:
            value = imread(path, cv2.IMREAD_UNCHANGED)
            if value is None:
                raise ValueError(f"{path}: cannot read the mask")
            value = value > 0
        expected = (h, w, 3) if name == "points" else (h, w)
        if value.shape != expected:
            raise ValueError(f"{path}: shape {value.shape}, expected {expected}")
        arrays[name] = value
    valid_points = np.all(np.isfinite(arrays["points"]), axis=2)
    if not np.array_equal(valid_points, arrays["valid"]) or np.any(arrays["overlap"] & ~arrays["valid"]):
        raise ValueError(f"{directory}: the {view} truth maps disagree (finite points, valid and "
                         f"overlap masks): damaged or edited files")
    return TruthMaps(arrays["points"], arrays["depth"].astype(np.float64), arrays["valid"],
                     arrays["overlap"])


#: Bound of ``python -m synth check`` on a surface dataset: truth points project back to their
#: pixel centres through the Fermat solver within this, px.
TRUTH_ROUND_TRIP_PX = 1e-6


def check_truth_maps(dataset) -> dict:
    """Checks of a surface dataset (a :class:`synth.products.dataset.Dataset`): per view, the largest
    distance between a truth point's Fermat projection and its pixel centre (px), the valid and
    overlap pixel counts, and how many pixels the renderer lit where the truth says the ray
    misses the surface (outside the valid mask dilated by one pixel) and left black inside it
    (eroded by one pixel) — both 0 for a self-luminous surface in clear water."""
    import cv2

    report = {"bound_px": TRUTH_ROUND_TRIP_PX}
    kernel = np.ones((3, 3), np.uint8)
    for view, camera, image in (("left", dataset.rig.left, dataset.left),
                                ("right", dataset.rig.right, dataset.right)):
        maps = read_truth_maps(dataset.path, view, camera.size)
        rows, cols = np.nonzero(maps.valid)
        uv = project(camera, dataset.rig.port, maps.points[rows, cols])
        error = np.abs(uv - np.column_stack([cols, rows]))
        valid8 = maps.valid.astype(np.uint8)
        report[view] = {
            "valid_pixels": int(rows.size), "overlap_pixels": int(maps.overlap.sum()),
            "round_trip_max_px": float(error.max()) if rows.size else float("nan"),
            "lit_outside_surface": int(np.sum(image[cv2.dilate(valid8, kernel) == 0] > 0)),
            "black_on_surface": int(np.sum(image[cv2.erode(valid8, kernel) > 0] <= 0))}
    report["passed"] = all(report[v]["round_trip_max_px"] <= TRUTH_ROUND_TRIP_PX
                           for v in ("left", "right"))
    return report
