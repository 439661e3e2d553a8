"""What the flat-port and the dome housing problems share: the board corners observed per
view, the starting board poses (``cv2.solvePnP``), and the sparse Jacobian's bookkeeping."""

from __future__ import annotations

import cv2
import numpy as np

from ..stereo.triangulate import StereoRig
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


def _start_poses(rig: StereoRig, board: Board, detections: Detections):
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


def usable_poses(rig: StereoRig, board: Board, detections: Detections):
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


def _check_boards_in_water(rig: StereoRig, board: Board, starts) -> None:
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

