"""Calibration from board images: OpenCV in air, then the housing by refractive bundle adjustment.

In air (:func:`calibrate_in_air`): ``cv2.calibrateCameraExtended`` per camera (k1, k2, p1, p2;
k3 fixed at 0) and ``cv2.stereoCalibrate`` with the intrinsics fixed give K1, D1, K2, D2 and the
stereo pose — OpenCV does it, nothing is re-implemented.

Underwater (:func:`calibrate_housing`): the cameras' intrinsics stay as calibrated in air; the
unknowns are every board pose (6 each) and the free housing parameters
(:data:`HOUSING_PARAMETERS`): ``distance`` (D, mm), ``normal`` (2 tilts, rad, about axes
perpendicular to the starting normal), ``thickness`` (first layer, mm), ``n_water``, and
``extrinsics`` (the right camera's pose: 3 rotation-vector and 3 translation increments, rad and
mm). Residuals: every detected corner's reprojection through the port with the project's exact
forward model (:func:`measure.projection.project`), px. ``scipy.optimize.least_squares`` with the
analytic Jacobian (``project(..., parameters=True)``: the implicit function theorem on the
travel time's stationarity, chained with the board poses and SO(3)'s left Jacobian) in its
sparse structure (a pose's 6 columns touch only its own corners' rows). Starting poses:
``cv2.solvePnP`` on the refracted images with the in-air intrinsics (a plain pinhole solve).

A rig of two domes (:class:`measure.dome.DomePair`, :func:`dome_problem`): the unknowns are
each camera's decentring — its dome's centre relative to the camera centre, in the camera's
frame (3 + 3 numbers, mm) — and optionally ``n_water`` (:data:`DOME_PARAMETERS`); radius,
thickness and glass index stay at the design values; the same poses, residuals and σ, the
in-air covariance entering the same two ways (each dome moves with its camera when the
in-air stereo pose moves); the joint covariance names each dome's centre in the reference
frame (``left/right.dome_center[k]``, :mod:`measure.rig_covariance`).

Uncertainty: ``s² (JᵀJ)⁻¹`` with ``s² = Σr² / (m − n)``; a parameter is reported not
identifiable when the column-scaled normal matrix is singular in its direction or two free
parameters correlate at :data:`CORRELATION_LIMIT` or more (then no estimate is returned).
Units mm, px (OpenCV convention); the reference frame is the left camera's.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from types import SimpleNamespace

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix
from scipy.spatial.transform import Rotation

from .board import MIN_CORNERS, Board
from .calibration_covariance import (AIR_INTRINSICS, AIR_NAMES, POSE_NAMES, air_covariance,
                                     intrinsics_jacobian, left_jacobian)
from .camera import Camera
from .dome import DomePair, DomePort
from .port import FlatPort, index_matched_port
from .projection import project
from .rig_covariance import RigCovariance
from .selfcal import tilt_basis
from .triangulate import StereoRig

#: Free housing parameters and how many numbers each is.
HOUSING_PARAMETERS = {"distance": 1, "normal": 2, "thickness": 1, "n_water": 1, "extrinsics": 6}
DEFAULT_FREE = ("distance", "normal")
#: Free parameters of a rig of two domes: each camera's decentring (x, y, z in its own frame,
#: left then right) and the water index; and the default.
DOME_PARAMETERS = {"dome_center": 6, "n_water": 1}
DEFAULT_DOME_FREE = ("dome_center",)
#: How the in-air calibration's covariance enters the housing's (:func:`calibrate_housing`).
UNCERTAINTY = ("propagate", "prior")
#: The default: both covered the chain's error on 30 seeds of rendered boards, the prior with
#: errors 30–53 % smaller (docs/calibration.md, "σ that covers the chain").
DEFAULT_UNCERTAINTY = "prior"
#: Fewest board poses a calibration accepts.
MIN_POSES = 3
#: Relative eigenvalue of the scaled normal matrix below which a direction is not determined.
IDENTIFIABILITY_LIMIT = 1e-12
#: |correlation| at which two free parameters cannot be told apart.
CORRELATION_LIMIT = 0.9995
#: A fit that leaves more reprojection RMS than this (px) has not found the housing.
FIT_RMS_LIMIT_PX = 2.0
#: Smallest port distance and layer thickness the adjustment may try (mm); largest index.
MIN_LENGTH_MM, MAX_INDEX = 1e-3, 3.0


class CalibrationError(ValueError):
    """Board images that cannot calibrate what was asked (too few poses, boards not found)."""


@dataclass(frozen=True)
class Detections:
    """Per pose and view the detected corners: ``ids[k][v]`` ``(M,)`` and ``pixels[k][v]``
    ``(M, 2)`` for pose k, view v (0 left, 1 right); empty arrays where the board was not
    found."""

    ids: list
    pixels: list

    @property
    def n_poses(self) -> int:
        return len(self.ids)

    def found(self, view: int) -> list[int]:
        return [k for k in range(self.n_poses) if len(self.ids[k][view]) >= MIN_CORNERS]


def detect_images(board: Board, images, workers: int | None = None) -> list:
    """``[(ids, pixels), …]``: :meth:`Board.detect` of every image, on ``workers`` threads
    (default: one per CPU; OpenCV's detectors release the GIL: 15 full-size pairs took 12 s on
    2 threads against 21 s on one, on a loaded 2-core machine)."""
    from concurrent.futures import ThreadPoolExecutor

    images = list(images)
    workers = max(1, min(workers or os.cpu_count() or 1, len(images) or 1))
    if workers == 1:
        return [board.detect(img) for img in images]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(board.detect, images))


def detect_boards(board: Board, images, workers: int | None = None) -> Detections:
    """Detect ``board`` in every ``(left, right)`` image pair (:func:`detect_images`)."""
    found = detect_images(board, [img for pair in images for img in pair], workers)
    ids = [[found[2 * k][0], found[2 * k + 1][0]] for k in range(len(images))]
    pixels = [[found[2 * k][1], found[2 * k + 1][1]] for k in range(len(images))]
    return Detections(ids, pixels)


# ---------------------------------------------------------------------------------------------
# in air, with OpenCV
# ---------------------------------------------------------------------------------------------
#: Lens models of the in-air calibration: OpenCV's flags and distortion coefficients.
#: ``standard`` k1 k2 p1 p2 (k3 fixed at 0), ``k3`` adds k3, ``rational`` k1…k6 p1 p2
#: (``CALIB_RATIONAL_MODEL``: wide and action-camera lenses).
LENS_MODELS = {"standard": (cv2.CALIB_FIX_K3, 4), "k3": (0, 5),
               "rational": (cv2.CALIB_RATIONAL_MODEL, 8)}
#: ``auto`` fits them in this order and keeps a richer model only when it lowers the
#: camera's RMS by at least :data:`LENS_MODEL_GAIN` (a fraction) against the one kept before:
#: on 18 real GoPro frames (2704 × 1520) standard 0.779 px, k3 0.620 px (kept), rational
#: 0.613 px (1 % lower: not kept) — docs/calibration.md.
LENS_MODEL_ORDER = ("standard", "k3", "rational")
DEFAULT_LENS_MODEL = "auto"
#: What :func:`calibrate_in_air` fits when not told: the model of the renders and of OpenCV's own
#: default flags here (eval calibrate's --lens defaults to ``auto``).
LIBRARY_LENS_MODEL = "standard"
LENS_MODEL_GAIN = 0.02
#: Names of OpenCV's intrinsics in ``stdDeviationsIntrinsics`` order.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
#: A pose whose own stereo pose (from the two cameras' board poses) lies farther than
#: max(:data:`STEREO_OUTLIER_FACTOR` × the median distance, :data:`STEREO_FLOOR_FRACTION` ×
#: the baseline) or turned by more than max(factor × the median angle,
#: :data:`STEREO_FLOOR_DEG`) from the poses' median stereo pose is left out of the stereo fit
#: (:func:`stereo_pose_outliers`): a swapped, turned or mirrored photo, or a pair not taken at
#: one moment.
STEREO_OUTLIER_FACTOR, STEREO_FLOOR_FRACTION, STEREO_FLOOR_DEG = 5.0, 0.02, 0.5


@dataclass(frozen=True)
class AirCalibration:
    """``rig`` (no port: index-matched), per camera ``rms_px`` and ``sigmas`` (fx, fy, cx, cy
    and the lens model's distortion coefficients, from ``calibrateCameraExtended``), the
    stereo ``stereo_rms_px`` and the number of poses used per camera and for the pair;
    ``rms_px_per`` ``{(pose, view): rms}`` (OpenCV's per-view errors: RMS of the 2D residual
    length, px) and ``board_poses`` ``{(pose, view): (R, t)}`` (board to the reference frame,
    mm, from that camera's ``calibrateCamera`` extrinsics); ``covariance`` the full covariance
    of both cameras' intrinsics and the stereo pose
    (:func:`measure.calibration_covariance.air_covariance`; None for a lens model other than
    ``standard``: its extra coefficients are not in that covariance yet). ``lens_models`` per
    camera: the model used and the RMS of each model tried; ``stereo_poses`` per pose seen by
    both cameras its own stereo pose and its distance from the median
    (:func:`stereo_pose_outliers`), ``stereo_left_out`` the poses left out of the stereo fit
    for it; ``stereo_rms_px_per`` ``{pose: rms}`` of the stereo fit (both views);
    ``residuals`` per view ``(pose, id, du, dv)`` rows of each camera's own fit (projected −
    detected, px), as :class:`HousingCalibration`'s."""

    rig: StereoRig
    rms_px: dict
    sigmas: dict
    stereo_rms_px: float
    poses_used: dict
    rms_px_per: dict = field(default_factory=dict)
    board_poses: dict = field(default_factory=dict)
    covariance: RigCovariance | None = None
    lens_models: dict = field(default_factory=dict)
    stereo_poses: dict = field(default_factory=dict)
    stereo_left_out: tuple = ()
    stereo_rms_px_per: dict = field(default_factory=dict)
    residuals: dict = field(default_factory=dict)


def calibrate_camera(obj, img, size, lens_model: str = DEFAULT_LENS_MODEL):
    """One camera's ``cv2.calibrateCameraExtended`` with ``lens_model`` (a key of
    :data:`LENS_MODELS`, or ``auto``: module constants). Returns ``(out, model, tried)``:
    OpenCV's outputs, the model used and ``{model: rms px}`` of each model fitted."""
    if lens_model != "auto" and lens_model not in LENS_MODELS:
        raise CalibrationError(f"lens model {lens_model!r}: choose from auto, "
                               f"{', '.join(LENS_MODELS)}")
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    order = LENS_MODEL_ORDER if lens_model == "auto" else (lens_model,)
    tried, best, best_model = {}, None, None
    for model in order:
        out = cv2.calibrateCameraExtended(obj, img, tuple(size), None, None,
                                          flags=LENS_MODELS[model][0], criteria=criteria)
        tried[model] = float(out[0])
        if best is None or (np.isfinite(out[0]) and out[0] < (1 - LENS_MODEL_GAIN) * best[0]
                            and lens_problem(out, model, size) is None):
            best, best_model = out, model
    return best, best_model, tried


def lens_problem(out, model: str, size) -> str | None:
    """Why the camera of a ``calibrateCameraExtended`` result ``out`` fitted with ``model``
    cannot be used over its whole image (its distortion folds: a richer model fitted to corners
    that leave the image's edges uncovered), or None
    (:meth:`measure.camera.Camera.distortion_problem`)."""
    dist = out[2].ravel()[:max(LENS_MODELS[model][1], 5)]
    if not np.all(np.isfinite(dist)) or not np.all(np.isfinite(out[1])):
        return "the fit gave non-finite intrinsics"
    return Camera(out[1], size, dist=dist).distortion_problem()


def relative_poses(left_extrinsics, right_extrinsics):
    """Per pose the stereo pose seen through that pose alone, in OpenCV's stereo convention
    (``X_right = R X_left + T``): ``(R (P, 3, 3), T (P, 3) mm)`` from each camera's
    board-to-camera ``(R, t)`` pairs."""
    R_l = np.stack([R for R, _ in left_extrinsics])
    R_r = np.stack([R for R, _ in right_extrinsics])
    t_l = np.stack([t for _, t in left_extrinsics])
    t_r = np.stack([t for _, t in right_extrinsics])
    R = R_r @ np.transpose(R_l, (0, 2, 1))
    return R, t_r - np.einsum("pij,pj->pi", R, t_l)


def stereo_pose_outliers(R, T) -> dict:
    """The poses whose own stereo pose ``(R (P, 3, 3), T (P, 3))`` disagrees with the others
    (module constants): the median pose is the component-wise median of ``T`` and the medoid
    of the rotations; returns ``{"deviation_mm" (P,), "deviation_deg" (P,),
    "threshold_mm", "threshold_deg", "outliers" [indices], "baseline_mm" (P,)}``."""
    T = np.asarray(T, dtype=np.float64)
    angles = np.degrees(Rotation.from_matrix(
        np.einsum("pij,qkj->pqik", R, R).reshape(-1, 3, 3)).magnitude()).reshape(len(R), len(R))
    medoid = int(np.argmin(np.median(angles, axis=1)))
    deviation_deg = angles[:, medoid]
    deviation_mm = np.linalg.norm(T - np.median(T, axis=0), axis=1)
    baseline = float(np.linalg.norm(np.median(T, axis=0)))
    threshold_mm = max(STEREO_OUTLIER_FACTOR * float(np.median(deviation_mm)),
                       STEREO_FLOOR_FRACTION * baseline)
    threshold_deg = max(STEREO_OUTLIER_FACTOR * float(np.median(deviation_deg)), STEREO_FLOOR_DEG)
    bad = (deviation_mm > threshold_mm) | (deviation_deg > threshold_deg)
    return {"deviation_mm": deviation_mm, "deviation_deg": deviation_deg,
            "threshold_mm": threshold_mm, "threshold_deg": threshold_deg,
            "outliers": [int(i) for i in np.flatnonzero(bad)],
            "baseline_mm": np.linalg.norm(T, axis=1)}


def calibrate_in_air(board: Board, detections: Detections, size,
                     lens_model: str = LIBRARY_LENS_MODEL) -> AirCalibration:
    """OpenCV calibration of both cameras (``lens_model``: :func:`calibrate_camera`) and their
    stereo pose from in-air board images; poses whose own stereo pose disagrees with the
    others' (:func:`stereo_pose_outliers`) are left out of the stereo fit and named."""
    corners = board.corners().astype(np.float32)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    cameras, rms, sigmas, used, per, extrinsics = [], {}, {}, {}, {}, {}
    views, s2, left_poses, models, own, residuals = [], [], {}, {}, {}, {}
    for view, name in enumerate(("left", "right")):
        poses = detections.found(view)
        if len(poses) < MIN_POSES:
            raise CalibrationError(f"the board was found in {len(poses)} {name} image(s); an "
                                   f"in-air calibration needs at least {MIN_POSES}")
        obj = [corners[detections.ids[k][view]] for k in poses]
        img = [detections.pixels[k][view].astype(np.float32) for k in poses]
        out, model, tried = calibrate_camera(obj, img, size, lens_model)
        n_dist = LENS_MODELS[model][1]
        models[name] = {"model": model, "rms_px": tried,
                        "problem": lens_problem(out, model, size)}
        rms[name], K, std = float(out[0]), out[1], out[5].ravel()
        D = out[2].ravel()[:max(n_dist, 5)]
        for k, error, rvec, tvec in zip(poses, out[7].ravel(), out[3], out[4]):
            per[(k, view)] = float(error)
            extrinsics[(k, view)] = (Rotation.from_rotvec(np.ravel(rvec)).as_matrix(),
                                     np.ravel(tvec).astype(np.float64))
        sigmas[name] = dict(zip(INTRINSIC_NAMES[:4 + n_dist], (float(s) for s in std)))
        residuals[view] = camera_residuals(obj, img, out, poses, detections.ids, view)
        cameras.append((K, D))
        n = sum(len(o) for o in obj)  # OpenCV's RMS is per corner of the 2D residual length
        s2.append(rms[name] ** 2 * n / max(2 * n - 4 - n_dist - 6 * len(poses), 1))
        views.append({"obj": obj, "keys": [[(k, i) for i in detections.ids[k][view]]
                                           for k in poses],
                      "rvecs": out[3], "tvecs": out[4], "K": K, "dist": D})
        if view == 0:
            left_poses = {k: (rv, tv) for k, rv, tv in zip(poses, out[3], out[4])}
        own[view] = {k: extrinsics[(k, view)] for k in poses}
        used[name] = len(poses)
    both = [k for k in detections.found(0) if k in set(detections.found(1))]
    stereo_poses, left_out = {}, ()
    if len(both) >= MIN_POSES:
        R_k, T_k = relative_poses([own[0][k] for k in both], [own[1][k] for k in both])
        check = stereo_pose_outliers(R_k, T_k)
        left_out = tuple(both[i] for i in check["outliers"])
        stereo_poses = {k: {"baseline_mm": float(check["baseline_mm"][i]),
                            "deviation_mm": float(check["deviation_mm"][i]),
                            "deviation_deg": float(check["deviation_deg"][i]),
                            "threshold_mm": check["threshold_mm"],
                            "threshold_deg": check["threshold_deg"]}
                        for i, k in enumerate(both)}
        both = [k for k in both if k not in set(left_out)]
    if len(both) < MIN_POSES:
        disagree = (f" ({len(left_out)} more left out: their own stereo poses disagree)"
                    if left_out else "")
        raise CalibrationError(f"the board was found in both views of {len(both)} pose(s)"
                               f"{disagree}; the stereo calibration needs at least {MIN_POSES}")
    obj, img_l, img_r, keys = [], [], [], []
    for k in both:
        common, il, ir = np.intersect1d(detections.ids[k][0], detections.ids[k][1],
                                        return_indices=True)
        obj.append(corners[common])
        keys.append([(k, i) for i in common])
        img_l.append(detections.pixels[k][0][il].astype(np.float32))
        img_r.append(detections.pixels[k][1][ir].astype(np.float32))
    (K1, D1), (K2, D2) = cameras
    out = cv2.stereoCalibrateExtended(obj, img_l, img_r, K1, D1, K2, D2, tuple(size), None,
                                      None, flags=cv2.CALIB_FIX_INTRINSIC, criteria=criteria)
    stereo_rms, R, T = float(out[0]), out[5], out[6].ravel()
    stereo_per = {k: float(np.sqrt(np.mean(np.square(e)))) for k, e in zip(both, out[-1])}
    used["stereo"] = len(both)
    left = Camera(K1, size, dist=D1)
    right = Camera(K2, size, dist=D2, R=_orthonormal(R).T, t=-_orthonormal(R).T @ T)
    port = index_matched_port(left.R[:, 2], np.stack([left.t, right.t]))
    board_poses = {}
    for (k, view), (R_cam, t_cam) in extrinsics.items():
        camera = (left, right)[view]
        board_poses[(k, view)] = (camera.R @ R_cam, camera.R @ t_cam + camera.t)
    covariance = None
    if all(m["model"] == "standard" for m in models.values()):
        # linearized at the left camera's own board poses (stereoCalibrate's refinement of
        # them moves the Jacobian by nothing that matters)
        covariance = air_covariance(
            views, {"obj": obj, "keys": keys, "rvecs": [left_poses[k][0] for k in both],
                    "tvecs": [left_poses[k][1] for k in both], "om": cv2.Rodrigues(R)[0],
                    "T": T}, s2)
    return AirCalibration(StereoRig(left, right, port), rms, sigmas, stereo_rms, used, per,
                          board_poses, covariance, models, stereo_poses, left_out, stereo_per,
                          residuals)


def camera_residuals(obj, img, out, poses, ids, view) -> np.ndarray:
    """``(pose, id, du, dv)`` rows of one camera's ``calibrateCamera`` (``out``): every corner
    projected with its pose's extrinsics minus where it was detected, px."""
    rows = []
    for k, o, observed, rvec, tvec in zip(poses, obj, img, out[3], out[4]):
        projected = cv2.projectPoints(o, rvec, tvec, out[1], out[2])[0].reshape(-1, 2)
        d = projected - np.asarray(observed, np.float64).reshape(-1, 2)
        rows.append(np.column_stack([np.full(len(d), k), ids[k][view], d]))
    return np.vstack(rows) if rows else np.empty((0, 4))


def _orthonormal(R) -> np.ndarray:
    u, _, vt = np.linalg.svd(np.asarray(R, dtype=np.float64))
    return u @ vt


# ---------------------------------------------------------------------------------------------
# underwater: refractive bundle adjustment
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class HousingCalibration:
    """Result of :func:`calibrate_housing`.

    ``rig`` the calibrated rig (the starting rig when not identifiable); ``estimates`` /
    ``sigmas`` per free parameter (``normal``: the unit vector and two tilt sigmas in rad;
    ``extrinsics``: the right camera's ``R``, ``t`` and six sigmas); ``labels`` and
    ``correlation`` of the free numbers; ``poses`` ``[(R, t), …]`` of the boards;
    ``rms_px`` overall and ``rms_px_per`` ``{(pose, view): rms}``; ``residuals`` per view
    ``(pose, id, du, dv)`` rows; ``identifiable`` / ``reason``; ``pose_ids`` the numbers of
    the poses used (``poses[i]`` is pose ``pose_ids[i]``). RMS values are per corner, of the
    2D residual length."""

    rig: StereoRig
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


def _observations(board: Board, detections: Detections, views=(0, 1)):
    corners = board.corners()
    obs = []
    for view in views:
        pose_idx, ids, uv = [], [], []
        for k in range(detections.n_poses):
            if len(detections.ids[k][view]) >= MIN_CORNERS:
                n = len(detections.ids[k][view])
                pose_idx.append(np.full(n, k))
                ids.append(detections.ids[k][view])
                uv.append(detections.pixels[k][view])
        if pose_idx:
            obs.append((view, np.concatenate(pose_idx), np.concatenate(ids),
                        np.concatenate(uv)))
        else:
            obs.append((view, np.empty(0, int), np.empty(0, int), np.empty((0, 2))))
    return corners, obs


def _start_poses(rig: StereoRig, board: Board, detections: Detections):
    """Per pose (R, t) board-to-reference from ``cv2.solvePnP`` on the left view (the right
    view, moved to the reference frame, where the left has no board)."""
    corners = board.corners()
    poses = []
    for k in range(detections.n_poses):
        for view, camera in enumerate(rig.cameras):
            ids = detections.ids[k][view]
            if len(ids) >= MIN_CORNERS:
                ok, rvec, tvec = cv2.solvePnP(corners[ids], detections.pixels[k][view], camera.K,
                                              camera.dist if camera.dist is not None else None,
                                              flags=cv2.SOLVEPNP_ITERATIVE)
                if ok:
                    R_cam = Rotation.from_rotvec(rvec.ravel()).as_matrix()
                    poses.append((camera.R @ R_cam, camera.R @ tvec.ravel() + camera.t))
                    break
        else:
            poses.append(None)
    return poses


def _usable_poses(rig: StereoRig, board: Board, detections: Detections):
    """``(starts, usable, detections)``: the starting board poses that ``cv2.solvePnP`` found,
    the numbers of those poses, and the detections of those poses only (in that order);
    CalibrationError when fewer than :data:`MIN_POSES` remain."""
    starts = _start_poses(rig, board, detections)
    usable = [k for k, s in enumerate(starts) if s is not None]
    if len(usable) < MIN_POSES:
        raise CalibrationError(f"the board was found in {len(usable)} pose(s); the housing "
                               f"calibration needs at least {MIN_POSES}")
    detections = Detections([detections.ids[k] for k in usable],
                            [detections.pixels[k] for k in usable])
    return [starts[k] for k in usable], usable, detections


def housing_problem(rig: StereoRig, board: Board, detections: Detections, names):
    """The bundle adjustment of :func:`calibrate_housing` as functions of the unknowns ``x``
    (free housing numbers, then 6 per usable pose): ``residuals``, its analytic ``jacobian``,
    ``unpack``, the start ``x0`` and its ``lower`` / ``upper`` bounds, and the bookkeeping."""
    starts, usable, detections = _usable_poses(rig, board, detections)
    P = len(starts)
    n_global = sum(HOUSING_PARAMETERS[n] for n in names)
    port0, basis = rig.port, tilt_basis(rig.port.normal)
    corners, obs = _observations(board, detections)
    m = sum(2 * o[1].size for o in obs)

    def unpack(x):
        indices, thick, distance = list(port0.indices), list(port0.thicknesses), port0.distance
        normal, right = port0.normal, rig.right
        k = 0
        for name in names:
            if name == "distance":
                distance = x[k]
            elif name == "normal":
                normal = port0.normal + x[k] * basis[0] + x[k + 1] * basis[1]
            elif name == "thickness":
                thick[0] = x[k]
            elif name == "n_water":
                indices[-1] = x[k]
            elif name == "extrinsics":
                dR = Rotation.from_rotvec(x[k:k + 3]).as_matrix()
                right = Camera(rig.right.K, rig.right.size, rig.right.dist,
                               dR @ rig.right.R, rig.right.t + x[k + 3:k + 6])
            k += HOUSING_PARAMETERS[name]
        port = FlatPort(normal, distance, tuple(thick), tuple(indices))
        Rs = Rotation.from_rotvec(x[n_global:].reshape(P, 6)[:, :3]).as_matrix()
        ts = x[n_global:].reshape(P, 6)[:, 3:]
        return port, (rig.left, right), Rs, ts

    def residuals(x):
        try:
            port, cameras, Rs, ts = unpack(x)
        except ValueError:  # e.g. a non-physical index or thickness on the way
            return np.full(m, 1e3)
        out = []
        for view, pose_idx, ids, uv in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            r = (project(cameras[view], port, world) - uv).ravel()
            out.append(np.where(np.isfinite(r), r, 1e3))
        return np.concatenate(out)

    def jacobian(x):
        """Analytic (:func:`measure.projection.project` with ``parameters=True``): a row touches
        the free housing numbers and its pose's 6 columns (rotation vector, translation)."""
        width = n_global + 6
        try:
            port, cameras, Rs, ts = unpack(x)
        except ValueError:  # the residuals are constant there
            return _rows_jacobian(np.zeros((m, width)), np.zeros(m, int), n_global, x.size)
        turn = _left_jacobian(x[n_global:].reshape(P, 6)[:, :3])
        blocks, poses = [], []
        for view, pose_idx, ids, _ in obs:
            rotated = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids])
            _, d_points, jac = project(cameras[view], port, rotated + ts[pose_idx],
                                       parameters=True)
            columns = []
            for name in names:
                if name == "distance":
                    columns.append(jac.distance[..., None])
                elif name == "normal":  # normal = m / |m|, m = N0 + a·x_a + b·x_b
                    k = _offset(names, name)
                    length = np.linalg.norm(port0.normal + x[k] * basis[0] + x[k + 1] * basis[1])
                    columns.append(np.stack([jac.normal @ axis / length for axis in basis], -1))
                elif name == "thickness":
                    columns.append(jac.thicknesses[..., :1])
                elif name == "n_water":
                    columns.append(jac.indices[..., -1:])
                elif view == 1:  # the right camera: R = exp(ω) R0, t = t0 + δt
                    k = _offset(names, name)
                    columns.append(jac.rotation @ _left_jacobian(x[None, k:k + 3])[0])
                    columns.append(jac.center)
                else:
                    columns.append(np.zeros(d_points.shape[:2] + (6,)))
            # a pose: X = exp(ω) c + t, so dX/dω = −[R c]× J_l(ω) and dX/dt = I
            d_turn = np.einsum("nrj,njk->nrk", np.cross(rotated[:, None, :], d_points),
                               turn[pose_idx])
            columns += [d_turn, d_points]
            blocks.append(np.concatenate(columns, axis=-1).reshape(-1, width))
            poses.append(np.repeat(pose_idx, 2))
        return _rows_jacobian(np.concatenate(blocks), np.concatenate(poses), n_global, x.size)

    def air_jacobian(x, air):
        """Dense ``(m, len(air))``: d residuals / d the in-air parameters ``air`` (names of
        :data:`measure.calibration_covariance.AIR_NAMES`) at ``x`` (module docs of
        :mod:`measure.calibration_covariance`)."""
        port, cameras, Rs, ts = unpack(x)
        column = {name: j for j, name in enumerate(air)}
        out, row = np.zeros((m, len(air))), 0
        for view, pose_idx, ids, _ in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            pixels, _, jac = project(cameras[view], port, world, parameters=True)
            n = 2 * pose_idx.size
            camera = ("left", "right")[view]
            d_int = intrinsics_jacobian(cameras[view], pixels).reshape(n, -1)
            for j, p in enumerate(AIR_INTRINSICS):
                if f"{camera}.{p}" in column:
                    out[row:row + n, column[f"{camera}.{p}"]] = d_int[:, j]
            if view == 1:
                for k in range(3):
                    for what, values in (("rotation", jac.rotation), ("center", jac.center)):
                        if f"right.{what}[{k}]" in column:
                            out[row:row + n, column[f"right.{what}[{k}]"]] = (
                                values[..., k].reshape(n))
            row += n
        return np.where(np.isfinite(out), out, 0.0)

    x0 = []
    for name in names:
        x0 += {"distance": [port0.distance], "normal": [0.0, 0.0],
               "thickness": list(port0.thicknesses[:1]), "n_water": [port0.n_water],
               "extrinsics": [0.0] * 6}[name]
    for R, t in starts:
        x0 += list(Rotation.from_matrix(R).as_rotvec()) + list(t)
    x0 = np.asarray(x0, dtype=np.float64)
    lower = np.full(x0.size, -np.inf)
    upper = np.full(x0.size, np.inf)
    k = 0
    for name in names:  # keep the port physical on the way: a layer, indices >= 1
        if name in ("distance", "thickness"):
            lower[k] = MIN_LENGTH_MM
        elif name == "n_water":
            lower[k], upper[k] = 1.0, MAX_INDEX
        k += HOUSING_PARAMETERS[name]
    x0[:n_global] = np.clip(x0[:n_global], lower[:n_global] + 1e-9, upper[:n_global] - 1e-9)
    return SimpleNamespace(residuals=residuals, jacobian=jacobian, unpack=unpack, x0=x0,
                           air_jacobian=air_jacobian,
                           lower=lower, upper=upper, obs=obs, usable=usable, P=P,
                           n_global=n_global, basis=basis, m=m)


def calibrate_housing(rig: StereoRig, board: Board, detections: Detections,
                      free=None, air_covariance: RigCovariance | None = None,
                      uncertainty: str = DEFAULT_UNCERTAINTY) -> HousingCalibration:
    """Refractive bundle adjustment of the housing (module docs). ``rig``: the in-air cameras
    with the starting port (its fixed parameters are the design values) — a flat port, or two
    domes (:func:`dome_problem`: each camera's decentring). ``free`` defaults to
    :data:`DEFAULT_FREE`, for domes :data:`DEFAULT_DOME_FREE`. ``air_covariance``: the in-air
    calibration's covariance (:attr:`AirCalibration.covariance`, or a calib.yaml's), brought
    into the housing's by ``uncertainty``: ``"propagate"`` (the in-air parameters fixed, their
    covariance propagated) or ``"prior"`` (freed, with the in-air result as a prior), for a
    flat port and for domes alike. Without it the σ is conditional on the in-air
    calibration."""
    if free is None:
        free = DEFAULT_DOME_FREE if rig.is_dome else DEFAULT_FREE
    if uncertainty not in UNCERTAINTY:
        raise CalibrationError(f"uncertainty {uncertainty!r}: expected one of "
                               f"{', '.join(UNCERTAINTY)}")
    names = tuple(dict.fromkeys(free))
    table = DOME_PARAMETERS if rig.is_dome else HOUSING_PARAMETERS
    unknown = [n for n in names if n not in table]
    if not names or unknown:
        raise CalibrationError(f"--free {','.join(free) or '(nothing)'}: the housing calibration "
                               f"{'of two domes ' if rig.is_dome else ''}estimates "
                               f"{', '.join(table)}")
    if not rig.is_dome and "thickness" in names and not rig.port.thicknesses:
        raise CalibrationError("--free thickness: the port has no glass layer")
    problem = (dome_problem if rig.is_dome else housing_problem)(rig, board, detections, names)
    residuals, unpack, x0, lower, upper = (problem.residuals, problem.unpack, problem.x0,
                                           problem.lower, problem.upper)
    obs, usable, P, n_global, basis, m = (problem.obs, problem.usable, problem.P,
                                          problem.n_global, problem.basis, problem.m)
    rms_start = float(np.sqrt(np.mean(residuals(x0) ** 2)))
    fit = least_squares(residuals, x0, jac=problem.jacobian, method="trf", x_scale="jac",
                        bounds=(lower, upper), xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=300,
                        tr_solver="lsmr", tr_options={"atol": 1e-14, "btol": 1e-14})
    r = fit.fun
    J = fit.jac.toarray() if hasattr(fit.jac, "toarray") else np.asarray(fit.jac)
    dof = max(r.size - x0.size, 1)
    s2 = float(r @ r) / dof
    N = J.T @ J
    scale = np.sqrt(np.diag(N))
    scale[scale == 0] = 1.0
    Ns = N / np.outer(scale, scale)
    eigval, eigvec = np.linalg.eigh(Ns)
    labels = tuple(f"{n}[{k}]" if table[n] > 1 else n for n in names for k in range(table[n]))
    port, cameras, Rs, ts = unpack(fit.x)
    poses = [(Rs[k], ts[k]) for k in range(P)]
    per, res = {}, {}
    offset = 0
    for view, pose_idx, ids, _ in obs:
        rv = r[offset:offset + 2 * pose_idx.size].reshape(-1, 2)
        offset += 2 * pose_idx.size
        res[view] = np.column_stack([usable_index(usable, pose_idx), ids, rv])
        for k in np.unique(pose_idx):
            per[(usable[k], view)] = float(np.sqrt(np.mean(rv[pose_idx == k] ** 2) * 2))
    base = dict(labels=labels, poses=poses, rms_px=float(np.sqrt(np.mean(r ** 2) * 2)),
                rms_px_start=rms_start * np.sqrt(2), rms_px_per=per, residuals=res,
                converged=bool(fit.status > 0), n_observations=m // 2, nfev=int(fit.nfev),
                message=str(fit.message), normal_axes=tuple(b.tolist() for b in basis),
                pose_ids=tuple(usable))
    relative = eigval / eigval[-1] if eigval[-1] > 0 else np.zeros_like(eigval)
    if relative[0] < IDENTIFIABILITY_LIMIT:
        worst = int(np.argmax(np.abs(eigvec[:n_global, 0]))) if n_global else 0
        name = labels[worst] if n_global else "a board pose"
        return HousingCalibration(
            rig=rig, estimates={}, sigmas={}, correlation=np.full((n_global, n_global), np.nan),
            identifiable=False, reason=f"{name} is not determined by these boards (relative "
                                       f"eigenvalue {relative[0]:.1e})", **base)
    covariance = s2 * np.linalg.inv(N)
    sig = np.sqrt(np.diag(covariance))
    cov_g = covariance[:n_global, :n_global]
    correlation = cov_g / np.outer(sig[:n_global], sig[:n_global])
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
            rig=rig, estimates={}, sigmas={}, correlation=np.full((n_global, n_global), np.nan),
            identifiable=False, reason=(
                f"the adjustment did not converge within {fit.nfev} evaluations (reprojection "
                f"RMS {base['rms_px']:.3g} px): the free parameters are barely determined by "
                f"these boards (free fewer, or render more varied poses)"
                if base["rms_px"] <= FIT_RMS_LIMIT_PX else
                f"the adjustment stopped with a reprojection RMS of {base['rms_px']:.3g} px "
                f"({fit.message.rstrip('.')}): it did not find a housing that fits the corners "
                f"(check the design values, the starting distance and --free)"),
            **{**base, "converged": False})
    at_bound = np.flatnonzero(fit.active_mask[:n_global] != 0)
    if at_bound.size:
        return HousingCalibration(
            rig=rig, estimates={}, sigmas={}, correlation=np.full((n_global, n_global), np.nan),
            identifiable=False, reason=f"{labels[at_bound[0]]} ran into its physical bound: "
                                       f"these boards do not determine it", **base)
    x, sig_conditional = fit.x, sig[:n_global].copy()
    air = _air_parameters(air_covariance, names)
    if air:
        sigma_air = _sub_covariance(air_covariance, air)
        if uncertainty == "prior":
            rig, x, joint = _prior_fit(rig, board, detections, names, x, s2, air, sigma_air)
            port, cameras, Rs, ts = (dome_problem if rig.is_dome else housing_problem)(
                rig, board, detections, names).unpack(x)
            base["poses"] = [(Rs[k], ts[k]) for k in range(P)]
        else:
            J_air = problem.air_jacobian(x, air)
            G = np.linalg.solve(N, J.T @ J_air)  # δx = −G δθ_air
            cross = -(G @ sigma_air)
            joint = np.block([[sigma_air, cross.T], [cross, covariance + G @ sigma_air @ G.T]])
        sig = np.sqrt(np.diag(joint))[len(air):]
    else:
        joint = covariance
    a = len(air)
    if rig.is_dome:
        rig_names, T, axes = _dome_rig_parameters(names, air, cameras, port)
    else:
        rig_names, transform, axes = _rig_parameters(names, x, basis, rig.port.normal, port,
                                                   n_global)
        T = np.eye(a + n_global)
        T[a:, a:] = transform
    keep = list(range(a + n_global))
    joint = T @ joint[np.ix_(keep, keep)] @ T.T
    rig_cov = RigCovariance(tuple(air) + rig_names, 0.5 * (joint + joint.T), axes)
    estimates, sigmas, conditional, k = {}, {}, {}, 0
    for name in names:
        w = table[name]
        if name == "dome_center":
            estimates[name] = {view: dome_offset(cameras[i], port[i]).tolist()
                               for i, view in enumerate(("left", "right"))}
        elif name == "distance":
            estimates[name] = port.distance
        elif name == "normal":
            estimates[name] = port.normal.tolist()
        elif name == "thickness":
            estimates[name] = port.thicknesses[0]
        elif name == "n_water":
            estimates[name] = port.n_water
        else:
            estimates[name] = {"R": cameras[1].R.tolist(), "t": cameras[1].t.tolist()}
        sigmas[name] = float(sig[k]) if w == 1 else sig[k:k + w].tolist()
        conditional[name] = (float(sig_conditional[k]) if w == 1
                             else sig_conditional[k:k + w].tolist())
        k += w
    calibrated = StereoRig(cameras[0], cameras[1], port)
    return HousingCalibration(rig=calibrated, estimates=estimates, sigmas=sigmas,
                              correlation=correlation, identifiable=True, reason="",
                              covariance=rig_cov, sigmas_conditional=conditional,
                              uncertainty=uncertainty if air else "conditional", **base)


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


def _rig_parameters(names, x, basis, start_normal, port, n_global):
    """The housing's free numbers as :mod:`measure.rig_covariance` names, the ``(g, g)``
    Jacobian of those parameters with respect to the free numbers at ``x``, and the tilt axes
    (⟂ the estimated normal; None without a free normal)."""
    out, T, axes, k = [], np.zeros((n_global, n_global)), None, 0
    for name in names:
        if name == "distance":
            out.append("port.distance")
            T[k, k] = 1.0
        elif name == "normal":  # n = m/|m|, m = n0 + a e0 + b e1; new tilts about axes ⟂ n
            m = start_normal + basis[0] * x[k] + basis[1] * x[k + 1]
            length = np.linalg.norm(m)
            n = m / length
            axes = np.array(tilt_basis(n))
            T[k:k + 2, k:k + 2] = axes @ (np.eye(3) - np.outer(n, n)) @ np.array(basis).T / length
            out += ["port.tilt[0]", "port.tilt[1]"]
        elif name == "thickness":
            out.append("port.thickness[0]")
            T[k, k] = 1.0
        elif name == "n_water":
            out.append(f"port.index[{len(port.indices) - 1}]")
            T[k, k] = 1.0
        else:  # R = exp(ω) R0: φ = J_l(ω) δω; the centre t = t0 + δt
            out += [f"right.rotation[{i}]" for i in range(3)]
            out += [f"right.center[{i}]" for i in range(3)]
            T[k:k + 3, k:k + 3] = left_jacobian(x[k:k + 3])
            T[k + 3:k + 6, k + 3:k + 6] = np.eye(3)
        k += HOUSING_PARAMETERS[name]
    return tuple(out), T, axes


def _dome_rig_parameters(names, air, cameras, domes):
    """The dome calibration's free numbers as :mod:`measure.rig_covariance` names —
    ``left/right.dome_center[0..2]`` (each dome's centre in the reference frame, mm) and
    ``port.index[2]`` — and the ``(a + g, a + g)`` Jacobian of (in-air parameters ``air``,
    those names) with respect to (``air``, the free numbers): ``M = C + R·o`` with ``o`` the
    decentring in the camera's frame, so ``δM = R·δo`` and, for the right camera,
    ``+ δC − [R·o]× φ`` where its pose is among ``air``. No tilt axes (None)."""
    a = len(air)
    out = []
    g = sum(DOME_PARAMETERS[n] for n in names)
    T = np.zeros((a + g, a + g))
    T[:a, :a] = np.eye(a)
    k = a
    for name in names:
        if name == "dome_center":
            for view, camera in enumerate(("left", "right")):
                R = cameras[view].R
                T[k:k + 3, k:k + 3] = R
                if view == 1:
                    lever = -_skew(domes[1].center - cameras[1].center)
                    for i in range(3):
                        if f"right.rotation[{i}]" in air:
                            T[k:k + 3, air.index(f"right.rotation[{i}]")] = lever[:, i]
                        if f"right.center[{i}]" in air:
                            T[k + i, air.index(f"right.center[{i}]")] = 1.0
                out += [f"{camera}.dome_center[{i}]" for i in range(3)]
                k += 3
        else:
            out.append(f"port.index[{len(domes.left.indices) - 1}]")
            T[k, k] = 1.0
            k += 1
    return tuple(out), T, None


def apply_air_change(rig: StereoRig, air, delta) -> StereoRig:
    """``rig`` with the in-air parameters ``air`` moved by ``delta`` (px, unitless, rad: the
    right camera's ``R → exp([φ]×) R``, mm: its centre)."""
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


#: Gauss-Newton iterations of the prior fit, and its stop: every step below this many σ.
PRIOR_ITERATIONS, PRIOR_STEP_SIGMA = 8, 1e-4


def _prior_fit(rig, board, detections, names, x, s2, air, sigma_air):
    """The housing with the in-air parameters ``air`` free under their in-air prior: the rows
    ``s·L(θ − θ_air)`` (``LᵀL = Σ_air⁻¹``, ``s²`` the corners' variance of the conditional fit)
    beside the corners' residuals; Gauss-Newton from the conditional solution ``x``. Returns
    the rig with the refined in-air parameters, the housing unknowns and the joint covariance
    ``s²(AᵀA)⁻¹`` ordered (in-air parameters, housing unknowns)."""
    L = np.linalg.inv(np.linalg.cholesky(sigma_air))
    s = np.sqrt(s2)
    delta, a = np.zeros(len(air)), len(air)
    for _ in range(PRIOR_ITERATIONS + 1):
        moved = apply_air_change(rig, air, delta)
        problem = (dome_problem if rig.is_dome else housing_problem)(moved, board, detections,
                                                                     names)
        if problem.x0.size != x.size:  # solvePnP found another set of usable poses
            raise CalibrationError("the prior fit lost a board pose when the intrinsics moved; "
                                   "use --air-uncertainty propagate")
        J = problem.jacobian(x)
        J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
        A = np.block([[J, problem.air_jacobian(x, air)],
                      [np.zeros((a, J.shape[1])), s * L]])
        b = np.concatenate([problem.residuals(x), s * L @ delta])
        inverse = np.linalg.inv(A.T @ A)
        step = -inverse @ (A.T @ b)
        sig = np.sqrt(s2 * np.diag(inverse))
        if np.max(np.abs(step) / sig) < PRIOR_STEP_SIGMA:
            break
        x = x + step[:J.shape[1]]
        delta = delta + step[J.shape[1]:]
    else:
        raise CalibrationError(f"the prior fit did not converge in {PRIOR_ITERATIONS + 1} "
                               f"Gauss-Newton steps; use --air-uncertainty propagate")
    cov = s2 * inverse
    order = np.r_[J.shape[1]:J.shape[1] + a, 0:J.shape[1]]
    return moved, x, cov[np.ix_(order, order)]


def _offset(names, name, table=None) -> int:
    """Position of a free housing parameter's first number in the unknowns."""
    table = HOUSING_PARAMETERS if table is None else table
    return sum(table[n] for n in names[:names.index(name)])


def dome_offset(camera: Camera, dome: DomePort) -> np.ndarray:
    """A dome's decentring: its centre relative to the camera's centre, in the camera's frame
    (mm), ``R^T (M − C)``."""
    return camera.R.T @ (dome.center - camera.center)


def dome_problem(rig: StereoRig, board: Board, detections: Detections, names):
    """:func:`housing_problem` of a rig of two domes (:data:`DOME_PARAMETERS`): the unknowns are
    the free dome numbers — ``dome_center``: each camera's decentring in its own frame (left
    x, y, z, then right), mm; ``n_water`` — then 6 per usable pose. Radius, thickness, glass
    index and the cameras stay at the starting rig's values. Residuals through each camera's
    own dome; the Jacobian from ``project(..., parameters=True)``'s
    :class:`measure.dome_projection.DomeParameterJacobian` (``dome_center`` turned into each
    camera's frame)."""
    starts, usable, detections = _usable_poses(rig, board, detections)
    P = len(starts)
    n_global = sum(DOME_PARAMETERS[n] for n in names)
    domes0 = (rig.port.left, rig.port.right)
    corners, obs = _observations(board, detections)
    m = sum(2 * o[1].size for o in obs)

    def unpack(x):
        offsets = [dome_offset(c, d) for c, d in zip(rig.cameras, domes0)]
        n_water = domes0[0].n_water
        k = 0
        for name in names:
            if name == "dome_center":
                offsets = [x[k:k + 3], x[k + 3:k + 6]]
            else:
                n_water = x[k]
            k += DOME_PARAMETERS[name]
        domes = DomePair(*(d.replace(center=c.center + c.R @ o,
                                     indices=d.indices[:-1] + (float(n_water),))
                           for c, d, o in zip(rig.cameras, domes0, offsets)))
        Rs = Rotation.from_rotvec(x[n_global:].reshape(P, 6)[:, :3]).as_matrix()
        ts = x[n_global:].reshape(P, 6)[:, 3:]
        return domes, rig.cameras, Rs, ts

    def residuals(x):
        try:
            domes, cameras, Rs, ts = unpack(x)
        except ValueError:  # e.g. a non-physical index on the way
            return np.full(m, 1e3)
        out = []
        for view, pose_idx, ids, uv in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            r = (project(cameras[view], domes[view], world) - uv).ravel()
            out.append(np.where(np.isfinite(r), r, 1e3))
        return np.concatenate(out)

    def jacobian(x):
        width = n_global + 6
        try:
            domes, cameras, Rs, ts = unpack(x)
        except ValueError:
            return _rows_jacobian(np.zeros((m, width)), np.zeros(m, int), n_global, x.size)
        turn = _left_jacobian(x[n_global:].reshape(P, 6)[:, :3])
        blocks, poses = [], []
        for view, pose_idx, ids, _ in obs:
            rotated = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids])
            _, d_points, jac = project(cameras[view], domes[view], rotated + ts[pose_idx],
                                       parameters=True)
            columns = []
            for name in names:
                if name == "dome_center":  # M = C + R·o: d pixel / d o = d pixel / d M · R
                    own = jac.dome_center @ cameras[view].R
                    zero = np.zeros_like(own)
                    columns += [own, zero] if view == 0 else [zero, own]
                else:
                    columns.append(jac.indices[..., -1:])
            d_turn = np.einsum("nrj,njk->nrk", np.cross(rotated[:, None, :], d_points),
                               turn[pose_idx])
            columns += [d_turn, d_points]
            blocks.append(np.concatenate(columns, axis=-1).reshape(-1, width))
            poses.append(np.repeat(pose_idx, 2))
        return _rows_jacobian(np.concatenate(blocks), np.concatenate(poses), n_global, x.size)

    def air_jacobian(x, air):
        """Dense ``(m, len(air))``: d residuals / d the in-air parameters ``air`` at ``x``, as
        :func:`housing_problem`'s. With ``dome_center`` free each dome moves with its camera
        (the unknowns are offsets in the camera's frame, ``M = C + R·o``): the right camera's
        ``rotation`` column adds ``d pixel / d M · (−[R·o]×)``, its ``center`` column
        ``d pixel / d M``; otherwise the domes stay where they are."""
        domes, cameras, Rs, ts = unpack(x)
        column = {name: j for j, name in enumerate(air)}
        follow = "dome_center" in names
        out, row = np.zeros((m, len(air))), 0
        for view, pose_idx, ids, _ in obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], corners[ids]) + ts[pose_idx]
            pixels, _, jac = project(cameras[view], domes[view], world, parameters=True)
            n = 2 * pose_idx.size
            camera = ("left", "right")[view]
            d_int = intrinsics_jacobian(cameras[view], pixels).reshape(n, -1)
            for j, p in enumerate(AIR_INTRINSICS):
                if f"{camera}.{p}" in column:
                    out[row:row + n, column[f"{camera}.{p}"]] = d_int[:, j]
            if view == 1:
                rotation, center = jac.rotation, jac.center
                if follow:
                    rotation = rotation - jac.dome_center @ _skew(domes[1].center
                                                                  - cameras[1].center)
                    center = center + jac.dome_center
                for k in range(3):
                    for what, values in (("rotation", rotation), ("center", center)):
                        if f"right.{what}[{k}]" in column:
                            out[row:row + n, column[f"right.{what}[{k}]"]] = (
                                values[..., k].reshape(n))
            row += n
        return np.where(np.isfinite(out), out, 0.0)

    x0 = []
    for name in names:
        x0 += (np.concatenate([dome_offset(c, d) for c, d in zip(rig.cameras, domes0)]).tolist()
               if name == "dome_center" else [domes0[0].n_water])
    for R, t in starts:
        x0 += list(Rotation.from_matrix(R).as_rotvec()) + list(t)
    x0 = np.asarray(x0, dtype=np.float64)
    lower = np.full(x0.size, -np.inf)
    upper = np.full(x0.size, np.inf)
    if "n_water" in names:
        k = _offset(names, "n_water", DOME_PARAMETERS)
        lower[k], upper[k] = 1.0, MAX_INDEX
        x0[k] = np.clip(x0[k], lower[k] + 1e-9, upper[k] - 1e-9)
    return SimpleNamespace(residuals=residuals, jacobian=jacobian, unpack=unpack, x0=x0,
                           air_jacobian=air_jacobian,
                           lower=lower, upper=upper, obs=obs, usable=usable, P=P,
                           n_global=n_global, basis=(), m=m)


def _skew(v) -> np.ndarray:
    """``[v]×`` ``(3, 3)``: ``[v]× w = v × w``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _left_jacobian(rotvecs) -> np.ndarray:
    """SO(3)'s left Jacobian ``(P, 3, 3)`` of rotation vectors ``(P, 3)``: ``exp(ω + δ) ≈
    exp([J_l(ω) δ]×) exp(ω)``, ``J_l = I + (1 − cos θ)/θ² [ω]× + (θ − sin θ)/θ³ [ω]×²``."""
    rotvecs = np.asarray(rotvecs, dtype=np.float64)
    theta = np.linalg.norm(rotvecs, axis=1)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta ** 2 / 24, (1 - np.cos(t)) / t ** 2)
    b = np.where(small, 1 / 6 - theta ** 2 / 120, (t - np.sin(t)) / t ** 3)
    skew = np.zeros((len(rotvecs), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -rotvecs[:, 2], rotvecs[:, 1], -rotvecs[:, 0]
    skew -= skew.transpose(0, 2, 1)
    return np.eye(3) + a[:, None, None] * skew + b[:, None, None] * (skew @ skew)


def _rows_jacobian(values, pose_idx, n_global: int, n_columns: int):
    """CSR Jacobian from per-row values ``(m, n_global + 6)``: the free housing numbers, then
    the row's pose's 6 columns. Non-finite values (corners with no image) become 0."""
    m, width = values.shape
    columns = np.concatenate([np.broadcast_to(np.arange(n_global), (m, n_global)),
                              n_global + 6 * pose_idx[:, None] + np.arange(6)], axis=1)
    data = np.where(np.isfinite(values), values, 0.0).ravel()
    return csr_matrix((data, columns.ravel(), np.arange(0, m * width + 1, width)),
                      shape=(m, n_columns))


def usable_index(usable, pose_idx) -> np.ndarray:
    """Original pose numbers of compacted pose indices."""
    return np.asarray(usable)[pose_idx]


__all__ = ["AirCalibration", "CalibrationError", "DEFAULT_DOME_FREE", "DEFAULT_FREE",
           "DEFAULT_LENS_MODEL", "DEFAULT_UNCERTAINTY", "DOME_PARAMETERS", "Detections",
           "HOUSING_PARAMETERS", "HousingCalibration", "INTRINSIC_NAMES", "LENS_MODELS",
           "LENS_MODEL_GAIN", "LENS_MODEL_ORDER", "LIBRARY_LENS_MODEL", "MIN_POSES",
           "STEREO_FLOOR_DEG", "STEREO_FLOOR_FRACTION", "STEREO_OUTLIER_FACTOR", "UNCERTAINTY",
           "apply_air_change", "calibrate_camera", "calibrate_housing", "calibrate_in_air",
           "camera_residuals", "detect_boards", "detect_images", "dome_offset", "dome_problem",
           "housing_problem", "lens_problem", "relative_poses", "stereo_pose_outliers"]
