"""Forward imaging through a flat port: where does a point in the water appear in a camera?

Two independent solvers of the same refracted path, both vectorized over N points:

* ``"fermat"`` — the paper's section 2.2: in the refraction plane (camera centre, point, port
  normal) the light crosses interface k at ``I_k = J_k + μ_k ε``, where ``J_k`` is where the
  straight line O→P crosses that interface and ``ε`` is the in-plane direction along the
  interface. Fermat's principle: minimize the travel time ``t(μ) = Σ n_i |I_{i+1} − I_i|`` (times
  1/c) by Newton's method on the analytic gradient and (tridiagonal) Hessian, to machine
  precision; the minimum condition (det H > 0, ∂²t/∂μ1² > 0, i.e. H positive definite) is
  reported per point.
* ``"snell"`` — the 1D root of the Snell invariant: ``p = n_i sin θ_i`` is the same in every
  medium and the lateral offsets ``h_i tan θ_i`` add up to the lateral distance of the point.
  Solved with SciPy's vectorized bracketing root finder.

Once the first refraction point ``I_1`` is known, the pixel is the pinhole projection of ``I_1``
(with lens distortion, as ``cv2.projectPoints``). Units mm, reference frame, OpenCV pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import elementwise

from .batching import map_row_chunks
from .camera import Camera
from .port import FlatPort, index_matched_port
from .reasons import Reason

SOLVERS = ("fermat", "snell")


@dataclass(frozen=True)
class RefractedPaths:
    """Light paths from points in the water to one camera centre.

    ``pixels`` ``(N, 2)``; ``interface_points`` ``(K, N, 3)`` (I1, I2 … in mm, reference frame);
    ``reason`` ``(N,)`` :class:`measure.Reason` codes; ``is_minimum`` ``(N,)`` whether the
    Hessian of the travel time is positive definite at the solution (Fermat solver; the Snell
    solver reports True where it converged); ``iterations`` used by the solver.
    """

    pixels: np.ndarray
    interface_points: np.ndarray
    reason: np.ndarray
    is_minimum: np.ndarray
    iterations: int


@dataclass(frozen=True)
class _PlaneProblem:
    """The path problem reduced to the refraction plane.

    ``heights`` ``(N, K+1)``: normal distances travelled in each medium (air gap, layers, water);
    ``lateral`` ``(N,)``: distance of the point from the normal through the camera centre;
    ``axis`` ``(N, 3)``: unit lateral direction from the camera towards the point (zero when the
    point lies on the normal); ``indices`` ``(K+1,)``.
    """

    heights: np.ndarray
    lateral: np.ndarray
    axis: np.ndarray
    indices: np.ndarray
    reason: np.ndarray

    heights_columns: list  # per medium: a scalar where all rows share it (air, layers), else (N,)
    heights_squared: list


def _reduce_to_plane(center: np.ndarray, port: FlatPort, points: np.ndarray) -> _PlaneProblem:
    n_points = points.shape[0]
    reason = np.full(n_points, Reason.OK, dtype=np.int8)
    reason[~np.all(np.isfinite(points), axis=1)] = Reason.INVALID_INPUT
    offsets = port.offsets
    relative = points - center
    along = relative @ port.normal
    lateral_vec = relative - along[:, None] * port.normal
    lateral = np.linalg.norm(lateral_vec, axis=1)
    water_height = points @ port.normal - offsets[-1]
    with np.errstate(invalid="ignore"):
        reason[(reason == Reason.OK) & ~(water_height > 0)] = Reason.NOT_IN_WATER
    ok = reason == Reason.OK
    # Normal distance travelled in each medium: the air gap and the layers are the same for
    # every point (scalars), the water column differs.
    columns = [float(offsets[0] - center @ port.normal), *port.thicknesses,
               np.where(ok, water_height, np.nan)]
    heights = np.column_stack([np.broadcast_to(c, (n_points,)) for c in columns])
    lateral = np.where(ok, lateral, np.nan)
    tiny = 1e-300
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = np.where((lateral > tiny)[:, None], lateral_vec / np.maximum(lateral, tiny)[:, None], 0.0)
    return _PlaneProblem(heights, lateral, axis, np.asarray(port.indices, dtype=float), reason,
                         columns, [h * h for h in columns])


def _segments(x, problem):
    """Lateral steps Δ_i and lengths L_i of the K+1 path segments (lists of ``(N,)`` arrays).

    ``x`` is the list of the K lateral positions of the interface points (mm from the camera's
    normal foot). Column lists keep every operation on contiguous vectors.
    """
    steps = [x[0]] + [x[k] - x[k - 1] for k in range(1, len(x))] + [problem.lateral - x[-1]]
    lengths = [np.sqrt(d * d + h2) for d, h2 in zip(steps, problem.heights_squared)]
    return steps, lengths


def _optical_length(lengths, indices):
    """Travel time times c: ``Σ n_i L_i`` (mm)."""
    total = indices[0] * lengths[0]
    for n_i, length in zip(indices[1:], lengths[1:]):
        total = total + n_i * length
    return total


def _fermat_gradient_hessian(x, problem):
    """Travel time, analytic ∂t/∂x_k and the tridiagonal Hessian (units of c = 1).

    With ``Δ_i`` the lateral step and ``h_i`` the normal height of segment i (length
    ``L_i = sqrt(Δ_i² + h_i²)``): ``t = Σ n_i L_i``, ``∂t/∂x_k = n_k Δ_k/L_k −
    n_{k+1} Δ_{k+1}/L_{k+1}``, ``∂²t/∂x_k² = n_k h²_k/L³_k + n_{k+1} h²_{k+1}/L³_{k+1}`` and
    ``∂²t/∂x_k∂x_{k+1} = −n_{k+1} h²_{k+1}/L³_{k+1}``. Since ``x_k = x(J_k) + μ_k`` these are
    also the derivatives with respect to the paper's μ_k (equations 23-24).
    """
    steps, lengths = _segments(x, problem)
    n = problem.indices
    slope, curvature = [], []
    for n_i, d, length, h2 in zip(n, steps, lengths, problem.heights_squared):
        inverse = 1.0 / length
        slope.append(n_i * d * inverse)  # n_i sin θ_i
        curvature.append(n_i * h2 * inverse * inverse * inverse)
    k = len(x)
    gradient = [slope[i] - slope[i + 1] for i in range(k)]
    diag = [curvature[i] + curvature[i + 1] for i in range(k)]
    off = [-curvature[i + 1] for i in range(k - 1)]
    return _optical_length(lengths, n), gradient, diag, off


def _solve_tridiagonal_spd(diag, off, rhs):
    """Solve ``H s = rhs`` for a symmetric tridiagonal H, vectorized over rows (Thomas).

    ``diag``: K arrays, ``off``: K-1 arrays (H[k, k+1]), ``rhs``: K arrays. Returns the solution
    (K arrays) and whether every pivot is positive, i.e. H is positive definite — for K = 2 the
    paper's minimum condition det H > 0 and ∂²t/∂μ1² > 0.
    """
    k = len(diag)
    pivots = [diag[0]]
    y = [rhs[0]]
    for i in range(1, k):
        factor = off[i - 1] / pivots[i - 1]
        pivots.append(diag[i] - factor * off[i - 1])
        y.append(rhs[i] - factor * y[i - 1])
    solution = [None] * k
    solution[-1] = y[-1] / pivots[-1]
    for i in range(k - 2, -1, -1):
        solution[i] = (y[i] - off[i] * solution[i + 1]) / pivots[i]
    positive = pivots[0] > 0
    for pivot in pivots[1:]:
        positive &= pivot > 0
    return solution, positive


def _solve_fermat(problem: _PlaneProblem, max_iterations: int = 60):
    """Damped Newton on μ (offsets from J_k along ε); returns lateral positions x ``(N, K)``.

    Starts from μ = 0, the straight line O→P through the points J_k; a step that would lengthen
    the travel time is halved. Stops when no step exceeds 1e-15 of the lateral scale (machine
    precision). Also returns whether the Hessian is positive definite at the solution.
    """
    lateral = problem.lateral
    total_height = sum(problem.heights_columns)
    cumulative = np.cumsum(problem.heights, axis=1)[:, :-1]
    straight = [lateral * cumulative[:, k] / total_height for k in range(cumulative.shape[1])]
    finite = np.isfinite(lateral)
    x = [np.where(finite, column, 0.0) for column in straight]
    tolerance = 1e-15 * (1.0 + np.abs(np.where(finite, lateral, 0.0)))
    converged = np.zeros(lateral.shape, dtype=bool)
    positive = converged
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        time_now, gradient, diag, off = _fermat_gradient_hessian(x, problem)
        step, positive = _solve_tridiagonal_spd(diag, off, gradient)
        step = [np.where(finite, s, 0.0) for s in step]
        largest = np.abs(step[0])
        for s in step[1:]:
            largest = np.maximum(largest, np.abs(s))
        if np.any(largest > 1e-6 * (1.0 + np.abs(lateral))):
            # Far from the minimum: halve the steps that would lengthen the travel time.
            limit = time_now * (1 + 4e-16)
            scale = np.ones_like(lateral)
            for _ in range(40):
                trial = [xi - scale * si for xi, si in zip(x, step)]
                worse = _optical_length(_segments(trial, problem)[1], problem.indices) > limit
                if not worse.any():
                    break
                scale[worse] *= 0.5
            step = [scale * s for s in step]
            largest *= scale
        x = [xi - si for xi, si in zip(x, step)]
        converged = largest <= tolerance
        if converged.all():
            break
    return np.column_stack(x), positive & converged, converged, iterations


def _solve_snell(problem: _PlaneProblem):
    """Root of ``Σ h_i p / sqrt(n_i² − p²) = lateral`` for the invariant p = n_i sin θ_i."""
    n = problem.indices
    heights = problem.heights
    upper = n.min() * (1.0 - 1e-13)

    def residual(p, lateral, *heights_per_medium):
        total = -lateral
        for n_i, h_i in zip(n, heights_per_medium):
            total = total + h_i * p / np.sqrt(n_i * n_i - p * p)
        return total

    lateral = problem.lateral
    ok = np.isfinite(lateral)
    p = np.full(lateral.shape, np.nan)
    converged = np.zeros(lateral.shape, dtype=bool)
    iterations = 0
    if ok.any():
        result = elementwise.find_root(
            residual, (np.zeros(ok.sum()), np.full(ok.sum(), upper)),
            args=(lateral[ok], *heights[ok].T),
            tolerances=dict(xatol=1e-17, xrtol=1e-15, fatol=0.0, frtol=0.0),
            maxiter=400)
        p[ok] = result.x
        converged[ok] = result.success | (result.x == 0)
        iterations = int(np.max(result.nit, initial=0))
    with np.errstate(invalid="ignore"):
        offsets = heights * p[:, None] / np.sqrt(n * n - (p * p)[:, None])
    x = np.cumsum(offsets, axis=1)[:, :-1]
    return x, converged, iterations


def _solve_paths_chunk(camera, port, points, solver):
    center = camera.center
    problem = _reduce_to_plane(center, port, points)
    reason = problem.reason.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        if solver == "fermat":
            x, is_minimum, converged, iterations = _solve_fermat(problem)
        else:
            x, converged, iterations = _solve_snell(problem)
            is_minimum = converged.copy()
    reason[(reason == Reason.OK) & ~converged] = Reason.NOT_CONVERGED
    bad = reason != Reason.OK
    x = np.where(bad[:, None], np.nan, x)
    heights_to = np.cumsum(problem.heights, axis=1)[:, :-1]
    interface_points = (center + heights_to.T[:, :, None] * port.normal
                        + x.T[:, :, None] * problem.axis[None])
    pixels = camera.project(interface_points[0])
    return (pixels, interface_points.transpose(1, 0, 2), reason, is_minimum & ~bad,
            np.full(points.shape[0], iterations))


def solve_paths(camera: Camera, port: FlatPort | None, points, solver: str = "fermat") -> RefractedPaths:
    """Refracted light paths from ``points (N, 3)`` (or one point ``(3,)``) in the water to
    ``camera``'s centre. ``port=None`` means no port (all air).

    Raises ``ValueError`` for an unknown solver or a camera centre on the water side of the
    port; per-point failures (a point not in the water, NaN input) are NaN rows with a reason.
    Large batches run in chunks on all cores (same result as one batch).
    """
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
    pixels, interface_points, reason, is_minimum, iterations = map_row_chunks(
        lambda chunk: _solve_paths_chunk(camera, port, chunk, solver), (points,))
    return RefractedPaths(pixels, interface_points.transpose(1, 0, 2), reason, is_minimum,
                          int(iterations.max(initial=0)))


def project(camera: Camera, port: FlatPort | None, points, solver: str = "fermat") -> np.ndarray:
    """Pixels ``(N, 2)`` of points ``(N, 3)`` in the water seen by ``camera`` through ``port``
    (``None``: no port, all air). One point ``(3,)`` gives ``(1, 2)``, like :func:`triangulate`
    gives ``(1, 3)`` for one pixel pair.

    NaN where no path exists (e.g. a point on the camera side of the port). Lens distortion is
    applied like ``cv2.projectPoints``. ``solver``: ``"fermat"`` (the paper) or ``"snell"``.
    """
    return solve_paths(camera, port, points, solver).pixels
