"""What the flat-port and the dome housing problems share: the board corners observed per
view, the starting board poses (``cv2.solvePnP``), and the sparse Jacobian's bookkeeping."""

from __future__ import annotations

import cv2
import numpy as np

from ..stereo.rig import Rig
from .air import MIN_POSES, CalibrationError, Detections
from .board import MIN_CORNERS, Board

#: Smallest port distance and layer thickness the adjustment may try (mm); largest index.
MIN_LENGTH_MM, MAX_INDEX = 1e-3, 3.0


def observations(board: Board, detections: Detections, views=(0, 1)):
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


def _start_poses(rig: Rig, board: Board, detections: Detections):
    """Per pose (R, t) board-to-reference from ``cv2.solvePnP`` on the left view (the right
    view, moved to the reference frame, where the left has no board)."""
    from scipy.spatial.transform import Rotation
    corners = board.corners()
    poses = []
    for k in range(detections.n_poses):
        for view, camera in enumerate(rig.cameras):
            ids = detections.ids[k][view]
            if len(ids) >= MIN_CORNERS:
                ok, rvec, tvec = cv2.solvePnP(corners[ids], detections.pixels[k][view], camera.K,
                                              camera.brown_conrady_dist("the housing calibration"),
                                              flags=cv2.SOLVEPNP_ITERATIVE)
                if ok:
                    R_cam = Rotation.from_rotvec(rvec.ravel()).as_matrix()
                    poses.append((camera.R @ R_cam, camera.R @ tvec.ravel() + camera.t))
                    break
        else:
            poses.append(None)
    return poses


def usable_poses(rig: Rig, board: Board, detections: Detections):
    """``(starts, usable, detections)``: the starting board poses that ``cv2.solvePnP`` found,
    the numbers of those poses, and the detections of those poses only (in that order);
    CalibrationError when fewer than :data:`MIN_POSES` remain."""
    starts = _start_poses(rig, board, detections)
    usable = [k for k, s in enumerate(starts) if s is not None]
    if len(usable) < MIN_POSES:
        raise CalibrationError(f"the board was found in {len(usable)} pose(s); the housing "
                               f"calibration needs at least {MIN_POSES}")
    _check_boards_in_water(rig, board, [starts[k] for k in usable])
    detections = Detections([detections.ids[k] for k in usable],
                            [detections.pixels[k] for k in usable])
    return [starts[k] for k in usable], usable, detections


def _check_boards_in_water(rig: Rig, board: Board, starts) -> None:
    """CalibrationError when the starting port puts most boards on the camera side of its
    glass (their centres, at the pinhole starting poses): a design distance or thickness that
    cannot be the housing's. The adjustment then has no path through the port to fit, and said
    that the distance was 'not determined by these boards'."""
    centre = board.corners().mean(axis=0)
    centres = np.array([R @ centre + t for R, t in starts])
    wet = rig.port.water_side(centres)
    if wet.sum() * 2 > len(starts):
        return
    depth = centres @ rig.depth_axis - rig.depth_axis @ rig.left.center
    raise CalibrationError(
        f"the design port puts {len(starts) - int(wet.sum())} of the {len(starts)} boards on "
        f"the cameras' side of its glass (the boards lie {depth.min():.0f}–{depth.max():.0f} mm "
        f"from the left camera at their starting poses; the water begins "
        f"{rig.port.glass_depth(rig.left):.0f} mm from it): check the design port's distance "
        f"and thickness (--start-distance, --glass-thickness, --design-port; domes: "
        f"--dome-radius, --dome-thickness)")


def parameter_offset(names, name, table) -> int:
    """Position of a free housing parameter's first number in the unknowns."""
    return sum(table[n] for n in names[:names.index(name)])


def pose_left_jacobians(rotvecs) -> np.ndarray:
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


def rows_jacobian(values, pose_idx, n_global: int, n_columns: int):
    """CSR Jacobian from per-row values ``(m, n_global + 6)``: the free housing numbers, then
    the row's pose's 6 columns. Non-finite values (corners with no image) become 0."""
    from scipy.sparse import csr_matrix
    m, width = values.shape
    columns = np.concatenate([np.broadcast_to(np.arange(n_global), (m, n_global)),
                              n_global + 6 * pose_idx[:, None] + np.arange(6)], axis=1)
    data = np.where(np.isfinite(values), values, 0.0).ravel()
    return csr_matrix((data, columns.ravel(), np.arange(0, m * width + 1, width)),
                      shape=(m, n_columns))



class HousingProblem:
    """The bundle adjustment of a housing calibration (:func:`measure.calibration.flat.
    housing_problem`, :func:`measure.calibration.dome.dome_problem`) as functions of the
    unknowns ``x``: ``n_global`` housing numbers (``names``, of widths ``table``), then 6 per
    usable pose (rotation vector, translation in mm). A kind of housing says how ``x`` becomes
    the housing (:meth:`unpack`), the start and bounds, and its own Jacobian columns
    (:meth:`housing_columns`) and the right camera's pose columns of the in-air Jacobian
    (:meth:`right_pose_columns`); residuals and Jacobians are assembled here. ``obs`` the
    corners' observations (px), ``usable`` the poses kept, ``m`` the residuals' count."""

    def __init__(self, rig: Rig, board: Board, detections: Detections, names, views,
                 table: dict):
        self.rig, self.names, self.views, self.table = rig, tuple(names), tuple(views), table
        self.starts, self.usable, detections = usable_poses(rig, board, detections)
        self.P = len(self.starts)
        self.n_global = sum(table[n] for n in self.names)
        self.corners, self.obs = observations(board, detections, self.views)
        self.m = sum(2 * o[1].size for o in self.obs)

    def unpack(self, x):
        """``(housing, cameras, Rs, ts)`` at ``x``: the housing (``.view(v)`` each camera's
        port), the two cameras, the poses' rotations ``(P, 3, 3)`` and translations (mm)."""
        raise NotImplementedError

    def housing_columns(self, x, name, view, jac, d_points, cameras) -> list:
        """The columns of free housing number ``name`` for the rows of camera ``view``."""
        raise NotImplementedError

    def right_pose_columns(self, jac, housing, cameras) -> tuple:
        """``(rotation, center)``: d pixel / d the right camera's pose (in-air Jacobian)."""
        return jac.rotation, jac.center

    def poses(self, x) -> tuple[np.ndarray, np.ndarray]:
        """The poses' rotations ``(P, 3, 3)`` and translations ``(P, 3)`` mm at ``x``."""
        from scipy.spatial.transform import Rotation

        poses = x[self.n_global:].reshape(self.P, 6)
        return Rotation.from_rotvec(poses[:, :3]).as_matrix(), poses[:, 3:]

    def start_poses(self) -> list:
        """The poses' start values (rotation vector, translation), flattened."""
        from scipy.spatial.transform import Rotation

        x0 = []
        for R, t in self.starts:
            x0 += list(Rotation.from_matrix(R).as_rotvec()) + list(t)
        return x0

    def residuals(self, x, cameras=None):
        """The corners' reprojection residuals (px) at ``x``; 1000 px where a ray fails.
        ``cameras``: others than the problem's (central differences over the in-air ones)."""
        from ..geometry.projection import project

        try:
            housing, own, Rs, ts = self.unpack(x)
        except ValueError:  # e.g. a non-physical index or thickness on the way
            return np.full(self.m, 1e3)
        cameras = own if cameras is None else cameras
        out = []
        for view, pose_idx, ids, uv in self.obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], self.corners[ids]) + ts[pose_idx]
            r = (project(cameras[view], housing.view(view), world) - uv).ravel()
            out.append(np.where(np.isfinite(r), r, 1e3))
        return np.concatenate(out)

    def jacobian(self, x):
        """Analytic (:func:`measure.geometry.projection.project` with ``parameters=True``): a
        row touches the free housing numbers and its pose's 6 columns."""
        from ..geometry.projection import project

        n_global = self.n_global
        width = n_global + 6
        try:
            housing, cameras, Rs, ts = self.unpack(x)
        except ValueError:  # the residuals are constant there
            return rows_jacobian(np.zeros((self.m, width)), np.zeros(self.m, int), n_global,
                                 x.size)
        turn = pose_left_jacobians(x[n_global:].reshape(self.P, 6)[:, :3])
        blocks, poses = [], []
        for view, pose_idx, ids, _ in self.obs:
            rotated = np.einsum("nij,nj->ni", Rs[pose_idx], self.corners[ids])
            _, d_points, jac = project(cameras[view], housing.view(view),
                                       rotated + ts[pose_idx], parameters=True)
            columns = [c for name in self.names
                       for c in self.housing_columns(x, name, view, jac, d_points, cameras)]
            # a pose: X = exp(ω) c + t, so dX/dω = −[R c]× J_l(ω) and dX/dt = I
            d_turn = np.einsum("nrj,njk->nrk", np.cross(rotated[:, None, :], d_points),
                               turn[pose_idx])
            columns += [d_turn, d_points]
            blocks.append(np.concatenate(columns, axis=-1).reshape(-1, width))
            poses.append(np.repeat(pose_idx, 2))
        return rows_jacobian(np.concatenate(blocks), np.concatenate(poses), n_global, x.size)

    def air_jacobian(self, x, air):
        """Dense ``(m, len(air))``: d residuals / d the in-air parameters ``air`` (names of
        :data:`measure.calibration.covariance.AIR_NAMES`) at ``x`` (module docs of
        :mod:`measure.calibration.covariance`)."""
        from ..geometry.projection import project
        from .covariance import AIR_INTRINSICS, intrinsics_jacobian

        housing, cameras, Rs, ts = self.unpack(x)
        column = {name: j for j, name in enumerate(air)}
        out, row = np.zeros((self.m, len(air))), 0
        for view, pose_idx, ids, _ in self.obs:
            world = np.einsum("nij,nj->ni", Rs[pose_idx], self.corners[ids]) + ts[pose_idx]
            pixels, _, jac = project(cameras[view], housing.view(view), world, parameters=True)
            n = 2 * pose_idx.size
            camera = ("left", "right")[view]
            d_int = intrinsics_jacobian(cameras[view], pixels).reshape(n, -1)
            for j, p in enumerate(AIR_INTRINSICS):
                if f"{camera}.{p}" in column:
                    out[row:row + n, column[f"{camera}.{p}"]] = d_int[:, j]
            if view == 1:
                rotation, center = self.right_pose_columns(jac, housing, cameras)
                for k in range(3):
                    for what, values in (("rotation", rotation), ("center", center)):
                        if f"right.{what}[{k}]" in column:
                            out[row:row + n, column[f"right.{what}[{k}]"]] = (
                                values[..., k].reshape(n))
            row += n
        return np.where(np.isfinite(out), out, 0.0)
