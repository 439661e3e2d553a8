"""Stereo triangulation through a flat port: the paper's optical-path model and its baselines.

* ``optical_path`` — Li et al. 2024, section 2.1: back-project each pixel, refract at every
  interface, take the midpoint of the common perpendicular of the two water rays.
* ``su`` — Su et al. 2021 as Li et al. describe it: regular triangulation gives a virtual point Q;
  the rays from each optical centre through Q are traced through the port; midpoint of the common
  perpendicular of the two water rays. Exact only where the camera rays intersect.
* ``regular`` — pinhole triangulation that ignores the port (exact in an all-air scene).
* ``reprojection`` — the point whose images through the port (the exact forward model) are
  nearest the two pixels (least squares from the optical-path point; ``gap`` is the optical-path
  gap of the pixels). Statistically optimal for Gaussian pixel noise; slower.

Every method also takes a rig of two domes (``port`` a :class:`measure.geometry.dome.DomePair`): the
rays are traced through each camera's own dome (:meth:`measure.stereo.rig.Rig.trace`); ``regular`` is exact
there when each camera sits at its dome's centre (no ray through the centre is bent).

Frames and units: reference frame = left camera frame (OpenCV axes), millimetres, pixels in the
OpenCV convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera
from ..geometry.lines import common_perpendicular
from ..geometry.port import FlatPort
from ..batching import map_row_chunks
from ..reasons import Reason
from .reprojection import reprojection_points
from .rig import Rig, StereoRig  # noqa: F401  (StereoRig: its former home)

METHODS = ("optical_path", "su", "regular", "reprojection")


@dataclass(frozen=True)
class Triangulation:
    """Result of :func:`triangulate`.

    ``points`` ``(N, 3)`` in the reference frame (mm); ``gap`` ``(N,)`` the length of the common
    perpendicular of the two final rays (mm); ``reason`` ``(N,)`` :class:`Reason` codes, NaN rows
    where not ``OK``; ``method`` the method's name.
    """

    points: np.ndarray
    gap: np.ndarray
    reason: np.ndarray
    method: str

    @property
    def valid(self) -> np.ndarray:
        return self.reason == Reason.OK


def _check_pixels(uv, name: str) -> np.ndarray:
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim == 1 and uv.shape == (2,):
        uv = uv[None]
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {uv.shape}")
    return uv


def _midpoint(origins1, dirs1, origins2, dirs2, reason):
    """Common-perpendicular midpoint; points with a negative ray parameter are behind a ray start."""
    perp = common_perpendicular(origins1, dirs1, origins2, dirs2)
    with np.errstate(invalid="ignore"):
        reason[(reason == Reason.OK) & np.isnan(perp.s1)] = Reason.PARALLEL_RAYS
        reason[(reason == Reason.OK) & ((perp.s1 < 0) | (perp.s2 < 0))] = Reason.BEHIND_CAMERA
    return perp


def _finish(perp, reason, method) -> Triangulation:
    bad = reason != Reason.OK
    points, gap = perp.midpoint, perp.length
    if bad.any():
        points[bad] = np.nan
        gap[bad] = np.nan
    return Triangulation(points, gap, reason, method)


def triangulate_rays(rig: Rig, rays_left: np.ndarray, rays_right: np.ndarray,
                     method: str = "optical_path") -> Triangulation:
    """Triangulate from unit camera rays ``(N, 3)`` (reference frame) instead of pixels."""
    if method not in METHODS or method == "reprojection":
        raise ValueError(f"method must be one of {', '.join(METHODS[:3])} for rays, got {method!r}")
    rays_left = np.asarray(rays_left, dtype=np.float64).reshape(-1, 3)
    rays_right = np.asarray(rays_right, dtype=np.float64).reshape(-1, 3)
    if rays_left.shape != rays_right.shape:
        raise ValueError(f"rays_left and rays_right must have the same shape, got "
                         f"{rays_left.shape} and {rays_right.shape}")
    if rays_left.shape[0] == 0:
        return Triangulation(np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int8), method)
    o_left, o_right = rig.left.center, rig.right.center
    reason = np.full(rays_left.shape[0], Reason.OK, dtype=np.int8)
    # A NaN or infinite component anywhere in a row makes the row's sum non-finite.
    invalid = ~np.isfinite(rays_left[:, 0] + rays_left[:, 1] + rays_left[:, 2]
                           + rays_right[:, 0] + rays_right[:, 1] + rays_right[:, 2])
    reason[invalid] = Reason.INVALID_INPUT
    if method == "regular":
        perp = _midpoint(o_left, rays_left, o_right, rays_right, reason)
        return _finish(perp, reason, method)
    if method == "su":
        virtual = _midpoint(o_left, rays_left, o_right, rays_right, reason).midpoint
        rays_left = virtual - o_left
        rays_left /= np.linalg.norm(rays_left, axis=1, keepdims=True)
        rays_right = virtual - o_right
        rays_right /= np.linalg.norm(rays_right, axis=1, keepdims=True)
    water_left = rig.trace(0, rays_left)
    water_right = rig.trace(1, rays_right)
    for water in (water_left, water_right):
        reason[reason == Reason.OK] = water.reason[reason == Reason.OK]
    perp = _midpoint(water_left.origins, water_left.directions,
                     water_right.origins, water_right.directions, reason)
    return _finish(perp, reason, method)


def _port_basis(normal):
    """Rows N, e1, e2: an orthonormal basis of the reference frame with the port normal first."""
    nx, ny, nz = (float(v) for v in normal)
    e1 = np.array([0.0, nz, -ny]) if abs(nx) < 0.9 else np.array([-nz, 0.0, nx])
    e1 /= np.sqrt(e1 @ e1)
    e2 = np.array([ny * e1[2] - nz * e1[1], nz * e1[0] - nx * e1[2], nx * e1[1] - ny * e1[0]])
    return np.stack([np.asarray(normal, dtype=float), e1, e2])


def _combine(terms, out=None):
    """``Σ array · coefficient`` over ``(array, coefficient)`` terms (``None``: a constant),
    skipping exact zero coefficients; into ``out`` if given (then at least one array term)."""
    total = None
    constant = 0.0
    for array, coefficient in terms:
        if coefficient == 0.0:
            continue
        if array is None:
            constant += coefficient
        elif total is None:
            total = np.multiply(array, coefficient, out=out)
        else:
            total += array * coefficient
    if total is None:
        if out is not None:
            out[...] = constant
            return out
        return constant
    if constant:
        total += constant
    return total


def _water_line(camera: Camera, port: FlatPort, basis, uv):
    """The water ray of pixels ``uv`` ``(N, 2)`` through ``port``, in the port basis (N, e1,
    e2): its origin on the last interface (3 columns; the normal one is the interface's offset,
    a float, the same for every camera), its direction (3 columns, unnormalized) and its
    squared length, the normal component ``w_n`` of the camera ray (> 0 where it reaches the
    port) and the camera's reason codes.

    The camera ray is ``w = B R (x, y, 1)`` (normalized image coordinates, not normalized;
    without lens distortion ``(x, y, 1) = K⁻¹ (u, v, 1)``, so each component is one linear
    function of the pixel); with ``ρ = |w|²`` and ``η_k = n_0/n_k`` the direction in medium k is
    ``(c_k, η_k w1, η_k w2)`` with ``c_k = sqrt(ρ − η_k² t²)`` (Snell's law, equation 7 in
    closed form for parallel interfaces), i.e. ``(A_k, w1, w2)`` times η_k with ``A_k = c_k /
    η_k = sqrt(μ_k w_n² + (μ_k − 1) t²)``, ``μ_k = 1/η_k²``; the ray advances ``Δh_k / A_k``
    times ``(w1, w2)`` across medium k. The water direction returned is ``(A_w, w1, w2)``."""
    M = basis @ camera.R
    if camera.dist is None:
        (fx, skew, cx), (fy, cy) = camera.K[0], camera.K[1, 1:]
        inverse_k = np.array([[1.0 / fx, -skew / (fx * fy), (skew * cy - cx * fy) / (fx * fy)],
                              [0.0, 1.0 / fy, -cy / fy], [0.0, 0.0, 1.0]])
        M = M @ inverse_k
        u, v = uv[:, 0], uv[:, 1]
        reason = None
    else:
        xy, reason = camera.normalized_with_reason(uv)
        u, v = xy[:, 0], xy[:, 1]
    w_n, w1, w2 = (_combine([(u, M[j, 0]), (v, M[j, 1]), (None, M[j, 2])]) for j in range(3))
    t2 = w1 * w1
    t2 += w2 * w2
    normal2 = w_n * w_n
    indices = port.indices
    heights = [port.distance - float(camera.center @ port.normal), *port.thicknesses]
    advance = heights[0] / w_n
    along = square = None
    for n_k, h in zip(indices[1:], heights[1:] + [None]):
        mu = (n_k / indices[0]) ** 2
        square = (mu - 1.0) * t2
        square += mu * normal2  # A_k²
        along = np.sqrt(square)
        if h is not None:
            advance = advance + h / along
    center = basis @ camera.center
    origin = (port.distance + sum(port.thicknesses), center[1] + advance * w1,
              center[2] + advance * w2)
    square += t2  # |(A_w, w1, w2)|²
    return origin, (along, w1, w2), square, w_n, reason


def _optical_path_rows(rig: Rig, uv_left, uv_right, out=None):
    """The optical-path triangulation of pixel rows, column by column in the port basis (the
    same equations as :func:`triangulate_rays`, fused: both water rays start on the last
    interface, so their difference has no normal component; the gap is ``|w·(d1×d2)| /
    |d1×d2|``); rows that are not plainly valid (a camera reason, a ray that misses the port or
    is reflected, parallel rays, a point behind a ray start) are recomputed by
    :func:`triangulate_rays` for their reason codes. Returns points, gap and reason codes; into
    ``out`` (those three arrays) if given."""
    basis = _port_basis(rig.port.normal)
    n_rows = uv_left.shape[0]
    if out is None:
        out = (np.empty((n_rows, 3)), np.empty(n_rows), np.empty(n_rows, dtype=np.int8))
    points, length, reason = out
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        line1 = _water_line(rig.left, rig.port, basis, uv_left)
        line2 = _water_line(rig.right, rig.port, basis, uv_right)
        h1, h2, determinant = _fused_midpoints(basis, line1[:3], line2[:3], points, length)
        good = _rows_not_plain(line1, line2, h1, h2, determinant, length)
    reason[...] = Reason.OK
    if good is not None and not good.all():
        bad = np.flatnonzero(~good)
        slow_points, slow_gap, slow_reason = _triangulate_pixels(rig, uv_left[bad], uv_right[bad],
                                                                 "optical_path")
        points[bad], length[bad], reason[bad] = slow_points, slow_gap, slow_reason
    return points, length, reason


def _fused_midpoints(basis, line1, line2, points, length):
    """The midpoints of the two water lines' common perpendicular into ``points`` (mm, world
    frame) and its length into ``length`` (mm); each line ``(origin, direction, |d|²)`` in
    the port basis (:func:`_water_line`). Returns ``(s1 / 2, s2 / 2, |d1 × d2|²)``."""
    (offset, o11, o12), (A1, u1, v1), a = line1
    (_, o21, o22), (A2, u2, v2), c = line2
    w1 = o11 - o21  # origin difference (its normal component is 0)
    w2 = o12 - o22
    # common perpendicular (lines.common_perpendicular) of p1 + s1 d1 and p2 + s2 d2:
    # k = d1 × d2, Δ = |k|², s1 = (b e − c d)/Δ, s2 = (a e − b d)/Δ
    k0 = u1 * v2
    k0 -= v1 * u2
    k1 = v1 * A2
    k1 -= A1 * v2
    k2 = A1 * u2
    k2 -= u1 * A2
    determinant = k0 * k0
    determinant += k1 * k1
    determinant += k2 * k2
    b = A1 * A2
    b += u1 * u2
    b += v1 * v2
    d = u1 * w1
    d += v1 * w2
    e = u2 * w1
    e += v2 * w2
    half = 0.5 / determinant
    h1 = b * e
    h1 -= c * d
    h1 *= half  # s1 / 2
    h2 = a * e
    h2 -= b * d
    h2 *= half  # s2 / 2
    np.multiply(k1, w1, out=length)
    length += k2 * w2
    np.abs(length, out=length)
    length /= np.sqrt(determinant)
    # midpoint (p1 + s1 d1 + p2 + s2 d2) / 2
    middle0 = h1 * A1
    middle0 += h2 * A2
    middle0 += offset
    middle1 = o11 + o21
    middle1 *= 0.5
    middle1 += h1 * u1
    middle1 += h2 * u2
    middle2 = o12 + o22
    middle2 *= 0.5
    middle2 += h1 * v1
    middle2 += h2 * v2
    for j in range(3):
        _combine([(middle0, basis[0, j]), (middle1, basis[1, j]), (middle2, basis[2, j])],
                 out=points[:, j])
    return h1, h2, determinant


def _rows_not_plain(line1, line2, h1, h2, determinant, length):
    """None where every row is plainly valid, else the mask of the rows that are (the others
    are recomputed for their reasons): a camera reason, a ray that misses the port or is
    reflected (``w_n ≤ 0``), a point behind a ray start, parallel rays, a NaN."""
    a, n1, reason1 = line1[2], line1[3], line1[4]
    c, n2, reason2 = line2[2], line2[3], line2[4]
    # one pass each (NaN anywhere fails them; not parallel: Δ > 1e-28 |d1|² |d2|², here
    # with the largest |d1|², |d2|²): the row mask only where something may be wrong
    plain = (min(np.min(n1, initial=1.0), np.min(n2, initial=1.0)) > 0
             and min(h1.min(initial=0.0), h2.min(initial=0.0)) >= 0
             and determinant.min(initial=np.inf) > 1e-28 * (a.max(initial=0.0)
                                                            * c.max(initial=0.0))
             and np.isfinite(length.sum()))
    if plain:
        good = None
    else:
        good = ((n1 > 0) & (n2 > 0) & (h1 >= 0) & (h2 >= 0)
                & (determinant > 1e-28 * a * c) & np.isfinite(length))
    for camera_reason in (reason1, reason2):
        if camera_reason is not None and (good is not None or np.any(camera_reason)):
            camera_ok = camera_reason == Reason.OK
            good = camera_ok if good is None else good & camera_ok
    return good


def _triangulate_pixels(rig, left, right, method):
    rays_left, reason_left = rig.left.rays_with_reason(left)
    rays_right, reason_right = rig.right.rays_with_reason(right)
    with np.errstate(invalid="ignore"):
        result = triangulate_rays(rig, rays_left, rays_right, method)
    reason = result.reason
    for camera_reason in (reason_left, reason_right):  # say why a ray is missing
        reason[(reason == Reason.INVALID_INPUT) & (camera_reason != Reason.OK)] = \
            camera_reason[(reason == Reason.INVALID_INPUT) & (camera_reason != Reason.OK)]
    return result.points, result.gap, reason


def triangulate(rig: Rig, uv_left, uv_right, method: str = "optical_path") -> Triangulation:
    """Triangulate matched pixels ``(N, 2)`` of the left and right images.

    ``method``: ``"optical_path"`` (the paper's model), ``"su"`` or ``"regular"``. Lens
    distortion is removed exactly. Rows with no answer (total internal reflection, rays that
    miss the port, points behind a camera, NaN pixels) are NaN with a reason code.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    uv_left = _check_pixels(uv_left, "uv_left")
    uv_right = _check_pixels(uv_right, "uv_right")
    if uv_left.shape != uv_right.shape:
        raise ValueError(f"uv_left and uv_right must have the same shape, got "
                         f"{uv_left.shape} and {uv_right.shape}")

    def solve(left, right):
        return _triangulate_pixels(rig, left, right, method)

    if method == "reprojection":
        start = triangulate(rig, uv_left, uv_right, "optical_path")
        points, _, _ = reprojection_points(rig, uv_left, uv_right, start.points)
        reason = start.reason.copy()
        points[reason != Reason.OK] = np.nan
        return Triangulation(points, start.gap, reason, method)
    if method == "optical_path" and rig.port.one_water_plane:  # the fused flat-port form
        n_rows = uv_left.shape[0]
        points, gap, reason = map_row_chunks(
            lambda left, right, out: _optical_path_rows(rig, left, right, out),
            (uv_left, uv_right),
            outputs=[np.empty((n_rows, 3)), np.empty(n_rows), np.empty(n_rows, dtype=np.int8)])
    else:
        points, gap, reason = map_row_chunks(solve, (uv_left, uv_right))
    return Triangulation(points, gap, reason, method)
