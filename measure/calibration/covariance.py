"""The full covariance of a calibrated rig: OpenCV's in-air calibration and the housing on top.

**In air** (:func:`air_covariance`). ``calibrate_in_air`` is a two-stage estimator: each
camera's ``calibrateCamera`` (8 intrinsics fx fy cx cy k1 k2 p1 p2 and its own board poses),
then ``stereoCalibrate`` with those intrinsics fixed (the stereo pose and the left board poses).
Linearized, every estimate is a linear map of the corners' noise ε:
``δθ_cam = [(JᵀJ)⁻¹Jᵀ]_intrinsics ε_cam`` per camera (board poses marginalized), and
``δθ_stereo = [(J_sᵀJ_s)⁻¹J_sᵀ]_pose (ε_s − J_si δθ_intrinsics)`` — the stereo stage sees the
same corners and the intrinsics' error. So ``Σ = M diag(σ²) Mᵀ`` with M the stacked maps and σ²
each camera's residual variance ``Σr² / (2n − p)`` (the scale OpenCV's
``stdDeviationsIntrinsics`` uses; they agree with this σ to 1e-3 relative, tested). The
Jacobians are ``cv2.projectPoints``' and ``cv2.composeRT``'s. The stereo pose is converted to
:mod:`measure.stereo.rig_covariance`'s names: ``right.rotation`` (``R → exp([φ]×) R`` of the
camera-to-reference rotation, reference axes, rad) and ``right.center`` (mm).

**Underwater** (:func:`air_jacobian`): the derivatives of the housing adjustment's residuals
(px) with respect to those in-air parameters. The refracted path does not depend on the
intrinsics (only on the camera's centre and pose), so d pixel / d intrinsics is the pinhole and
distortion model's at the path's first direction in the camera frame (the pixel undistorted);
d pixel / d pose is :class:`measure.geometry.projection.ParameterJacobian`'s ``rotation`` and ``center``.
Units px, mm, rad; the reference frame is the left camera's.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry.camera import Camera
from ..stereo.rig_covariance import RigCovariance

#: The intrinsics OpenCV's in-air calibration estimates per camera (k3 is fixed at 0).
AIR_INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")
#: Their columns in ``cv2.projectPoints``' Jacobian (rvec 0:3, tvec 3:6, f, c, k1 k2 p1 p2 k3).
_PROJECT_COLUMNS = np.arange(6, 14)
POSE_NAMES = tuple(f"right.rotation[{k}]" for k in range(3)) + tuple(
    f"right.center[{k}]" for k in range(3))
AIR_NAMES = tuple(f"{cam}.{p}" for cam in ("left", "right") for p in AIR_INTRINSICS) + POSE_NAMES


def _dist5(camera_dist) -> np.ndarray:
    out = np.zeros(5)
    if camera_dist is not None:
        d = np.ravel(camera_dist)[:5]
        out[:d.size] = d
    return out


def _project(obj, rvec, tvec, K, dist):
    """``cv2.projectPoints``: pixels ``(n, 2)`` and the Jacobian ``(2n, 15)``."""
    uv, jac = cv2.projectPoints(np.asarray(obj, np.float64).reshape(-1, 1, 3),
                                np.asarray(rvec, np.float64).reshape(3, 1),
                                np.asarray(tvec, np.float64).reshape(3, 1), K, _dist5(dist))
    return uv.reshape(-1, 2), jac


def camera_map(obj, rvecs, tvecs, K, dist):
    """One camera's ``calibrateCamera`` linearized: ``(A, s2)`` with ``A`` ``(8, 2n)`` the map
    from its corners' noise (px, the poses' corners in order, u and v interleaved) to the 8
    intrinsics, and ``s2`` the residual variance ``Σr² / (2n − 8 − 6P)`` (px²) — ``obj`` and the
    matching image points per pose, ``rvecs``/``tvecs`` OpenCV's board-to-camera poses."""
    sizes = [len(o) for o in obj]
    n, P = sum(sizes), len(obj)
    J = np.zeros((2 * n, 8 + 6 * P))
    row = 0
    for p, (o, rv, tv) in enumerate(zip(obj, rvecs, tvecs)):
        _, jac = _project(o, rv, tv, K, dist)
        rows = slice(row, row + 2 * len(o))
        J[rows, :8] = jac[:, _PROJECT_COLUMNS]
        J[rows, 8 + 6 * p:14 + 6 * p] = jac[:, :6]
        row += 2 * len(o)
    return np.linalg.solve(J.T @ J, J.T)[:8], J.shape[1]


def air_covariance(views, stereo, s2) -> RigCovariance:
    """The covariance of an in-air calibration (module docs), named :data:`AIR_NAMES`.

    ``views``: per camera (left, right) a dict ``obj`` (list of ``(n_p, 3)`` board corners, mm),
    ``keys`` (list of ``(n_p,)`` corner keys: any hashable ``(pose, id)`` per corner), ``rvecs``,
    ``tvecs`` (OpenCV's board-to-camera poses of ``calibrateCamera``), ``K``, ``dist``.
    ``stereo``: ``obj`` and ``keys`` per pose of the stereo stage (corners seen in both views),
    ``rvecs``/``tvecs`` (board to the left camera), ``om``/``T`` (OpenCV's stereo rotation
    vector and translation, ``X_right = R X_left + T``). ``s2``: per camera the corners' noise
    variance, px²."""
    index, offset, maps, noise = [], 0, [], []
    for v, view in enumerate(views):
        keys = [(v,) + tuple(k) for ks in view["keys"] for k in ks]
        index.append({k: offset + 2 * i for i, k in enumerate(keys)})
        A, _ = camera_map(view["obj"], view["rvecs"], view["tvecs"], view["K"], view["dist"])
        maps.append((offset, A))
        noise.append(np.full(2 * len(keys), s2[v]))
        offset += 2 * len(keys)
    n_eps = offset
    M_int = np.zeros((16, n_eps))
    for v, (start, A) in enumerate(maps):
        M_int[8 * v:8 * v + 8, start:start + A.shape[1]] = A
    # the stereo stage: rows (left corners, right corners) per pose; columns om, T, poses
    (K1, D1), (K2, D2) = ((view["K"], view["dist"]) for view in views)
    om, T = np.ravel(stereo["om"]), np.ravel(stereo["T"])
    P = len(stereo["obj"])
    blocks, intr, sel = [], [], []
    for p, (o, keys, rv, tv) in enumerate(zip(stereo["obj"], stereo["keys"], stereo["rvecs"],
                                              stereo["tvecs"])):
        m = 2 * len(o)
        _, jl = _project(o, rv, tv, K1, D1)
        r3, t3, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = cv2.composeRT(
            np.reshape(rv, (3, 1)), np.reshape(tv, (3, 1)), om.reshape(3, 1), T.reshape(3, 1))
        _, jr = _project(o, r3, t3, K2, D2)
        d_pose = np.block([[dr3dr1, dr3dt1], [dt3dr1, dt3dt1]])
        d_stereo = np.block([[dr3dr2, dr3dt2], [dt3dr2, dt3dt2]])
        block = np.zeros((2 * m, 6 + 6 * P))
        block[:m, 6 + 6 * p:12 + 6 * p] = jl[:, :6]
        block[m:, :6] = jr[:, :6] @ d_stereo
        block[m:, 6 + 6 * p:12 + 6 * p] = jr[:, :6] @ d_pose
        blocks.append(block)
        d_int = np.zeros((2 * m, 16))
        d_int[:m, :8] = jl[:, _PROJECT_COLUMNS]
        d_int[m:, 8:] = jr[:, _PROJECT_COLUMNS]
        intr.append(d_int)
        for v in (0, 1):
            for key in keys:
                start = index[v][(v,) + tuple(key)]
                sel += [start, start + 1]
    J_s = np.concatenate(blocks)
    S = np.zeros((J_s.shape[0], n_eps))
    S[np.arange(J_s.shape[0]), sel] = 1.0
    B = np.linalg.solve(J_s.T @ J_s, J_s.T)[:6]
    M_stereo = B @ (S - np.concatenate(intr) @ M_int)
    M = np.concatenate([M_int, stereo_to_rig(om, T) @ M_stereo])
    W = np.concatenate(noise)
    return RigCovariance(AIR_NAMES, (M * W) @ M.T)


def stereo_to_rig(om, T) -> np.ndarray:
    """``(6, 6)``: d(``right.rotation``, ``right.center``) / d(om, T) at OpenCV's stereo pose
    (``X_right = R(om) X_left + T``; the camera-to-reference rotation is ``Rᵀ``, the centre
    ``−Rᵀ T``). With ``R(om + δ) ≈ exp([J_l δ]×) R``: ``φ = −Rᵀ J_l δ`` and
    ``d centre = −Rᵀ δT − Rᵀ [T]× J_l δ``."""
    from scipy.spatial.transform import Rotation

    om, T = np.ravel(om).astype(np.float64), np.ravel(T).astype(np.float64)
    R = Rotation.from_rotvec(om).as_matrix()
    Jl = left_jacobian(om)
    skew_T = np.array([[0, -T[2], T[1]], [T[2], 0, -T[0]], [-T[1], T[0], 0]])
    out = np.zeros((6, 6))
    out[:3, :3] = -R.T @ Jl
    out[3:, :3] = -R.T @ skew_T @ Jl
    out[3:, 3:] = -R.T
    return out


def left_jacobian(rotvec) -> np.ndarray:
    """SO(3)'s left Jacobian ``(3, 3)``: ``exp(ω + δ) ≈ exp([J_l(ω) δ]×) exp(ω)``."""
    w = np.ravel(rotvec).astype(np.float64)
    theta = float(np.linalg.norm(w))
    skew = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if theta < 1e-6:
        a, b = 0.5 - theta ** 2 / 24, 1 / 6 - theta ** 2 / 120
    else:
        a, b = (1 - np.cos(theta)) / theta ** 2, (theta - np.sin(theta)) / theta ** 3
    return np.eye(3) + a * skew + b * skew @ skew


def intrinsics_jacobian(camera: Camera, pixels) -> np.ndarray:
    """``(N, 2, 8)``: d pixel / d (fx fy cx cy k1 k2 p1 p2) with the ray in the camera frame
    held (the pixel's undistorted direction); NaN rows stay NaN."""
    pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    out = np.full((len(pixels), 2, 8), np.nan)
    ok = np.all(np.isfinite(pixels), axis=1)
    if not np.any(ok):
        return out
    xy = camera.normalized(pixels[ok])
    points = np.column_stack([xy, np.ones(len(xy))])
    _, jac = _project(points, np.zeros(3), np.zeros(3), camera.K,
                      camera.brown_conrady_dist("the intrinsics' Jacobian"))
    out[ok] = jac[:, _PROJECT_COLUMNS].reshape(-1, 2, 8)
    return out


def air_names(names) -> tuple:
    """The in-air parameters (of :data:`AIR_NAMES`) present in ``names``, in that order."""
    return tuple(n for n in AIR_NAMES if n in set(names))


__all__ = ["AIR_INTRINSICS", "AIR_NAMES", "POSE_NAMES", "air_covariance", "air_names",
           "camera_map", "intrinsics_jacobian", "left_jacobian", "stereo_to_rig"]
