"""The housing of ONE camera from its own board corners (no render): the Fermat forward model's
pixels of a camera behind a tilted flat port and inside a decentred dome give the port back
(:func:`measure.calibration.housing.calibrate_camera_housing`), and with pixel noise σ covers
the error."""

from __future__ import annotations

import numpy as np
import pytest

from measure import FlatPort, StereoRig
from measure.calibration.air import CalibrationError, Detections
from measure.calibration.board import Board
from measure.calibration.dome import dome_offset
from measure.calibration.housing import calibrate_camera_housing
from measure.geometry.projection import project
from synth.products.boards import sample_poses
from synth.scene.dome import dome_pair
from synth.scene.rig import paper_cameras

INDICES = (1.0, 1.54, 1.33)
BOARD = Board("chessboard", (9, 6), 40.0)
TILT = np.radians(1.0)
FLAT = FlatPort((np.sin(TILT), 0.0, np.cos(TILT)), 100.0, (5.0,), INDICES)
START = FlatPort((0.0, 0.0, 1.0), 95.0, (5.0,), INDICES)
OFFSET = (2.0, 0.0, 0.0)


def _camera():
    return paper_cameras()[0]


def _corners(camera, port, noise_px=0.0, seed=0, n_poses=10):
    """The board's corners seen by ``camera`` behind ``port`` (a rig port, its view 0), with
    a second, empty view (as a one-camera folder's detections are)."""
    rig = StereoRig(camera, camera, port)
    rng = np.random.default_rng(seed)
    ids, pixels = [], []
    for pose in sample_poses(rig, BOARD, n_poses, seed, True, (350.0, 800.0)):
        world = pose.apply(BOARD.corners())
        uv = project(camera, rig.view_port(0), world)
        ids.append([np.arange(len(world)), np.empty(0, int)])
        pixels.append([uv + rng.normal(0.0, noise_px, uv.shape), np.empty((0, 2))])
    return Detections(ids, pixels)


def test_exact_corners_give_a_tilted_flat_port_and_a_decentred_dome_exactly():
    camera = _camera()
    cal = calibrate_camera_housing(camera, START, BOARD, _corners(camera, FLAT))
    assert cal.identifiable and cal.rms_px < 1e-6
    port = cal.rig.view_port(0)
    assert abs(port.distance - FLAT.distance) < 1e-6
    assert np.degrees(np.arccos(min(1.0, port.normal @ FLAT.normal))) < 1e-6
    assert set(cal.estimates) == {"distance", "normal"}
    truth = dome_pair((camera, camera), 50.0, 8.0, OFFSET, INDICES)
    start = dome_pair((camera, camera), 50.0, 8.0, (0.0, 0.0, 0.0), INDICES)
    cal = calibrate_camera_housing(camera, start, BOARD, _corners(camera, truth))
    assert cal.identifiable and cal.rms_px < 1e-6
    np.testing.assert_allclose(cal.estimates["dome_center"]["left"], OFFSET, atol=1e-6)
    np.testing.assert_allclose(dome_offset(camera, cal.rig.port.left), OFFSET, atol=1e-6)
    assert np.shape(cal.sigmas["dome_center"]) == (3,)
    assert cal.covariance.names == tuple(f"left.dome_center[{i}]" for i in range(3))


def test_noisy_corners_give_sigmas_that_cover_the_error():
    """0.05 px of pixel noise: D and the decentring within 3σ of the truth (σ from the
    covariance of the fit, s²(JᵀJ)⁻¹), and σ small enough to mean something."""
    camera = _camera()
    cal = calibrate_camera_housing(camera, START, BOARD, _corners(camera, FLAT, 0.05, seed=3))
    error = cal.rig.view_port(0).distance - FLAT.distance
    assert cal.identifiable and 0.01 < cal.sigmas["distance"] < 0.5
    assert abs(error) < 3 * cal.sigmas["distance"], (error, cal.sigmas)
    truth = dome_pair((camera, camera), 50.0, 8.0, OFFSET, INDICES)
    start = dome_pair((camera, camera), 50.0, 8.0, (0.0, 0.0, 0.0), INDICES)
    cal = calibrate_camera_housing(camera, start, BOARD, _corners(camera, truth, 0.05, seed=3))
    error = np.asarray(cal.estimates["dome_center"]["left"]) - OFFSET
    sigma = np.asarray(cal.sigmas["dome_center"])
    assert np.all(sigma < 0.1) and np.all(np.abs(error) < 3 * sigma), (error, sigma)


def test_one_camera_has_no_extrinsics():
    camera = _camera()
    with pytest.raises(CalibrationError, match="of one camera estimates distance, normal"):
        calibrate_camera_housing(camera, START, BOARD, _corners(camera, FLAT, n_poses=3),
                                 ("distance", "extrinsics"))
