"""Calibration from board images: OpenCV in air (:mod:`measure.calibration.air`), then the
housing by refractive bundle adjustment (here; each kind of port's problem in
:mod:`measure.calibration.flat` and :mod:`measure.calibration.dome`, :data:`HOUSINGS`).

In air (:func:`measure.calibration.air.calibrate_in_air`): ``cv2.calibrateCameraExtended`` per
camera (k1, k2, p1, p2; k3 fixed at 0) and ``cv2.stereoCalibrate`` with the intrinsics fixed
give K1, D1, K2, D2 and the stereo pose — OpenCV does it, nothing is re-implemented.

Underwater (:func:`calibrate_housing`): the cameras' intrinsics stay as calibrated in air; the
unknowns are every board pose (6 each) and the free housing parameters
(:data:`HOUSING_PARAMETERS`): ``distance`` (D, mm), ``normal`` (2 tilts, rad, about axes
perpendicular to the starting normal), ``thickness`` (first layer, mm), ``n_water``, and
``extrinsics`` (the right camera's pose: 3 rotation-vector and 3 translation increments, rad and
mm). Residuals: every detected corner's reprojection through the port with the project's exact
forward model (:func:`measure.geometry.projection.project`), px. ``scipy.optimize.least_squares`` with the
analytic Jacobian (``project(..., parameters=True)``: the implicit function theorem on the
travel time's stationarity, chained with the board poses and SO(3)'s left Jacobian) in its
sparse structure (a pose's 6 columns touch only its own corners' rows). Starting poses:
``cv2.solvePnP`` on the refracted images with the in-air intrinsics (a plain pinhole solve).

A rig of two domes (:class:`measure.geometry.dome.DomePair`, :func:`dome_problem`): the unknowns are
each camera's decentring — its dome's centre relative to the camera centre, in the camera's
frame (3 + 3 numbers, mm) — and optionally ``n_water`` (:data:`DOME_PARAMETERS`); radius,
thickness and glass index stay at the design values; the same poses, residuals and σ, the
in-air covariance entering the same two ways (each dome moves with its camera when the
in-air stereo pose moves); the joint covariance names each dome's centre in the reference
frame (``left/right.dome_center[k]``, :mod:`measure.stereo.rig_covariance`).

A rig of two housings (:class:`measure.geometry.flat_pair.FlatPair`, each camera behind its own
flat port; :data:`measure.calibration.flat.FLAT_PAIR_HOUSING`): the flat port's problem with
``distance``, ``normal`` and ``thickness`` per camera (left, then right: 2, 4, 2 numbers; each
port's tilts about axes ⟂ its own starting normal), one ``n_water`` and the ``extrinsics``;
each camera's corners through its own port. The estimates are ``{"left": …, "right": …}``;
the joint covariance names ``left/right.port.distance``, ``left/right.port.tilt[0/1]`` (both
about one pair of axes ⟂ the left port's normal), ``left/right.port.thickness[0]`` and
``port.index[2]``.

Uncertainty: ``s² (JᵀJ)⁻¹`` with ``s² = Σr² / (m − n)``; a parameter is reported not
identifiable when the column-scaled normal matrix is singular in its direction or two free
parameters correlate at :data:`CORRELATION_LIMIT` or more (then no estimate is returned).
Units mm, px (OpenCV convention); the reference frame is the left camera's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.camera import Camera
from ..geometry.port import RigPort
from ..stereo.rig import Rig, StereoRig
from .air import CalibrationError, Detections
from .board import Board
from .covariance import AIR_INTRINSICS, AIR_NAMES, POSE_NAMES
from .dome import DOME_HOUSING
from .flat import FLAT_HOUSING, FLAT_PAIR_HOUSING
from ..stereo.rig_covariance import RigCovariance

#: The free parameters by default: of a flat port, of two domes.
DEFAULT_FREE = FLAT_HOUSING.default_free
DEFAULT_DOME_FREE = DOME_HOUSING.default_free
#: What :func:`calibrate_housing` asks of each kind of port (``rig.port.kind``): its free
#: parameters and their default, its problem (residuals, Jacobian), its names in a covariance.
#: A new kind of port adds its own here (module docs of :mod:`measure.calibration.flat`).
HOUSINGS = {"flat": FLAT_HOUSING, "dome": DOME_HOUSING, "flat pair": FLAT_PAIR_HOUSING}
#: How the in-air calibration's covariance enters the housing's (:func:`calibrate_housing`).
UNCERTAINTY = ("propagate", "prior")
#: The default: both covered the chain's error on 30 seeds of rendered boards, the prior with
#: errors 30–53 % smaller (docs/calibration.md, "σ that covers the chain").
DEFAULT_UNCERTAINTY = "prior"
#: Relative eigenvalue of the scaled normal matrix below which a direction is not determined.
IDENTIFIABILITY_LIMIT = 1e-12
#: |correlation| at which two free parameters cannot be told apart.
CORRELATION_LIMIT = 0.9995
#: A fit that leaves more reprojection RMS than this (px) has not found the housing.
FIT_RMS_LIMIT_PX = 2.0


# ---------------------------------------------------------------------------------------------
# underwater: refractive bundle adjustment
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class HousingCalibration:
    """Result of :func:`calibrate_housing`.

    ``rig`` the calibrated rig (the starting rig when not identifiable); ``estimates`` /
    ``sigmas`` per free parameter (``normal``: the unit vector and two tilt sigmas in rad;
    ``extrinsics``: the right camera's ``R``, ``t`` and six sigmas; two housings: ``distance``,
    ``normal``, ``thickness`` as ``{"left": …, "right": …}``, their sigmas left then right); ``labels`` and
    ``correlation`` of the free numbers; ``poses`` ``[(R, t), …]`` of the boards;
    ``rms_px`` overall and ``rms_px_per`` ``{(pose, view): rms}``; ``residuals`` per view
    ``(pose, id, du, dv)`` rows; ``identifiable`` / ``reason``; ``pose_ids`` the numbers of
    the poses used (``poses[i]`` is pose ``pose_ids[i]``); ``fitted`` the rig where the
    adjustment stopped (also when not identifiable: ``rig`` is then the start). RMS values are
    per corner, of the 2D residual length."""

    rig: Rig
    estimates: dict
    sigmas: dict
    labels: tuple
    correlation: np.ndarray
    poses: list
    rms_px: float
    rms_px_start: float
    rms_px_per: dict
    residuals: dict
    converged: bool
    identifiable: bool
    reason: str
    n_observations: int
    nfev: int
    message: str = ""
    normal_axes: tuple = field(default=())
    pose_ids: tuple = field(default=())
    covariance: RigCovariance | None = None
    sigmas_conditional: dict = field(default_factory=dict)
    uncertainty: str = "conditional"
    fitted: Rig | None = None



def calibrate_housing(rig: Rig, board: Board, detections: Detections,
                      free=None, air_covariance: RigCovariance | None = None,
                      uncertainty: str = DEFAULT_UNCERTAINTY, views=(0, 1)) -> HousingCalibration:
    """Refractive bundle adjustment of the housing (module docs). ``rig``: the in-air cameras
    with the starting port (its fixed parameters are the design values) — a flat port, or two
    domes (:func:`dome_problem`: each camera's decentring). ``free`` defaults to
    :data:`DEFAULT_FREE`, for domes :data:`DEFAULT_DOME_FREE`. ``air_covariance``: the in-air
    calibration's covariance (:attr:`AirCalibration.covariance`, or a calib.yaml's), brought
    into the housing's by ``uncertainty``: ``"propagate"`` (the in-air parameters fixed, their
    covariance propagated) or ``"prior"`` (freed, with the in-air result as a prior), for a
    flat port and for domes alike. Without it the σ is conditional on the in-air
    calibration. ``views``: the cameras whose corners enter (``(0,)``: the left camera alone,
    :func:`calibrate_camera_housing`)."""
    housing, names = _housing_and_names(rig, views, free, uncertainty)
    table = housing.parameters
    turns = {}
    if board.symmetric and tuple(views) == (0, 1):  # each pose's right numbering by the rig
        from .symmetry import relabelled, settle_by_rig

        turns = {k: s for k, s in settle_by_rig(rig, board, detections).items() if s}
        detections = relabelled(detections, 1, turns, board)
    problem = housing.problem(rig, board, detections, names)
    obs, usable, P, n_global = problem.obs, problem.usable, problem.P, problem.n_global
    rms_start = float(np.sqrt(np.mean(problem.residuals(problem.x0) ** 2)))
    fit = _least_squares(problem.residuals, problem.jacobian, problem.x0, problem.lower,
                         problem.upper, problem.m)
    r = fit.fun
    J = fit.jac.toarray() if hasattr(fit.jac, "toarray") else np.asarray(fit.jac)
    s2 = float(r @ r) / max(r.size - problem.x0.size, 1)
    N = J.T @ J
    labels = tuple(f"{n}[{k}]" if table[n] > 1 else n for n in names for k in range(table[n]))
    port, cameras, Rs, ts = problem.unpack(fit.x)
    base = dict(labels=labels, poses=[(Rs[k], ts[k]) for k in range(P)],
                **_residual_summary(r, obs, usable), rms_px_start=rms_start * np.sqrt(2),
                converged=bool(fit.status > 0), n_observations=problem.m // 2,
                nfev=int(fit.nfev), message=str(fit.message),
                normal_axes=tuple(b.tolist() for b in problem.basis), pose_ids=tuple(usable),
                fitted=StereoRig(cameras[0], cameras[1], port))
    base["residuals"] = _detected_numbers(base["residuals"], turns, board)
    covariance = s2 * np.linalg.inv(N) if _identifiable(N) else None
    failed = _not_determined(rig, fit, N, covariance, labels, n_global, base)
    if failed is not None:
        return failed
    sig = np.sqrt(np.diag(covariance))
    correlation = covariance[:n_global, :n_global] / np.outer(sig[:n_global], sig[:n_global])
    x, sig_conditional = fit.x, sig[:n_global].copy()
    air = _air_parameters(air_covariance, names)
    if air:
        sigma_air = _sub_covariance(air_covariance, air)
        if uncertainty == "prior":
            rig, x, joint, r = _prior_fit(rig, board, detections, names, x, s2, air,
                                          sigma_air, housing)
            port, cameras, Rs, ts = housing.problem(rig, board, detections, names).unpack(x)
            base.update(_residual_summary(r, obs, usable))
            base["residuals"] = _detected_numbers(base["residuals"], turns, board)
            base["poses"] = [(Rs[k], ts[k]) for k in range(P)]
        else:
            G = np.linalg.solve(N, J.T @ problem.air_jacobian(x, air))  # δx = −G δθ_air
            cross = -(G @ sigma_air)
            joint = np.block([[sigma_air, cross.T], [cross, covariance + G @ sigma_air @ G.T]])
        sig = np.sqrt(np.diag(joint))[len(air):]
    else:
        joint = covariance
    rig_names, T, axes = housing.rig_parameters(names, air, x, problem.basis, rig, port,
                                                cameras, n_global)
    keep = list(range(len(air) + n_global))
    joint = T @ joint[np.ix_(keep, keep)] @ T.T
    rig_cov = RigCovariance(tuple(air) + rig_names, 0.5 * (joint + joint.T), axes)
    estimates, sigmas, conditional = _estimates(housing, names, port, cameras, sig,
                                                sig_conditional)
    calibrated = StereoRig(cameras[0], cameras[1], port)
    base["fitted"] = calibrated
    return HousingCalibration(rig=calibrated, estimates=estimates, sigmas=sigmas,
                              correlation=correlation, identifiable=True, reason="",
                              covariance=rig_cov, sigmas_conditional=conditional,
                              uncertainty=uncertainty if air else "conditional", **base)


def _estimates(housing, names, port, cameras, sig, sig_conditional) -> tuple[dict, dict, dict]:
    """``(estimates, σ, conditional σ)`` by free parameter (a number, or a list for the
    parameters of several numbers)."""
    estimates, sigmas, conditional, k = {}, {}, {}, 0
    for name in names:
        w = housing.parameters[name]
        estimates[name] = housing.estimate(name, port, cameras)
        sigmas[name] = float(sig[k]) if w == 1 else sig[k:k + w].tolist()
        conditional[name] = (float(sig_conditional[k]) if w == 1
                             else sig_conditional[k:k + w].tolist())
        k += w
    return estimates, sigmas, conditional


def _housing_and_names(rig, views, free, uncertainty):
    """``(housing, names)``: the housing problem of ``rig``'s kind of port for ``views`` and
    the free parameters' names (its defaults when ``free`` is None); CalibrationError for a
    kind without one, an unknown ``uncertainty`` or free parameter."""
    housing = HOUSINGS.get(rig.port.kind)
    if housing is None:  # a kind of port without a housing problem
        raise CalibrationError(f"no housing calibration of {rig.port.rig_name} "
                               f"({rig.port.rig_detail}) yet")
    housing = housing.for_views(views)
    if free is None:
        free = housing.default_free
    if uncertainty not in UNCERTAINTY:
        raise CalibrationError(f"uncertainty {uncertainty!r}: expected one of "
                               f"{', '.join(UNCERTAINTY)}")
    names = tuple(dict.fromkeys(free))
    table = housing.parameters
    unknown = [n for n in names if n not in table]
    if not names or unknown:
        raise CalibrationError(f"--free {','.join(free) or '(nothing)'}: the housing calibration "
                               f"{housing.label}estimates "
                               f"{', '.join(table)}")
    housing.check_free(rig, names)
    return housing, names


def _relative_eigen(N):
    """The scaled normal matrix's eigenvalues relative to the largest, and its eigenvectors."""
    scale = np.sqrt(np.diag(N))
    scale[scale == 0] = 1.0
    eigval, eigvec = np.linalg.eigh(N / np.outer(scale, scale))
    return (eigval / eigval[-1] if eigval[-1] > 0 else np.zeros_like(eigval)), eigvec


def _identifiable(N) -> bool:
    return _relative_eigen(N)[0][0] >= IDENTIFIABILITY_LIMIT


def _not_determined(rig, fit, N, covariance, labels, n_global, base):
    """A HousingCalibration that says why the fit determines no housing — a parameter no
    board determines, two parameters the boards cannot tell apart, no convergence or a fit
    far off the corners, a parameter at its physical bound — or None when it does."""
    nan = np.full((n_global, n_global), np.nan)
    if covariance is None:
        relative, eigvec = _relative_eigen(N)
        worst = int(np.argmax(np.abs(eigvec[:n_global, 0]))) if n_global else 0
        name = labels[worst] if n_global else "a board pose"
        return HousingCalibration(
            rig=rig, estimates={}, sigmas={}, correlation=nan,
            identifiable=False, reason=f"{name} is not determined by these boards (relative "
                                       f"eigenvalue {relative[0]:.1e})", **base)
    sig = np.sqrt(np.diag(covariance))
    correlation = covariance[:n_global, :n_global] / np.outer(sig[:n_global], sig[:n_global])
    off = np.abs(np.triu(correlation, 1))  # each pair once, named in the order of labels
    if n_global > 1 and off.max() >= CORRELATION_LIMIT:
        i, j = np.unravel_index(np.argmax(off), off.shape)
        return HousingCalibration(rig=rig, estimates={}, sigmas={}, correlation=correlation,
                                  identifiable=False,
                                  reason=f"{labels[i]} and {labels[j]} are correlated at "
                                         f"{correlation[i, j]:+.4f}: these boards cannot tell "
                                         f"them apart", **base)
    if not base["converged"] or base["rms_px"] > FIT_RMS_LIMIT_PX:
        return HousingCalibration(
            rig=rig, estimates={}, sigmas={}, correlation=nan, identifiable=False, reason=(
                f"the adjustment did not converge within {fit.nfev} evaluations (reprojection "
                f"RMS {base['rms_px']:.3g} px): the free parameters are barely determined by "
                f"these boards"
                if base["rms_px"] <= FIT_RMS_LIMIT_PX else
                f"the adjustment stopped with a reprojection RMS of {base['rms_px']:.3g} px "
                f"({fit.message.rstrip('.')}): it did not find a housing that fits the corners "
                f"(check the design values, the starting distance and --free)"),
            **{**base, "converged": False})
    at_bound = np.flatnonzero(fit.active_mask[:n_global] != 0)
    if at_bound.size:
        return HousingCalibration(
            rig=rig, estimates={}, sigmas={}, correlation=nan, identifiable=False,
            reason=f"{labels[at_bound[0]]} ran into its physical bound: these boards do not "
                   f"determine it", **base)
    return None

#: A fit whose sparse (LSMR) trust-region steps stop with more than :data:`FIT_RMS_LIMIT_PX`
#: is run again with the steps solved exactly (dense SVD), where the Jacobian has at most this
#: many columns and entries: LSMR's inexact steps stalled on an ill-conditioned real rig (the
#: Minions pair, f ≈ 12,000 px: 18 px where exact steps reach 0.69 px, the stereo pose freed),
#: and exact steps cost 6× more on a well-conditioned one (a dome, 25 photos: 5.9 s against
#: 0.9 s, the same solution), so they are the second try only.
DENSE_COLUMNS, DENSE_ENTRIES = 400, 8_000_000


def _least_squares(residuals, jacobian, x0, lower, upper, m):
    """``scipy.optimize.least_squares`` (trf, Jacobian-scaled) of the housing problem: sparse
    LSMR steps, then exact steps where those stalled (module constants)."""
    from scipy.optimize import least_squares

    common = dict(method="trf", x_scale="jac", bounds=(lower, upper), xtol=1e-12, ftol=1e-12,
                  gtol=1e-12, max_nfev=300)
    fit = least_squares(residuals, x0, jac=jacobian, tr_solver="lsmr",
                        tr_options={"atol": 1e-14, "btol": 1e-14}, **common)
    rms = float(np.sqrt(np.mean(fit.fun ** 2) * 2))
    if rms <= FIT_RMS_LIMIT_PX or x0.size > DENSE_COLUMNS or x0.size * m > DENSE_ENTRIES:
        return fit

    def dense(x):
        J = jacobian(x)
        return J.toarray() if hasattr(J, "toarray") else np.asarray(J)

    exact = least_squares(residuals, x0, jac=dense, tr_solver="exact", **common)
    return exact if float(exact.fun @ exact.fun) < float(fit.fun @ fit.fun) else fit


def _residual_summary(r, obs, usable) -> dict:
    """``rms_px``, ``rms_px_per`` ``{(pose, view): rms}`` and ``residuals`` ``{view: (pose,
    id, du, dv) rows}`` of the corners' residual vector ``r`` (px, ``obs`` order)."""
    per, res, offset = {}, {}, 0
    for view, pose_idx, ids, _ in obs:
        rv = r[offset:offset + 2 * pose_idx.size].reshape(-1, 2)
        offset += 2 * pose_idx.size
        res[view] = np.column_stack([usable_index(usable, pose_idx), ids, rv])
        for k in np.unique(pose_idx):
            per[(usable[k], view)] = float(np.sqrt(np.mean(rv[pose_idx == k] ** 2) * 2))
    return {"rms_px": float(np.sqrt(np.mean(r ** 2) * 2)), "rms_px_per": per, "residuals": res}


def _detected_numbers(residuals: dict, turns: dict, board: Board) -> dict:
    """Residual rows ``{view: (pose, id, du, dv)}`` with the right view's ids of the poses in
    ``turns`` (renumbered by :func:`measure.calibration.symmetry.settle_by_rig`) back to the
    numbers they were detected with."""
    if not turns or 1 not in residuals:
        return residuals
    symmetries = board.symmetries()
    rows = residuals[1].copy()
    for k, s in turns.items():
        here = rows[:, 0] == k
        rows[here, 1] = np.argsort(symmetries[s][0])[rows[here, 1].astype(int)]
    return {**residuals, 1: rows}


def calibrate_camera_housing(camera: Camera, port: RigPort, board: Board,
                             detections: Detections, free=None,
                             air_covariance: RigCovariance | None = None,
                             uncertainty: str = DEFAULT_UNCERTAINTY) -> HousingCalibration:
    """The housing of ONE camera behind its own port, from that camera's board corners: the
    stereo fit (:func:`calibrate_housing`, module docs) over the corners of view 0 only, the
    camera being the reference (left) camera. ``port``: the starting rig port whose view 0 is
    the camera's — a :class:`measure.FlatPort` (free: ``distance``, ``normal``, ``thickness``,
    ``n_water``; no ``extrinsics``), or a :class:`measure.geometry.dome.DomePair` whose left dome
    is the camera's (its right dome is not used; free: ``dome_center``, the camera's decentring
    in its own frame, 3 numbers, and ``n_water``). ``detections``: view 0 per pose (a view 1 is
    ignored). ``air_covariance``: the camera's in-air covariance named ``left.fx`` …
    ``left.p2`` (:data:`measure.calibration.covariance.AIR_NAMES`), or None (σ conditional on
    the intrinsics). Returns :class:`HousingCalibration` whose ``rig`` is the camera twice
    behind the calibrated port: ``rig.left`` and ``rig.view_port(0)`` are the result (behind
    domes the pair's right dome stays the start's: no corner sees it)."""
    empty = (np.empty(0, int), np.empty((0, 2)))
    one = Detections([[ids[0], empty[0]] for ids in detections.ids],
                     [[px[0], empty[1]] for px in detections.pixels])
    try:
        rig = StereoRig(camera, camera, port)
    except ValueError as exc:
        raise CalibrationError(f"the design port: {exc}") from None
    return calibrate_housing(rig, board, one, free, air_covariance, uncertainty, views=(0,))


def _air_parameters(covariance: RigCovariance | None, names) -> tuple:
    """The in-air parameters whose uncertainty enters the housing: the intrinsics in
    ``covariance`` and — unless the housing frees the extrinsics — the right camera's pose."""
    if covariance is None:
        return ()
    have = set(covariance.names)
    return tuple(n for n in AIR_NAMES if n in have
                 and not ("extrinsics" in names and n in POSE_NAMES))


def _sub_covariance(covariance: RigCovariance, names) -> np.ndarray:
    where = [covariance.names.index(n) for n in names]
    return covariance.matrix[np.ix_(where, where)]


def apply_air_change(rig: Rig, air, delta) -> Rig:
    """``rig`` with the in-air parameters ``air`` moved by ``delta`` (px, unitless, rad: the
    right camera's ``R → exp([φ]×) R``, mm: its centre)."""
    from scipy.spatial.transform import Rotation
    change = dict(zip(air, np.asarray(delta, dtype=np.float64)))
    cameras = []
    for name, camera in (("left", rig.left), ("right", rig.right)):
        K, dist = camera.K.copy(), np.zeros(5)
        if camera.dist is not None:
            dist[:min(5, camera.dist.size)] = camera.dist[:5]
        for (i, j), p in zip(((0, 0), (1, 1), (0, 2), (1, 2)), AIR_INTRINSICS[:4]):
            K[i, j] += change.get(f"{name}.{p}", 0.0)
        for i, p in enumerate(AIR_INTRINSICS[4:]):
            dist[i] += change.get(f"{name}.{p}", 0.0)
        R, t = camera.R, camera.t
        if name == "right":
            phi = [change.get(f"right.rotation[{i}]", 0.0) for i in range(3)]
            R = Rotation.from_rotvec(phi).as_matrix() @ R
            t = t + np.array([change.get(f"right.center[{i}]", 0.0) for i in range(3)])
        cameras.append(Camera(K, camera.size, dist if np.any(dist) else None, R, t))
    return StereoRig(cameras[0], cameras[1], rig.port)


#: Gauss-Newton iterations of the prior fit at most, its stop (every step below this many σ),
#: and the halvings of a step that does not lower the cost. On a real flat port (OUC's, D ≈ 40
#: mm, the intrinsics moving D by several mm per σ) the undamped iteration needed 12 steps
#: where 9 were allowed and stopped; damped it converges in fewer.
PRIOR_ITERATIONS, PRIOR_STEP_SIGMA, PRIOR_HALVINGS = 40, 1e-4, 8


def _prior_fit(rig, board, detections, names, x, s2, air, sigma_air, housing):
    """The housing with the in-air parameters ``air`` free under their in-air prior: the rows
    ``s·L(θ − θ_air)`` (``LᵀL = Σ_air⁻¹``, ``s²`` the corners' variance of the conditional fit)
    beside the corners' residuals; Gauss-Newton from the conditional solution ``x``, a step
    halved while it raises the cost. Returns the rig with the refined in-air parameters, the
    housing unknowns, the joint covariance ``s²(AᵀA)⁻¹`` ordered (in-air parameters, housing
    unknowns) and the corners' residuals at the solution."""
    L = np.linalg.inv(np.linalg.cholesky(sigma_air))
    s = np.sqrt(s2)
    delta, a = np.zeros(len(air)), len(air)

    def state(delta):
        moved = apply_air_change(rig, air, delta)
        problem = housing.problem(moved, board, detections, names)
        if problem.x0.size != x.size:  # solvePnP found another set of usable poses
            raise CalibrationError("the prior fit lost a board pose when the intrinsics moved; "
                                   "use --air-uncertainty propagate")
        return moved, problem

    def cost(problem, x, delta):
        r = problem.residuals(x)
        return float(r @ r) + float(np.sum((s * L @ delta) ** 2)), r

    moved, problem = state(delta)
    current, r = cost(problem, x, delta)
    for _ in range(PRIOR_ITERATIONS):
        J = problem.jacobian(x)
        J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
        A = np.block([[J, problem.air_jacobian(x, air)],
                      [np.zeros((a, J.shape[1])), s * L]])
        b = np.concatenate([r, s * L @ delta])
        inverse = np.linalg.inv(A.T @ A)
        step = -inverse @ (A.T @ b)
        if np.max(np.abs(step) / np.sqrt(s2 * np.diag(inverse))) < PRIOR_STEP_SIGMA:
            break
        for _ in range(PRIOR_HALVINGS):
            trial = state(delta + step[J.shape[1]:])
            value, r_trial = cost(trial[1], x + step[:J.shape[1]], delta + step[J.shape[1]:])
            if value <= current:
                break
            step = step / 2
        else:
            break  # no step lowers the cost: the minimum, to the cost's rounding
        x, delta = x + step[:J.shape[1]], delta + step[J.shape[1]:]
        (moved, problem), current, r = trial, value, r_trial
    else:
        raise CalibrationError(f"the prior fit did not converge in {PRIOR_ITERATIONS} "
                               f"Gauss-Newton steps (free fewer parameters with --free)")
    cov = s2 * inverse
    order = np.r_[J.shape[1]:J.shape[1] + a, 0:J.shape[1]]
    return moved, x, cov[np.ix_(order, order)], r


def usable_index(usable, pose_idx) -> np.ndarray:
    """Original pose numbers of compacted pose indices."""
    return np.asarray(usable)[pose_idx]


__all__ = ["DEFAULT_DOME_FREE", "DEFAULT_FREE", "DEFAULT_UNCERTAINTY", "HousingCalibration",
           "UNCERTAINTY", "apply_air_change", "calibrate_camera_housing", "calibrate_housing",
           "usable_index"]
