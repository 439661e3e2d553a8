"""Forward imaging through a dome port: where does a point in the water appear in a camera?

The light path from a point ``P`` in the water to the camera centre ``C`` through a dome
(:class:`measure.geometry.dome.DomePort`, centre ``M``) lies in the plane of ``C``, ``M`` and ``P``: the
sphere normals at both interface points lie in it, so Snell's law keeps the path there. In that
plane, with ``M`` at the origin and the first axis ``u`` towards ``P``, the interface points are
``I_k = M + r_k (cos φ_k u + sin φ_k v)`` (``v``: the in-plane unit vector towards ``C``). When
``C``, ``M`` and ``P`` are collinear (a centred dome, or a point on the line through both
centres) the plane is not defined; any plane through that line holds the straight path
(``φ = 0``), and ``v`` is then any unit vector perpendicular to ``u``.

Two independent solvers, both vectorized over N points:

* ``"fermat"`` — minimize the optical path ``t(φ1, φ2) = n0 |I1 − C| + n1 |I2 − I1| +
  n2 |P − I2|`` (mm) by Newton's method on the analytic gradient and 2×2 Hessian, from the
  straight line C→P (its crossings of the two spheres); far from the minimum a step that would
  lengthen the path is halved. A row has converged when its full Newton step is at most
  1e-13 rad (that step is taken; the row then stops). ``is_minimum``: the in-plane Hessian is
  positive definite at the solution.
* ``"shooting"`` — one unknown per point, the angle φ1 of the first interface point: the ray
  C→I1(φ1) is traced backward through both spheres (:func:`measure.geometry.dome.trace_through_dome`,
  the vector form of Snell's law in 3D) and the signed angle at which its water ray misses
  ``P`` is driven to zero by SciPy's elementwise bracket and root finders. It shares nothing
  with the Fermat solver but the reduction to the plane.

The pixel is the pinhole projection (with lens distortion, as ``cv2.projectPoints``) of the
first interface point ``I1``. Rows without an answer are NaN with a :class:`measure.Reason`:
``NOT_IN_WATER`` (the point is inside the dome or in its glass), ``NOT_CONVERGED`` (no physical
stationary path found), ``BEHIND_CAMERA`` (``I1`` at or behind the camera plane),
``INVALID_INPUT``. Total internal reflection cannot occur while ``n_water ≥ n_air``: a ray in
the glass keeps its distance ``b`` from ``M`` (``b = r_1 sin α_1 = r_2 sin β_2``), so at the
outer sphere ``n_glass sin β_2 = (r_1 / r_2) n_air sin θ_air < n_water``; only indices with
``n_air > n_water`` can reach ``NOT_CONVERGED`` that way.

Jacobians (:func:`dome_paths` with ``jacobian``) come from the implicit function theorem on
the stationarity (Karush–Kuhn–Tucker) conditions of the optical path in 3D: unknowns ``I1, I2``
and two multipliers, ``∇_{I_k} t = λ_k (I_k − M)`` and ``|I_k − M|² = r_k²`` — an 8×8 linear
system per point, no finite differences. Units mm, reference frame, OpenCV pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..batching import map_row_chunks
from .camera import Camera
from .dome import DomePort, trace_through_dome
from ..reasons import Reason

DOME_SOLVERS = ("fermat", "shooting")

#: A Newton step (rad) at most this large ends the Fermat iteration of a row.
STEP_TOLERANCE_RAD = 1e-13


@dataclass(frozen=True)
class DomeParameterJacobian:
    """Derivatives of pixels ``(N, 2)`` (px) with respect to the dome and camera parameters.

    * ``dome_center`` ``(N, 2, 3)``: px/mm, d pixel / d M (the dome centre in the reference
      frame — the decentring a calibration estimates).
    * ``radius`` ``(N, 2)``: px/mm, d pixel / d inner radius (thickness fixed: the outer
      sphere moves with it).
    * ``thickness`` ``(N, 2)``: px/mm, d pixel / d thickness (inner radius fixed).
    * ``indices`` ``(N, 2, 3)``: d pixel / d n_i, ``(n_air, n_glass, n_water)``.
    * ``center`` ``(N, 2, 3)``: px/mm, d pixel / d t of the camera centre (R, the dome and the
      point fixed), as :class:`measure.geometry.projection.ParameterJacobian`.
    * ``rotation`` ``(N, 2, 3)``: px/rad, d pixel / d φ for ``R → exp([φ]×) R``.
    """

    dome_center: np.ndarray
    radius: np.ndarray
    thickness: np.ndarray
    indices: np.ndarray
    center: np.ndarray
    rotation: np.ndarray


@dataclass(frozen=True)
class _Plane:
    """Points reduced to their refraction planes: per row the unit axes ``u`` (M→P) and ``v``
    (towards C) ``(N, 3)``, the camera centre's in-plane coordinates ``(cu, cv)`` and the
    point's distance ``p`` from M (mm)."""

    u: np.ndarray
    v: np.ndarray
    cu: np.ndarray
    cv: np.ndarray
    p: np.ndarray


def _reduce(camera: Camera, dome: DomePort, points: np.ndarray):
    """The in-plane problem of ``points`` ``(N, 3)`` and the reasons of rows without one (those
    rows get a harmless stand-in point two outer radii from M)."""
    reason = np.zeros(points.shape[0], dtype=np.int8)
    finite = np.all(np.isfinite(points), axis=1)
    reason[~finite] = Reason.INVALID_INPUT
    offsets = np.where(finite[:, None], points - dome.center, 0.0)
    p = np.sqrt(np.einsum("ij,ij->i", offsets, offsets))
    reason[finite & ~(p > dome.radii[1])] = Reason.NOT_IN_WATER
    bad = reason != Reason.OK
    if bad.any():
        offsets[bad] = (0.0, 0.0, 2.0 * dome.radii[1])
        p[bad] = 2.0 * dome.radii[1]
    u = offsets / p[:, None]
    c = camera.center - dome.center
    cu = u @ c
    perpendicular = c - cu[:, None] * u
    cv = np.sqrt(np.einsum("ij,ij->i", perpendicular, perpendicular))
    # collinear C, M, P (e.g. a centred dome): any unit vector perpendicular to u
    degenerate = ~(cv > 1e-12 * dome.radius)
    if degenerate.any():
        ud = u[degenerate]
        axis = np.zeros_like(ud)
        axis[np.arange(ud.shape[0]), np.argmin(np.abs(ud), axis=1)] = 1.0
        other = np.cross(ud, axis)
        perpendicular[degenerate] = other
        cv[degenerate] = 0.0
    v = perpendicular / np.linalg.norm(perpendicular, axis=1)[:, None]
    return _Plane(u, v, cu, cv, p), reason


def _straight_angles(plane: _Plane, radii):
    """Angles φ_k of the points where the straight line C→P leaves each sphere (far root)."""
    du = plane.p - plane.cu
    dv = -plane.cv
    length = np.sqrt(du * du + dv * dv)
    du, dv = du / length, dv / length
    angles = []
    for r in radii:
        b = plane.cu * du + plane.cv * dv
        c = plane.cu * plane.cu + plane.cv * plane.cv - r * r
        h = -b + np.sqrt(b * b - c)
        angles.append(np.arctan2(plane.cv + h * dv, plane.cu + h * du))
    return angles


def _path_terms(phi1, phi2, plane: _Plane, radii, indices):
    """Segments of the in-plane path: interface points, unit directions, lengths, and the
    optical path length ``t`` (mm)."""
    r1, r2 = radii
    i1 = (r1 * np.cos(phi1), r1 * np.sin(phi1))
    i2 = (r2 * np.cos(phi2), r2 * np.sin(phi2))
    corners = [(plane.cu, plane.cv), i1, i2, (plane.p, np.zeros_like(plane.p))]
    directions, lengths = [], []
    for a, b in zip(corners[:-1], corners[1:]):
        du, dv = b[0] - a[0], b[1] - a[1]
        length = np.sqrt(du * du + dv * dv)
        directions.append((du / length, dv / length))
        lengths.append(length)
    t = sum(n * length for n, length in zip(indices, lengths))
    return i1, i2, directions, lengths, t


def _gradient_hessian(phi1, phi2, plane, radii, indices):
    """Analytic ∂t/∂φ_k and the 2×2 Hessian (mm/rad, mm/rad²).

    With ``T_k = dI_k/dφ_k`` (``d²I_k/dφ_k² = −(I_k − M)``), unit segment directions ``d_i``
    and lengths ``L_i``: ``∂t/∂φ1 = (n0 d0 − n1 d1)·T1``, ``∂t/∂φ2 = (n1 d1 − n2 d2)·T2``;
    ``H11 = n0 (T1·d0⊥)²/L0 + n1 (T1·d1⊥)²/L1 − (n0 d0 − n1 d1)·I1``, ``H12 = −n1 (T1·d1⊥)
    (T2·d1⊥)/L1``, ``H22 = n1 (T2·d1⊥)²/L1 + n2 (T2·d2⊥)²/L2 − (n1 d1 − n2 d2)·I2``
    (``d⊥`` the in-plane perpendicular of d: ``T Q T`` with ``Q = 1 − d dᵀ``)."""
    n0, n1, n2 = indices
    i1, i2, (d0, d1, d2), (l0, l1, l2), t = _path_terms(phi1, phi2, plane, radii, indices)
    t1 = (-i1[1], i1[0])
    t2 = (-i2[1], i2[0])

    def dot(a, b):
        return a[0] * b[0] + a[1] * b[1]

    def perp(a, d):  # a · d⊥ with d⊥ = (−d_v, d_u)
        return -a[0] * d[1] + a[1] * d[0]

    g1 = (n0 * d0[0] - n1 * d1[0], n0 * d0[1] - n1 * d1[1])
    g2 = (n1 * d1[0] - n2 * d2[0], n1 * d1[1] - n2 * d2[1])
    grad = (dot(g1, t1), dot(g2, t2))
    a0, a1, b1, b2 = perp(t1, d0), perp(t1, d1), perp(t2, d1), perp(t2, d2)
    h11 = n0 * a0 * a0 / l0 + n1 * a1 * a1 / l1 - dot(g1, i1)
    h12 = -n1 * a1 * b1 / l1
    h22 = n1 * b1 * b1 / l1 + n2 * b2 * b2 / l2 - dot(g2, i2)
    return grad, (h11, h12, h22), t


def _solve_fermat(plane: _Plane, radii, indices, max_iterations: int = 60):
    """Newton on (φ1, φ2); returns the angles, is_minimum, converged and the iterations."""
    phi1, phi2 = _straight_angles(plane, radii)
    n_rows = phi1.shape[0]
    converged = np.zeros(n_rows, dtype=bool)
    positive = np.zeros(n_rows, dtype=bool)
    rows = np.arange(n_rows)
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (read after the loop)
        work = _Plane(*(a[rows] for a in (plane.u, plane.v, plane.cu, plane.cv, plane.p)))
        x1, x2 = phi1[rows], phi2[rows]
        (g1, g2), (h11, h12, h22), t = _gradient_hessian(x1, x2, work, radii, indices)
        det = h11 * h22 - h12 * h12
        definite = (h11 > 0) & (det > 0)
        s1 = (h22 * g1 - h12 * g2) / det
        s2 = (h11 * g2 - h12 * g1) / det
        if not definite.all():  # a scaled gradient step where the Newton step is no descent
            scale = np.abs(h11) + np.abs(h22) + 1e-300
            s1 = np.where(definite, s1, g1 / scale)
            s2 = np.where(definite, s2, g2 / scale)
        largest = np.maximum(np.abs(s1), np.abs(s2))
        now = definite & (largest <= STEP_TOLERANCE_RAD)
        far = largest > 1e-8
        factor = np.where(largest > 0.2, 0.2 / np.where(largest > 0, largest, 1.0), 1.0)
        if far.any():
            limit = t * (1 + 4e-16)
            for _ in range(40):
                trial = _path_terms(x1 - factor * s1, x2 - factor * s2, work, radii,
                                    indices)[4]
                worse = far & ~(trial <= limit)
                if not worse.any():
                    break
                factor[worse] *= 0.5
        phi1[rows] = x1 - factor * s1
        phi2[rows] = x2 - factor * s2
        positive[rows] = definite
        converged[rows] = now
        if now.all():
            break
        rows = rows[~now]
    return (phi1, phi2), positive & converged, converged, iterations


def _shooting_residual(phi1, cu, cv, p, u0, u1, u2, v0, v1, v2, *, camera_center, dome):
    """Signed angle (rad) between the water ray of the camera ray through I1(φ1) and the
    direction from its start to the point, in the plane (NaN where the ray has no water ray)."""
    u = np.stack([u0, u1, u2], axis=-1)
    v = np.stack([v0, v1, v2], axis=-1)
    r1 = dome.radius
    first = dome.center + r1 * (np.cos(phi1)[..., None] * u + np.sin(phi1)[..., None] * v)
    heading = first - camera_center
    heading /= np.linalg.norm(heading, axis=-1, keepdims=True)
    shape = phi1.shape
    rays = trace_through_dome(camera_center, heading.reshape(-1, 3), dome,
                              keep_interface_points=False)
    origins = rays.origins.reshape(*shape, 3)
    w = rays.directions.reshape(*shape, 3)
    target = dome.center + p[..., None] * u - origins
    wu, wv = np.einsum("...j,...j->...", w, u), np.einsum("...j,...j->...", w, v)
    qu, qv = np.einsum("...j,...j->...", target, u), np.einsum("...j,...j->...", target, v)
    return np.arctan2(wu * qv - wv * qu, wu * qu + wv * qv)


def _solve_shooting(camera: Camera, dome: DomePort, plane: _Plane):
    """The root φ1 of :func:`_shooting_residual`, bracketed from the straight line's angle;
    returns the angles (φ1, φ2), converged and the iterations."""
    from scipy.optimize import elementwise

    start = _straight_angles(plane, dome.radii)[0]
    args = (plane.cu, plane.cv, plane.p, *plane.u.T, *plane.v.T)

    def residual(phi1, *row_args):
        return _shooting_residual(phi1, *row_args, camera_center=camera.center, dome=dome)

    bracket = elementwise.bracket_root(residual, start - 1e-3, start + 1e-3, xmin=start - 1.5,
                                       xmax=start + 1.5, args=args)
    phi1 = np.full(start.shape, np.nan)
    converged = np.zeros(start.shape, dtype=bool)
    iterations = int(np.max(bracket.nit, initial=0))
    ok = bracket.success
    if ok.any():
        result = elementwise.find_root(
            residual, (bracket.bracket[0][ok], bracket.bracket[1][ok]), args=tuple(a[ok] for a in args),
            tolerances=dict(xatol=1e-16, xrtol=1e-16, fatol=0.0, frtol=0.0), maxiter=400)
        phi1[ok] = result.x
        converged[ok] = result.success
        iterations += int(np.max(result.nit, initial=0))
    # the second interface point from the traced ray
    first = dome.center + dome.radius * (np.cos(phi1)[:, None] * plane.u
                                         + np.sin(phi1)[:, None] * plane.v)
    heading = first - camera.center
    heading /= np.linalg.norm(heading, axis=1)[:, None]
    second = trace_through_dome(camera.center, heading, dome).interface_points[1] - dome.center
    phi2 = np.arctan2(np.einsum("ij,ij->i", second, plane.v),
                      np.einsum("ij,ij->i", second, plane.u))
    converged &= np.isfinite(phi2)
    return (phi1, phi2), converged, iterations


def _physical(plane: _Plane, angles, radii, indices):
    """Whether the stationary in-plane path is a refracted one: every segment leaves its
    sphere outwards (a stationary path can also be a reflection-like fold)."""
    i1, i2, (d0, d1, d2), _, _ = _path_terms(*angles, plane, radii, indices)
    out1 = (d0[0] * i1[0] + d0[1] * i1[1] > 0) & (d1[0] * i1[0] + d1[1] * i1[1] > 0)
    out2 = (d1[0] * i2[0] + d1[1] * i2[1] > 0) & (d2[0] * i2[0] + d2[1] * i2[1] > 0)
    return out1 & out2


def _pixels(camera: Camera, first: np.ndarray, jacobian: bool):
    """Pinhole + distortion pixels of reference-frame points ``(N, 3)`` and, with
    ``jacobian``, d pixel / d point ``(N, 2, 3)`` (reference frame); NaN at or behind the
    camera plane."""
    X = camera.to_camera(first)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(X[:, 2] > 0, X[:, 2], np.nan)
        x, y = X[:, 0] / z, X[:, 1] / z
    distorted = camera.distort_columns(x, y, jacobian=jacobian)
    K = camera.K
    pixels = np.stack([K[0, 0] * distorted[0] + K[0, 1] * distorted[1] + K[0, 2],
                       K[1, 1] * distorted[1] + K[1, 2]], axis=1)
    if not jacobian:
        return pixels, None
    if len(distorted) == 2:
        dxx, dxy, dyy = np.ones_like(x), np.zeros_like(x), np.ones_like(x)
    else:
        _, _, dxx, dxy, dyy = distorted
    m = np.empty((x.shape[0], 2, 2))
    m[:, 0, 0] = K[0, 0] * dxx + K[0, 1] * dxy
    m[:, 0, 1] = K[0, 0] * dxy + K[0, 1] * dyy
    m[:, 1, 0] = K[1, 1] * dxy
    m[:, 1, 1] = K[1, 1] * dyy
    normalized = np.zeros((x.shape[0], 2, 3))
    normalized[:, 0, 0] = 1.0 / z
    normalized[:, 1, 1] = 1.0 / z
    normalized[:, 0, 2] = -x / z
    normalized[:, 1, 2] = -y / z
    return pixels, m @ normalized @ camera.R.T


def _outer(a):
    return a[:, :, None] * a[:, None, :]


def _path_jacobian(camera: Camera, dome: DomePort, points, first, second):
    """d I1 / d θ ``(N, 3, 14)`` for θ = (P (3), M (3), C (3), radius, thickness, n0, n1, n2):
    the implicit function theorem on the KKT conditions (module docs)."""
    n0, n1, n2 = dome.indices
    center, m = camera.center, dome.center
    r1, r2 = dome.radii
    s0, s1, s2 = first - center, second - first, points - second
    lengths = [np.linalg.norm(s, axis=1)[:, None] for s in (s0, s1, s2)]
    d0, d1, d2 = (s / length for s, length in zip((s0, s1, s2), lengths))
    eye = np.eye(3)
    q0, q1, q2 = ((eye - _outer(d)) / length[:, :, None]
                  for d, length in zip((d0, d1, d2), lengths))
    a1, a2 = first - m, second - m
    g1, g2 = n0 * d0 - n1 * d1, n1 * d1 - n2 * d2
    lam1 = np.einsum("ij,ij->i", g1, a1) / (r1 * r1)
    lam2 = np.einsum("ij,ij->i", g2, a2) / (r2 * r2)
    n_rows = points.shape[0]
    jac = np.zeros((n_rows, 8, 8))
    jac[:, 0:3, 0:3] = n0 * q0 + n1 * q1 - lam1[:, None, None] * eye
    jac[:, 0:3, 3:6] = -n1 * q1
    jac[:, 3:6, 0:3] = -n1 * q1
    jac[:, 3:6, 3:6] = n1 * q1 + n2 * q2 - lam2[:, None, None] * eye
    jac[:, 0:3, 6] = -a1
    jac[:, 3:6, 7] = -a2
    jac[:, 6, 0:3] = a1
    jac[:, 7, 3:6] = a2
    rhs = np.zeros((n_rows, 8, 14))
    rhs[:, 3:6, 0:3] = -n2 * q2  # P
    rhs[:, 0:3, 3:6] = lam1[:, None, None] * eye  # M
    rhs[:, 3:6, 3:6] = lam2[:, None, None] * eye
    rhs[:, 6, 3:6] = -a1
    rhs[:, 7, 3:6] = -a2
    rhs[:, 0:3, 6:9] = -n0 * q0  # C
    rhs[:, 6, 9] = -r1  # radius moves both spheres
    rhs[:, 7, 9] = -r2
    rhs[:, 7, 10] = -r2  # thickness moves the outer one
    rhs[:, 0:3, 11] = d0  # n0, n1, n2
    rhs[:, 0:3, 12] = -d1
    rhs[:, 3:6, 12] = d1
    rhs[:, 3:6, 13] = -d2
    return -np.linalg.solve(jac, rhs)[:, 0:3, :]


def dome_paths(camera: Camera, dome: DomePort, points, solver: str = "fermat",
               jacobian: int = 0):
    """Light paths from ``points`` ``(N, 3)`` (mm, reference frame) through ``dome`` to
    ``camera``'s centre.

    Returns ``(pixels (N, 2), reason (N,), is_minimum (N,), interface_points (N, 2, 3),
    iterations, jacobians)``; ``jacobians`` is empty for ``jacobian=0``, ``[d_points]``
    ``(N, 2, 3)`` for 1 and ``[d_points, DomeParameterJacobian]`` for 2. Raises ``ValueError``
    for an unknown solver or a camera centre not inside the dome's inner sphere.
    """
    if solver not in DOME_SOLVERS:
        raise ValueError(f"solver must be one of {', '.join(DOME_SOLVERS)} for a dome port, "
                         f"got {solver!r}")
    dome.check_camera(camera.center, "camera")
    points = np.asarray(points, dtype=np.float64)
    if points.shape == (3,):
        points = points[None]
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3) or (3,), got {points.shape}")
    iterations = []
    parts = map_row_chunks(lambda chunk: _chunk(camera, dome, chunk, solver, jacobian,
                                                iterations), (points,))
    pixels, reason, is_minimum, interface = parts[:4]
    jacobians = []
    if jacobian:
        d_pixel, center, rotation = parts[4:]
        jacobians.append(np.ascontiguousarray(d_pixel[:, :, 0:3]))
        if jacobian > 1:
            jacobians.append(DomeParameterJacobian(
                dome_center=np.ascontiguousarray(d_pixel[:, :, 3:6]),
                radius=np.ascontiguousarray(d_pixel[:, :, 9]),
                thickness=np.ascontiguousarray(d_pixel[:, :, 10]),
                indices=np.ascontiguousarray(d_pixel[:, :, 11:14]), center=center,
                rotation=rotation))
    return pixels, reason, is_minimum, interface, max(iterations, default=0), jacobians


def _chunk(camera: Camera, dome: DomePort, points, solver: str, jacobian: int,
           iterations_used: list):
    """:func:`dome_paths` of one chunk of rows: pixels, reasons, minimum flags, interface
    points and, with ``jacobian``, d pixel / d θ ``(n, 2, 14)`` (θ of :func:`_path_jacobian`,
    the camera centre's direct term not yet added), d pixel / d camera centre and d pixel /
    d rotation; NaN in every output where the reason is not OK. Appends the iterations."""
    radii, indices = dome.radii, dome.indices
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        plane, reason = _reduce(camera, dome, points)
        if solver == "fermat":
            angles, is_minimum, converged, iterations = _solve_fermat(plane, radii, indices)
        else:
            angles, converged, iterations = _solve_shooting(camera, dome, plane)
            is_minimum = converged.copy()
        iterations_used.append(iterations)
        converged &= _physical(plane, angles, radii, indices)
        reason[(reason == Reason.OK) & ~converged] = Reason.NOT_CONVERGED
        interface = np.stack([dome.center + r * (np.cos(phi)[:, None] * plane.u
                                                 + np.sin(phi)[:, None] * plane.v)
                              for r, phi in zip(radii, angles)], axis=1)
        pixels, d_first = _pixels(camera, interface[:, 0], jacobian > 0)
        reason[(reason == Reason.OK) & ~np.all(np.isfinite(pixels), axis=1)] = \
            Reason.BEHIND_CAMERA
        bad = reason != Reason.OK
        outputs = [pixels, reason, is_minimum & ~bad, interface]
        if jacobian:
            d_path = np.full((points.shape[0], 3, 14), np.nan)
            good = ~bad
            if good.any():
                d_path[good] = _path_jacobian(camera, dome, points[good], interface[good, 0],
                                              interface[good, 1])
            d_pixel = d_first @ d_path  # (n, 2, 14)
            center = d_pixel[:, :, 6:9] - d_first  # the pixel also moves with I1 − C directly
            rotation = np.cross(d_first, (interface[:, 0] - camera.center)[:, None, :])
            outputs += [d_pixel, center, rotation]
    if bad.any():
        for array in outputs[:1] + outputs[3:]:
            array[bad] = np.nan
    return tuple(outputs)


__all__ = ["DOME_SOLVERS", "DomeParameterJacobian", "dome_paths"]
