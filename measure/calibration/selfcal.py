"""Port parameters from the measurement itself: refractive bundle adjustment of matched targets.

No calibration object: the unknowns are every matched target's 3D position and the chosen port
parameters (``n_water`` by default; ``port_distance`` and ``port_normal`` on request). The
residuals are the reprojection errors of every target in both images, through the port, with the
exact forward model (:func:`measure.geometry.projection.project`): 4 per target, in pixels.
``scipy.optimize.least_squares`` minimizes them with the analytic Jacobian of the projection
(:func:`measure.geometry.projection.project` with ``parameters=True``: the implicit function theorem on
the travel time's stationarity, no finite differences) in its sparse block-arrow structure — each
point touches only its own 4 residuals, each port parameter touches all of them.

Uncertainty: the covariance of the parameters is ``s² (JᵀJ)⁻¹`` restricted to them, with
``s² = Σr² / (m − n)`` (m residuals, n unknowns). With the rig's covariance
(``rig_covariance``, a calibration's :class:`measure.stereo.rig_covariance.RigCovariance`) the fixed
parameters' uncertainty is propagated as in the housing calibration: ``+ G Σ_fixed Gᵀ`` with
``G = S⁻¹ J̃ᵀ J_fixed`` (S the Schur complement below, J̃ the parameter columns with the points
projected out, ``J_fixed`` d residuals / d the rig parameters held: intrinsics, the right
camera's pose, the port parameters not estimated); the estimated ones' earlier uncertainty
does not enter (the data estimate them afresh). A parameter is reported as *not identifiable*
(no number) when the normal equations are singular for it: the smallest singular value of the
column-scaled Jacobian, relative to the largest, is below :data:`IDENTIFIABILITY_LIMIT`, or a
correlation between free parameters reaches :data:`CORRELATION_LIMIT`.

Units: mm, pixels (OpenCV convention), the reference frame is the left camera's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.port import FlatPort
from ..stereo.reprojection import (block_arrow_jacobian, reprojection_points, stereo_projections,
                           stereo_residuals)
from ..stereo.rig import Rig, StereoRig
from ..stereo.triangulate import triangulate

#: Port parameters the refinement can estimate, and how many numbers each one is.
PARAMETERS = {"n_water": 1, "port_distance": 1, "port_normal": 2}
#: Relative singular value below which the free parameters are not identifiable.
IDENTIFIABILITY_LIMIT = 1e-9
#: |correlation| at which two free parameters cannot be told apart.
CORRELATION_LIMIT = 0.999


@dataclass(frozen=True)
class SelfCalibration:
    """Result of :func:`self_calibrate`.

    ``estimates`` / ``sigmas``: ``{name: value}`` (``port_normal`` as a unit 3-vector; its sigma
    as two tilt angles in radians); ``correlation`` of the free numbers (square, in the order of
    ``labels``); ``rig`` the refined rig; ``points`` ``(N, 3)`` the reprojection-optimal points
    (mm); ``rms_px`` the reprojection RMS after, ``rms_px_before`` before; ``converged``;
    ``identifiable`` False with ``reason`` when the data do not determine the parameters (then
    ``estimates`` and ``sigmas`` are empty and ``rig`` is the starting rig);
    ``sigmas_conditional`` the σ with the rest of the rig taken as exact and ``propagated`` the
    names of the rig parameters whose covariance is in ``sigmas`` (empty: none given)."""

    estimates: dict
    sigmas: dict
    correlation: np.ndarray
    labels: tuple
    rig: Rig
    points: np.ndarray
    rms_px: float
    rms_px_before: float
    converged: bool
    identifiable: bool
    reason: str
    n_points: int
    message: str
    sigmas_conditional: dict = field(default_factory=dict)
    propagated: tuple = ()


def tilt_basis(normal):
    """Two unit vectors perpendicular to ``normal`` and to each other: the axes of the two tilt
    parameters of a port normal."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(normal, helper)
    a /= np.linalg.norm(a)
    return a, np.cross(normal, a)


def _port_from(port: FlatPort, names, values, basis):
    indices, distance, normal = list(port.indices), port.distance, port.normal
    k = 0
    for name in names:
        if name == "n_water":
            indices[-1] = values[k]
        elif name == "port_distance":
            distance = values[k]
        elif name == "port_normal":
            a, b = basis
            normal = port.normal + values[k] * a + values[k + 1] * b
            normal = normal / np.linalg.norm(normal)
        k += PARAMETERS[name]
    return FlatPort(normal, distance, port.thicknesses, tuple(indices))


def _parameter_normal_matrix(jacobian, n: int, n_free: int) -> np.ndarray:
    """The normal matrix of the free parameters with the points eliminated (Schur complement of
    the block-arrow ``JᵀJ``): ``Jpᵀ Jp − Σ_i Bᵢᵀ Aᵢ⁻¹ Bᵢ`` with ``Aᵢ = Jᵢᵀ Jᵢ`` (point i's 3×3
    block) and ``Bᵢ = Jᵢᵀ Jp,ᵢ``. Its inverse is the parameters' block of ``(JᵀJ)⁻¹``."""
    Jp_i, _, _, B, A_inv_B = _point_blocks(jacobian, n, n_free)
    Jp = Jp_i.reshape(4 * n, n_free)
    return Jp.T @ Jp - np.einsum("nki,nkj->ij", B, A_inv_B)


def _point_blocks(jacobian, n: int, n_free: int):
    """The block-arrow Jacobian's pieces per point: ``Jp,ᵢ`` ``(n, 4, n_free)`` (the free
    parameters' columns), ``Jx,ᵢ`` ``(n, 4, 3)`` (the point's own), ``Aᵢ = Jx,ᵢᵀ Jx,ᵢ``,
    ``Bᵢ = Jx,ᵢᵀ Jp,ᵢ`` and ``Aᵢ⁻¹ Bᵢ``; ``jacobian`` dense or sparse, rows 4 per point,
    columns the free parameters then 3 per point."""
    J = jacobian.tocsr() if hasattr(jacobian, "tocsr") else np.asarray(jacobian)
    rows = np.arange(4 * n)
    cols = n_free + 3 * (rows // 4)[:, None] + np.arange(3)
    if hasattr(J, "tocsr"):
        Jp = J[:, :n_free].toarray()
        Jx = np.asarray(J[np.repeat(rows, 3), cols.ravel()]).reshape(n, 4, 3)
    else:
        Jp = J[:, :n_free]
        Jx = J[rows[:, None], cols].reshape(n, 4, 3)
    Jp_i = Jp.reshape(n, 4, n_free)
    A = np.einsum("nki,nkj->nij", Jx, Jx)
    B = np.einsum("nki,nkj->nij", Jx, Jp_i)
    return Jp_i, Jx, A, B, np.linalg.solve(A, B)


def refinement_residuals(rig, port0, names, basis, observed, x) -> np.ndarray:
    """The 4N reprojection residuals (px) of the unknowns ``x`` (free port numbers, then the
    points' coordinates)."""
    n_free = sum(PARAMETERS[p] for p in names)
    port = _port_from(port0, names, x[:n_free], basis)
    return stereo_residuals(rig, port, x[n_free:].reshape(-1, 3), observed)


def refinement_jacobian(rig, port0, names, basis, x):
    """The analytic Jacobian of :func:`refinement_residuals` (:func:`measure.geometry.projection.project` with
    ``parameters=True``) in its sparse block-arrow structure: each point's 3 columns touch its 4
    rows, the port parameters touch all."""
    n_free = sum(PARAMETERS[p] for p in names)
    port = _port_from(port0, names, x[:n_free], basis)
    _, d_points, views = stereo_projections(rig, port, x[n_free:].reshape(-1, 3), True)
    columns = []
    for name in names:
        per_view = []
        for jac in views:
            if name == "n_water":
                per_view.append([jac.indices[..., -1]])
            elif name == "port_distance":
                per_view.append([jac.distance])
            else:  # normal = m / |m| with m = N0 + v_a a + v_b b: d/dv = (dN/dm)·a = jac·a / |m|
                k = sum(PARAMETERS[before] for before in names[:names.index(name)])
                length = np.linalg.norm(port0.normal + x[k] * basis[0] + x[k + 1] * basis[1])
                per_view.append([jac.normal @ axis / length for axis in basis])
        for j in range(len(per_view[0])):
            columns.append(np.concatenate([per_view[0][j], per_view[1][j]], axis=1))
    return block_arrow_jacobian(d_points, np.stack(columns, axis=-1))


def self_calibrate(rig: Rig, uv_left, uv_right, parameters=("n_water",),
                   points=None, rig_covariance=None) -> SelfCalibration:
    """Estimate ``parameters`` (names of :data:`PARAMETERS`) of ``rig.port`` from matched pixels
    ``(N, 2)`` of unknown points. ``points`` ``(N, 3)`` start values (default: the optical-path
    triangulation with ``rig``); ``rig_covariance`` the calibration's covariance, propagated
    into σ (module docs). Raises ``ValueError`` for an unknown parameter or fewer
    targets than free numbers."""
    names = _check_parameters(rig, parameters)
    uv_left, uv_right, start = _usable_matches(rig, uv_left, uv_right, points)
    n_free = sum(PARAMETERS[p] for p in names)
    n = start.shape[0]
    if 4 * n <= 3 * n + n_free or n < 2:
        raise ValueError(f"{n} usable matched targets cannot determine {n_free} port "
                         f"parameter(s) and their own positions")
    port0, basis = rig.port, tilt_basis(rig.port.normal)
    fit, rms_before = _refine(rig, port0, names, basis, uv_left, uv_right, start)
    r = fit.fun
    s2 = float(r @ r) / (r.size - fit.x.size)
    schur = _parameter_normal_matrix(fit.jac, n, n_free)
    scale = np.sqrt(np.diag(schur))
    scale[scale == 0] = 1.0
    eigen = np.linalg.eigvalsh(schur / np.outer(scale, scale))
    relative = float(eigen[0] / eigen[-1]) if eigen[-1] > 0 else 0.0
    labels = tuple(f"{name}[{k}]" if PARAMETERS[name] > 1 else name
                   for name in names for k in range(PARAMETERS[name]))
    base = dict(labels=labels, points=fit.x[n_free:].reshape(n, 3),
                rms_px=float(np.sqrt(np.mean(r ** 2))), rms_px_before=rms_before,
                converged=bool(fit.success), n_points=n, message=str(fit.message))
    if relative < IDENTIFIABILITY_LIMIT:
        return SelfCalibration({}, {}, np.full((n_free, n_free), np.nan), rig=rig,
                               identifiable=False,
                               reason=f"the normal equations are singular (relative singular "
                                      f"value {relative:.1e})", **base)
    covariance = s2 * np.linalg.inv(schur)
    sig_conditional = np.sqrt(np.diag(covariance))
    correlation = covariance / np.outer(sig_conditional, sig_conditional)
    sig, fixed = _with_rig_covariance(rig, port0, names, basis, fit, schur, covariance,
                                      rig_covariance)
    off = np.abs(correlation - np.eye(n_free))
    refined = StereoRig(rig.left, rig.right, _port_from(port0, names, fit.x[:n_free], basis))
    if n_free > 1 and off.max() >= CORRELATION_LIMIT:
        return SelfCalibration({}, {}, correlation, rig=rig, identifiable=False,
                               reason=f"free parameters are correlated at {off.max():.4f}: the "
                                      f"data cannot tell them apart", **base)
    estimates, sigmas, conditional = _estimates(names, refined.port, sig, sig_conditional)
    return SelfCalibration(estimates, sigmas, correlation, rig=refined, identifiable=True,
                           reason="", sigmas_conditional=conditional, propagated=fixed, **base)


def _check_parameters(rig, parameters) -> tuple:
    """The names to estimate, each once; ValueError for a port that does not self-calibrate or
    a name not in :data:`PARAMETERS`."""
    if not rig.port.self_calibrates:
        raise ValueError(f"self-calibration estimates the parameters of one flat port; "
                         f"{rig.port.rig_name} ({type(rig.port).__name__}: "
                         f"{rig.port.rig_detail}) is not supported yet")
    names = tuple(dict.fromkeys(parameters))
    unknown = [p for p in names if p not in PARAMETERS]
    if not names or unknown:
        raise ValueError(f"cannot estimate {', '.join(unknown) or 'nothing'}: the refinement "
                         f"estimates {', '.join(PARAMETERS)}")
    return names


def _usable_matches(rig, uv_left, uv_right, points):
    """``(uv_left, uv_right, start)``: the matches (px) whose pixels and start point (mm; the
    optical-path triangulation when ``points`` is None) are finite."""
    uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
    uv_right = np.asarray(uv_right, dtype=np.float64).reshape(-1, 2)
    start = triangulate(rig, uv_left, uv_right).points if points is None else np.asarray(points, float)
    keep = np.all(np.isfinite(start), axis=1) & np.all(np.isfinite(uv_left), axis=1) & np.all(
        np.isfinite(uv_right), axis=1)
    return uv_left[keep], uv_right[keep], start[keep]


def _refine(rig, port0, names, basis, uv_left, uv_right, start):
    """``(fit, rms_before)``: SciPy's ``least_squares`` over the port's parameters ``names``
    and the points (their pixels' residuals, analytic Jacobian), and the RMS (px) it started
    from."""
    from scipy.optimize import least_squares

    p0 = []
    for name in names:
        p0 += {"n_water": [port0.n_water], "port_distance": [port0.distance],
               "port_normal": [0.0, 0.0]}[name]
    observed = np.concatenate([uv_left, uv_right], axis=1).ravel()

    def residuals(x):
        return refinement_residuals(rig, port0, names, basis, observed, x)

    def jacobian(x):
        return refinement_jacobian(rig, port0, names, basis, x)

    x0 = np.concatenate([p0, start.ravel()])
    rms_before = float(np.sqrt(np.mean(residuals(x0) ** 2)))
    # Tight LSMR tolerances: with its defaults the trust-region steps stay inexact and the fit
    # took 121 evaluations instead of 8 for the same estimate (measured on the paper's targets).
    fit = least_squares(residuals, x0, jac=jacobian, method="trf", x_scale="jac",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200, tr_solver="lsmr",
                        tr_options={"atol": 1e-14, "btol": 1e-14})
    return fit, rms_before


def _with_rig_covariance(rig, port0, names, basis, fit, schur, covariance, rig_covariance):
    """``(σ, fixed)``: the estimates' σ with the calibration's covariance of the parameters
    held ``fixed`` propagated (module docs); the conditional σ and ``()`` without one."""
    sig = np.sqrt(np.diag(covariance))
    if rig_covariance is None:
        return sig, ()
    n_free = schur.shape[0]
    n = (fit.x.size - n_free) // 3
    port = _port_from(port0, names, fit.x[:n_free], basis)
    fixed = tuple(name for name in rig_covariance.names if name not in _estimated(names, port))
    if fixed:
        where = [rig_covariance.names.index(n) for n in fixed]
        sigma_fixed = rig_covariance.matrix[np.ix_(where, where)]
        G = _influence(fit.jac, n, n_free, schur) @ _fixed_jacobian(
            rig, port, fit.x[n_free:].reshape(n, 3), fixed, rig_covariance.normal_axes)
        sig = np.sqrt(np.diag(covariance + G @ sigma_fixed @ G.T))
    return sig, fixed


def _estimates(names, port, sig, sig_conditional) -> tuple[dict, dict, dict]:
    """``(estimates, σ, conditional σ)`` by name from the refined ``port`` and the σ vectors
    (the port normal's two tilts one entry)."""
    estimates, sigmas, conditional, k = {}, {}, {}, 0
    for name in names:
        if name == "n_water":
            estimates[name], sigmas[name] = port.n_water, float(sig[k])
        elif name == "port_distance":
            estimates[name], sigmas[name] = port.distance, float(sig[k])
        else:
            estimates[name], sigmas[name] = port.normal.tolist(), sig[k:k + 2].tolist()
        w = PARAMETERS[name]
        conditional[name] = (float(sig_conditional[k]) if w == 1
                             else sig_conditional[k:k + w].tolist())
        k += w
    return estimates, sigmas, conditional


def _estimated(names, port) -> set:
    """The :mod:`measure.stereo.rig_covariance` names of the parameters the refinement estimates."""
    out = set()
    for name in names:
        out |= {"n_water": {f"port.index[{len(port.indices) - 1}]"},
                "port_distance": {"port.distance"},
                "port_normal": {"port.tilt[0]", "port.tilt[1]"}}[name]
    return out


def _influence(jacobian, n: int, n_free: int, schur) -> np.ndarray:
    """``(n_free, 4n)``: the free parameters' rows of ``(JᵀJ)⁻¹Jᵀ`` — ``S⁻¹ J̃ᵀ`` with
    ``J̃ᵢ = Jp,ᵢ − Jx,ᵢ Aᵢ⁻¹ Bᵢ`` per point (the block-arrow's points eliminated)."""
    Jp_i, Jx, _, _, A_inv_B = _point_blocks(jacobian, n, n_free)
    projected = Jp_i - np.einsum("nki,nij->nkj", Jx, A_inv_B)
    return np.linalg.solve(schur, projected.reshape(4 * n, n_free).T)


def _fixed_jacobian(rig, port, points, fixed, normal_axes) -> np.ndarray:
    """``(4N, F)``: d residuals (u_left, v_left, u_right, v_right per point) / d the rig
    parameters ``fixed`` (:mod:`measure.stereo.rig_covariance` names) at the solution."""
    from .covariance import AIR_INTRINSICS, intrinsics_jacobian

    predicted, _, views = stereo_projections(rig, port, points, True)
    n = len(points)
    out = np.zeros((n, 4, len(fixed)))
    for v, (camera, jac) in enumerate(zip(rig.cameras, views)):
        rows = slice(2 * v, 2 * v + 2)
        cam = ("left", "right")[v]
        d_int = intrinsics_jacobian(camera, predicted[:, rows])
        for j, name in enumerate(fixed):
            group, _, item = name.partition(".")
            key, _, index = item.partition("[")
            k = int(index[:-1]) if index else None
            if group == cam and key in AIR_INTRINSICS:
                out[:, rows, j] = d_int[:, :, AIR_INTRINSICS.index(key)]
            elif group == "right" and v == 1 and key in ("rotation", "center"):
                out[:, rows, j] = getattr(jac, key)[..., k]
            elif name == "port.distance":
                out[:, rows, j] = jac.distance
            elif key == "tilt":
                out[:, rows, j] = jac.normal @ np.asarray(normal_axes)[k]
            elif key == "thickness":
                out[:, rows, j] = jac.thicknesses[..., k]
            elif key == "index":
                out[:, rows, j] = jac.indices[..., k]
    return np.where(np.isfinite(out), out, 0.0).reshape(4 * n, len(fixed))


__all__ = ["PARAMETERS", "SelfCalibration", "refinement_jacobian", "refinement_residuals",
           "reprojection_points", "self_calibrate"]
