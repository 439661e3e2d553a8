"""The pose of a known rigid object seen through the port by one camera or several.

A known object (a board, a marker constellation, a docking frame) has points ``X_obj`` ``(M, 3)``
in its own frame (mm). Its pose is ``(R, t)`` with ``X_ref = R · X_obj + t`` (the reference frame
= the left camera's frame, as everywhere in the project): ``t`` is the object origin's position.
Each camera behind its port (a :class:`measure.stereo.multiview.View`: any port that traces
rays and is projected through by :func:`measure.geometry.projection.project` — a flat port of
any number of layers, a dome, ``index_matched_port`` for a camera in air) sees some of the points
at pixels ``(M, 2)`` (NaN rows: not seen).

**Start, no guess needed.** The pixels of the view that sees the most points are back-projected
and traced into the water (:meth:`View.water_rays`). Through a flat port these rays do not meet
in one centre (an axial camera: every ray crosses the normal through the camera centre, the
crossings spread by a few mm) and through a decentred dome neither — but nearly. The start
treats them as a virtual pinhole at the point nearest to all of them (least squares) whose axis
is their mean direction, and solves that central PnP problem with OpenCV: ``SOLVEPNP_SQPNP``
(globally optimal, planar and non-planar objects, three points or more, no guess), and for a
planar object also ``SOLVEPNP_IPPE``'s two solutions (the two-fold ambiguity of a plane seen
small). The candidate with the smallest refractive reprojection error is refined (others within
:data:`CANDIDATE_COST_RATIO` of it too, the best kept). A linear generalized PnP on the rays'
Plücker lines (``[d]× (R X + t) = [d]× o``, twelve unknowns) would use the rays as they are,
but its scale rests on the few-mm spread of the rays' centres: with the paper's port at 1 m a
0.1 px noise moves it by tens of per cent, so it is the worse start.

**Refinement** on the refractive reprojection error: ``scipy.optimize.least_squares`` (``trf``)
over ``(φ, t)`` with ``R = exp([φ]×) R₀`` (``R₀`` the start), residuals ``(project(X_ref) −
pixels) / σ`` of every observation in every view, and the analytic Jacobian: d pixel / d point
of :func:`measure.geometry.projection.project` (``jacobian=True``) chained with
``d X_ref / d φ = −[R X_obj]× J_l(φ)`` (``J_l`` the left Jacobian of SO(3)) and
``d X_ref / d t = I``. Vectorized over the points of all views.

**Covariance** ``(6, 6)`` of ``(φ, t)`` — rad and mm, ``φ`` a small rotation of the object about
reference-frame axes applied on the left (``R → exp([φ]×) R``, as the rig's
``right.rotation[k]``), ``t`` the object origin: first order, ``Σ_pix = (JᵀWJ)⁻¹`` with ``W =
diag(1/σ²)``; with a :class:`measure.stereo.rig_covariance.RigCovariance` of the rig (views
given as a pair, :class:`measure.stereo.rig.Rig` of two) also ``A Σ_θ Aᵀ``, ``A =
−(JᵀWJ)⁻¹ JᵀW J_θ``, ``J_θ`` the pixels' derivatives with respect to the rig's named parameters
(:func:`measure.stereo.uncertainty.pixel_jacobians`): the pose an error of the calibration
causes. Without a stated σ the pixel part is scaled by the residuals' own variance
``σ̂² = Σ r² / (2n − 6)`` (``sigma_px`` in the result).

A pose that cannot be had is NaN with a :class:`measure.Reason`: ``TOO_FEW_POINTS`` (fewer than
four observations or fewer than three object points after the rays are traced),
``DEGENERATE`` (collinear object points, or a normal matrix whose condition exceeds
:data:`DEGENERATE_CONDITION`: a direction of the pose the pixels do not fix),
``NOT_CONVERGED`` (the refinement stopped without meeting its tolerances, a point left the
water, or the RMS reprojection error is above ``max_rms_px``). :func:`estimate_poses` runs a
batch of frames and never raises half-way. Units mm, rad, px.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares

from ..geometry.projection import project
from ..reasons import Reason
from .multiview import View
from .rig_covariance import RigCovariance
from .rig import Rig
from .uncertainty import pixel_jacobians

#: A start candidate whose refractive reprojection cost is within this factor of the best
#: candidate's is refined as well (the better result is kept).
CANDIDATE_COST_RATIO = 4.0
#: An object whose centred points' second singular value is below this fraction of the first
#: is collinear: its rotation about that line is not fixed.
COLLINEAR_LIMIT = 1e-9
#: An object whose third singular value is below this fraction of the first is planar (IPPE's
#: two solutions join the candidates).
PLANAR_LIMIT = 1e-9
#: Largest condition number of the column-scaled normal matrix ``JᵀWJ`` of a pose that counts
#: as determined (above: ``DEGENERATE``).
DEGENERATE_CONDITION = 1e12
#: Default largest RMS reprojection error (px) of an accepted pose (above: ``NOT_CONVERGED``:
#: the refinement settled in a wrong minimum, or the pixels are not those of the object).
MAX_RMS_PX = 10.0
#: ``least_squares``' ``xtol``, ``ftol`` and ``gtol`` (relative; the variables scaled by the
#: Jacobian): at 5 m a step of 1e-12 of the pose is 5e-9 mm.
TOLERANCE = 1e-12


@dataclass(frozen=True)
class Pose:
    """One pose: ``R`` ``(3, 3)``, ``t`` ``(3,)`` mm with ``X_ref = R · X_obj + t``;
    ``covariance`` ``(6, 6)`` of ``(φx, φy, φz, tx, ty, tz)`` (rad, mm; module docs) with its
    ``pixel`` and ``rig`` parts; ``rms_px`` the RMS reprojection error of the observations
    used, ``sigma_px`` the pixel σ the covariance holds (stated, or estimated from the
    residuals), ``observations`` how many pixels were used, ``reason`` a :class:`Reason`
    (NaN everywhere unless ``OK``)."""

    R: np.ndarray
    t: np.ndarray
    covariance: np.ndarray
    pixel: np.ndarray
    rig: np.ndarray
    rms_px: float
    sigma_px: float
    observations: int
    reason: int

    @property
    def valid(self) -> bool:
        return self.reason == Reason.OK

    def transform(self, points_obj) -> np.ndarray:
        """Object-frame points ``(N, 3)`` in the reference frame: ``R · X + t``."""
        return np.asarray(points_obj, dtype=np.float64).reshape(-1, 3) @ self.R.T + self.t

    @property
    def rotation_vector(self) -> np.ndarray:
        """``R`` as a rotation vector (rad), ``(3,)``."""
        return np.full(3, np.nan) if not self.valid else cv2.Rodrigues(self.R)[0].ravel()


@dataclass(frozen=True)
class Poses:
    """:func:`estimate_poses`' answer for F frames: the fields of :class:`Pose` stacked —
    ``R`` ``(F, 3, 3)``, ``t`` ``(F, 3)``, ``covariance``/``pixel``/``rig`` ``(F, 6, 6)``,
    ``rms_px``, ``sigma_px``, ``observations``, ``reason`` ``(F,)``."""

    R: np.ndarray
    t: np.ndarray
    covariance: np.ndarray
    pixel: np.ndarray
    rig: np.ndarray
    rms_px: np.ndarray
    sigma_px: np.ndarray
    observations: np.ndarray
    reason: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.reason == Reason.OK

    def __getitem__(self, frame: int) -> Pose:
        return Pose(self.R[frame], self.t[frame], self.covariance[frame], self.pixel[frame],
                    self.rig[frame], float(self.rms_px[frame]), float(self.sigma_px[frame]),
                    int(self.observations[frame]), int(self.reason[frame]))

    def __len__(self) -> int:
        return self.reason.shape[0]


def _failed(reason: Reason, observations: int = 0, rms_px: float = np.nan) -> Pose:
    nan = np.full((6, 6), np.nan)
    return Pose(np.full((3, 3), np.nan), np.full(3, np.nan), nan, nan.copy(), nan.copy(),
                float(rms_px), np.nan, int(observations), int(reason))


def as_views(views) -> tuple[View, ...]:
    """``views`` as a tuple of :class:`View`: a :class:`measure.stereo.rig.Rig` (its cameras
    in order — a pair's left, right —, each with its port), one :class:`View`, or a sequence of
    them."""
    if isinstance(views, Rig):
        return tuple(views.views())
    if isinstance(views, View):
        return (views,)
    try:
        views = tuple(views)
    except TypeError:
        raise ValueError("views must be a Rig, a View or a sequence of Views") from None
    if not views or not all(isinstance(v, View) for v in views):
        raise ValueError("views must be a Rig, a View or a sequence of Views")
    return views


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]×`` of vectors ``(N, 3)`` as ``(N, 3, 3)``."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """``exp([φ]×)``: the rotation matrix of the rotation vector ``φ`` ``(3,)`` (Rodrigues)."""
    return cv2.Rodrigues(np.asarray(phi, dtype=np.float64).reshape(3, 1))[0]


def left_jacobian(phi: np.ndarray) -> np.ndarray:
    """``J_l(φ)``: ``exp([φ + δ]×) ≈ exp([J_l δ]×) exp([φ]×)``."""
    theta = float(np.linalg.norm(phi))
    K = skew(phi)
    if theta < 1e-6:
        return np.eye(3) + 0.5 * K + K @ K / 6.0
    return (np.eye(3) + (1 - np.cos(theta)) / theta ** 2 * K
            + (theta - np.sin(theta)) / theta ** 3 * K @ K)


class _Problem:
    """The observations of one frame: per view the indices of the object points it saw and
    their pixels, flattened."""

    def __init__(self, views, object_points, pixels, weights):
        self.views = views
        self.object_points = object_points
        self.rows = []  # per view: object point indices
        self.slices = []
        start = 0
        for v in range(len(views)):
            rows = np.flatnonzero(np.all(np.isfinite(pixels[v]), axis=1))
            self.rows.append(rows)
            self.slices.append(slice(start, start + rows.size))
            start += rows.size
        self.n = start
        self.observed = np.concatenate([pixels[v][r] for v, r in enumerate(self.rows)])
        self.weights = np.concatenate([weights[v][r] for v, r in enumerate(self.rows)])
        self.sqrt_weights = np.sqrt(self.weights)

    def project(self, R, t, jacobian=True):
        """Pixels ``(n, 2)`` of the observations at pose ``(R, t)`` and d pixel / d X_ref
        ``(n, 2, 3)``; also X_ref of every object point."""
        X = self.object_points @ R.T + t
        pixels = np.empty((self.n, 2))
        d_points = np.empty((self.n, 2, 3)) if jacobian else None
        for view, rows, where in zip(self.views, self.rows, self.slices):
            if rows.size == 0:
                continue
            if jacobian:
                pixels[where], d_points[where] = project(view.camera, view.port, X[rows],
                                                         jacobian=True)
            else:
                pixels[where] = project(view.camera, view.port, X[rows])
        return pixels, d_points, X

    @property
    def object_rows(self) -> np.ndarray:
        return np.concatenate(self.rows)


def _start_candidates(problem: _Problem, origins, directions, planar: bool):
    """Poses ``[(R, t), …]`` from a central PnP on the rays of the view with the most
    observations (module docs)."""
    counts = [r.size for r in problem.rows]
    view = int(np.argmax(counts))
    ok = np.all(np.isfinite(directions[problem.slices[view]]), axis=1)
    o = origins[problem.slices[view]][ok]
    d = directions[problem.slices[view]][ok]
    X = problem.object_points[problem.rows[view][ok]]
    if X.shape[0] < 3:
        return []
    # the point nearest to every ray: Σ (I − d dᵀ) c = Σ (I − d dᵀ) o
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = P.sum(axis=0)
    b = np.einsum("nij,nj->i", P, o)
    try:
        centre = np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        centre = o.mean(axis=0)
    # the virtual camera: z along the mean ray, its rays the directions from the centre to a
    # point of each ray (the ray's own direction if the centre is on it)
    axis = d.sum(axis=0)
    axis /= np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x_axis = np.cross(helper, axis)
    x_axis /= np.linalg.norm(x_axis)
    B = np.stack([x_axis, np.cross(axis, x_axis), axis])  # rows: virtual camera axes
    local = d @ B.T
    with np.errstate(divide="ignore", invalid="ignore"):
        normalized = local[:, :2] / local[:, 2:3]
    front = local[:, 2] > 1e-6
    if front.sum() < 3:
        return []
    X, normalized = X[front], normalized[front]
    candidates = []
    methods = [cv2.SOLVEPNP_SQPNP]
    if planar and X.shape[0] >= 4:
        methods.append(cv2.SOLVEPNP_IPPE)
    for method in methods:
        try:
            count, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                X.reshape(-1, 1, 3), normalized.reshape(-1, 1, 2), np.eye(3), None,
                flags=method)
        except cv2.error:
            continue
        for k in range(count):
            Rv = cv2.Rodrigues(rvecs[k])[0]
            tv = tvecs[k].ravel()
            if not (np.all(np.isfinite(Rv)) and np.all(np.isfinite(tv))):
                continue
            # X_virtual = Rv X_obj + tv, X_ref = Bᵀ X_virtual + centre
            candidates.append((B.T @ Rv, B.T @ tv + centre))
    return candidates


def _refine(problem: _Problem, R0, t0, max_nfev: int):
    """Least squares on the refractive reprojection error from ``(R0, t0)``: ``(R, t, result,
    whether every point is in the water there)``, or None if a point of the start is not."""
    cache = {}

    def evaluate(x):
        key = x.tobytes()
        if key not in cache:  # kept: the solution is among them
            R = exp_so3(x[:3]) @ R0
            pixels, d_points, X = problem.project(R, x[3:])
            cache[key] = (R, pixels, d_points, X)
        return cache[key]

    def residual(x):
        _, pixels, _, _ = evaluate(x)
        r = ((pixels - problem.observed) * problem.sqrt_weights[:, None]).ravel()
        return np.where(np.isfinite(r), r, 1e8)

    def jacobian(x):
        R, _, d_points, X = evaluate(x)
        Xr = X[problem.object_rows] - x[3:]  # R X_obj of every observation
        d_phi = -skew(Xr) @ left_jacobian(x[:3])  # (n, 3, 3)
        J = np.concatenate([d_points @ d_phi, d_points], axis=2)  # (n, 2, 6)
        J *= problem.sqrt_weights[:, None, None]
        J = J.reshape(-1, 6)
        return np.where(np.isfinite(J), J, 0.0)

    x0 = np.concatenate([np.zeros(3), t0])
    if not np.all(np.isfinite(evaluate(x0)[1])):
        return None  # a point of the start is not in the water
    result = least_squares(residual, x0, jac=jacobian, method="trf", x_scale="jac",
                           xtol=TOLERANCE, ftol=TOLERANCE, gtol=TOLERANCE, max_nfev=max_nfev)
    inside = bool(np.all(np.isfinite(evaluate(result.x)[1])))
    return exp_so3(result.x[:3]) @ R0, result.x[3:].copy(), result, inside


def _cost(problem: _Problem, R, t) -> float:
    pixels, _, _ = problem.project(R, t, jacobian=False)
    r = (pixels - problem.observed) * problem.sqrt_weights[:, None]
    return float(np.sum(r * r)) if np.all(np.isfinite(r)) else np.inf


def _rig_jacobian(rig: Rig, problem: _Problem, X, rig_covariance: RigCovariance):
    """d pixel / d rig parameters ``(n, 2, P)`` of the observations."""
    _, _, d_parameters = pixel_jacobians(rig, X, rig_covariance.names,
                                         rig_covariance.normal_axes)
    return np.concatenate([d_parameters[rows, 2 * v:2 * v + 2]
                           for v, rows in enumerate(problem.rows)])


def _solve_frame(views, object_points, pixels, weights, stated_sigma, rig, rig_covariance,
                 max_rms_px, max_nfev, collinear, planar) -> Pose:
    problem = _Problem(views, object_points, pixels, weights)
    if problem.n == 0:
        return _failed(Reason.TOO_FEW_POINTS)
    # trace every observation into the water; drop those without a water ray
    origins = np.full((problem.n, 3), np.nan)
    directions = np.full((problem.n, 3), np.nan)
    for view, rows, where in zip(views, problem.rows, problem.slices):
        if rows.size:
            origins[where], directions[where], _ = view.water_rays(problem.observed[where])
    traced = np.all(np.isfinite(directions), axis=1)
    if not traced.all():
        keep = [(rows[traced[where]]) for rows, where in zip(problem.rows, problem.slices)]
        masked = [np.full_like(pixels[v], np.nan) for v in range(len(views))]
        for v, rows in enumerate(keep):
            masked[v][rows] = pixels[v][rows]
        problem = _Problem(views, object_points, masked, weights)
        origins, directions = origins[traced], directions[traced]
    used = np.unique(problem.object_rows)
    if problem.n < 4 or used.size < 3:
        return _failed(Reason.TOO_FEW_POINTS, problem.n)
    if collinear is None:
        singular = np.linalg.svd(object_points[used] - object_points[used].mean(axis=0),
                                 compute_uv=False)
        collinear = singular[1] <= COLLINEAR_LIMIT * singular[0]
        planar = singular[2] <= PLANAR_LIMIT * singular[0]
    if collinear:
        return _failed(Reason.DEGENERATE, problem.n)
    candidates = _start_candidates(problem, origins, directions, planar)
    if len(candidates) > 1:  # refine the best and those not much worse
        costs = np.array([_cost(problem, R, t) for R, t in candidates])
        order = [k for k in np.argsort(costs) if costs[k] <= CANDIDATE_COST_RATIO * costs.min()]
        candidates = [candidates[k] for k in order]
    best = None
    for start in candidates:
        refined = _refine(problem, *start, max_nfev)
        if refined is not None and refined[3] and (best is None
                                                   or refined[2].cost < best[2].cost):
            best = refined  # every point in the water at the solution
    if best is None:
        return _failed(Reason.NOT_CONVERGED, problem.n)
    R, t, result, _ = best
    # the weighted Jacobian at the solution, for a rotation applied on the left of R itself
    J = result.jac.copy()
    J[:, :3] = np.linalg.solve(left_jacobian(result.x[:3]).T, J[:, :3].T).T
    J = (J.reshape(-1, 2, 6) / problem.sqrt_weights[:, None, None])
    r = result.fun.reshape(-1, 2) / problem.sqrt_weights[:, None]
    X = problem.object_points @ R.T + t
    rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    if result.status <= 0 or rms > max_rms_px:
        return _failed(Reason.NOT_CONVERGED, problem.n, rms)
    Jw = J * problem.sqrt_weights[:, None, None]
    Jw = Jw.reshape(-1, 6)
    normal = Jw.T @ Jw
    scale = np.sqrt(np.diag(normal))
    if not np.all(scale > 0):
        return _failed(Reason.DEGENERATE, problem.n, rms)
    eig = np.linalg.eigvalsh(normal / np.outer(scale, scale))
    if eig[0] <= eig[-1] / DEGENERATE_CONDITION:
        return _failed(Reason.DEGENERATE, problem.n, rms)
    pixel_cov = np.linalg.inv(normal)
    if stated_sigma:
        sigma = float(np.sqrt(np.mean(1.0 / problem.weights)))
    else:  # the residuals' variance (unit weights)
        dof = 2 * problem.n - 6
        sigma = float(np.sqrt(np.sum(r * r) / dof)) if dof > 0 else np.nan
        pixel_cov = pixel_cov * sigma * sigma
    pixel_cov = 0.5 * (pixel_cov + pixel_cov.T)
    rig_cov = np.zeros((6, 6))
    if rig_covariance is not None:
        J_theta = _rig_jacobian(rig, problem, X, rig_covariance)  # (n, 2, P)
        Jt = (J_theta * problem.weights[:, None, None]).reshape(-1, J_theta.shape[2])
        # A = −(JᵀWJ)⁻¹ JᵀW J_θ (with the stated weights; unit weights: the same A)
        A = -np.linalg.solve(normal, J.reshape(-1, 6).T @ Jt)
        rig_cov = A @ rig_covariance.matrix @ A.T
        rig_cov = 0.5 * (rig_cov + rig_cov.T)
    return Pose(R, t, pixel_cov + rig_cov, pixel_cov, rig_cov, rms, sigma, problem.n,
                int(Reason.OK))


def _weights(pixel_sigma, n_views: int, n_points: int, frames: int):
    """``(F, V, M)`` weights 1/σ² and whether σ was stated."""
    if pixel_sigma is None:
        return np.ones((frames, n_views, n_points)), False
    sigma = np.asarray(pixel_sigma, dtype=np.float64)
    try:
        sigma = np.broadcast_to(sigma, (frames, n_views, n_points)) if sigma.ndim != 2 else \
            np.broadcast_to(sigma[None], (frames, n_views, n_points))
    except ValueError:
        raise ValueError(f"pixel_sigma must be a number, (V, M) = ({n_views}, {n_points}) or "
                         f"(F, V, M), got shape {sigma.shape}") from None
    if not np.all(sigma[np.isfinite(sigma)] > 0):
        raise ValueError("pixel_sigma must be positive")
    with np.errstate(divide="ignore"):
        return 1.0 / (sigma * sigma), True


def estimate_poses(views, object_points, pixels, pixel_sigma=None,
                   rig_covariance: RigCovariance | None = None, max_rms_px: float = MAX_RMS_PX,
                   max_nfev: int = 100) -> Poses:
    """The pose of a known object in each of F frames (module docs).

    ``views``: a :class:`measure.stereo.rig.Rig` (every camera, each through its port), one
    :class:`measure.stereo.multiview.View` or a sequence of them (V views). ``object_points``
    ``(M, 3)`` mm in the object frame. ``pixels`` ``(F, V, M, 2)`` (``(F, M, 2)`` for one
    view), NaN where a view did not see a point. ``pixel_sigma`` px: a number, ``(V, M)`` or
    ``(F, V, M)``; None: estimated from each frame's residuals. ``rig_covariance``: the rig's
    :class:`RigCovariance` (views given as a pair, ``StereoRig``, only). ``max_rms_px``: the
    largest RMS reprojection error of an accepted pose.

    Bad arguments raise ``ValueError``; a frame without a pose is NaN with its reason, and the
    batch goes on."""
    rig = views if isinstance(views, Rig) and views.port is not None else None
    views = as_views(views)
    if rig_covariance is not None:
        if rig is None:
            raise ValueError("rig_covariance needs the views as a StereoRig (its parameters "
                             "name the rig's cameras and port)")
        rig.port.check_parameter_names(rig_covariance.names)
    object_points = np.asarray(object_points, dtype=np.float64)
    if object_points.ndim != 2 or object_points.shape[1] != 3 or object_points.shape[0] == 0:
        raise ValueError(f"object_points must have shape (M, 3), got {object_points.shape}")
    if not np.all(np.isfinite(object_points)):
        raise ValueError("object_points must be finite")
    pixels = np.asarray(pixels, dtype=np.float64)
    n_views, n_points = len(views), object_points.shape[0]
    if pixels.ndim == 3 and n_views == 1:
        pixels = pixels[:, None]
    if pixels.ndim != 4 or pixels.shape[1:] != (n_views, n_points, 2):
        raise ValueError(f"pixels must have shape (F, {n_views}, {n_points}, 2) (frames, views, "
                         f"object points, (u, v)), got {pixels.shape}")
    frames = pixels.shape[0]
    weights, stated = _weights(pixel_sigma, n_views, n_points, frames)
    pixels = np.where(np.isfinite(weights)[..., None], pixels, np.nan)
    centred = object_points - object_points.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False) if n_points >= 3 else np.zeros(3)
    # the whole object's shape once; a frame that sees a subset checks its own
    whole = None if n_points < 3 else (bool(singular[1] <= COLLINEAR_LIMIT * singular[0]),
                                       bool(singular[2] <= PLANAR_LIMIT * singular[0]))
    out = [] if frames else [_failed(Reason.OK)]  # zero frames: shapes from a stand-in
    for f in range(frames):
        seen = np.any(np.all(np.isfinite(pixels[f]), axis=2), axis=0)
        shape = whole if whole is not None and seen.all() else (None, None)
        try:
            pose = _solve_frame(views, object_points, pixels[f], weights[f], stated, rig,
                                rig_covariance, max_rms_px, max_nfev, *shape)
        except (np.linalg.LinAlgError, ValueError, cv2.error):
            pose = _failed(Reason.NOT_CONVERGED)  # e.g. a singular system: no pose, go on
        out.append(pose)
    poses = Poses(np.stack([p.R for p in out]), np.stack([p.t for p in out]),
                  np.stack([p.covariance for p in out]), np.stack([p.pixel for p in out]),
                  np.stack([p.rig for p in out]), np.array([p.rms_px for p in out]),
                  np.array([p.sigma_px for p in out]),
                  np.array([p.observations for p in out], dtype=np.int64),
                  np.array([p.reason for p in out], dtype=np.int8))
    if not frames:
        poses = Poses(*(getattr(poses, name)[:0] for name in Poses.__dataclass_fields__))
    return poses


def estimate_pose(views, object_points, pixels, pixel_sigma=None,
                  rig_covariance: RigCovariance | None = None, max_rms_px: float = MAX_RMS_PX,
                  max_nfev: int = 100) -> Pose:
    """:func:`estimate_poses` of one frame: ``pixels`` ``(V, M, 2)`` (``(M, 2)`` for one
    view), ``pixel_sigma`` a number or ``(V, M)``."""
    pixels = np.asarray(pixels, dtype=np.float64)
    sigma = pixel_sigma if pixel_sigma is None or np.ndim(pixel_sigma) == 0 else \
        np.asarray(pixel_sigma, dtype=np.float64)[None]
    return estimate_poses(views, object_points, pixels[None], sigma, rig_covariance,
                          max_rms_px, max_nfev)[0]


def pinhole_pose(camera, object_points, pixels):
    """The baseline: ``cv2.solvePnP`` (SQPnP, then Levenberg–Marquardt refinement) with
    ``camera``'s intrinsics as a pinhole that ignores the port — what a calibration in air
    gives. ``(R, t)`` in the reference frame (``X_ref = R · X_obj + t``); NaN if OpenCV fails
    or fewer than four points are seen."""
    object_points = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    ok = np.all(np.isfinite(pixels), axis=1)
    nan = (np.full((3, 3), np.nan), np.full(3, np.nan))
    if ok.sum() < 4:
        return nan
    dist = camera.dist if camera.dist is not None else None
    try:
        found, rvec, tvec = cv2.solvePnP(object_points[ok].reshape(-1, 1, 3),
                                         pixels[ok].reshape(-1, 1, 2), camera.K, dist,
                                         flags=cv2.SOLVEPNP_SQPNP)
        if not found:
            return nan
        rvec, tvec = cv2.solvePnPRefineLM(object_points[ok].reshape(-1, 1, 3),
                                          pixels[ok].reshape(-1, 1, 2), camera.K, dist,
                                          rvec, tvec)
    except cv2.error:
        return nan
    Rc = cv2.Rodrigues(rvec)[0]  # X_cam = Rc X_obj + tc
    return camera.R @ Rc, camera.R @ tvec.ravel() + camera.t


def rotation_error(R_a, R_b) -> np.ndarray:
    """Angle (rad) of ``R_a R_bᵀ``, for ``(3, 3)`` or ``(F, 3, 3)`` stacks."""
    D = np.asarray(R_a) @ np.swapaxes(np.asarray(R_b), -1, -2)
    cos = (np.trace(D, axis1=-2, axis2=-1) - 1.0) / 2.0
    # near zero arccos loses precision: use the skew part's norm there
    skew = np.stack([D[..., 2, 1] - D[..., 1, 2], D[..., 0, 2] - D[..., 2, 0],
                     D[..., 1, 0] - D[..., 0, 1]], axis=-1)
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=-1), cos)


def shared_offset_covariance(views, object_points, pixels, pose: Pose, offsets,
                             pixel_sigma=None) -> np.ndarray:
    """``(6, 6)`` of ``(φ, t)`` (rad, mm; as :attr:`Pose.covariance`): the pose's covariance
    from one error the observations share — every observed pixel moved by ``β · offsets``,
    ``β ~ N(0, 1)`` one number for them all — to first order at ``pose``:
    ``g gᵀ``, ``g = (JᵀWJ)⁻¹ JᵀW · offsets`` (``J`` d pixel / d pose at the solution, ``W`` the
    weights ``1/σ²`` of ``pixel_sigma`` as :func:`estimate_pose` takes it, unit for None).
    Such an error (a scale of the constellation's image, say) leaves the residuals as they are,
    so the residuals' σ never holds it. ``views``, ``object_points`` and ``pixels`` ``(V, M, 2)``
    as for :func:`estimate_pose` (NaN rows and NaN σ: not seen); ``offsets`` ``(V, M, 2)`` px,
    the pattern of one σ (NaN rows: left out). The observations are those given: one without a
    water ray, which :func:`estimate_pose` drops, should be NaN here too. NaN where ``pose``
    is not valid or fewer than six pixel coordinates remain."""
    views = as_views(views)
    object_points = np.asarray(object_points, dtype=np.float64)
    pixels = np.asarray(pixels, dtype=np.float64).reshape(len(views), -1, 2)
    offsets = np.asarray(offsets, dtype=np.float64).reshape(pixels.shape)
    if not pose.valid:
        return np.full((6, 6), np.nan)
    weights, _ = _weights(pixel_sigma, len(views), object_points.shape[0], 1)
    used = np.isfinite(weights[0]) & np.all(np.isfinite(offsets), axis=2)  # as estimate_pose
    problem = _Problem(views, object_points, np.where(used[..., None], pixels, np.nan),
                       weights[0])
    _, d_points, X = problem.project(pose.R, pose.t)
    Xr = X[problem.object_rows] - pose.t  # R X_obj; φ applied on the left of R
    J = np.concatenate([d_points @ -skew(Xr), d_points], axis=2).reshape(-1, 6)
    shift = np.concatenate([offsets[v][rows] for v, rows in enumerate(problem.rows)]).ravel()
    w = np.repeat(problem.weights, 2)
    ok = np.all(np.isfinite(J), axis=1) & np.isfinite(shift) & np.isfinite(w)
    if ok.sum() < 6:
        return np.full((6, 6), np.nan)
    Jw = J[ok] * w[ok, None]
    g = np.linalg.solve(J[ok].T @ Jw, Jw.T @ shift[ok])
    return np.outer(g, g)


__all__ = ["CANDIDATE_COST_RATIO", "DEGENERATE_CONDITION", "MAX_RMS_PX", "TOLERANCE", "Pose",
           "Poses", "as_views", "estimate_pose", "estimate_poses", "exp_so3", "left_jacobian",
           "pinhole_pose", "rotation_error", "shared_offset_covariance", "skew"]
