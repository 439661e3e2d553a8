"""In-air calibration of a rig of N cameras from board images: every camera and every board
pose jointly.

Each camera is first calibrated on its own (``cv2.calibrateCameraExtended``,
:func:`measure.calibration.air.calibrate_camera`), which gives its intrinsics and the board's
pose in its frame for every image it found the board in. The cameras' poses relative to the
first (the reference) follow from the board poses they share — the median (rotations: their
chordal mean, ``scipy.spatial.transform.Rotation.mean``) over the shared poses, chained
breadth-first through the cameras when one shares no pose with the first. Then one bundle
adjustment (``scipy.optimize.least_squares``, Levenberg–Marquardt, OpenCV's
``projectPoints``) refines every camera's pose (the first held at the origin), every board
pose and, with ``intrinsics="free"``, every camera's intrinsics and distortion together, over
the pixel residuals of all corners in all views.

Units: mm, pixels in the OpenCV convention; poses camera-to-reference ``X_ref = R · X_cam + t``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..geometry.camera import Camera
from ..stereo.rig import Rig, default_names
from .air import MIN_POSES, CalibrationError, Detections, fit_camera, fit_each_camera
from .board import Board
from .covariance import left_jacobian
from .outliers import outlier_threshold, relative_pose_check


@dataclass(frozen=True)
class MultiAirCalibration:
    """``rig`` (a :class:`measure.stereo.rig.Rig`, every camera in air: no port),
    ``rms_px`` per camera of its own calibration, ``joint_rms_px`` of the bundle adjustment
    (RMS of the residual length over all corners, px), ``poses_used`` per camera, and
    ``board_poses`` ``{pose: (R, t)}`` (board to the reference frame, mm); ``parameter_names``
    and ``covariance`` (:func:`camera_parameter_names`: every camera's pose but the first's and,
    with free intrinsics, every camera's intrinsics; the board poses marginalized),
    ``s² (JᵀJ)⁻¹`` of the joint adjustment with ``s² = Σr² / (m − n)``; ``rms_px_per``
    ``{(pose, view): rms}`` and ``residuals`` ``{view: (pose, id, du, dv) rows}`` of the joint
    adjustment; ``left_out`` ``{(pose, view): why}`` the views screened out before it
    (:func:`screen_views`)."""

    rig: Rig
    rms_px: dict
    joint_rms_px: float
    poses_used: dict
    board_poses: dict
    parameter_names: tuple = ()
    covariance: np.ndarray | None = None
    rms_px_per: dict = field(default_factory=dict)
    residuals: dict = field(default_factory=dict)
    left_out: dict = field(default_factory=dict)

    def sigmas(self) -> dict:
        """``{name: σ}`` of :attr:`parameter_names` (px, rad, mm)."""
        if self.covariance is None:
            return {}
        return dict(zip(self.parameter_names, np.sqrt(np.diag(self.covariance)).tolist()))


#: The intrinsics of a camera in :attr:`MultiAirCalibration.parameter_names`, before its
#: distortion coefficients (``k1 k2 p1 p2 k3 …``, OpenCV's order).
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def camera_parameter_names(names, n_dist: int, free_intrinsics: bool) -> tuple:
    """The camera parameters of a joint in-air calibration, in order: per camera but the first
    ``NAME.rotation[0..2]`` (rad, ``R → exp([φ]×) R`` about the reference axes) and
    ``NAME.center[0..2]`` (mm, reference frame); then, with free intrinsics, per camera
    ``NAME.fx`` … ``NAME.cy`` (px) and its ``n_dist`` distortion coefficients."""
    out = [f"{name}.{what}[{k}]" for name in names[1:] for what in ("rotation", "center")
           for k in range(3)]
    if free_intrinsics:
        out += [f"{name}.{p}" for name in names
                for p in INTRINSIC_NAMES + DISTORTION_NAMES[:n_dist]]
    return tuple(out)


def _chain_poses(own: list[dict], n_views: int, names) -> list:
    """Camera-to-reference poses ``[(R, t)…]`` from each camera's board poses ``own[v]``
    ``{pose: (R board→camera, t)}``, breadth-first from camera 0."""
    poses = [None] * n_views
    poses[0] = (np.eye(3), np.zeros(3))
    queue = deque([0])
    while queue:
        a = queue.popleft()
        for b in range(n_views):
            if poses[b] is not None:
                continue
            shared = sorted(set(own[a]) & set(own[b]))
            if not shared:
                continue
            # camera b in camera a's frame: X_a = R_a R_b^T (X_b − t_b) + t_a
            Rs = [own[a][k][0] @ own[b][k][0].T for k in shared]
            ts = [own[a][k][1] - R @ own[b][k][1] for k, R in zip(shared, Rs)]
            R_ab = Rotation.from_matrix(np.array(Rs)).mean().as_matrix()
            t_ab = np.median(np.array(ts), axis=0)
            R_a, t_a = poses[a]
            poses[b] = (R_a @ R_ab, R_a @ t_ab + t_a)
            queue.append(b)
    missing = [names[v] for v in range(n_views) if poses[v] is None]
    if missing:
        raise CalibrationError(f"{missing[0]} shares no board pose with the other cameras "
                               f"(directly or through others): its pose cannot be found")
    return poses


def calibrate_rig_in_air(board: Board, detections: Detections, size, names=None,
                         lens_model: str = "standard",
                         intrinsics: str = "fixed") -> MultiAirCalibration:
    """The rig of N cameras (``detections.ids[k][v]`` for pose k, view v of N) in air (module
    docs). ``intrinsics``: ``"fixed"`` (each camera's own calibration) or ``"free"`` (refined
    in the joint adjustment too). CalibrationError (one line naming the camera) when a camera
    found the board in fewer than :data:`measure.calibration.air.MIN_POSES` images or shares
    no pose with the others."""
    if intrinsics not in ("fixed", "free"):
        raise CalibrationError(f"intrinsics must be fixed or free, got {intrinsics!r}")
    if lens_model == "fisheye":
        raise CalibrationError("the joint adjustment of N cameras projects with OpenCV's "
                               "Brown–Conrady model: the fisheye lens model is not fitted here")
    n_views = len(detections.ids[0]) if detections.n_poses else 0
    names = default_names(n_views) if names is None else tuple(names)
    corners = board.corners().astype(np.float64)
    detections, left_out = screen_views(board, detections, size, names, lens_model)
    fits = fit_each_camera(corners.astype(np.float32), detections, size, lens_model, names)
    cams = [(np.asarray(K, float), np.asarray(D, float)) for K, D in fits.cameras]
    own = [fits.own[v] for v in range(n_views)]
    camera_poses = _chain_poses(own, n_views, names)
    board_poses = _board_poses_in_reference(own, camera_poses, detections.n_poses)
    joint = _JointAdjustment.of(corners, detections, cams, own, sorted(board_poses),
                                intrinsics == "free")
    x0 = joint.pack(camera_poses, board_poses)
    # dense forward differences: a few hundred parameters, each a pass over the corners; at
    # most JOINT_ITERATIONS Jacobians (a clean rig converges in a handful; without a limit a bad
    # view kept the adjustment going for more than ten minutes)
    fit = least_squares(joint.residuals, x0, method="lm", x_scale="jac", xtol=1e-12,
                        ftol=1e-12, max_nfev=JOINT_ITERATIONS * (x0.size + 1))
    joint_rms, per, rows = joint.residuals_per_view(fit.fun)
    cameras = []
    for v in range(n_views):
        R, t, K, D = joint.camera(fit.x, v)
        cameras.append(Camera(K, size, dist=D, R=None if v == 0 else R, t=None if v == 0 else t))
    return MultiAirCalibration(Rig(cameras, [None] * n_views, names), fits.rms, joint_rms,
                               fits.used,
                               joint.board_poses(fit.x),
                               camera_parameter_names(names, joint.n_intrinsics - 4, joint.free),
                               joint.covariance(fit), per, rows, left_out)


def _board_poses_in_reference(own: list[dict], camera_poses: list, n_poses: int) -> dict:
    """``{pose: (R, t)}`` board to the reference frame, from the first camera (in order) that
    found each pose (``own[v]``: board → camera v; ``camera_poses[v]``: camera v → reference)."""
    board_poses = {}
    for k in range(n_poses):
        for v in range(len(own)):
            if k in own[v]:
                R_v, t_v = camera_poses[v]
                R_b, t_b = own[v][k]
                board_poses[k] = (R_v @ R_b, R_v @ t_b + t_v)
                break
    return board_poses


@dataclass(frozen=True)
class _JointAdjustment:
    """The parameters of the joint adjustment and its residuals: per camera but the first its
    pose (rotation vector, centre: 6), per board pose its pose (6), and with ``free``
    intrinsics per camera fx fy cx cy and its distortion; ``cams`` each camera's own ``(K, D)``,
    ``observations`` the ``(pose, view)`` pairs in residual order."""

    corners: np.ndarray
    detections: Detections
    cams: list
    pose_ids: list
    observations: list
    free: bool

    @classmethod
    def of(cls, corners, detections, cams, own, pose_ids, free):
        observations = [(k, v) for k in pose_ids for v in range(len(cams)) if k in own[v]]
        return cls(corners, detections, cams, pose_ids, observations, free)

    @property
    def n_views(self) -> int:
        return len(self.cams)

    @property
    def n_intrinsics(self) -> int:
        return 4 + len(self.cams[0][1])

    @property
    def board_at(self) -> dict:
        n_cam = 6 * (self.n_views - 1)
        return {k: n_cam + 6 * i for i, k in enumerate(self.pose_ids)}

    @property
    def intrinsics_at(self) -> int:
        return 6 * (self.n_views - 1) + 6 * len(self.pose_ids)

    def pack(self, camera_poses, board_poses) -> np.ndarray:
        x = [np.concatenate([Rotation.from_matrix(R).as_rotvec(), t])
             for R, t in camera_poses[1:]]
        x += [np.concatenate([Rotation.from_matrix(board_poses[k][0]).as_rotvec(),
                              board_poses[k][1]]) for k in self.pose_ids]
        if self.free:
            x += [np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], D]) for K, D in self.cams]
        return np.concatenate(x) if x else np.zeros(0)

    def camera(self, x, v):
        """Camera ``v``'s ``(R, t, K, D)`` at parameters ``x`` (camera → reference, mm)."""
        if v == 0:
            R, t = np.eye(3), np.zeros(3)
        else:
            p = x[6 * (v - 1):6 * v]
            R, t = Rotation.from_rotvec(p[:3]).as_matrix(), p[3:]
        if self.free:
            n, at = self.n_intrinsics, self.intrinsics_at
            q = x[at + n * v:at + n * (v + 1)]
            K = np.array([[q[0], 0, q[2]], [0, q[1], q[3]], [0, 0, 1.0]])
            D = q[4:]
        else:
            K, D = self.cams[v]
        return R, t, K, D

    def residuals(self, x) -> np.ndarray:
        """Every observed corner's projection − detection (px), ``(du, dv)`` interleaved."""
        out, board_at = [], self.board_at
        cameras = [self.camera(x, v) for v in range(self.n_views)]
        for (k, v) in self.observations:
            p = x[board_at[k]:board_at[k] + 6]
            R_b, t_b = Rotation.from_rotvec(p[:3]).as_matrix(), p[3:]
            R_c, t_c, K, D = cameras[v]
            # board → camera: X_cam = R_cᵀ (R_b X + t_b − t_c)
            R = R_c.T @ R_b
            t = R_c.T @ (t_b - t_c)
            uv = cv2.projectPoints(self.corners[self.detections.ids[k][v]], cv2.Rodrigues(R)[0],
                                   t, K, D)[0].reshape(-1, 2)
            out.append((uv - self.detections.pixels[k][v]).ravel())
        return np.concatenate(out)

    def residuals_per_view(self, fun):
        """``(joint RMS, {(pose, view): RMS}, {view: (pose, id, du, dv) rows})`` of the
        residuals ``fun`` (px)."""
        r = fun.reshape(-1, 2)
        joint = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
        per, rows, offset = {}, {}, 0
        for k, v in self.observations:
            n = len(self.detections.ids[k][v])
            block = r[offset:offset + n]
            offset += n
            per[(k, v)] = float(np.sqrt(np.mean(np.sum(block * block, axis=1))))
            rows.setdefault(v, []).append(np.column_stack([np.full(n, k),
                                                           self.detections.ids[k][v], block]))
        return joint, per, {v: np.vstack(b) for v, b in rows.items()}

    def board_poses(self, x) -> dict:
        """``{pose: (R, t)}`` board to the reference frame at parameters ``x``."""
        board_at = self.board_at
        return {k: (Rotation.from_rotvec(x[board_at[k]:board_at[k] + 3]).as_matrix(),
                    x[board_at[k] + 3:board_at[k] + 6].copy()) for k in self.pose_ids}

    def covariance(self, fit) -> np.ndarray:
        """σ: s² (JᵀJ)⁻¹ at the solution (the forward-difference Jacobian of the fit), the
        board poses marginalized; rotation vectors turned into reference-axes angles
        (φ = J_l(ω) δω)."""
        J = np.asarray(fit.jac)
        s2 = float(fit.fun @ fit.fun) / max(fit.fun.size - fit.x.size, 1)
        full = s2 * np.linalg.pinv(J.T @ J)
        n_cam = 6 * (self.n_views - 1)
        keep = np.r_[np.arange(n_cam),
                     np.arange(self.intrinsics_at, fit.x.size) if self.free else []].astype(int)
        T = np.eye(keep.size)
        for v in range(1, self.n_views):
            i = 6 * (v - 1)
            T[i:i + 3, i:i + 3] = left_jacobian(fit.x[i:i + 3])
        covariance = T @ full[np.ix_(keep, keep)] @ T.T
        return 0.5 * (covariance + covariance.T)


#: Jacobians of the joint adjustment at most (:func:`calibrate_rig_in_air`).
JOINT_ITERATIONS = 30


def screen_views(board: Board, detections: Detections, size, names, lens_model):
    """``(detections, left_out {(pose, view): why})``: the views that do not belong left out
    before the joint adjustment — by each camera's own calibration, a view whose RMS exceeds
    :func:`measure.calibration.outliers.outlier_threshold` of that camera's views (a photo
    turned, mirrored or of another board), again until none does; then, for each camera and the
    first camera (or, where those share fewer than :data:`MIN_POSES` poses, the first camera
    before it that shares as many), a pose whose own relative pose disagrees with theirs
    (the pair's check, :func:`measure.calibration.outliers.relative_pose_check`: a photo of
    another moment), that camera's view of it."""
    corners = board.corners().astype(np.float32)
    ids = [list(v) for v in detections.ids]
    pixels = [list(v) for v in detections.pixels]
    empty = (np.empty(0, int), np.empty((0, 2)))
    left_out, own = {}, []
    for v, name in enumerate(names):
        while True:
            fit = fit_camera(corners, Detections(ids, pixels), v, name, size, lens_model)
            errors = fit.rms_px_per
            limit = outlier_threshold(errors.values())
            bad = [k for k, e in errors.items() if e > limit]
            if not bad:
                break
            for k in bad:
                left_out[(k, v)] = (f"its RMS in {name}'s own calibration, {errors[k]:.3g} px, "
                                    f"exceeds {limit:.3g} px")
                ids[k][v], pixels[k][v] = empty
        own.append(fit.own)
    for v in range(1, len(names)):
        # the pair's check against the first camera, or where they share too few poses the
        # first camera before it that shares enough (a rig whose cameras see the board in turn)
        u = next((u for u in range(v) if len(set(own[u]) & set(own[v])) >= MIN_POSES), None)
        if u is None:
            continue
        shared = sorted(set(own[u]) & set(own[v]))
        checked, outliers = relative_pose_check(own[u], own[v], shared)
        for k in outliers:
            c = checked[k]
            left_out[(k, v)] = (f"its pose relative to {names[u]} lies "
                                f"{c['deviation_mm']:.3g} mm and "
                                f"{c['deviation_deg']:.3g}° from the median (limits "
                                f"{c['threshold_mm']:.3g} mm, {c['threshold_deg']:.3g}°)")
            ids[k][v], pixels[k][v] = empty
            del own[v][k]
    return Detections(ids, pixels), left_out


__all__ = ["JOINT_ITERATIONS", "MultiAirCalibration", "calibrate_rig_in_air",
           "camera_parameter_names", "screen_views"]
