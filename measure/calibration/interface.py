"""The flat interface in front of one camera, estimated from a known object (after Agrawal et
al., "A Theory of Multi-Layer Flat Refractive Geometry", CVPR 2012: the interface's normal and
distance are determined by the images of a known object through it).

Unknowns: the port's distance ``D`` (mm) and its normal, tilted from the starting normal ``n₀``
by ``(a₀, a₁)`` rad about the two axes of :func:`measure.calibration.selfcal.tilt_basis` (``n =
normalize(n₀ + a₀ e₀ + a₁ e₁)``, as the rig covariance's ``port.tilt[k]``), and the object's
pose in each of F frames (``X_ref = R · X_obj + t``), and optionally the thicknesses of some
layers (``free_thicknesses``: e.g. the water of a tank, air | glass | water | glass | air,
whose thickness is unknown; Agrawal et al. show the layers' thicknesses are fixed by a known
object). The indices and the other thicknesses stay as given. Start: the given port (a design
value) and each frame's pose from :func:`measure.stereo.pose.estimate_pose` through it; then
one ``least_squares`` over everything on the refractive reprojection error, with the analytic
Jacobian (the port's from ``project(..., parameters=True)``, the poses' as in
:mod:`measure.stereo.pose`). Agrawal et al.'s start is :func:`interface_start`, for when no
design value is at hand: the normal in closed form from their flat refraction constraint, the
distance from a one-dimensional search (where they solve a polynomial).

Where this differs from :func:`measure.calibration.housing.calibrate_housing`: one camera, any
known object (not only a board), no in-air stereo calibration. Units mm, rad, px.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .selfcal import tilt_basis
from ..geometry.port import require_flat_port
from ..geometry.projection import project
from ..reasons import Reason
from ..stereo.multiview import View
from ..stereo.pose import (DEGENERATE_CONDITION, TOLERANCE, estimate_poses, exp_so3, left_jacobian,
                           skew)

#: The distances (mm beyond the camera centre, along the normal) :func:`interface_start` tries.
START_DISTANCES_MM = np.geomspace(1.0, 1000.0, 31)

#: A column of the Jacobian below this fraction of the largest is a number no pixel moves with:
#: its column holds rounding only (3e-16 px/mm for a tank's distance, where a layer's thickness
#: moves the pixels 0.05 px/mm), which the column scaling would otherwise blow up to one.
NO_EFFECT = 1e-9

#: The names of the interface's parameters, in the order of :attr:`InterfaceEstimate.covariance`.
INTERFACE_NAMES = ("port.distance", "port.tilt[0]", "port.tilt[1]")


@dataclass(frozen=True)
class InterfaceEstimate:
    """``port`` (the given port with the estimated distance, normal and free thicknesses),
    ``R`` ``(F, 3, 3)`` and ``t`` ``(F, 3)`` the object's poses, ``covariance`` of the
    estimated numbers named in ``names`` (of ``port.distance`` mm, ``port.tilt[0]``,
    ``port.tilt[1]`` rad about ``normal_axes`` ``(2, 3)`` — the axes ⟂ the start normal — and
    ``port.thickness[j]`` mm of each free layer; the marginal of the joint covariance with the
    poses), ``rms_px``, ``sigma_px`` (the pixel σ the covariance holds: stated,
    or from the residuals), ``reason``, ``residuals_px`` ``(F, M, 2)`` (NaN where unseen)."""

    port: object
    R: np.ndarray
    t: np.ndarray
    covariance: np.ndarray
    normal_axes: np.ndarray
    rms_px: float
    sigma_px: float
    reason: int
    names: tuple = INTERFACE_NAMES
    residuals_px: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        return self.reason == Reason.OK


def estimate_interface(view: View, object_points, pixels, pixel_sigma=None,
                       max_nfev: int = 200, free_thicknesses=(),
                       free_distance: bool = True, camera_covariance=None) -> InterfaceEstimate:
    """The distance and normal of ``view.port`` (a :class:`measure.FlatPort`, the start) and
    the object's poses from ``pixels`` ``(F, M, 2)`` of ``object_points`` ``(M, 3)`` (module
    docs); ``free_thicknesses``: the layers (indices into ``port.thicknesses``) whose thickness
    is estimated too; ``free_distance`` False keeps the distance (an object in the camera's own
    medium beyond a tank: parallel layers shift a ray by their thicknesses only, wherever they
    stand, and no image fixes their distance). NaN results with a reason where a frame has no
    starting pose (its reason), the refinement does not converge (``NOT_CONVERGED``) or the
    data do not fix the interface (``DEGENERATE``). ValueError for a layer that is not one of
    the port's. ``camera_covariance``: the in-air calibration's covariance of the camera's
    intrinsics (a :class:`measure.stereo.rig_covariance.RigCovariance` of ``left.fx`` …, as
    ``camera.yaml`` carries it); the intrinsics stay held and their covariance is propagated
    into the interface's (:func:`camera_term`), else the covariance is conditional on them."""
    port = require_flat_port(view.port, "estimate_interface needs a flat port (a FlatPort)")
    object_points, pixels, layers = _checked_inputs(port, object_points, pixels,
                                                    free_thicknesses)
    frames = pixels.shape[0]
    axes = np.array(tilt_basis(port.normal))
    active = np.array(([0] if free_distance else []) + [1, 2]
                      + [3 + i for i in range(len(layers))])
    k = active.size
    names = tuple((INTERFACE_NAMES + tuple(f"port.thickness[{j}]" for j in layers))[i]
                  for i in active)
    nan = InterfaceEstimate(port, np.full((frames, 3, 3), np.nan), np.full((frames, 3), np.nan),
                            np.full((k, k), np.nan), axes, np.nan, np.nan, int(Reason.OK),
                            names, np.full(pixels.shape, np.nan))
    starts = estimate_poses(view, object_points, pixels, pixel_sigma)
    if not starts.valid.all():
        first = int(starts.reason[~starts.valid][0])
        return InterfaceEstimate(**{**nan.__dict__, "reason": first})
    problem = _InterfaceProblem(view.camera, port, object_points, pixels, axes, active, layers,
                                starts, 1.0 if pixel_sigma is None else float(pixel_sigma))
    lower = np.full(problem.n_params, -np.inf)
    lower[:k][active >= 3] = 0.0  # a thickness stays positive (FlatPort refuses 0)
    try:
        result = least_squares(problem.residual, problem.x0, jac=problem.jacobian, method="trf",
                               x_scale="jac", bounds=(lower, np.inf), xtol=TOLERANCE,
                               ftol=TOLERANCE, gtol=TOLERANCE, max_nfev=max_nfev)
    except ValueError:
        return InterfaceEstimate(**{**nan.__dict__, "reason": int(Reason.NOT_CONVERGED)})
    moved, _, phi, R, t, X, uv, _, _ = problem.evaluate(result.x)
    r = uv - problem.observed
    if result.status <= 0 or not np.all(np.isfinite(r)):
        return InterfaceEstimate(**{**nan.__dict__, "reason": int(Reason.NOT_CONVERGED)})
    J = result.jac.copy()
    for f in range(frames):  # rotations applied on the left of each R itself
        cols = slice(k + 6 * f, k + 3 + 6 * f)
        J[:, cols] = np.linalg.solve(left_jacobian(phi[f]).T, J[:, cols].T).T
    normal = J.T @ J
    scale = np.sqrt(np.diag(normal))
    if not np.all(scale > NO_EFFECT * scale.max()):  # a number no pixel moves with (rounding)
        return InterfaceEstimate(**{**nan.__dict__, "reason": int(Reason.DEGENERATE)})
    eig = np.linalg.eigvalsh(normal / np.outer(scale, scale))
    if eig[0] <= eig[-1] / DEGENERATE_CONDITION:
        return InterfaceEstimate(**{**nan.__dict__, "reason": int(Reason.DEGENERATE)})
    inverse = np.linalg.inv(normal)
    covariance = inverse[:k, :k]
    rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    residuals = np.full(pixels.shape, np.nan)
    residuals[problem.rows, problem.points] = r
    if pixel_sigma is None:
        dof = r.size - problem.n_params
        sigma_px = float(np.sqrt(np.sum(r * r) / dof)) if dof > 0 else np.nan
        covariance = covariance * sigma_px ** 2
    else:
        sigma_px = float(pixel_sigma)
    if camera_covariance is not None:
        covariance = covariance + camera_term(view.camera, moved, X, J, inverse, k,
                                              problem.sigma, camera_covariance)
    # the tilts reported about the start normal's axes: at the solution the normal is m/|m|
    return InterfaceEstimate(moved, R, t, 0.5 * (covariance + covariance.T), axes, rms,
                             sigma_px, int(Reason.OK), names, residuals)


def _checked_inputs(port, object_points, pixels, free_thicknesses):
    """``(object_points (M, 3), pixels (F, M, 2), layers)`` as arrays and a tuple; ValueError
    for pixels of another shape or a free layer the port does not have."""
    object_points = np.asarray(object_points, dtype=np.float64)
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim != 3 or pixels.shape[1:] != (object_points.shape[0], 2):
        raise ValueError(f"pixels must have shape (F, {object_points.shape[0]}, 2), got "
                         f"{pixels.shape}")
    layers = tuple(int(j) for j in free_thicknesses)
    if len(set(layers)) != len(layers) or any(not 0 <= j < len(port.thicknesses)
                                              for j in layers):
        raise ValueError(f"free_thicknesses {list(layers)}: the port has "
                         f"{len(port.thicknesses)} layer(s) with a thickness (0 … "
                         f"{len(port.thicknesses) - 1}), each at most once")
    return object_points, pixels, layers


class _InterfaceProblem:
    """The refinement of :func:`estimate_interface`: the unknowns are the free interface
    numbers (``active`` of distance, two tilts about ``axes``, the free layers' thicknesses;
    mm, rad) then 6 per frame (a rotation vector applied on the left of the start pose, and
    the translation, mm); the residuals the seen pixels' errors over ``sigma``."""

    def __init__(self, camera, port, object_points, pixels, axes, active, layers, starts,
                 sigma):
        self.camera, self.port, self.object_points = camera, port, object_points
        self.axes, self.active, self.layers, self.sigma = axes, active, layers, sigma
        self.frames, self.k = pixels.shape[0], active.size
        self.design = np.concatenate([[port.distance, 0.0, 0.0],
                                      [port.thicknesses[j] for j in layers]])
        seen = [np.flatnonzero(np.all(np.isfinite(pixels[f]), axis=1))
                for f in range(self.frames)]
        self.rows = np.concatenate([np.full(s.size, f) for f, s in enumerate(seen)])
        self.points = np.concatenate([s for s in seen])
        self.observed = np.concatenate([pixels[f][s] for f, s in enumerate(seen)])
        self.R0 = starts.R
        self.n_params = self.k + 6 * self.frames
        self.x0 = np.concatenate([self.design[active],
                                  np.column_stack([np.zeros((self.frames, 3)),
                                                   starts.t]).ravel()])
        self._cache = {}

    def unpack(self, x):
        """``(port, |m|, φ, R, t)`` at ``x``: the moved port (its normal ``m / |m|``), the
        frames' rotation vectors, rotations and translations."""
        k, port, frames = self.k, self.port, self.frames
        g = self.design.copy()
        g[self.active] = x[:k]
        m = port.normal + g[1] * self.axes[0] + g[2] * self.axes[1]
        length = np.linalg.norm(m)
        thick = list(port.thicknesses)
        for i, j in enumerate(self.layers):
            thick[j] = g[3 + i]
        moved = port.replace(distance=g[0], normal=m / length, thicknesses=tuple(thick))
        phi = x[k:].reshape(frames, 6)[:, :3]
        t = x[k:].reshape(frames, 6)[:, 3:]
        R = np.stack([exp_so3(phi[f]) @ self.R0[f] for f in range(frames)])
        return moved, length, phi, R, t

    def evaluate(self, x):
        """:meth:`unpack` and the projection of the seen points with its Jacobians (cached by
        ``x``: the residuals and the Jacobian ask at the same ``x``)."""
        key = x.tobytes()
        if key not in self._cache:
            moved, length, phi, R, t = self.unpack(x)
            X = (np.einsum("nij,nj->ni", R[self.rows], self.object_points[self.points])
                 + t[self.rows])
            try:
                uv, d_points, jac = project(self.camera, moved, X, parameters=True)
            except ValueError:  # the camera on the water side, a layer of no thickness
                uv = np.full((X.shape[0], 2), np.nan)
                d_points = jac = None
            self._cache[key] = (moved, length, phi, R, t, X, uv, d_points, jac)
        return self._cache[key]

    def residual(self, x):
        uv = self.evaluate(x)[6]
        r = ((uv - self.observed) / self.sigma).ravel()
        return np.where(np.isfinite(r), r, 1e8)

    def jacobian(self, x):
        moved, length, phi, R, t, X, uv, d_points, jac = self.evaluate(x)
        k, n_params, rows = self.k, self.n_params, self.rows
        J = np.zeros((self.observed.shape[0], 2, n_params))
        if jac is None:
            return J.reshape(-1, n_params)
        interface = np.zeros((self.observed.shape[0], 2, self.design.size))
        interface[:, :, 0] = jac.distance
        interface[:, :, 1:3] = (jac.normal / length) @ self.axes.T
        for i, j in enumerate(self.layers):
            interface[:, :, 3 + i] = jac.thicknesses[..., j]
        J[:, :, :k] = interface[:, :, self.active]
        d_phi = -skew(X - t[rows])  # (n, 3, 3), then J_l(φ) per frame
        for f in range(self.frames):
            mine = rows == f
            block = d_points[mine] @ (d_phi[mine] @ left_jacobian(phi[f]))
            J[mine, :, k + 6 * f:k + 3 + 6 * f] = block
            J[mine, :, k + 3 + 6 * f:k + 6 + 6 * f] = d_points[mine]
        J /= self.sigma
        J = J.reshape(-1, n_params)
        return np.where(np.isfinite(J), J, 0.0)

def camera_term(camera, port, X, J, inverse, k: int, sigma: float, camera_covariance):
    """``(k, k)``: the in-air intrinsics' covariance carried into the first ``k`` estimated
    numbers at the solution, ``A Σ_c Aᵀ`` with ``A = −(JᵀJ)⁻¹ Jᵀ J_c`` (the shift of the least
    squares solution per shift of the held intrinsics; ``J`` the residuals' Jacobian, scaled by
    the pixel σ ``sigma``, ``inverse`` ``(JᵀJ)⁻¹``). ``J_c``: the pixels of the points ``X``
    ``(n, 3)`` (mm) through ``port`` per intrinsic, by central differences of
    :func:`measure.geometry.projection.project` over steps of 1e-4 σ
    (:func:`measure.stereo.uncertainty.perturbed_rig`'s definition of each name)."""
    from ..stereo.rig import StereoRig
    from ..stereo.uncertainty import perturbed_rig

    names = list(camera_covariance.names)
    bad = [n for n in names if not n.startswith("left.")]
    if bad:
        raise ValueError(f"camera_covariance: {bad} are not the camera's intrinsics (left.fx …)")
    steps = 1e-4 * np.sqrt(np.diag(camera_covariance.matrix))
    rig = StereoRig(camera, camera, port)
    columns = []
    for i, h in enumerate(steps):
        delta = np.zeros(len(names))
        delta[i] = h
        plus = project(perturbed_rig(rig, names, delta).left, port, X)
        minus = project(perturbed_rig(rig, names, -delta).left, port, X)
        columns.append(((plus - minus) / (2.0 * h)).ravel() / sigma)
    A = -(inverse @ (J.T @ np.column_stack(columns)))[:k]
    term = A @ camera_covariance.matrix @ A.T
    return 0.5 * (term + term.T)


def refraction_axis(camera, object_points, pixels) -> np.ndarray:
    """The interface normal (unit, reference frame, pointing into the water) from pixels
    ``(F, M, 2)`` of a known object ``(M, 3)`` seen through any stack of parallel flat layers,
    in closed form (Agrawal et al. 2012, the "flat refraction constraint"): every refraction
    keeps a ray in the plane through the camera centre ``c`` spanned by its pixel's ray ``v``
    and the normal ``n``, and the object point ``X = R·p + t`` lies in that plane:
    ``vᵀ [n]ₓ R p + vᵀ [n]ₓ (t − c) = 0`` — linear in ``E = [n]ₓR`` and ``s = [n]ₓ(t − c)``
    (12 unknowns, 11 points per frame; a planar object 9 and 8). ``n`` is the common left null
    vector of every frame's ``[E, s]``. NaN where a frame has too few points or the pixels do
    not fix the axis (no refraction: a pinhole's rays pass through their points whatever
    ``n``). Units mm, px."""
    object_points = np.asarray(object_points, dtype=np.float64)
    pixels = np.asarray(pixels, dtype=np.float64)
    centred = object_points - object_points.mean(axis=0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    rank = int(np.sum(sv > 1e-9 * sv[0])) if sv[0] > 0 else 0
    if rank < 2:
        return np.full(3, np.nan)
    basis = vt[:rank].T  # (3, k): the object's points span these directions
    q = centred @ basis / np.sqrt(np.mean(sv[:rank] ** 2) / len(object_points))
    blocks = []
    for uv in pixels:
        seen = np.all(np.isfinite(uv), axis=1)
        if seen.sum() < 3 * rank + 2:
            continue
        v = camera.rays(uv[seen])
        design = np.column_stack([np.einsum("ni,nj->nij", v, q[seen]).reshape(seen.sum(), -1),
                                  v])
        _, sv, vt = np.linalg.svd(design, full_matrices=False)
        if sv[-2] <= 1e-9 * sv[0]:  # more than one null vector: no refraction to see
            return np.full(3, np.nan)
        null = vt[-1]
        blocks.append(np.column_stack([null[:3 * rank].reshape(3, rank), null[3 * rank:]]))
    if not blocks:
        return np.full(3, np.nan)
    u, sv, _ = np.linalg.svd(np.hstack(blocks))
    if sv[1] <= 1e-9 * sv[0]:  # a second null direction: the axis is not fixed
        return np.full(3, np.nan)
    n = u[:, -1]
    ahead = camera.rays(np.array([[(camera.size[0] - 1) / 2.0, (camera.size[1] - 1) / 2.0]]))[0]
    return n if n @ ahead > 0 else -n


def interface_start(view: View, object_points, pixels, distances=START_DISTANCES_MM):
    """A start for :func:`estimate_interface` without a design value: ``view.port`` (a
    :class:`measure.FlatPort`: its layers' thicknesses and indices are kept) with the normal
    from :func:`refraction_axis` and the distance, beyond the camera centre along it, of the
    ``distances`` (mm) whose poses (:func:`measure.stereo.pose.estimate_poses` through that
    port) reproject best, refined by a bounded search between its neighbours. None where the
    axis is not fixed or no distance gives every frame a pose."""
    from scipy.optimize import minimize_scalar

    port = require_flat_port(view.port, "interface_start needs a flat port (a FlatPort)")
    camera = view.camera
    normal = refraction_axis(camera, object_points, pixels)
    if not np.all(np.isfinite(normal)):
        return None
    offset = float(normal @ camera.center)

    def cost(distance):
        try:
            trial = port.replace(normal=normal, distance=offset + distance)
            poses = estimate_poses(View(camera, trial), object_points, pixels,
                                   max_rms_px=np.inf)
        except ValueError:
            return np.inf
        if not poses.valid.all():
            return np.inf
        return float(np.sum(poses.rms_px ** 2 * poses.observations))

    distances = np.asarray(distances, dtype=np.float64)
    costs = np.array([cost(d) for d in distances])
    if not np.isfinite(costs).any():
        return None
    best = int(np.argmin(costs))
    lo, hi = distances[max(best - 1, 0)], distances[min(best + 1, distances.size - 1)]
    found = minimize_scalar(lambda x: cost(np.exp(x)), bounds=(np.log(lo), np.log(hi)),
                            method="bounded", options={"xatol": 1e-4})
    distance = float(np.exp(found.x)) if found.fun <= costs[best] else float(distances[best])
    return port.replace(normal=normal, distance=offset + distance)


__all__ = ["INTERFACE_NAMES", "InterfaceEstimate", "estimate_interface", "interface_start",
           "refraction_axis"]
