"""Housing calibration of a rig of two domes from board corners (no render): each camera's
decentring recovered, its analytic Jacobian against finite differences, σ that covers the
error."""

from __future__ import annotations

import numpy as np
import pytest

from measure import StereoRig
from measure.board import Board
from measure.calibration import (CalibrationError, Detections, calibrate_housing, dome_offset,
                                 dome_problem)
from measure.projection import project
from synth.boards import sample_poses
from synth.rig import paper_cameras
from synth.scene.dome import dome_pair

INDICES = (1.0, 1.54, 1.33)
OFFSET = (2.0, -0.5, 1.0)
BOARD = Board("chessboard", (9, 6), 40.0)


def _rigs():
    cameras = paper_cameras()
    truth = StereoRig(*cameras, dome_pair(cameras, 50.0, 8.0, OFFSET, INDICES))
    start = StereoRig(*cameras, dome_pair(cameras, 50.0, 8.0, (0.0, 0.0, 0.0), INDICES))
    return truth, start


def _detections(truth, n_poses=15, noise_px=0.0, seed=0):
    rng = np.random.default_rng(seed)
    ids, pixels = [], []
    for pose in sample_poses(truth, BOARD, n_poses, seed, True, (350.0, 800.0)):
        world = pose.apply(BOARD.corners())
        uv = [project(truth.cameras[v], truth.port_of(v), world) for v in (0, 1)]
        ids.append([np.arange(len(world))] * 2)
        pixels.append([p + rng.normal(0.0, noise_px, p.shape) if noise_px else p for p in uv])
    return Detections(ids, pixels)


def test_exact_corners_give_the_decentring_exactly():
    truth, start = _rigs()
    cal = calibrate_housing(start, BOARD, _detections(truth))
    assert cal.identifiable and cal.rms_px < 1e-6
    for view in ("left", "right"):
        np.testing.assert_allclose(cal.estimates["dome_center"][view], OFFSET, atol=1e-6)
    for view in (0, 1):
        np.testing.assert_allclose(dome_offset(cal.rig.cameras[view], cal.rig.port[view]),
                                   OFFSET, atol=1e-6)


def test_noisy_corners_give_sigmas_that_cover_the_error():
    truth, start = _rigs()
    cal = calibrate_housing(start, BOARD, _detections(truth, noise_px=0.05, seed=4))
    assert cal.identifiable
    estimate = np.concatenate([cal.estimates["dome_center"][v] for v in ("left", "right")])
    sigma = np.asarray(cal.sigmas["dome_center"])
    error = estimate - np.tile(OFFSET, 2)
    assert np.all(np.abs(error) < 0.1) and np.all(sigma < 0.05)
    assert np.all(np.abs(error) < 4 * sigma), (error, sigma)


def test_dome_jacobian_matches_finite_differences():
    truth, start = _rigs()
    problem = dome_problem(start, BOARD, _detections(truth, n_poses=4), ("dome_center",
                                                                          "n_water"))
    x = problem.x0.copy()
    x[:6] += [0.3, -0.2, 0.1, 0.2, 0.1, -0.3]
    J = problem.jacobian(x).toarray()
    for k in (0, 1, 2, 3, 4, 5, 6, 7, 10, 12):
        step = np.zeros_like(x)
        step[k] = 1e-6
        fd = (problem.residuals(x + step) - problem.residuals(x - step)) / 2e-6
        np.testing.assert_allclose(J[:, k], fd, rtol=0, atol=2e-5 * max(1, np.abs(fd).max()))


def test_bad_dome_requests():
    truth, start = _rigs()
    detections = _detections(truth, n_poses=3)
    with pytest.raises(CalibrationError, match="of two domes estimates dome_center, n_water"):
        calibrate_housing(start, BOARD, detections, ("distance",))
