"""In-air calibration of four cameras (measure.calibration.multi_air) from the pinhole
projections of board corners (OpenCV's projectPoints, 0.05 px noise): the cameras' poses come
back near the truth, jointly; a camera with too few boards is named."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure.calibration.air import CalibrationError, Detections, calibrate_in_air
from measure.calibration.board import Board
from measure.calibration.multi_air import calibrate_rig_in_air

SIZE = (1224, 1024)
K = np.array([[550.0, 0, 611.5], [0, 550.0, 511.5], [0, 0, 1]])
DIST = np.array([-0.05, 0.02, 0.0, 0.0, 0.0])


def _rig(n=4):
    out = []
    for k in range(n):
        R = Rotation.from_rotvec([0, -np.radians(5.0 * k), 0]).as_matrix()
        out.append((R, np.array([200.0 * k, 0, 0])))
    return out


def _views(board, poses, rig, rng, noise=0.05):
    corners = board.corners()
    ids, pixels = [], []
    for R_b, t_b in poses:
        row_ids, row_px = [], []
        for R_c, t_c in rig:
            R, t = R_c.T @ R_b, R_c.T @ (t_b - t_c)
            uv = cv2.projectPoints(corners, cv2.Rodrigues(R)[0], t, K, DIST)[0].reshape(-1, 2)
            depth = (corners @ R.T + t)[:, 2]
            inside = np.all((uv > 0) & (uv < np.array(SIZE) - 1), axis=1) & (depth > 0)
            if inside.all():  # a board is used when wholly seen (like the detector's)
                row_ids.append(np.arange(len(corners)))
                row_px.append(uv + rng.normal(0, noise, uv.shape))
            else:
                row_ids.append(np.zeros(0, int))
                row_px.append(np.zeros((0, 2)))
        ids.append(row_ids)
        pixels.append(row_px)
    return Detections(ids, pixels)


def _poses(rng, n=18):
    out = []
    for _ in range(n):
        R = Rotation.from_rotvec(np.radians(rng.uniform(-25, 25, 3))).as_matrix()
        centre = np.array([rng.uniform(0, 600), rng.uniform(-150, 150), rng.uniform(900, 1400)])
        out.append((R, centre - R @ np.array([200.0, 140.0, 0])))
    return out


def test_fixed_intrinsics_agree_with_opencvs_stereo_calibration():
    """With each camera's own intrinsics held, the joint fit of two cameras is
    cv2.stereoCalibrate's (CALIB_FIX_INTRINSIC) from the same corners."""
    rng = np.random.default_rng(5)
    board = Board("chessboard", (9, 6), 50.0)
    detections = _views(board, _poses(rng, 10), _rig(2), rng)
    result = calibrate_rig_in_air(board, detections, SIZE, names=("cam0", "cam1"))
    air = calibrate_in_air(board, detections, SIZE)
    assert air.poses_used["stereo"] == result.poses_used["cam1"] == 10
    opencv, mine = air.rig.right, result.rig.cameras[1]
    assert np.linalg.norm(mine.t - opencv.t) < 0.01
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(mine.R.T @ opencv.R).as_rotvec())) < 0.01
    assert result.joint_rms_px < 0.1  # the noise: 0.05 px per coordinate


@pytest.mark.slow
def test_free_intrinsics_fit_down_to_the_noise():
    """Refining the intrinsics too fits at least as well as holding them (more parameters),
    down to the pixel noise (0.05 px per coordinate: 0.0707 px of residual length), and keeps
    every camera near its true pose (12 poses of a 40-corner board: a few tenths of a mm)."""
    rng = np.random.default_rng(7)
    board = Board("chessboard", (9, 6), 50.0)
    rig = _rig(4)
    detections = _views(board, _poses(rng, 12), rig, rng)
    fixed = calibrate_rig_in_air(board, detections, SIZE)
    free = calibrate_rig_in_air(board, detections, SIZE, intrinsics="free")
    assert free.joint_rms_px <= fixed.joint_rms_px
    assert abs(free.joint_rms_px - 0.05 * np.sqrt(2)) < 0.01
    for camera, (R, t) in zip(free.rig.cameras, rig):
        assert np.linalg.norm(camera.t - t) < 0.5
        angle = np.degrees(np.linalg.norm(Rotation.from_matrix(camera.R.T @ R).as_rotvec()))
        assert angle < 0.2


def test_a_camera_without_boards_is_named():
    rng = np.random.default_rng(6)
    board = Board("chessboard", (11, 8), 40.0)
    detections = _views(board, _poses(rng, 6), _rig(3), rng)
    for row_ids, row_px in zip(detections.ids, detections.pixels):
        row_ids[2], row_px[2] = np.zeros(0, int), np.zeros((0, 2))
    with pytest.raises(CalibrationError, match="the board was found in 0 cam2 image"):
        calibrate_rig_in_air(board, detections, SIZE)


def test_a_view_of_another_moment_is_left_out_by_the_camera_it_shares_poses_with():
    """A rig whose cameras see the board in turn: cam2 shares 2 poses with cam0 (too few for
    the pair's check) and 8 with cam1, and its view of pose 8 was taken with cam2 40 mm off
    (another moment). The pair's per-pose check against cam1 leaves that view out: the rig is
    the one calibrated without that view."""
    rng = np.random.default_rng(12)
    board = Board("chessboard", (9, 6), 50.0)
    rig, poses = _rig(3), _poses(rng, 12)
    detections = _views(board, poses, rig, rng)
    moved = [(R, t + (np.array([0, 40.0, 0]) if v == 2 else 0)) for v, (R, t) in enumerate(rig)]
    other = _views(board, poses, moved, np.random.default_rng(13))
    assert all(len(detections.ids[k][v]) for k in range(12) for v in range(3))
    empty = (np.zeros(0, int), np.zeros((0, 2)))
    for k in range(6, 12):
        detections.ids[k][0], detections.pixels[k][0] = empty
    for k in range(4):
        detections.ids[k][2], detections.pixels[k][2] = empty
    detections.ids[8][2], detections.pixels[8][2] = other.ids[8][2], other.pixels[8][2]
    result = calibrate_rig_in_air(board, detections, SIZE)
    assert list(result.left_out) == [(8, 2)]
    assert "relative to cam1" in result.left_out[(8, 2)]
    detections.ids[8][2], detections.pixels[8][2] = empty
    without = calibrate_rig_in_air(board, detections, SIZE)
    assert not without.left_out
    for mine, clean in zip(result.rig.cameras, without.rig.cameras):
        assert np.array_equal(mine.t, clean.t) and np.array_equal(mine.R, clean.R)


def _errors(result, rig):
    """Each named camera parameter's error against the truth (:func:`_rig`, K, DIST)."""
    out = {}
    for v, (camera, (R, t)) in enumerate(zip(result.rig.cameras, rig)):
        name = f"cam{v}"
        if v > 0:
            phi = Rotation.from_matrix(camera.R @ R.T).as_rotvec()  # R → exp([φ]×) R
            for k in range(3):
                out[f"{name}.rotation[{k}]"] = phi[k]
                out[f"{name}.center[{k}]"] = camera.t[k] - t[k]
        for p, value, true in zip(("fx", "fy", "cx", "cy"),
                                  (camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]),
                                  (K[0, 0], K[1, 1], K[0, 2], K[1, 2])):
            out[f"{name}.{p}"] = value - true
        for p, value, true in zip(("k1", "k2", "p1", "p2", "k3"), camera.dist, DIST):
            out[f"{name}.{p}"] = value - true
    return out


@pytest.mark.slow
def test_the_joint_covariance_covers_the_errors():
    """σ of every camera pose and intrinsic (s²(JᵀJ)⁻¹ of the joint fit, board poses
    marginalized) against the truth over 6 noise draws of the same 12 poses (54 parameters
    each): the errors in σ have a spread near 1 (a σ off by 25 % leaves the band) and about
    95 % lie within 2σ."""
    board = Board("chessboard", (9, 6), 50.0)
    rig = _rig(4)
    poses = _poses(np.random.default_rng(7), 12)
    z = []
    for seed in range(6):
        result = calibrate_rig_in_air(board, _views(board, poses, rig,
                                                    np.random.default_rng(100 + seed)),
                                      SIZE, intrinsics="free")
        sigma, error = result.sigmas(), _errors(result, rig)
        assert len(result.parameter_names) == 3 * 6 + 4 * 9
        z += [error[n] / sigma[n] for n in result.parameter_names]
    z = np.asarray(z)
    assert 0.8 <= z.std() <= 1.25, z.std()
    assert 0.90 <= np.mean(np.abs(z) <= 2.0) <= 0.99
