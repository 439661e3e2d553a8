"""The truth a learner needs, per view and per pair, from the exact forward model through the
port — never from the renderer's samples.

Every pixel centre's ray (OpenCV pixels; :meth:`measure.Camera.rays`) is traced through its own
port in float64 (:meth:`measure.Rig.trace`: one flat port, a flat port per camera or a
dome per camera alike) and cut with the scene's mesh (Mitsuba finds the triangle, float64 finds
the point on its plane: :class:`synth.products.truth_maps.MeshTracer`). Frames and units:
millimetres, the reference frame (the left camera's, OpenCV axes) unless a name says otherwise.

Per view (:class:`ViewTruth`, ``(H, W)`` maps, NaN where the ray meets nothing): the 3D point,
the unit normal of the triangle hit (turned towards the camera), the depth ``z`` along that
camera's own optical axis, and the *range* — the distance from the camera's centre to the
point (the depth "along the ray" of a pinhole; behind a port the ray bends, so it is not the
length of the path).

Per pair, left → right (:func:`correspondence`): each left pixel's point projected into the right
camera by the Fermat forward model (:func:`measure.geometry.projection.project`) — the flow
``(u_r − u_l, v_r − v_l)`` — and whether the right camera sees it: inside its image and the first
thing its ray through that sub-pixel position meets (within
:data:`synth.products.truth_maps.VISIBILITY_TOLERANCE_MM`); otherwise the left pixel is
*occluded* (valid, not seen).

Rectified pair (:func:`rectified_truth`): the port-exact warp of :mod:`measure.stereo.rectify`
(exact on the plane ``depth_axis · X = distance``), and for every rectified left pixel ``q``: the
real left pixel it shows (float64), that pixel's point ``X``, where ``X`` lands on the rectified
right image (:func:`measure.stereo.rectify.rectified_pixels` of its Fermat right pixel) — the
disparity ``q_u − q'_u`` and the row error ``q_v − q'_v`` — and the warp's *residual*: the larger
of ``|q − P_L(X)|`` and ``|q' − P_R(X)|`` (px), ``P`` the virtual pinhole cameras. Where the
residual is 0 the rectified pair is a pinhole pair for that pixel (depth = f·B / disparity);
elsewhere the row error and the residual say by how much it is not.

A wide or converging rig close to the floor sees disparities of hundreds of pixels; the right
virtual camera's principal point may be moved to the right by a whole number of pixels
(:func:`disparity_offset`: the smallest pinhole disparity of the points given — what the left
camera sees — down to :data:`OFFSET_MARGIN_PX`; the rectified crop sees less of the floor, so
its smallest disparity is that or more), as Middlebury's ``doffs``: every disparity falls by
it, depth = f·B / (d + offset), and the rectified pair's ``calib.yaml`` holds the moved
principal point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from measure import Camera, StereoRig
from measure.geometry.projection import project
from measure.stereo.rectify import (Rectification, plane_points, rectified_pixels,
                                    virtual_pair)
from synth.products.truth_maps import VISIBILITY_TOLERANCE_MM, MeshTracer, pixel_grid

#: Rays per batch (bounded memory).
BATCH = 1 << 19
#: The smallest disparity (px) the rectified pair keeps after its offset (:func:`disparity_offset`).
OFFSET_MARGIN_PX = 16.0


@dataclass(frozen=True)
class ViewTruth:
    """One view's truth maps (module docs): ``points``, ``normals`` ``(H, W, 3)``; ``z``,
    ``range`` ``(H, W)`` mm; ``valid`` ``(H, W)`` bool."""

    points: np.ndarray
    normals: np.ndarray
    z: np.ndarray
    range: np.ndarray
    valid: np.ndarray


def hits_and_normals(tracer: MeshTracer, origins: np.ndarray, directions: np.ndarray):
    """First hits ``(N, 3)`` of rays on the mesh and the unit normals ``(N, 3)`` of the
    triangles hit, turned against the rays (NaN where a ray misses)."""
    points = np.full(origins.shape, np.nan)
    normals = np.full(origins.shape, np.nan)
    for start in range(0, origins.shape[0], BATCH):
        rows = slice(start, start + BATCH)
        o, d = origins[rows], directions[rows]
        tri = tracer.first_triangles(o, d)
        hit = tri >= 0
        if not hit.any():
            continue
        corners = tracer.vertices[tracer.triangles[tri[hit]]]
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        oh, dh = o[hit], d[hit]
        s = (np.einsum("ij,ij->i", corners[:, 0] - oh, normal)
             / np.einsum("ij,ij->i", dh, normal))
        facing = np.where(np.einsum("ij,ij->i", dh, normal) > 0, -1.0, 1.0)
        block_points = np.full(o.shape, np.nan)
        block_normals = np.full(o.shape, np.nan)
        block_points[hit] = oh + s[:, None] * dh
        block_normals[hit] = normal * facing[:, None]
        points[rows], normals[rows] = block_points, block_normals
    return points, normals


def pixel_hits(tracer: MeshTracer, rig, view: int, uv: np.ndarray):
    """Points and normals ``(N, 3)`` where the refracted rays of camera ``view``'s pixels
    ``uv`` ``(N, 2)`` first meet the mesh."""
    water = rig.trace(view, rig.cameras[view].rays(uv))
    return hits_and_normals(tracer, water.origins, water.directions)


def view_truth(tracer: MeshTracer, rig, view: int) -> ViewTruth:
    """The truth maps of camera ``view`` (0 left, 1 right) of ``rig``."""
    camera = rig.cameras[view]
    w, h = camera.size
    points, normals = pixel_hits(tracer, rig, view, pixel_grid(camera.size))
    valid = np.all(np.isfinite(points), axis=1)
    z = (points - camera.center) @ camera.R[:, 2]
    distance = np.linalg.norm(points - camera.center, axis=1)
    return ViewTruth(points.reshape(h, w, 3), normals.reshape(h, w, 3), z.reshape(h, w),
                     distance.reshape(h, w), valid.reshape(h, w))


def correspondence(tracer: MeshTracer, rig, points: np.ndarray, view: int = 1):
    """Where points ``(N, 3)`` (NaN: none) appear in camera ``view`` (Fermat, px ``(N, 2)``,
    NaN where no path) and whether that camera sees them (``(N,)`` bool: inside its image and
    the first hit of its ray there)."""
    camera = rig.cameras[view]
    uv = np.full((points.shape[0], 2), np.nan)
    seen = np.zeros(points.shape[0], dtype=bool)
    finite = np.flatnonzero(np.all(np.isfinite(points), axis=1))
    for start in range(0, finite.size, BATCH):
        rows = finite[start:start + BATCH]
        found = project(camera, rig.view_port(view), points[rows])
        uv[rows] = found
        inside = camera.in_image(found)
        if inside.any():
            first, _ = pixel_hits(tracer, rig, view, found[inside])
            with np.errstate(invalid="ignore"):
                near = np.linalg.norm(first - points[rows[inside]], axis=1)
            seen[rows[inside]] = near <= VISIBILITY_TOLERANCE_MM
    return uv, seen


def flow_truth(tracer: MeshTracer, rig, left: ViewTruth):
    """The left → right flow ``(H, W, 2)`` (px; NaN where the left pixel's point has no right
    pixel) and the masks ``seen`` (the right camera sees the point) and ``occluded`` (valid,
    not seen)."""
    h, w = left.valid.shape
    uv, seen = correspondence(tracer, rig, left.points.reshape(-1, 3), 1)
    flow = (uv - pixel_grid((w, h))).reshape(h, w, 2)
    seen = seen.reshape(h, w)
    return flow, seen, left.valid & ~seen


@dataclass(frozen=True)
class RectifiedTruth:
    """The rectified pair's truth (module docs), maps on the rectified grid ``(H, W)``:
    ``disparity`` and ``row_error`` (px; NaN where the left pixel shows nothing or the right
    camera does not see it), ``residual`` (px; NaN where the left pixel shows nothing),
    ``valid`` (the rectified left pixel shows the mesh), ``occluded`` (valid, not seen by the
    right camera), ``depth`` (the point's z along the virtual left camera's axis, mm) and
    ``right_depth`` (what each rectified right pixel shows, z along the virtual right camera)."""

    rectification: Rectification
    disparity: np.ndarray
    row_error: np.ndarray
    residual: np.ndarray
    valid: np.ndarray
    occluded: np.ndarray
    depth: np.ndarray
    right_depth: np.ndarray


def real_pixels(rig, virtual, view: int, uv: np.ndarray, distance: float) -> np.ndarray:
    """The real pixels ``(N, 2)`` of camera ``view`` that its rectified pixels ``uv`` show (the
    plane's point on each virtual ray, projected through the port; float64, NaN where none)."""
    points = plane_points(virtual.cameras[view], uv, rig.depth_axis, distance)
    return project(rig.cameras[view], rig.view_port(view), points)


def shifted_right(virtual, offset_px: float):
    """The virtual pair with the right camera's principal point moved ``offset_px`` to the
    right: every disparity ``u_left − u_right`` falls by ``offset_px`` (Middlebury's ``doffs``:
    depth = f·B / (d + doffs))."""
    right = virtual.right
    K = right.K.copy()
    K[0, 2] += float(offset_px)
    return StereoRig(virtual.left, Camera(K, right.size, R=right.R, t=right.t), virtual.port)


def disparity_offset(rig, points: np.ndarray, margin_px: float = OFFSET_MARGIN_PX) -> int:
    """The whole-pixel offset that brings the smallest disparity of ``points`` ``(N, 3)``
    (the virtual pinhole pair's, within the warp's residual of the truth) down to
    ``margin_px``; 0 when it is smaller already."""
    virtual = virtual_pair(rig)
    points = points[np.all(np.isfinite(points), axis=1)]
    if not points.size:
        return 0
    d = virtual.left.project(points)[:, 0] - virtual.right.project(points)[:, 0]
    d = d[np.isfinite(d)]
    return int(max(0.0, np.floor(d.min() - margin_px))) if d.size else 0


def rectification_of(rig, distance: float, offset_px: float = 0.0):
    """:func:`measure.stereo.rectify.rectify` with its maps from float64 real pixels (the right
    virtual camera shifted by ``offset_px``: :func:`shifted_right`), and those real pixels
    ``(W·H, 2)`` per view (row by row; NaN where none)."""
    virtual = shifted_right(virtual_pair(rig), offset_px)
    grid = pixel_grid(rig.left.size)
    w, h = rig.left.size
    maps, reals = [], []
    for view, camera in enumerate(rig.cameras):
        real = real_pixels(rig, virtual, view, grid, distance)
        reals.append(real)
        real = np.where(camera.in_image(real)[:, None], real, -1.0).astype(np.float32)
        maps.append((real[:, 0].reshape(h, w), real[:, 1].reshape(h, w)))
    return Rectification(rig, float(distance), virtual, tuple(maps)), reals


def rectified_truth_at(tracer: MeshTracer, rectification: Rectification, q: np.ndarray,
                       real: np.ndarray | None = None):
    """For rectified left pixels ``q`` ``(N, 2)``: ``(disparity, row_error, residual, seen,
    point, depth)`` (module docs; NaN where undefined). ``real``: the real left pixels they
    show, when known (:func:`real_pixels`)."""
    rig, virtual = rectification.rig, rectification.virtual
    if real is None:
        real = real_pixels(rig, virtual, 0, q, rectification.distance_mm)
    shows = rig.left.in_image(real)
    points = np.full((q.shape[0], 3), np.nan)
    if shows.any():
        points[shows] = pixel_hits(tracer, rig, 0, real[shows])[0]
    uv_right, seen = correspondence(tracer, rig, points, 1)
    q_right = np.full_like(q, np.nan)
    if seen.any():
        q_right[seen] = rectified_pixels(rectification, 1, uv_right[seen])
    ideal_left = virtual.left.project(points)
    ideal_right = virtual.right.project(points)
    residual = np.fmax(np.linalg.norm(q - ideal_left, axis=1),
                       np.where(seen, np.linalg.norm(q_right - ideal_right, axis=1), np.nan))
    depth = (points - virtual.left.center) @ virtual.left.R[:, 2]
    return q[:, 0] - q_right[:, 0], q[:, 1] - q_right[:, 1], residual, seen, points, depth


def rectified_truth(tracer: MeshTracer, rig, distance: float,
                    offset_px: float = 0.0) -> RectifiedTruth:
    """The rectified pair's truth maps at the warp plane ``distance`` mm, the right virtual
    camera shifted by ``offset_px`` (module docs)."""
    rectification, reals = rectification_of(rig, distance, offset_px)
    w, h = rig.left.size
    disparity, rows, residual, seen, points, depth = rectified_truth_at(
        tracer, rectification, pixel_grid((w, h)), reals[0])
    valid = np.all(np.isfinite(points), axis=1)
    shape = (h, w)
    right_depth = _right_depth(tracer, rectification, reals[1]).reshape(shape)
    return RectifiedTruth(rectification, disparity.reshape(shape), rows.reshape(shape),
                          residual.reshape(shape), valid.reshape(shape),
                          (valid & ~seen).reshape(shape), depth.reshape(shape), right_depth)


def _right_depth(tracer, rectification, real) -> np.ndarray:
    """z (mm) along the virtual right camera of the point each rectified right pixel shows
    (``real`` the real right pixels they show)."""
    rig, virtual = rectification.rig, rectification.virtual
    points = np.full((real.shape[0], 3), np.nan)
    shows = rig.right.in_image(real)
    points[shows] = pixel_hits(tracer, rig, 1, real[shows])[0]
    return (points - virtual.right.center) @ virtual.right.R[:, 2]


# ---------------------------------------------------------------------------------------------
# checks
# ---------------------------------------------------------------------------------------------
def sample_pixels(mask: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """Up to ``count`` distinct pixels ``(N, 2)`` (u, v) where ``mask`` ``(H, W)`` is true."""
    rows, cols = np.nonzero(mask)
    pick = rng.choice(rows.size, size=min(count, rows.size), replace=False)
    return np.column_stack([cols[pick], rows[pick]]).astype(np.float64)


def fermat_round_trip(rig, view: int, points: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Distances (px) between pixels ``uv`` ``(N, 2)`` and the Fermat projections of their
    truth points ``(N, 3)`` into camera ``view``."""
    return np.linalg.norm(project(rig.cameras[view], rig.view_port(view), points) - uv, axis=1)


def bilinear(image: np.ndarray, uv: np.ndarray):
    """``image`` ``(H, W)`` at sub-pixel ``uv`` ``(N, 2)`` (OpenCV pixels), bilinear, and the
    spread (max − min) of the four texels used; NaN outside or where a texel is NaN."""
    h, w = image.shape
    u0 = np.floor(uv[:, 0]).astype(np.int64)
    v0 = np.floor(uv[:, 1]).astype(np.int64)
    inside = (u0 >= 0) & (v0 >= 0) & (u0 < w - 1) & (v0 < h - 1)
    u0, v0 = np.where(inside, u0, 0), np.where(inside, v0, 0)
    a, b = uv[:, 0] - u0, uv[:, 1] - v0
    corners = np.stack([image[v0, u0], image[v0, u0 + 1], image[v0 + 1, u0],
                        image[v0 + 1, u0 + 1]], axis=1)
    value = ((1 - a) * (1 - b) * corners[:, 0] + a * (1 - b) * corners[:, 1]
             + (1 - a) * b * corners[:, 2] + a * b * corners[:, 3])
    spread = corners.max(axis=1) - corners.min(axis=1)
    return np.where(inside, value, np.nan), np.where(inside, spread, np.nan)


__all__ = ["BATCH", "OFFSET_MARGIN_PX", "RectifiedTruth", "ViewTruth", "bilinear",
           "correspondence", "disparity_offset", "fermat_round_trip", "flow_truth",
           "hits_and_normals", "pixel_hits", "real_pixels", "rectification_of",
           "rectified_truth", "rectified_truth_at", "sample_pixels", "shifted_right",
           "view_truth"]
