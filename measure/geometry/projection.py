"""Forward imaging through a flat port: where does a point in the water appear in a camera?

Two independent solvers of the same refracted path, both vectorized over N points:

* ``"fermat"`` — the paper's section 2.2: in the refraction plane (camera centre, point, port
  normal) the light crosses interface k at ``I_k = J_k + μ_k ε``, where ``J_k`` is where the
  straight line O→P crosses that interface and ``ε`` is the in-plane direction along the
  interface. Fermat's principle: minimize the travel time ``t(μ) = Σ n_i |I_{i+1} − I_i|`` (times
  1/c) by Newton's method on the analytic gradient and (tridiagonal) Hessian, to machine
  precision; the minimum condition (det H > 0, ∂²t/∂μ1² > 0, i.e. H positive definite) is
  reported per point. The Newton iteration starts from the paraxial path refined by a few
  scalar Newton steps on Snell's invariant (:func:`snell_start`), so that one Fermat step
  normally confirms the minimum; points where that start fails fall back to the damped Newton
  iteration from the straight line O→P.
* ``"snell"`` — the 1D root of the Snell invariant: ``p = n_i sin θ_i`` is the same in every
  medium and the lateral offsets ``h_i tan θ_i`` add up to the lateral distance of the point.
  Solved with SciPy's vectorized bracketing root finder (independent of the Fermat solver and
  its start).

Once the first refraction point ``I_1`` is known, the pixel is the pinhole projection of ``I_1``
(with lens distortion, as ``cv2.projectPoints``). :func:`project` with ``jacobian=True`` also
returns the analytic derivatives of the pixels (see :func:`project`). Units mm, reference frame,
OpenCV pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..batching import map_row_chunks
from .camera import Camera
from .dome import DomePort
from .dome_projection import dome_paths
from .plane_path import (PlaneProblem, snell_start, solve_fermat, solve_snell,
                         straight_start)
from .port import FlatPort, RigPort, index_matched_port
from ..reasons import Reason

SOLVERS = ("fermat", "snell")



@dataclass(frozen=True)
class RefractedPaths:
    """Light paths from points in the water to one camera centre.

    ``pixels`` ``(N, 2)``; ``interface_points`` ``(K, N, 3)`` (I1, I2 … in mm, reference frame);
    ``reason`` ``(N,)`` :class:`measure.Reason` codes; ``is_minimum`` ``(N,)`` whether the
    Hessian of the travel time is positive definite at the solution (Fermat solver; the Snell
    solver reports True where it converged); ``iterations`` used by the solver (Fermat: the
    Newton steps of its start plus the Fermat Newton steps, the largest over the chunks).
    """

    pixels: np.ndarray
    interface_points: np.ndarray
    reason: np.ndarray
    is_minimum: np.ndarray
    iterations: int


@dataclass(frozen=True)
class ParameterJacobian:
    """Derivatives of pixels ``(N, 2)`` (px) with respect to the port and camera parameters, by
    the implicit function theorem on the stationarity condition of the travel time.

    * ``distance`` ``(N, 2)``: px/mm, d pixel / d D (the port's first interface ``N·X = D``).
    * ``normal`` ``(N, 2, 3)``: px per unit, d pixel / d N for a change of the unit normal
      tangent to the unit sphere (D fixed); the component along N is zero. For a normal
      ``m / |m|`` built from an unnormalized vector m, d pixel / d m = ``normal / |m|``.
    * ``indices`` ``(N, 2, K+1)``: d pixel / d n_i, air first, water last.
    * ``thicknesses`` ``(N, 2, K-1)``: px/mm, d pixel / d d_j of each layer (the water column
      shortens by the same amount; D fixed).
    * ``center`` ``(N, 2, 3)``: px/mm, d pixel / d t of the camera centre (reference frame; R,
      the port and the point fixed).
    * ``rotation`` ``(N, 2, 3)``: px/rad, d pixel / d φ for the camera rotation
      ``R → exp([φ]×) R`` (a small rotation about reference-frame axes, applied on the left).
    """

    distance: np.ndarray
    normal: np.ndarray
    indices: np.ndarray
    thicknesses: np.ndarray
    center: np.ndarray
    rotation: np.ndarray


@dataclass(frozen=True)
class _Frame:
    """Constants of one camera behind one port: the orthonormal basis ``(N, e1, e2)`` of the
    reference frame with the port normal first, the camera centre's coordinates in it, the air
    gap and layer heights (mm) and the same basis in the camera frame."""

    normal: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    center_e: tuple  # (C·e1, C·e2)
    water_offset: float  # N·X of the last interface
    heights: tuple  # air gap, layers (mm)
    indices: np.ndarray
    camera_basis: tuple  # R^T N, R^T e1, R^T e2 (camera frame)


def _frame(camera: Camera, port: FlatPort) -> _Frame:
    normal = port.normal
    nx, ny, nz = (float(v) for v in normal)
    # e1 = N × x̂ (or N × ŷ when N is near x̂), e2 = N × e1 (np.cross costs ~0.1 ms here)
    e1 = np.array([0.0, nz, -ny]) if abs(nx) < 0.9 else np.array([-nz, 0.0, nx])
    e1 /= np.sqrt(e1 @ e1)
    e2 = np.array([ny * e1[2] - nz * e1[1], nz * e1[0] - nx * e1[2], nx * e1[1] - ny * e1[0]])
    center = camera.center
    heights = (port.distance - float(center @ normal), *port.thicknesses)
    water_offset = port.distance + sum(port.thicknesses)
    Rt = camera.R.T
    return _Frame(normal, e1, e2, (float(center @ e1), float(center @ e2)), water_offset,
                  heights, np.asarray(port.indices, dtype=float), (Rt @ normal, Rt @ e1, Rt @ e2))


def _reduce(frame: _Frame, points: np.ndarray):
    """The plane problem of ``points`` ``(N, 3)``: per point the water column ``h_w`` (mm), the
    lateral coordinates ``l1, l2`` (mm, along e1, e2 from the camera's normal foot) and the
    lateral distance ``ℓ``; rows that are not in the water get ``ℓ = 0, h_w = 1`` (a harmless
    problem) and a reason."""
    water = points @ frame.normal
    water -= frame.water_offset
    l1 = points @ frame.e1
    l1 -= frame.center_e[0]
    l2 = points @ frame.e2
    l2 -= frame.center_e[1]
    lateral = np.sqrt(l1 * l1 + l2 * l2)
    with np.errstate(invalid="ignore"):
        ok = (water > 0) & (water < np.inf) & (lateral < np.inf)
    reason = np.zeros(points.shape[0], dtype=np.int8)
    if not ok.all():
        finite = np.isfinite(water) & np.isfinite(lateral)
        reason[~finite] = Reason.INVALID_INPUT
        reason[finite & ~ok] = Reason.NOT_IN_WATER
        lateral[~ok] = 0.0
        water[~ok] = 1.0
        l1[~ok] = 0.0
        l2[~ok] = 0.0
    columns = [*frame.heights, water]
    problem = PlaneProblem(lateral, frame.indices, columns, [h * h for h in columns])
    return problem, l1, l2, reason


def _path_derivatives(frame: _Frame, problem: PlaneProblem, x1):
    """Derivatives of the first interface point's lateral position ``x1`` (implicit function
    theorem on Snell's invariant, equivalent to the Fermat stationarity ∂t/∂x = 0).

    With ``p = n_0 x1 / L_0`` and ``c_i = sqrt(n_i² − p²)``, the condition is ``F(p) = Σ h_i p
    / c_i − ℓ = 0`` and ``x1 = h_0 p / c_0``; ``F_p = Σ h_i n_i² / c_i³``, ``A = ∂x1/∂p =
    h_0 n_0² / c_0³``. Returns ``p``, ``c`` (list per medium), ``A`` and ``F_p``."""
    n = frame.indices
    h0 = problem.heights_columns[0]
    p = n[0] * x1 / np.sqrt(x1 * x1 + h0 * h0)
    p2 = p * p
    c = [np.sqrt(n_i * n_i - p2) for n_i in n]
    slope = 0.0
    for n_i, h, c_i in zip(n, problem.heights_columns, c):
        slope = slope + (h * n_i * n_i) / (c_i * c_i * c_i)
    a = (h0 * n[0] * n[0]) / (c[0] * c[0] * c[0])
    return p, c, a, slope


def _outputs(n_rows: int, port: FlatPort, paths: bool, jacobian: int) -> list:
    """The arrays :func:`_chunk` fills (all rows): pixels; with ``paths`` the reasons, minimum
    flags and interface points; with ``jacobian`` d pixel / d point; with ``jacobian > 1`` the
    :class:`ParameterJacobian` fields."""
    k = len(port.thicknesses) + 1
    out = [np.empty((n_rows, 2))]
    if paths:
        out += [np.empty(n_rows, dtype=np.int8), np.empty(n_rows, dtype=bool),
                np.empty((n_rows, k, 3))]
    if jacobian:
        out.append(np.empty((n_rows, 2, 3)))
    if jacobian > 1:
        out += [np.empty((n_rows, 2)), np.empty((n_rows, 2, 3)), np.empty((n_rows, 2, k + 1)),
                np.empty((n_rows, 2, k - 1)), np.empty((n_rows, 2, 3)), np.empty((n_rows, 2, 3))]
    return out


def _chunk(camera: Camera, frame: _Frame, points, solver: str, paths: bool, jacobian: int,
           iterations_used: list, out: list):
    """Fill ``out`` (this chunk's rows of :func:`_outputs`) for one chunk of points; append the
    solver's iterations to ``iterations_used``."""
    problem, l1, l2, reason = _reduce(frame, points)
    lateral = problem.lateral
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        if solver == "fermat":
            start, started, start_iterations = snell_start(problem)
            if not started.all():  # the damped iteration from the straight line for the rest
                straight = straight_start(problem)
                start = [np.where(started, s, t) for s, t in zip(start, straight)]
            x, is_minimum, converged, iterations, curvature = solve_fermat(problem, start)
            iterations += start_iterations
        else:
            x, converged, iterations = solve_snell(problem)
            is_minimum = converged.copy()
            curvature = None
        iterations_used.append(iterations)
        if not converged.all():
            reason[(reason == Reason.OK) & ~converged] = Reason.NOT_CONVERGED
        bad = reason != Reason.OK
        x1 = x[0]
        inverse_lateral = np.divide(1.0, lateral, out=np.zeros_like(lateral), where=lateral > 0)
        ratio = x1 * inverse_lateral  # x1 / ℓ (0 on the normal through the camera)
        s1 = ratio * l1
        s2 = ratio * l2
        # I1 − C = h0 N + (x1/ℓ)(l1 e1 + l2 e2); in the camera frame with R^T N, R^T e1, R^T e2
        # (exact zeros of these constant vectors skipped).
        h0 = frame.heights[0]
        nc, e1c, e2c = frame.camera_basis
        X, Y, Z = (_combine([(s1, e1c[j]), (s2, e2c[j]), (None, h0 * nc[j])]) for j in range(3))
        inverse_z = np.full(lateral.shape, 1.0 / Z) if np.ndim(Z) == 0 else 1.0 / Z
        front = Z > 0
        if not front.all():
            inverse_z[~front] = np.nan
        xn = X * inverse_z
        yn = Y * inverse_z
        distortion = camera.distort_columns(xn, yn, jacobian=jacobian > 0)
        K = camera.K
        pixels = out[0]
        np.multiply(distortion[0], K[0, 0], out=pixels[:, 0])
        if K[0, 1] != 0.0:
            pixels[:, 0] += K[0, 1] * distortion[1]
        pixels[:, 0] += K[0, 2]
        np.multiply(distortion[1], K[1, 1], out=pixels[:, 1])
        pixels[:, 1] += K[1, 2]
        if bad.any():
            pixels[bad] = np.nan
        if paths:
            out[1][...] = reason
            np.logical_and(is_minimum, ~bad, out=out[2])
            out[3][...] = _interface_points(camera, frame, problem, x, l1, l2, bad)
        if jacobian:
            _jacobians(camera, frame, problem, points, x, curvature, ratio, inverse_lateral, l1,
                       l2, inverse_z, xn, yn, distortion, bad, out[4 if paths else 1:])


def _interface_points(camera, frame, problem, x, l1, l2, bad):
    """``(N, K, 3)`` refraction points in the reference frame."""
    lateral = problem.lateral
    inverse = np.divide(1.0, lateral, out=np.zeros_like(lateral), where=lateral > 0)
    axis = np.multiply.outer(l1 * inverse, frame.e1) + np.multiply.outer(l2 * inverse, frame.e2)
    heights_to = np.cumsum(frame.heights)
    points = np.stack([camera.center + h * frame.normal + xk[:, None] * axis
                       for h, xk in zip(heights_to, x)], axis=1)
    points[bad] = np.nan
    return points


def _combine(terms, out=None):
    """``Σ array · coefficient`` over ``(array, coefficient)`` terms (``None`` as the array: the
    constant coefficient), skipping exact zero coefficients; into ``out`` if given."""
    terms = [(a, c) for a, c in terms if c != 0.0]
    constant = sum(c for a, c in terms if a is None)
    terms = [(a, c) for a, c in terms if a is not None]
    if not terms:
        if out is None:
            return constant
        out[...] = constant
        return out
    first, coefficient = terms[0]
    out = np.multiply(first, coefficient, out=out)
    for array, coefficient in terms[1:]:
        out += array * coefficient
    if constant != 0.0:
        out += constant
    return out


def _sum_of_products(pairs):
    """``Σ u·v`` over pairs of ``(N,)`` arrays or floats, skipping pairs with an exact float
    zero and not multiplying by a float 1 (the frame vectors of a port square to the camera
    have many); an array or a float (0.0 when every pair is skipped). Inputs are never
    modified; an input array may be returned as it is."""
    total, owned = 0.0, False
    for u, v in pairs:
        if np.ndim(u) == 0 and np.ndim(v) != 0:
            u, v = v, u
        if np.ndim(v) == 0:
            if v == 0.0:
                continue
            if np.ndim(u) == 0:
                term = u * v
            else:
                term = u if v == 1.0 else u * v
        else:
            term = u * v
        if np.ndim(total) == 0 and total == 0.0:
            total, owned = term, term is not u and term is not v
        elif owned and np.ndim(total) != 0:
            total += term
        else:
            total, owned = total + term, np.ndim(total) != 0 or np.ndim(term) != 0
    return total


def _point_jacobian(camera, frame, problem, x, curvature, ratio, inverse, l1, l2, inverse_z, xn,
                    yn, distortion, d_points):
    """d pixel / d point into ``d_points`` ``(N, 2, 3)`` (module docs of :func:`project`).

    The implicit function theorem on Snell's invariant (:func:`_path_derivatives`) gives
    ``α = ∂x1/∂ℓ = (h_0 n_0² / c_0³) / Σ h_i n_i² / c_i³`` with ``c_i = n_i cos θ_i = n_i h_i /
    L_i``, i.e. ``α = w_0 / Σ w_i`` with ``w_i = L_i³ / (n_i h_i²)`` from the segment lengths
    of the solved path — the reciprocals of the segment curvatures of the Fermat solver's last
    step (for one interface ``α = κ_1 / (κ_0 + κ_1)``) — and ``β_w = ∂x1/∂h_w = −α tan θ_w =
    −α Δ_w / h_w``. Returns α, β_w and
    the in-plane axis ``(a1, a2)`` (components along e1, e2; zero on the normal through the
    camera) and ``ratio`` (x1/ℓ, α on that normal)."""
    lateral = problem.lateral
    water_step = lateral - x[-1]
    if curvature is not None and len(curvature) == 2:
        alpha = curvature[0] + curvature[1]
        np.divide(curvature[1], alpha, out=alpha)
    elif curvature is not None:
        weights = [1.0 / k for k in curvature]
        alpha = weights[0] / sum(weights[1:], weights[0])
    else:
        steps = [x[0]] + [x[k] - x[k - 1] for k in range(1, len(x))] + [water_step]
        alpha = total = None
        for n_i, d, h2 in zip(problem.indices, steps, problem.heights_squared):
            weight = d * d
            weight += h2
            weight *= np.sqrt(weight)  # L_i³
            weight /= n_i * h2
            if alpha is None:
                alpha, total = weight, weight.copy()
            else:
                total += weight
        alpha /= total  # d x1 / d ℓ
    beta_water = alpha * water_step
    beta_water /= problem.heights_columns[-1]
    np.negative(beta_water, out=beta_water)  # d x1 / d h_w
    if not lateral.min(initial=1.0) > 0:
        ratio = np.where(lateral > 0, ratio, alpha)  # x1/ℓ → dx1/dℓ on the normal
    a1 = l1 * inverse  # in-plane axis a = a1 e1 + a2 e2 (zero on the normal)
    a2 = l2 * inverse
    gain = alpha - ratio
    # Row r of d pixel / d I1 is scale_r (ρ_r · (e1, e2)) on the interface: d pixel / d (x, y,
    # z)_camera = M (1/Z) [[1, 0, −x], [0, 1, −y]] (M: K's upper block times the distortion
    # Jacobian), with φ, ψ its two rows projected onto R^T e1, R^T e2.
    _, e1c, e2c = frame.camera_basis
    phi = [_combine([(None, vec[0]), (xn, -vec[2])]) for vec in (e1c, e2c)]
    psi = [_combine([(None, vec[1]), (yn, -vec[2])]) for vec in (e1c, e2c)]
    K = camera.K
    if len(distortion) == 2:
        skew = K[0, 1] / K[0, 0]
        rho = [[_sum_of_products([(f, 1.0), (s, skew)]) for f, s in zip(phi, psi)], psi]
        scales = [K[0, 0] * inverse_z, K[1, 1] * inverse_z]
    else:
        _, _, dxx, dxy, dyy = distortion
        m = [[K[0, 0] * dxx + K[0, 1] * dxy, K[0, 0] * dxy + K[0, 1] * dyy],
             [K[1, 1] * dxy, K[1, 1] * dyy]]
        rho = [[_sum_of_products([(f, mr[0]), (s, mr[1])]) for f, s in zip(phi, psi)]
               for mr in m]
        scales = [inverse_z, inverse_z]
    for r in range(2):
        rho1, rho2 = rho[r]
        # d I1 / d P = α a aᵀ + (x1/ℓ) b bᵀ + β_w a Nᵀ with b = N × a, and a aᵀ + b bᵀ = e1 e1ᵀ +
        # e2 e2ᵀ: the row is (x1/ℓ)(ρ1 e1 + ρ2 e2) + (α − x1/ℓ)(ρ·a) a + β_w (ρ·a) N.
        along = _sum_of_products([(a1, rho1), (a2, rho2)])
        c_normal = _sum_of_products([(beta_water, along)])
        tilt = _sum_of_products([(gain, along)])
        c1 = _sum_of_products([(ratio, rho1), (tilt, a1)])
        c2 = _sum_of_products([(ratio, rho2), (tilt, a2)])
        for j in range(3):
            value = _sum_of_products([(c_normal, frame.normal[j]), (c1, frame.e1[j]),
                                      (c2, frame.e2[j])])
            np.multiply(value, scales[r], out=d_points[:, r, j])
    return alpha, beta_water, ratio, a1, a2


def _jacobians(camera, frame, problem, points, x, curvature, ratio, inverse, l1, l2, inverse_z,
               xn, yn, distortion, bad, out):
    """Fill ``out``: d pixel / d point ``(N, 2, 3)`` and, if ``out`` has room for them, the
    :class:`ParameterJacobian` fields (module docs of :func:`project`); ``x`` the solved path
    (lateral positions of the interface points), ``curvature`` its segment curvatures if the
    solver gives them (else None), ``inverse`` 1/ℓ (0 on the normal through the camera)."""
    d_points = out[0]
    alpha, beta_water, ratio, a1, a2 = _point_jacobian(camera, frame, problem, x, curvature,
                                                       ratio, inverse, l1, l2, inverse_z, xn, yn,
                                                       distortion, d_points)
    if bad.any():
        d_points[bad] = np.nan
    if len(out) == 1:
        return
    x1 = x[0]
    p, c, _, _ = _path_derivatives(frame, problem, x1)
    # Rows of d pixel / d (x, y, z)_camera: M (2x2: K's upper block times the distortion
    # Jacobian) times (1/Z) [[1, 0, −x], [0, 1, −y]], projected onto the basis N, e1, e2.
    K = camera.K
    skew = K[0, 1] * inverse_z if K[0, 1] != 0.0 else None
    if len(distortion) == 2:
        m = [[K[0, 0] * inverse_z, skew], [None, K[1, 1] * inverse_z]]
    else:
        _, _, dxx, dxy, dyy = distortion
        m = [[(K[0, 0] * dxx + K[0, 1] * dxy) * inverse_z,
              (K[0, 0] * dxy + K[0, 1] * dyy) * inverse_z],
             [K[1, 1] * dxy * inverse_z, K[1, 1] * dyy * inverse_z]]
    phi = [_combine([(None, vec[0]), (xn, -vec[2])]) for vec in frame.camera_basis]
    psi = [_combine([(None, vec[1]), (yn, -vec[2])]) for vec in frame.camera_basis]
    rows_nea = []
    for mr0, mr1 in m:
        if mr0 is None:
            rows_nea.append([mr1 * ps for ps in psi])
        elif mr1 is None:
            rows_nea.append([mr0 * ph for ph in phi])
        else:
            rows_nea.append([mr0 * ph + mr1 * ps for ph, ps in zip(phi, psi)])
    n_rows = points.shape[0]
    # --- port and camera parameters: general (N, 2, 3) algebra --------------------------------
    n = frame.indices
    N, e1, e2 = frame.normal, frame.e1, frame.e2
    q = np.stack([np.stack(rows, axis=-1) for rows in rows_nea], axis=1)  # (n, 2, 3) in N,e1,e2
    q = q[..., :1] * N + q[..., 1:2] * e1 + q[..., 2:] * e2  # d pixel / d I1, reference frame
    axis = a1[:, None] * e1 + a2[:, None] * e2
    qa = np.einsum("nrj,nj->nr", q, axis)
    qn = q @ N
    h0 = frame.heights[0]
    heights = problem.heights_columns
    tans = [p / c_i for c_i in c]
    beta = [-alpha * t for t in tans]  # d x1 / d h_i through p ...
    beta[0] = beta[0] + tans[0]  # ... and directly
    gamma = [alpha * (h * p * n_i) / (c_i * c_i * c_i) for n_i, h, c_i in zip(n, heights, c)]
    gamma[0] = gamma[0] - (h0 * p * n[0]) / (c[0] * c[0] * c[0])
    d_distance = qn + qa * (beta[0] - beta[-1])[:, None]
    d_thick = np.stack([qa * (beta[j] - beta[-1])[:, None] for j in range(1, len(n) - 1)],
                       axis=-1) if len(n) > 2 else np.zeros((n_rows, 2, 0))
    d_indices = np.stack([qa * g[:, None] for g in gamma], axis=-1)
    center = camera.center
    relative = points - center
    along = relative @ N
    first = (h0 * N + x1[:, None] * axis)[:, None, :]  # I1 − C
    d_normal = (-qn[..., None] * center + h0 * q
                + qa[..., None] * (-beta[0][:, None, None] * center
                                   + beta[-1][:, None, None] * points[:, None, :]
                                   - (alpha * along)[:, None, None] * axis[:, None, :])
                - (ratio[:, None, None] * qn[..., None]) * relative[:, None, :]
                - (ratio * along)[:, None, None] * (q - qa[..., None] * axis[:, None, :]))
    d_normal -= (d_normal @ N)[..., None] * N
    d_center = -d_points - d_distance[..., None] * N
    d_rotation = np.cross(q, first)
    for target, value in zip(out[1:], (d_distance, d_normal, d_indices, d_thick, d_center,
                                       d_rotation)):
        target[...] = value
        if bad.any():
            target[bad] = np.nan


def _run(camera, port, points, solver, paths: bool, jacobian: int):
    if not (port is None or isinstance(port, FlatPort)):
        raise ValueError(f"port must be a measure.FlatPort, a measure.geometry.dome.DomePort or None, got "
                         f"{type(port).__name__}" + (f" (a {type(port).__name__} holds one port "
                                                     f"per camera, {port.description}: pass "
                                                     f"rig.view_port(view))"
                                                     if isinstance(port, RigPort) else ""))
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
    points = np.asarray(points, dtype=np.float64)
    if points.shape == (3,):
        points = points[None]
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3) or (3,), got {points.shape}")
    if port is None:  # no port: all air, the pinhole model through an index-matched plane
        port = index_matched_port(camera.R[:, 2], camera.center)
    port.check_camera(camera.center, "camera")
    frame = _frame(camera, port)
    iterations = []
    outputs = _outputs(points.shape[0], port, paths, jacobian)
    map_row_chunks(lambda chunk, out: _chunk(camera, frame, chunk, solver, paths, jacobian,
                                             iterations, out), (points,), outputs=outputs)
    return outputs, max(iterations, default=0)


def solve_paths(camera: Camera, port: FlatPort | DomePort | None, points,
                solver: str = "fermat") -> RefractedPaths:
    """Refracted light paths from ``points (N, 3)`` (or one point ``(3,)``) in the water to
    ``camera``'s centre. ``port=None`` means no port (all air); a
    :class:`measure.geometry.dome.DomePort` is solved by :func:`measure.geometry.dome_projection.dome_paths`
    (solvers ``"fermat"`` and ``"shooting"``; ``interface_points`` on the inner and outer
    sphere).

    Raises ``ValueError`` for an unknown solver or a camera centre on the water side of the
    port; per-point failures (a point not in the water, NaN input) are NaN rows with a reason.
    Large batches run in chunks on all cores (same result as one batch).
    """
    if isinstance(port, DomePort):
        pixels, reason, is_minimum, interface_points, iterations, _ = dome_paths(
            camera, port, points, solver)
        return RefractedPaths(pixels, interface_points.transpose(1, 0, 2), reason, is_minimum,
                              int(iterations))
    (pixels, reason, is_minimum, interface_points), iterations = _run(camera, port, points,
                                                                      solver, True, 0)
    return RefractedPaths(pixels, interface_points.transpose(1, 0, 2), reason, is_minimum,
                          int(iterations))


def project(camera: Camera, port: FlatPort | DomePort | None, points, solver: str = "fermat", *,
            jacobian: bool = False, parameters: bool = False):
    """Pixels ``(N, 2)`` of points ``(N, 3)`` in the water seen by ``camera`` through ``port``
    (``None``: no port, all air). One point ``(3,)`` gives ``(1, 2)``, like :func:`triangulate`
    gives ``(1, 3)`` for one pixel pair.

    NaN where no path exists (e.g. a point on the camera side of the port). Lens distortion is
    applied like ``cv2.projectPoints``. ``solver``: ``"fermat"`` (the paper) or ``"snell"``.

    ``jacobian=True`` returns ``(pixels, d_points)`` with ``d_points`` ``(N, 2, 3)`` the
    analytic derivatives of each pixel with respect to its point (px/mm, reference frame);
    ``parameters=True`` as well returns ``(pixels, d_points, ParameterJacobian)`` with the
    derivatives with respect to the port (D, normal, indices, thicknesses) and the camera pose.
    They come from the implicit function theorem on the stationarity of the travel time (at
    the solution, Snell's invariant ``p = n_i sin θ_i`` is the same in every medium: one
    equation ``F(p; ℓ, h, n) = 0`` per point) chained with the pinhole and distortion model —
    no finite differences. Rows without a pixel are NaN in every output.

    A :class:`measure.geometry.dome.DomePort` as ``port`` goes to
    :func:`measure.geometry.dome_projection.dome_paths` (solvers ``"fermat"``, ``"shooting"``); its
    ``parameters=True`` gives a :class:`measure.geometry.dome_projection.DomeParameterJacobian`
    (dome centre, radius, thickness, indices, camera centre and rotation).
    """
    if parameters:
        jacobian = True
    if isinstance(port, DomePort):
        pixels, _, _, _, _, rest = dome_paths(camera, port, points, solver,
                                              2 if parameters else int(bool(jacobian)))
        return (pixels, *rest) if jacobian else pixels
    (pixels, *rest), _ = _run(camera, port, points, solver, False,
                              2 if parameters else int(bool(jacobian)))
    if not jacobian:
        return pixels
    if not parameters:
        return pixels, rest[0]
    return pixels, rest[0], ParameterJacobian(*rest[1:])
