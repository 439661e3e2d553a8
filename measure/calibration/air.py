"""Calibration from board images in air, with OpenCV: the boards found in every image pair
(:func:`detect_boards`) and the cameras calibrated through no port (:func:`calibrate_in_air`).

``cv2.calibrateCameraExtended`` per camera (k1, k2, p1, p2; k3 fixed at 0) and
``cv2.stereoCalibrate`` with the intrinsics fixed give K1, D1, K2, D2 and the stereo pose —
OpenCV does it, nothing is re-implemented. The housing underwater:
:mod:`measure.calibration.housing`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.camera import Camera
from ..geometry.port import index_matched_port
from ..stereo.triangulate import StereoRig
from .board import MIN_CORNERS, Board
from .covariance import air_covariance
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


def detect_boards(board: Board, images, workers: int | None = None) -> Detections:
    """Detect ``board`` in every ``(left, right)`` image pair, on ``workers`` threads (default:
    one per CPU; OpenCV's detectors release the GIL: 15 full-size pairs took 12 s on 2 threads
    against 21 s on one, on a loaded 2-core machine)."""
    from concurrent.futures import ThreadPoolExecutor

    flat = [img for pair in images for img in pair]
    workers = max(1, min(workers or os.cpu_count() or 1, len(flat) or 1))
    if workers == 1:
        found = [board.detect(img) for img in flat]
    else:
        with ThreadPoolExecutor(workers) as pool:
            found = list(pool.map(board.detect, flat))
    ids = [[found[2 * k][0], found[2 * k + 1][0]] for k in range(len(images))]
    pixels = [[found[2 * k][1], found[2 * k + 1][1]] for k in range(len(images))]
    return Detections(ids, pixels)


# ---------------------------------------------------------------------------------------------
# in air, with OpenCV
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AirCalibration:
    """``rig`` (no port: index-matched), per camera ``rms_px`` and ``sigmas`` (fx, fy, cx, cy,
    k1, k2, p1, p2 from ``calibrateCameraExtended``), the stereo ``stereo_rms_px`` and the
    number of poses used per camera and for the pair; ``rms_px_per`` ``{(pose, view): rms}``
    (OpenCV's per-view errors: RMS of the 2D residual length, px) and ``board_poses``
    ``{(pose, view): (R, t)}`` (board to the reference frame, mm, from that camera's
    ``calibrateCamera`` extrinsics); ``covariance`` the full covariance of both cameras'
    intrinsics and the stereo pose (:func:`measure.calibration.covariance.air_covariance`)."""

    rig: StereoRig
    rms_px: dict
    sigmas: dict
    stereo_rms_px: float
    poses_used: dict
    rms_px_per: dict = field(default_factory=dict)
    board_poses: dict = field(default_factory=dict)
    covariance: RigCovariance | None = None


def calibrate_in_air(board: Board, detections: Detections, size) -> AirCalibration:
    """OpenCV calibration of both cameras and their stereo pose from in-air board images."""
    corners = board.corners().astype(np.float32)
    flags = cv2.CALIB_FIX_K3
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    cameras, rms, sigmas, used, per, extrinsics = [], {}, {}, {}, {}, {}
    views, s2, left_poses = [], [], {}
    for view, name in enumerate(("left", "right")):
        poses = detections.found(view)
        if len(poses) < MIN_POSES:
            raise CalibrationError(f"the board was found in {len(poses)} {name} image(s); an "
                                   f"in-air calibration needs at least {MIN_POSES}")
        obj = [corners[detections.ids[k][view]] for k in poses]
        img = [detections.pixels[k][view].astype(np.float32) for k in poses]
        out = cv2.calibrateCameraExtended(obj, img, tuple(size), None, None, flags=flags,
                                          criteria=criteria)
        rms[name], K, D, std = float(out[0]), out[1], out[2].ravel()[:5], out[5].ravel()
        for k, error, rvec, tvec in zip(poses, out[7].ravel(), out[3], out[4]):
            per[(k, view)] = float(error)
            extrinsics[(k, view)] = (Rotation.from_rotvec(np.ravel(rvec)).as_matrix(),
                                     np.ravel(tvec).astype(np.float64))
        sigmas[name] = dict(zip(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
                                (float(s) for s in std[:8])))
        cameras.append((K, D))
        n = sum(len(o) for o in obj)  # OpenCV's RMS is per corner of the 2D residual length
        s2.append(rms[name] ** 2 * n / max(2 * n - 8 - 6 * len(poses), 1))
        views.append({"obj": obj, "keys": [[(k, i) for i in detections.ids[k][view]]
                                           for k in poses],
                      "rvecs": out[3], "tvecs": out[4], "K": K, "dist": D})
        if view == 0:
            left_poses = {k: (rv, tv) for k, rv, tv in zip(poses, out[3], out[4])}
        used[name] = len(poses)
    both = [k for k in detections.found(0) if k in set(detections.found(1))]
    if len(both) < MIN_POSES:
        raise CalibrationError(f"the board was found in both views of {len(both)} pose(s); the "
                               f"stereo calibration needs at least {MIN_POSES}")
    obj, img_l, img_r, keys = [], [], [], []
    for k in both:
        common, il, ir = np.intersect1d(detections.ids[k][0], detections.ids[k][1],
                                        return_indices=True)
        obj.append(corners[common])
        keys.append([(k, i) for i in common])
        img_l.append(detections.pixels[k][0][il].astype(np.float32))
        img_r.append(detections.pixels[k][1][ir].astype(np.float32))
    (K1, D1), (K2, D2) = cameras
    out = cv2.stereoCalibrate(obj, img_l, img_r, K1, D1, K2, D2, tuple(size),
                              flags=cv2.CALIB_FIX_INTRINSIC, criteria=criteria)
    stereo_rms, R, T = float(out[0]), out[5], out[6].ravel()
    used["stereo"] = len(both)
    left = Camera(K1, size, dist=D1)
    right = Camera(K2, size, dist=D2, R=_orthonormal(R).T, t=-_orthonormal(R).T @ T)
    port = index_matched_port(left.R[:, 2], np.stack([left.t, right.t]))
    board_poses = {}
    for (k, view), (R_cam, t_cam) in extrinsics.items():
        camera = (left, right)[view]
        board_poses[(k, view)] = (camera.R @ R_cam, camera.R @ t_cam + camera.t)
    # the covariance is linearized at the left camera's own board poses (stereoCalibrate's
    # refinement of them moves the Jacobian by nothing that matters)
    covariance = air_covariance(
        views, {"obj": obj, "keys": keys, "rvecs": [left_poses[k][0] for k in both],
                "tvecs": [left_poses[k][1] for k in both], "om": cv2.Rodrigues(R)[0], "T": T},
        s2)
    return AirCalibration(StereoRig(left, right, port), rms, sigmas, stereo_rms, used, per,
                          board_poses, covariance)


def _orthonormal(R) -> np.ndarray:
    u, _, vt = np.linalg.svd(np.asarray(R, dtype=np.float64))
    return u @ vt


__all__ = ["AirCalibration", "CalibrationError", "Detections", "MIN_POSES", "calibrate_in_air",
           "detect_boards"]
