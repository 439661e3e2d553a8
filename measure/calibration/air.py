"""Calibration from board images in air, with OpenCV: the boards found in every image pair
(:func:`detect_boards`) and the cameras calibrated through no port (:func:`calibrate_in_air`).

``cv2.calibrateCameraExtended`` per camera (the lens model :data:`LENS_MODELS`: k1, k2, p1, p2
with k3 fixed at 0 by default; k3; OpenCV's rational model) and ``cv2.stereoCalibrate`` with the
intrinsics fixed give K1, D1, K2, D2 and the stereo pose — OpenCV does it, nothing is
re-implemented; poses whose own stereo pose disagrees with the others' are left out of the
stereo fit (:func:`measure.calibration.outliers.relative_pose_check`). Every camera's own fit,
:func:`fit_camera` / :func:`fit_each_camera`, is the one first step of every in-air
calibration: one camera (``eval calibrate``'s one-camera folder), the pair
(:func:`calibrate_in_air`) and N cameras (:func:`measure.calibration.multi_air.calibrate_rig_in_air`,
which checks every camera's board poses against the first's with the pair's rule). The housing
underwater: :mod:`measure.calibration.housing`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..geometry.camera import BROWN_CONRADY, FISHEYE, Camera
from ..geometry.port import index_matched_port
from ..stereo.rig import Rig, StereoRig
from .board import MIN_CORNERS, Board
from .covariance import air_covariance
from .outliers import (STEREO_FLOOR_DEG, STEREO_FLOOR_FRACTION, STEREO_OUTLIER_FACTOR,
                       relative_pose_check, relative_poses, stereo_pose_outliers)
from ..stereo.rig_covariance import RigCovariance

#: Fewest board poses a calibration accepts.
MIN_POSES = 3


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
#: (``CALIB_RATIONAL_MODEL``: wide and action-camera lenses), ``radial`` k1 k2 only (p1 p2
#: fixed at 0: MATLAB's stereo calibrator's default, and long lenses whose tangential terms
#: trade with the principal point) — OpenCV's Brown–Conrady model,
#: ``cv2.calibrateCameraExtended``; ``fisheye`` OpenCV's fisheye model (Kannala–Brandt: k1…k4
#: on the angle θ, skew fixed at 0), ``cv2.fisheye.calibrate``.
FISHEYE_FLAGS = cv2.fisheye.CALIB_RECOMPUTE_EXTRINSIC | cv2.fisheye.CALIB_FIX_SKEW
LENS_MODELS = {"standard": (cv2.CALIB_FIX_K3, 4), "k3": (0, 5),
               "rational": (cv2.CALIB_RATIONAL_MODEL, 8), "fisheye": (FISHEYE_FLAGS, 4),
               "radial": (cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST, 4)}
#: ``auto`` fits them in this order and keeps a richer model only when it lowers the
#: camera's RMS by at least :data:`LENS_MODEL_GAIN` (a fraction) against the one kept before:
#: on 18 real GoPro frames (2704 × 1520) standard 0.779 px, k3 0.620 px (kept), rational
#: 0.613 px (1 % lower: not kept) — docs/calibration.md.
#: (``fisheye`` is fitted when asked for: it is no richer Brown–Conrady model; on the GoPro
#: frames it leaves 0.540 px against rational's 0.529 px, docs/calibration.md.)
LENS_MODEL_ORDER = ("standard", "k3", "rational")
DEFAULT_LENS_MODEL = "auto"
#: What :func:`calibrate_in_air` fits when not told: the model of the renders and of OpenCV's own
#: default flags here (eval calibrate's --lens defaults to ``auto``).
LIBRARY_LENS_MODEL = "standard"
LENS_MODEL_GAIN = 0.02
#: OpenCV's stopping rule for every calibration here (count, eps).
CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
#: Names of OpenCV's intrinsics in ``stdDeviationsIntrinsics`` order.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
#: Those of the fisheye model (:func:`calibrate_fisheye`).
FISHEYE_INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")


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

    rig: Rig
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


def intrinsic_names(model: str) -> tuple:
    """The names of the σ of ``model``'s intrinsics, in the order of its fit's output."""
    if model == "fisheye":
        return FISHEYE_INTRINSIC_NAMES
    return INTRINSIC_NAMES[:4 + LENS_MODELS[model][1]]


def lens_camera(out, model: str, size, R=None, t=None) -> Camera:
    """The :class:`Camera` of a fit ``out`` (:func:`calibrate_camera`) with ``model``."""
    dist = np.ravel(out[2])
    if model == "fisheye":
        return Camera(out[1], size, dist[:4], R, t, FISHEYE)
    return Camera(out[1], size, dist[:max(LENS_MODELS[model][1], 5)], R, t, BROWN_CONRADY)


def project_board(model: str, obj, rvec, tvec, K, D) -> np.ndarray:
    """``(M, 2)`` pixels of board points ``obj`` ``(M, 3)`` at one pose, by OpenCV's own
    projection of ``model`` (``cv2.projectPoints`` or ``cv2.fisheye.projectPoints``)."""
    obj = np.asarray(obj, np.float64).reshape(-1, 1, 3)
    if model == "fisheye":
        return cv2.fisheye.projectPoints(obj, np.ravel(rvec).astype(np.float64),
                                         np.ravel(tvec).astype(np.float64), K,
                                         np.ravel(D)[:4])[0].reshape(-1, 2)
    return cv2.projectPoints(obj, rvec, tvec, K, D)[0].reshape(-1, 2)


def calibrate_fisheye(obj, img, size):
    """``cv2.fisheye.calibrate`` (:data:`FISHEYE_FLAGS`) in ``cv2.calibrateCameraExtended``'s
    layout: ``(rms, K, D (4, 1), rvecs, tvecs, σ intrinsics (8, 1), σ extrinsics, per-view
    RMS)`` — the RMS as OpenCV's (of the 2D residual length per corner, px); the σ as
    ``calibrateCameraExtended`` computes them: ``s² (JᵀJ)⁻¹`` over the intrinsics and every
    pose, ``s²`` the residual sum of squares over its degrees of freedom, J from
    ``cv2.fisheye.projectPoints``."""
    obj = [np.asarray(o, np.float64).reshape(1, -1, 3) for o in obj]
    img = [np.asarray(i, np.float64).reshape(1, -1, 2) for i in img]
    try:
        _, K, D, rvecs, tvecs = cv2.fisheye.calibrate(obj, img, tuple(size), None, None,
                                                      flags=FISHEYE_FLAGS, criteria=CRITERIA)
    except cv2.error as exc:
        reason = (str(exc).strip().splitlines() or ["?"])[-1]
        raise CalibrationError(f"OpenCV's fisheye calibration failed ({reason[:160]})") from None
    n_par = 8 + 6 * len(obj)
    rows, squares, per = [], 0.0, []
    for v, (o, i, rvec, tvec) in enumerate(zip(obj, img, rvecs, tvecs)):
        projected, jac = cv2.fisheye.projectPoints(o.reshape(-1, 1, 3), np.ravel(rvec),
                                                   np.ravel(tvec), K, D)
        e = projected.reshape(-1, 2) - i.reshape(-1, 2)
        per.append(np.sqrt(np.sum(e * e) / len(e)))
        squares += float(np.sum(e * e))
        block = np.zeros((jac.shape[0], n_par))
        block[:, :8] = jac[:, :8]  # f (2), c (2), k (4); then om (3), T (3), alpha
        block[:, 8 + 6 * v: 14 + 6 * v] = jac[:, 8:14]
        rows.append(block)
    n = sum(o.shape[1] for o in obj)
    J = np.vstack(rows)
    s2 = squares / max(2 * n - n_par, 1)
    with np.errstate(invalid="ignore"):
        covariance = s2 * np.linalg.pinv(J.T @ J)
        std = np.sqrt(np.diag(covariance))
    rms = float(np.sqrt(squares / n))
    return (rms, K, D.reshape(4, 1), tuple(rvecs), tuple(tvecs), std[:8].reshape(-1, 1),
            std[8:].reshape(-1, 1), np.array(per).reshape(-1, 1))


def calibrate_camera(obj, img, size, lens_model: str = DEFAULT_LENS_MODEL):
    """One camera's ``cv2.calibrateCameraExtended`` with ``lens_model`` (a key of
    :data:`LENS_MODELS`, or ``auto``: module constants). Returns ``(out, model, tried,
    problem)``: OpenCV's outputs, the model used, ``{model: rms px}`` of each model fitted and
    the used model's :func:`lens_problem` (None when its distortion can be used)."""
    if lens_model != "auto" and lens_model not in LENS_MODELS:
        raise CalibrationError(f"lens model {lens_model!r}: choose from auto, "
                               f"{', '.join(LENS_MODELS)}")
    order = LENS_MODEL_ORDER if lens_model == "auto" else (lens_model,)
    tried, best, best_model, best_problem = {}, None, None, None
    for model in order:
        if model == "fisheye":
            out = calibrate_fisheye(obj, img, size)
        else:
            out = cv2.calibrateCameraExtended(obj, img, tuple(size), None, None,
                                              flags=LENS_MODELS[model][0], criteria=CRITERIA)
        tried[model] = float(out[0])
        if best is None:
            best, best_model, best_problem = out, model, lens_problem(out, model, size)
        elif np.isfinite(out[0]) and out[0] < (1 - LENS_MODEL_GAIN) * best[0]:
            problem = lens_problem(out, model, size)
            if problem is None:
                best, best_model, best_problem = out, model, None
    return best, best_model, tried, best_problem


def lens_problem(out, model: str, size) -> str | None:
    """Why the camera of a ``calibrateCameraExtended`` result ``out`` fitted with ``model``
    cannot be used over its whole image (its distortion folds: a richer model fitted to corners
    that leave the image's edges uncovered), or None
    (:meth:`measure.camera.Camera.distortion_problem`)."""
    if not np.all(np.isfinite(out[2])) or not np.all(np.isfinite(out[1])):
        return "the fit gave non-finite intrinsics"
    return lens_camera(out, model, size).distortion_problem()


#: How the stereo fit treats the cameras' intrinsics: ``fixed`` (each camera's own fit held;
#: the default) or ``refined`` (``stereoCalibrate`` refines both cameras' intrinsics with the
#: stereo pose from those fits, as MATLAB's stereo calibrator and OpenCV's stereo sample do: on
#: a long lens, f ≈ 12,000 px, the cameras' own fits leave f uncertain and the joint fit's
#: stereo RMS is lower, 0.49 against 0.58 px on the Minions rig underwater).
STEREO_INTRINSICS = ("fixed", "refined")


def calibrate_in_air(board: Board, detections: Detections, size,
                     lens_model: str = LIBRARY_LENS_MODEL,
                     stereo_intrinsics: str = "fixed") -> AirCalibration:
    """OpenCV calibration of both cameras (``lens_model``: :func:`calibrate_camera`) and their
    stereo pose from in-air board images; poses whose own stereo pose disagrees with the
    others' (:func:`stereo_pose_outliers`) are left out of the stereo fit and named.
    ``stereo_intrinsics``: :data:`STEREO_INTRINSICS` (``refined``: no covariance, and not with
    the fisheye model)."""
    if stereo_intrinsics not in STEREO_INTRINSICS:
        raise CalibrationError(f"stereo intrinsics {stereo_intrinsics!r}: choose from "
                               f"{', '.join(STEREO_INTRINSICS)}")
    corners = board.corners().astype(np.float32)
    fits = fit_each_camera(corners, detections, size, lens_model)
    if board.symmetric:  # the right camera's numbering of each pose settled by the rig
        detections = _settle_turns(board, detections, fits.own, fits.extrinsics)
    both, stereo_poses, left_out = _stereo_poses_checked(detections, fits.own)
    shared = _shared_corners(detections, corners, both)
    stereo_rms, R, T, stereo_per, cameras, fisheye = _stereo_fit(fits, shared, both, size,
                                                                 stereo_intrinsics)
    fits.used["stereo"] = len(both)
    (K1, D1), (K2, D2) = cameras
    lens = FISHEYE if fisheye else BROWN_CONRADY
    left = Camera(K1, size, dist=D1, distortion_model=lens)
    right = Camera(K2, size, dist=D2, R=_orthonormal(R).T, t=-_orthonormal(R).T @ T,
                   distortion_model=lens)
    port = index_matched_port(left.R[:, 2], np.stack([left.t, right.t]))
    board_poses = {}
    for (k, view), (R_cam, t_cam) in fits.extrinsics.items():
        camera = (left, right)[view]
        board_poses[(k, view)] = (camera.R @ R_cam, camera.R @ t_cam + camera.t)
    covariance = None
    if stereo_intrinsics == "fixed" and all(m["model"] == "standard"
                                            for m in fits.models.values()):
        # linearized at the left camera's own board poses (stereoCalibrate's refinement of
        # them moves the Jacobian by nothing that matters)
        obj, _, _, keys = shared
        covariance = air_covariance(
            fits.views, {"obj": obj, "keys": keys,
                         "rvecs": [fits.vectors[0][k][0] for k in both],
                         "tvecs": [fits.vectors[0][k][1] for k in both],
                         "om": cv2.Rodrigues(R)[0], "T": T}, fits.s2)
    return AirCalibration(StereoRig(left, right, port), fits.rms, fits.sigmas, stereo_rms,
                          fits.used, fits.per, board_poses, covariance, fits.models,
                          stereo_poses, left_out, stereo_per, fits.residuals)


@dataclass(frozen=True)
class CameraFit:
    """One camera's own OpenCV calibration (:func:`fit_camera`): ``out`` in
    ``cv2.calibrateCameraExtended``'s layout, the lens ``model`` used, ``tried`` ``{model: RMS
    px}``, its ``problem`` (:func:`lens_problem`), the ``poses`` it found the board in, per pose
    ``obj`` (board corners, mm) and ``img`` (detected pixels, px; both float32, as OpenCV
    takes them) and ``residuals`` ``(pose, id, du, dv)`` rows (projected − detected, px)."""

    out: tuple
    model: str
    tried: dict
    problem: str | None
    poses: list
    obj: list
    img: list
    residuals: np.ndarray

    @property
    def rms_px_per(self) -> dict:
        """``{pose: RMS px}`` (OpenCV's per-view errors)."""
        return {k: float(e) for k, e in zip(self.poses, np.ravel(self.out[7]))}

    @property
    def own(self) -> dict:
        """``{pose: (R, t)}`` board → camera (mm), from the fit's extrinsics."""
        from scipy.spatial.transform import Rotation
        return {k: (Rotation.from_rotvec(np.ravel(rvec)).as_matrix(),
                    np.ravel(tvec).astype(np.float64))
                for k, rvec, tvec in zip(self.poses, self.out[3], self.out[4])}

    def distortion(self, size) -> np.ndarray:
        """The lens model's distortion coefficients (at least k1 k2 p1 p2 k3 for
        Brown–Conrady; k1…k4 for the fisheye model)."""
        if self.model == "fisheye":
            return np.ravel(lens_camera(self.out, self.model, size).dist)
        return np.ravel(self.out[2].ravel()[:max(LENS_MODELS[self.model][1], 5)])


def fit_camera(corners, detections: Detections, view: int, name: str, size,
               lens_model) -> CameraFit:
    """Camera ``view``'s own calibration (:func:`calibrate_camera`) over the poses it found
    the board in; ``corners`` the board's (float32, mm). CalibrationError naming the camera
    where it found the board in fewer than :data:`MIN_POSES` images."""
    poses = detections.found(view)
    if len(poses) < MIN_POSES:
        raise CalibrationError(f"the board was found in {len(poses)} {name} image(s); an "
                               f"in-air calibration needs at least {MIN_POSES}")
    obj = [corners[detections.ids[k][view]] for k in poses]
    img = [detections.pixels[k][view].astype(np.float32) for k in poses]
    out, model, tried, problem = calibrate_camera(obj, img, size, lens_model)
    return CameraFit(out, model, tried, problem, poses, obj, img,
                     camera_residuals(obj, img, out, poses, detections.ids, view, model))


@dataclass
class CameraFits:
    """Every camera's own OpenCV calibration (:func:`fit_each_camera`; views 0, 1, … named
    ``names``): ``cameras`` ``[(K, D)]``; per name ``rms`` (px), ``sigmas``, ``used`` (poses),
    ``models``; per ``(pose, view)`` ``per`` (RMS px) and ``extrinsics`` (board → camera
    ``(R, t)``, mm); ``own`` per view ``{pose: (R, t)}``; ``views`` and ``s2`` for
    :func:`measure.calibration.covariance.air_covariance`; ``vectors`` per view ``{pose:
    (rvec, tvec)}`` (OpenCV's); ``residuals`` per view."""

    cameras: list = field(default_factory=list)
    rms: dict = field(default_factory=dict)
    sigmas: dict = field(default_factory=dict)
    used: dict = field(default_factory=dict)
    per: dict = field(default_factory=dict)
    extrinsics: dict = field(default_factory=dict)
    views: list = field(default_factory=list)
    s2: list = field(default_factory=list)
    vectors: dict = field(default_factory=dict)
    models: dict = field(default_factory=dict)
    own: dict = field(default_factory=dict)
    residuals: dict = field(default_factory=dict)


def fit_each_camera(corners, detections: Detections, size, lens_model,
                    names=("left", "right")) -> CameraFits:
    """Every camera (view v named ``names[v]``) calibrated on its own (:func:`fit_camera`);
    the one first step of every in-air calibration, whatever the number of cameras."""
    fits = CameraFits()
    for view, name in enumerate(names):
        fit = fit_camera(corners, detections, view, name, size, lens_model)
        out, model, poses = fit.out, fit.model, fit.poses
        n_dist = LENS_MODELS[model][1]
        fits.models[name] = {"model": model, "rms_px": fit.tried, "problem": fit.problem}
        fits.rms[name], K, std = float(out[0]), out[1], out[5].ravel()
        D = fit.distortion(size)
        fits.own[view] = fit.own
        for k, error in fit.rms_px_per.items():
            fits.per[(k, view)] = error
            fits.extrinsics[(k, view)] = fits.own[view][k]
        fits.sigmas[name] = dict(zip(intrinsic_names(model), (float(s) for s in std)))
        fits.residuals[view] = fit.residuals
        fits.cameras.append((K, D))
        n = sum(len(o) for o in fit.obj)  # OpenCV's RMS is per corner of the 2D residual length
        fits.s2.append(fits.rms[name] ** 2 * n
                       / max(2 * n - 4 - n_dist - 6 * len(poses), 1))
        fits.views.append({"obj": fit.obj, "keys": [[(k, i) for i in detections.ids[k][view]]
                                                    for k in poses],
                           "rvecs": out[3], "tvecs": out[4], "K": K, "dist": D})
        fits.vectors[view] = {k: (rv, tv) for k, rv, tv in zip(poses, out[3], out[4])}
        fits.used[name] = len(poses)
    return fits


def _stereo_poses_checked(detections: Detections, own: dict):
    """``(poses, {pose: its own stereo pose's check}, left out)``: the poses both cameras
    found, less those whose own stereo pose disagrees with the others'
    (:func:`relative_pose_check`); CalibrationError where fewer than :data:`MIN_POSES`
    remain."""
    both = [k for k in detections.found(0) if k in set(detections.found(1))]
    stereo_poses, left_out = {}, ()
    if len(both) >= MIN_POSES:
        stereo_poses, left_out = relative_pose_check(own[0], own[1], both)
        both = [k for k in both if k not in set(left_out)]
    if len(both) < MIN_POSES:
        disagree = (f" ({len(left_out)} more left out: their own stereo poses disagree)"
                    if left_out else "")
        raise CalibrationError(f"the board was found in both views of {len(both)} pose(s)"
                               f"{disagree}; the stereo calibration needs at least {MIN_POSES}")
    return both, stereo_poses, left_out


def _shared_corners(detections: Detections, corners, poses):
    """``(board points, left pixels, right pixels, [(pose, id)…])`` per pose of the corners
    both views found (float32, as OpenCV's stereo fit takes them)."""
    obj, img_l, img_r, keys = [], [], [], []
    for k in poses:
        common, il, ir = np.intersect1d(detections.ids[k][0], detections.ids[k][1],
                                        return_indices=True)
        obj.append(corners[common])
        keys.append([(k, i) for i in common])
        img_l.append(detections.pixels[k][0][il].astype(np.float32))
        img_r.append(detections.pixels[k][1][ir].astype(np.float32))
    return obj, img_l, img_r, keys


def _stereo_fit(fits: CameraFits, shared, poses, size, stereo_intrinsics):
    """The stereo pose from the shared corners: ``(rms, R, T, {pose: rms}, [(K, D)…],
    fisheye)`` (OpenCV's stereo convention; the intrinsics refined where asked)."""
    obj, img_l, img_r, keys = shared
    (K1, D1), (K2, D2) = fits.cameras
    kinds = {m["model"] == "fisheye" for m in fits.models.values()}
    if len(kinds) > 1:
        raise CalibrationError("one camera fitted with the fisheye model and the other not: "
                               "give both the same --lens")
    fisheye = kinds == {True}
    if fisheye and stereo_intrinsics == "refined":
        raise CalibrationError("the fisheye model's stereo fit holds the intrinsics: "
                               "stereo intrinsics 'refined' is for the Brown–Conrady models")
    if fisheye:
        stereo_rms, R, T, stereo_per = _fisheye_stereo(obj, img_l, img_r, fits.cameras, size,
                                                       poses, [[i for _, i in k] for k in keys])
        return stereo_rms, R, T, stereo_per, [(K1, D1), (K2, D2)], fisheye
    flags = cv2.CALIB_FIX_INTRINSIC
    if stereo_intrinsics == "refined":
        flags = LENS_MODELS[fits.models["left"]["model"]][0] | cv2.CALIB_USE_INTRINSIC_GUESS
    out = cv2.stereoCalibrateExtended(obj, img_l, img_r, K1, D1, K2, D2, tuple(size), None,
                                      None, flags=flags, criteria=CRITERIA)
    stereo_rms, R, T = float(out[0]), out[5], out[6].ravel()
    if stereo_intrinsics == "refined":  # OpenCV returns 14 coefficients: the model's first
        (K1, D1), (K2, D2) = ((out[1], np.ravel(out[2])[:len(D1)]),
                              (out[3], np.ravel(out[4])[:len(D2)]))
    stereo_per = {k: float(np.sqrt(np.mean(np.square(e)))) for k, e in zip(poses, out[-1])}
    return stereo_rms, R, T, stereo_per, [(K1, D1), (K2, D2)], fisheye


def _settle_turns(board, detections, own, extrinsics):
    """A symmetric board's right view renumbered where the rig says it is turned
    (:func:`measure.calibration.symmetry.settle_in_air`): ``own[1]`` and ``extrinsics`` follow
    (in place; the residual rows keep the numbers the photos were detected with); returns the
    renumbered detections."""
    from .symmetry import relabelled, settle_in_air, turned_pose

    symmetries = board.symmetries()
    turns = {k: s for k, s in settle_in_air(board, own[0], own[1]).items() if s}
    for k, s in turns.items():
        own[1][k] = extrinsics[(k, 1)] = turned_pose(*own[1][k], symmetries[s])
    return relabelled(detections, 1, turns, board)


#: The fewest corners every pose must share for OpenCV's fisheye stereo fit.
MIN_COMMON_CORNERS = 12


def _fisheye_stereo(obj, img_l, img_r, cameras, size, poses, ids):
    """``cv2.fisheye.stereoCalibrate`` with both cameras' intrinsics fixed: ``(rms, R, T,
    {pose: rms of both views})`` (px, OpenCV's stereo convention). OpenCV's fisheye stereo fit
    needs the same number of corners in every pose (OpenCV 5.1 fails on a reshape otherwise):
    where the poses hold different corners (``ids`` per pose), the corners every pose holds
    are used; CalibrationError when fewer than :data:`MIN_COMMON_CORNERS` are left."""
    if len({len(i) for i in ids}) > 1:
        common = set(ids[0]).intersection(*map(set, ids[1:]))
        if len(common) < MIN_COMMON_CORNERS:
            raise CalibrationError(f"OpenCV's fisheye stereo fit needs the same corners in every "
                                   f"pose; the poses seen by both cameras share {len(common)} "
                                   f"(fewer than {MIN_COMMON_CORNERS}): photograph the whole "
                                   f"board in both views")
        keep = [np.isin(i, sorted(common)) for i in ids]
        obj = [o[k] for o, k in zip(obj, keep)]
        img_l = [p[k] for p, k in zip(img_l, keep)]
        img_r = [p[k] for p, k in zip(img_r, keep)]
    (K1, D1), (K2, D2) = cameras
    as3 = [np.asarray(o, np.float64).reshape(1, -1, 3) for o in obj]
    as2 = [[np.asarray(i, np.float64).reshape(1, -1, 2) for i in img] for img in (img_l, img_r)]
    out = cv2.fisheye.stereoCalibrate(as3, as2[0], as2[1], K1, D1, K2, D2, tuple(size),
                                      flags=cv2.fisheye.CALIB_FIX_INTRINSIC, criteria=CRITERIA)
    R, T = out[5], np.ravel(out[6])
    squares, count, per = 0.0, 0, {}
    for k, o, il, ir, rvec, tvec in zip(poses, as3, *as2, out[7], out[8]):
        # each pose as the fit holds it: the left camera's, and through (R, T) the right's
        e_l = project_board("fisheye", o, rvec, tvec, K1, D1) - il.reshape(-1, 2)
        R_r = R @ cv2.Rodrigues(np.ravel(rvec))[0]
        e_r = (project_board("fisheye", o, cv2.Rodrigues(R_r)[0], R @ np.ravel(tvec) + T, K2,
                             D2) - ir.reshape(-1, 2))
        both = np.vstack([e_l, e_r])
        per[k] = float(np.sqrt(np.mean(np.sum(both * both, axis=1))))
        squares += float(np.sum(both * both))
        count += len(both)
    return float(np.sqrt(squares / max(count, 1))), R, T, per


def camera_residuals(obj, img, out, poses, ids, view, model: str = "standard") -> np.ndarray:
    """``(pose, id, du, dv)`` rows of one camera's fit ``out`` with ``model``
    (:func:`calibrate_camera`): every corner projected with its pose's extrinsics minus where
    it was detected, px."""
    rows = []
    for k, o, observed, rvec, tvec in zip(poses, obj, img, out[3], out[4]):
        projected = project_board(model, o, rvec, tvec, out[1], out[2])
        d = projected - np.asarray(observed, np.float64).reshape(-1, 2)
        rows.append(np.column_stack([np.full(len(d), k), ids[k][view], d]))
    return np.vstack(rows) if rows else np.empty((0, 4))


def _orthonormal(R) -> np.ndarray:
    u, _, vt = np.linalg.svd(np.asarray(R, dtype=np.float64))
    return u @ vt


__all__ = ["AirCalibration", "CalibrationError", "CameraFit", "CameraFits", "DEFAULT_LENS_MODEL",
           "Detections",
           "FISHEYE_FLAGS", "FISHEYE_INTRINSIC_NAMES", "INTRINSIC_NAMES", "LENS_MODELS",
           "LENS_MODEL_GAIN", "LENS_MODEL_ORDER", "LIBRARY_LENS_MODEL", "MIN_POSES",
           "STEREO_FLOOR_DEG", "STEREO_FLOOR_FRACTION", "STEREO_INTRINSICS",
           "STEREO_OUTLIER_FACTOR",
           "calibrate_camera", "calibrate_fisheye", "calibrate_in_air", "camera_residuals",
           "detect_boards", "detect_images", "fit_camera", "fit_each_camera",
           "intrinsic_names", "lens_camera", "lens_problem",
           "project_board", "relative_poses", "stereo_pose_outliers"]
