"""Scoring of a dense surface reconstruction against the true mesh (pure functions of arrays).

Units mm; reference frame = the left camera's (x right, y down, z forward into the water; the
camera centre is the origin); images ``(H, W)``, pixel ``(u, v)`` = (column, row); NaN = no value.

Inputs (:class:`SurfaceCase`): the true surface as a triangle mesh, and in the left image grid
the measured point of each pixel (NaN where the matcher gave nothing), the true point its
refracted ray meets (NaN where it misses), the overlap mask (pixels whose true point the right
camera also sees: the ones a stereo method can measure) and the port normal (depth = n · X).

Point-to-mesh distances: Open3D's ``RaycastingScene`` (float32) proposes the nearest triangle,
and the distance is computed in float64 to it and its edge neighbours (:func:`point_to_mesh`),
on coordinates shifted by the mean of the mesh vertices; ``distance_resolution_mm`` reports one
float64 ulp of the largest *centred* coordinate (1.1e-13 mm at 1 m), and the distances hold to a
few dozen of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

#: Distance thresholds τ (mm) of precision / recall / F-score.
THRESHOLDS_MM = (0.5, 1.0, 5.0)
#: Nearest-neighbour distances of the truth points to the measured cloud are searched up to this
#: (mm) and truncated there, and so are the measured→mesh distances in the Chamfer mean (a
#: truncated Chamfer distance). Without a bound, a cloud far from a dense truth sheet (the
#: pinhole baseline, ~250 mm off) makes every k-d tree query visit hundreds of thousands of
#: points: tens of minutes at full size.
NEAREST_TRUNCATION_MM = 50.0
#: A mesh whose vertices all lie within this distance (mm) of their least-squares plane is planar.
PLANAR_TOLERANCE_MM = 1e-6


@dataclass(frozen=True)
class SurfaceCase:
    """One scored reconstruction. ``mesh_vertices`` ``(V, 3)`` mm, ``mesh_triangles`` ``(T, 3)``
    int; ``measured_points`` and ``truth_points`` ``(H, W, 3)`` mm (NaN = none); ``overlap_mask``
    ``(H, W)`` bool; ``port_normal`` ``(3,)`` (normalized here; pointing into the water, a
    positive depth error means measured too deep). Arrays are converted and checked on creation."""

    mesh_vertices: np.ndarray
    mesh_triangles: np.ndarray
    measured_points: np.ndarray
    truth_points: np.ndarray
    overlap_mask: np.ndarray
    port_normal: np.ndarray

    def __post_init__(self):
        put = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731 (frozen)
        vertices = np.asarray(self.mesh_vertices, dtype=np.float64)
        triangles = np.asarray(self.mesh_triangles)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.isfinite(vertices).all():
            raise ValueError("mesh_vertices must be a finite (V, 3) array")
        if (triangles.ndim != 2 or triangles.shape[1] != 3 or len(triangles) == 0
                or not np.issubdtype(triangles.dtype, np.integer)
                or triangles.min() < 0 or triangles.max() >= len(vertices)):
            raise ValueError("mesh_triangles must be a non-empty (T, 3) int array of vertex indices")
        measured = np.asarray(self.measured_points, dtype=np.float64)
        truth = np.asarray(self.truth_points, dtype=np.float64)
        overlap = np.asarray(self.overlap_mask, dtype=bool)
        if measured.ndim != 3 or measured.shape[2] != 3:
            raise ValueError("measured_points must be an (H, W, 3) array")
        if truth.shape != measured.shape or overlap.shape != measured.shape[:2]:
            raise ValueError("truth_points must match measured_points (H, W, 3), overlap_mask (H, W)")
        normal = np.asarray(self.port_normal, dtype=np.float64).reshape(-1)
        if normal.shape != (3,) or not np.isfinite(normal).all() or np.linalg.norm(normal) == 0:
            raise ValueError("port_normal must be a finite non-zero 3-vector")
        for name, value in (("mesh_vertices", vertices), ("mesh_triangles", triangles.astype(np.int64)),
                            ("measured_points", measured), ("truth_points", truth),
                            ("overlap_mask", overlap), ("port_normal", normal / np.linalg.norm(normal))):
            put(name, value)

    @property
    def measured_mask(self) -> np.ndarray:
        """``(H, W)`` bool: pixels with a finite measured point."""
        return np.isfinite(self.measured_points).all(axis=2)

    @property
    def measured_valid(self) -> np.ndarray:
        """``(N, 3)`` mm: the finite measured points, in row-major pixel order."""
        return self.measured_points[self.measured_mask]


def closest_points_on_triangles(points, a, b, c) -> np.ndarray:
    """``(N, 3)``: the point of each triangle ``(a[i], b[i], c[i])`` nearest to ``points[i]``
    (all ``(N, 3)``, float64), by the Voronoi-region test of Ericson, *Real-Time Collision
    Detection* §5.1.5: a vertex, a point on an edge, or the projection on the face's plane.
    A degenerate (zero-area) triangle gives a point of an edge or, failing that, its nearest
    vertex."""
    ab, ac, ap = b - a, c - a, points - a
    bp, cp = points - b, points - c
    dot = lambda x, y: np.einsum("ij,ij->i", x, y)  # noqa: E731
    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        # the face: the projection on the plane (not a + v·ab + w·ac, whose barycentric weights
        # lose digits on sliver triangles — 1e-9 mm on a 1600 × 5.6 mm one)
        normal = np.cross(ab, ac)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        out = points - normal * dot(ap, normal)[:, None]
        # the regions, from the lowest priority to the highest (a later one overrides)
        bc_t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out = np.where(((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))[:, None],
                       b + (c - b) * bc_t[:, None], out)
        out = np.where(((vb <= 0) & (d2 >= 0) & (d6 <= 0))[:, None],
                       a + ac * (d2 / (d2 - d6))[:, None], out)
        out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
        out = np.where(((vc <= 0) & (d1 >= 0) & (d3 <= 0))[:, None],
                       a + ab * (d1 / (d1 - d3))[:, None], out)
        out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
        out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    if not np.isfinite(out).all():  # a degenerate triangle whose tests all failed: its vertices
        bad = ~np.isfinite(out).all(axis=1)
        corners = np.stack([a[bad], b[bad], c[bad]], axis=1)
        out[bad] = corners[np.arange(bad.sum()), np.argmin(
            np.linalg.norm(corners - points[bad, None], axis=2), axis=1)]
    return out


def _edge_neighbours(triangles: np.ndarray) -> np.ndarray:
    """``(T, 3)`` int: for each triangle, the triangle across each of its edges (itself where
    the edge is a border or is shared by more than two triangles)."""
    count = len(triangles)
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    owner = np.tile(np.arange(count), 3)
    slot = np.repeat(np.arange(3), count)
    edges = np.sort(edges, axis=1)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner, slot = edges[order], owner[order], slot[order]
    neighbours = np.tile(np.arange(count)[:, None], (1, 3))
    same = (edges[1:] == edges[:-1]).all(axis=1)
    # a pair only where exactly two triangles share the edge
    alone_before = np.concatenate([[True], ~same[:-1]])
    alone_after = np.concatenate([~same[1:], [True]])
    pair = same & alone_before & alone_after
    first, second = np.flatnonzero(pair), np.flatnonzero(pair) + 1
    neighbours[owner[first], slot[first]] = owner[second]
    neighbours[owner[second], slot[second]] = owner[first]
    return neighbours


def point_to_mesh(vertices, triangles, points, chunk: int = 200_000) -> tuple[np.ndarray, np.ndarray, float]:
    """Distances (mm) of ``points`` ``(N, 3)`` to the mesh: ``(unsigned, signed, resolution)``.

    Open3D's ``RaycastingScene.compute_closest_points`` (float32) proposes a triangle; the
    distance is then computed exactly in float64 (:func:`closest_points_on_triangles`) to that
    triangle and the triangles across its edges, moving to the nearest of them until none is
    nearer (a descent over the mesh). Open3D alone is not enough: on sliver triangles (a
    cylinder strip of 1600 × 5.6 mm triangles) its float32 search picks the wrong triangle of a
    quad and puts the foot point up to 1.2 mm away, for a point lying on the mesh.

    Signed: the unsigned distance times the sign of ``(p − closest) · n``, ``n`` the closest
    triangle's normal turned away from the camera centre (the origin) — positive = beyond the
    surface as seen from the left camera. (Not ``compute_signed_distance``: it needs a
    watertight mesh, ours are open sheets.) The sign is ill-defined where the view grazes the
    surface. ``resolution``: one float64 ulp of the largest coordinate after centring on the
    mean vertex (see the module docs).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    origin = vertices.mean(axis=0)
    centred = vertices - origin
    query = points - origin
    scale = max(np.abs(centred).max(), np.abs(query).max() if len(points) else 0)
    resolution = float(np.spacing(scale))
    if len(points) == 0:
        return np.zeros(0), np.zeros(0), resolution
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(centred.astype(np.float32)),
                        o3d.core.Tensor(triangles.astype(np.uint32)))
    neighbours = _edge_neighbours(triangles)
    unsigned = np.empty(len(points))
    foot = np.empty((len(points), 3))
    best = np.empty(len(points), dtype=np.int64)
    for start in range(0, len(points), chunk):
        part = query[start:start + chunk]
        ids = scene.compute_closest_points(o3d.core.Tensor(part.astype(np.float32)))[
            "primitive_ids"].numpy().astype(np.int64)
        near = closest_points_on_triangles(part, *np.moveaxis(centred[triangles[ids]], 1, 0))
        dist = np.linalg.norm(part - near, axis=1)
        moving = np.arange(len(part))
        while moving.size:  # the descent: each round, the nearest of the three neighbours
            candidates = neighbours[ids[moving]]  # (M, 3)
            corners = centred[triangles[candidates.reshape(-1)]]
            repeated = np.repeat(part[moving], 3, axis=0)
            trial = closest_points_on_triangles(repeated, *np.moveaxis(corners, 1, 0))
            trial_dist = np.linalg.norm(repeated - trial, axis=1).reshape(-1, 3)
            pick = np.argmin(trial_dist, axis=1)
            rows = np.arange(len(moving))
            better = trial_dist[rows, pick] < dist[moving]
            chosen = moving[better]
            ids[chosen] = candidates[rows[better], pick[better]]
            dist[chosen] = trial_dist[rows[better], pick[better]]
            near[chosen] = trial.reshape(-1, 3, 3)[rows[better], pick[better]]
            moving = chosen
        unsigned[start:start + chunk], foot[start:start + chunk] = dist, near
        best[start:start + chunk] = ids
    corners = centred[triangles[best]]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals *= np.where(np.einsum("ij,ij->i", normals, foot + origin) < 0, -1.0, 1.0)[:, None]
    signed = unsigned * np.sign(np.einsum("ij,ij->i", query - foot, normals))
    return unsigned, signed, resolution


def fit_plane(points) -> tuple[np.ndarray, float, np.ndarray]:
    """Least-squares plane of ``(N, 3)`` points (SVD of the centred points, every point counts):
    ``(unit normal, d, signed residuals)`` with ``n · X + d = residual`` (mm); the normal's sign is
    chosen with a positive z (towards the water)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    centroid = points.mean(axis=0)
    normal = np.linalg.svd(points - centroid, full_matrices=False)[2][-1]
    if normal[2] < 0 or (normal[2] == 0 and normal[np.argmax(np.abs(normal))] < 0):
        normal = -normal
    d = -float(normal @ centroid)
    return normal, d, points @ normal + d


def mesh_is_planar(vertices, tolerance_mm: float = PLANAR_TOLERANCE_MM) -> bool:
    """Whether every vertex lies within ``tolerance_mm`` of the vertices' least-squares plane."""
    return bool(np.abs(fit_plane(vertices)[2]).max() < tolerance_mm)


_REDUCERS = {"rms": lambda v: np.sqrt(np.mean(v ** 2)), "mean": np.mean, "std": np.std,
             "median": np.median, "p95": lambda v: np.percentile(v, 95), "max": np.max,
             "max_abs": lambda v: np.max(np.abs(v))}


def _stats(values: np.ndarray, prefix: str, names, count: bool = True) -> dict:
    """``{prefix}_count`` (if ``count``) and ``{prefix}_{name}_mm`` for each of ``names`` (keys
    of :data:`_REDUCERS`; NaN when ``values`` is empty)."""
    out = {f"{prefix}_count": int(values.size)} if count else {}
    for name in names:
        out[f"{prefix}_{name}_mm"] = float(_REDUCERS[name](values)) if values.size else float("nan")
    return out


def surface_arrays(case: SurfaceCase) -> dict:
    """The per-point and per-pixel arrays behind :func:`score_surface` (for figures and PLYs):
    ``measured`` ``(N, 3)``, ``distance`` / ``signed_distance`` ``(N,)`` point-to-mesh (mm, same
    order as ``measured``), ``truth_to_measured`` ``(M,)`` (mm, truth points at overlap pixels),
    ``depth_error`` / ``error_3d`` ``(H, W)`` (mm, NaN where either point is missing),
    ``resolution_mm``."""
    measured = case.measured_valid
    distance, signed, resolution = point_to_mesh(case.mesh_vertices, case.mesh_triangles, measured)
    truth = case.truth_points[case.overlap_mask]
    truth = truth[np.isfinite(truth).all(axis=1)]
    if len(truth) and len(measured):
        truth_to_measured = cKDTree(measured).query(
            truth, workers=-1, distance_upper_bound=NEAREST_TRUNCATION_MM)[0]
        truth_to_measured = np.minimum(truth_to_measured, NEAREST_TRUNCATION_MM)
    else:
        truth_to_measured = np.full(len(truth), NEAREST_TRUNCATION_MM)
    difference = case.measured_points - case.truth_points  # NaN where either is missing
    return {"measured": measured, "distance": distance, "signed_distance": signed,
            "truth_to_measured": truth_to_measured, "resolution_mm": resolution,
            "depth_error": difference @ case.port_normal,
            "error_3d": np.linalg.norm(difference, axis=2)}


def score_surface(case: SurfaceCase, thresholds=THRESHOLDS_MM, plane: bool | None = None,
                  arrays: dict | None = None) -> dict:
    """Scores of one reconstruction: a flat dict of ints, floats (NaN when undefined; the
    project's ``jsonable`` writes null) and one bool. All lengths mm. Keys:

    * coverage — ``overlap_pixels``, ``measured_pixels``, ``measured_fraction`` (share of overlap
      pixels with a measured point), ``measured_outside_overlap`` (pixels; should be ~0);
    * point-to-mesh of every measured point — ``p2m_count``, ``p2m_rms_mm``, ``p2m_mean_mm``,
      ``p2m_median_mm``, ``p2m_p95_mm`` (linear interpolation), ``p2m_max_mm``;
      ``p2m_signed_mean_mm`` / ``p2m_signed_std_mm`` (+ = beyond the surface seen from the left
      camera, see :func:`point_to_mesh`); ``distance_resolution_mm`` (one float64 ulp, module docs);
    * Tanks-and-Temples style, for each τ in ``thresholds`` (key part ``f"{τ:g}"``):
      ``precision_{τ}mm`` = share of measured points with point-to-mesh distance < τ,
      ``recall_{τ}mm`` = share of truth points (``truth_points`` at overlap pixels, ``truth_count``
      of them) within < τ of the measured cloud (nearest neighbour, scipy ``cKDTree``, float64),
      ``fscore_{τ}mm`` = 2PR / (P + R) (0 when both are 0);
    * ``mean_measured_to_mesh_mm``, ``mean_truth_to_measured_mm`` and ``chamfer_mm`` = their
      *average* (half the sum; ``cloud_metrics.cloud_distances`` reports the sum), every
      distance truncated at :data:`NEAREST_TRUNCATION_MM` (a truncated Chamfer distance);
    * per pixel where both points exist — ``depth_count``, ``depth_rms_mm``, ``depth_mean_mm``,
      ``depth_max_abs_mm`` of (measured − truth) · port_normal; ``error3d_rms_mm``,
      ``error3d_mean_mm``, ``error3d_max_mm`` of |measured − truth|: the measured point need not
      lie on the pixel's own ray (it does for a triangulator along the left ray), so this holds
      lateral error as well as depth; ``lateral_rms_mm`` = RMS of sqrt(|e|² − depth²);
    * ``planar``; for planes only (``plane=True``, or ``None`` and :func:`mesh_is_planar`):
      ``flatness_rms_mm`` and ``flatness_pv_mm`` (max − min) of the residuals of the measured
      points to their least-squares plane (every point counts, outliers too), and
      ``normal_angle_deg`` between that plane's normal and the mesh's ([0°, 90°]; for a forced
      ``plane=True`` on a curved mesh, the normal of its vertices' least-squares plane).

    ``arrays``: the output of :func:`surface_arrays` for this case, to avoid computing it twice.
    """
    arrays = surface_arrays(case) if arrays is None else arrays
    both = np.isfinite(arrays["depth_error"])
    return _scores(arrays["distance"], arrays["signed_distance"], arrays["truth_to_measured"],
                   arrays["resolution_mm"], arrays["depth_error"][both], arrays["error_3d"][both],
                   case.measured_mask, case.overlap_mask, arrays["measured"],
                   case.mesh_vertices, thresholds, plane)


def score_surface_cloud(vertices, triangles, points, pixels, truth_points, overlap_mask,
                        port_normal, thresholds=THRESHOLDS_MM, plane: bool | None = None) -> dict:
    """The scores of :func:`score_surface` for a reconstruction given as a point cloud rather
    than one point per left pixel. ``points`` ``(N, 3)`` mm (reference frame), ``pixels``
    ``(N, 2)`` the left image pixel ``(u, v)`` each point projects to (float, NaN where none;
    rounded to the nearest pixel here); ``truth_points`` ``(H, W, 3)``, ``overlap_mask``
    ``(H, W)`` and ``port_normal`` as in :class:`SurfaceCase`.

    Every point counts in the point-to-mesh, precision, recall, F-score and Chamfer metrics
    (as each pixel's point does for a depth map); the per-pixel metrics compare each point with
    the true point of the pixel it projects to (``depth_*``, ``error3d_*``, ``lateral_rms_mm``,
    over the points whose pixel has a true point); the coverage counts the pixels hit by at
    least one point (``measured_pixels``, ``measured_fraction`` of the overlap pixels,
    ``measured_outside_overlap``). Adds ``cloud_points`` (N)."""
    case = SurfaceCase(vertices, triangles, np.zeros((1, 1, 3)), np.zeros((1, 1, 3)),
                       np.ones((1, 1), bool), port_normal)  # checks the mesh and the normal
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not np.isfinite(points).all():
        raise ValueError("points must be finite")
    truth = np.asarray(truth_points, dtype=np.float64)
    overlap = np.asarray(overlap_mask, dtype=bool)
    h, w = overlap.shape
    if truth.shape != (h, w, 3):
        raise ValueError("truth_points must be (H, W, 3) with overlap_mask (H, W)")
    uv = np.rint(np.asarray(pixels, dtype=np.float64).reshape(-1, 2))
    inside = np.isfinite(uv).all(axis=1)
    inside[inside] &= ((uv[inside, 0] >= 0) & (uv[inside, 0] < w) & (uv[inside, 1] >= 0)
                       & (uv[inside, 1] < h))
    cols, rows = uv[inside, 0].astype(np.int64), uv[inside, 1].astype(np.int64)
    measured_mask = np.zeros((h, w), dtype=bool)
    measured_mask[rows, cols] = True
    distance, signed, resolution = point_to_mesh(case.mesh_vertices, case.mesh_triangles, points)
    truth_overlap = truth[overlap]
    truth_overlap = truth_overlap[np.isfinite(truth_overlap).all(axis=1)]
    if len(truth_overlap) and len(points):
        t_to_m = cKDTree(points).query(truth_overlap, workers=-1,
                                       distance_upper_bound=NEAREST_TRUNCATION_MM)[0]
        t_to_m = np.minimum(t_to_m, NEAREST_TRUNCATION_MM)
    else:
        t_to_m = np.full(len(truth_overlap), NEAREST_TRUNCATION_MM)
    difference = points[inside] - truth[rows, cols]
    known = np.isfinite(difference).all(axis=1)
    difference = difference[known]
    out = _scores(distance, signed, t_to_m, resolution, difference @ case.port_normal,
                  np.linalg.norm(difference, axis=1), measured_mask, overlap, points,
                  case.mesh_vertices, thresholds, plane)
    out["cloud_points"] = int(len(points))
    return out


def _scores(distance, signed, t_to_m, resolution, depth, error_3d, measured_mask, overlap,
            measured, vertices, thresholds, plane) -> dict:
    """The flat dict of :func:`score_surface` from per-point distances to the mesh
    (``distance``, ``signed``), the truncated truth-to-measured distances ``t_to_m``, per-point
    depth and 3D errors against the truth of their pixel, the coverage masks and the measured
    points ``(N, 3)``."""
    nan = float("nan")
    out = {"overlap_pixels": int(overlap.sum()), "measured_pixels": int(measured_mask.sum()),
           "measured_fraction": float((measured_mask & overlap).sum() / overlap.sum())
           if overlap.any() else nan,
           "measured_outside_overlap": int((measured_mask & ~overlap).sum())}
    out.update(_stats(distance, "p2m", ("rms", "mean", "median", "p95", "max")))
    out.update(_stats(signed, "p2m_signed", ("mean", "std"), count=False))
    out.update({"distance_resolution_mm": resolution, "truth_count": int(t_to_m.size)})
    for tau in thresholds:
        precision = float(np.mean(distance < tau)) if distance.size else nan
        recall = float(np.mean(t_to_m < tau)) if t_to_m.size else nan
        total = precision + recall
        out.update({f"precision_{tau:g}mm": precision, f"recall_{tau:g}mm": recall,
                    f"fscore_{tau:g}mm": 2 * precision * recall / total if total > 0 else
                    (0.0 if total == 0 else nan)})
    m_to_mesh = float(np.minimum(distance, NEAREST_TRUNCATION_MM).mean()) if distance.size else nan
    t_to_m_mean = float(t_to_m.mean()) if t_to_m.size else nan
    out.update({"mean_measured_to_mesh_mm": m_to_mesh, "mean_truth_to_measured_mm": t_to_m_mean,
                "chamfer_mm": 0.5 * (m_to_mesh + t_to_m_mean)})
    out.update(_stats(depth, "depth", ("rms", "mean", "max_abs")))
    out.update(_stats(error_3d, "error3d", ("rms", "mean", "max"), count=False))
    out.update(_stats(np.sqrt(np.maximum(error_3d ** 2 - depth ** 2, 0.0)), "lateral", ("rms",),
                      count=False))
    planar = mesh_is_planar(vertices) if plane is None else bool(plane)
    out["planar"] = planar
    if planar:
        out.update(plane_scores(measured, fit_plane(vertices)[0]))
    return out


def plane_scores(points, true_normal) -> dict:
    """``flatness_rms_mm``, ``flatness_pv_mm`` (mm) of ``(N, 3)`` points about their
    least-squares plane and ``normal_angle_deg`` to ``true_normal`` (NaN below 3 points)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) < 3:
        return {"flatness_rms_mm": float("nan"), "flatness_pv_mm": float("nan"),
                "normal_angle_deg": float("nan")}
    normal, _, residual = fit_plane(points)
    true_normal = np.asarray(true_normal, dtype=np.float64) / np.linalg.norm(true_normal)
    # the angle from the cross product's length: accurate near 0, unlike arccos of the dot
    sine, cosine = np.linalg.norm(np.cross(normal, true_normal)), abs(float(normal @ true_normal))
    return {"flatness_rms_mm": float(np.sqrt(np.mean(residual ** 2))),
            "flatness_pv_mm": float(residual.max() - residual.min()),
            "normal_angle_deg": float(np.degrees(np.arctan2(sine, cosine)))}


def surface_table(scores_by_method: dict, thresholds=THRESHOLDS_MM) -> str:
    """A fixed-width text table of :func:`score_surface` dicts, one row per method: measured %,
    point-to-mesh RMS / median / max (mm), F-score at each τ, depth RMS (mm), flatness RMS (mm,
    planes only; "-" where a value is missing or NaN)."""
    columns = [("method", None, "{}"), ("meas %", "measured_fraction", "{:.1f}"),
               ("RMS mm", "p2m_rms_mm", "{:.4f}"), ("med mm", "p2m_median_mm", "{:.4f}"),
               ("max mm", "p2m_max_mm", "{:.3f}")]
    columns += [(f"F@{tau:g}", f"fscore_{tau:g}mm", "{:.3f}") for tau in thresholds]
    columns += [("depth RMS", "depth_rms_mm", "{:.4f}"), ("flat RMS", "flatness_rms_mm", "{:.4f}")]
    rows = [[c[0] for c in columns]]
    for method, scores in scores_by_method.items():
        row = [str(method)]
        for _, key, form in columns[1:]:
            value = scores.get(key)
            if value is None or not np.isfinite(value):
                row.append("-")
            else:
                row.append(form.format(100 * value if key == "measured_fraction" else value))
        rows.append(row)
    widths = [max(len(r[i]) for r in rows) for i in range(len(columns))]
    lines = ["  ".join(cell.ljust(w) if i == 0 else cell.rjust(w)
                       for i, (cell, w) in enumerate(zip(row, widths))) for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(line.rstrip() for line in lines) + "\n"
