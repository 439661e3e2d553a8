"""Calibration from board corners: OpenCV in air and the refractive bundle adjustment of the
housing, on corners projected with the forward model plus Gaussian noise (no rendering)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure import Camera, FlatPort, StereoRig
from measure.calibration.board import Board
from measure.calibration.air import CalibrationError, Detections, calibrate_in_air
from measure.calibration.housing import calibrate_housing
from measure.geometry.projection import project
from synth.products.boards import board_rig, sample_poses
from synth.scene.rig import paper_rig

BOARD = Board("chessboard", (11, 8), 40.0)
TILT = np.radians(1.0)


def _tilted_rig():
    rig = paper_rig()
    normal = Rotation.from_rotvec([0, TILT, 0]).apply([0, 0, 1.0])
    return StereoRig(rig.left, rig.right, rig.port.replace(normal=normal))


def _observe(rig, poses, sigma, rng, board=BOARD):
    corners = board.corners()
    ids, pixels = [], []
    for pose in poses:
        world = pose.apply(corners)
        views = [project(c, rig.port, world) + rng.normal(0, sigma, (len(world), 2))
                 for c in rig.cameras]
        ids.append([np.arange(len(world))] * 2)
        pixels.append(views)
    return Detections(ids, pixels)


class _Spec:  # the attributes board_rig needs of a SceneSpec
    def __init__(self, rig):
        self.cameras = rig.cameras
        self.extra_cameras = ()


def test_housing_bundle_adjustment_recovers_a_tilted_port():
    """12 poses, σ = 0.05 px, port tilted 1°, starting from the untilted design at 90 mm: D
    and the normal within 3σ, σ_D ≈ 0.1 mm and σ_normal ≈ 10″ (the issue's prototype reached
    0.13 mm and 15″ with this set-up)."""
    truth = _tilted_rig()
    rng = np.random.default_rng(3)
    poses = sample_poses(truth, BOARD, 12, seed=5, water=True)
    detections = _observe(truth, poses, 0.05, rng)
    design = FlatPort((0, 0, 1.0), 90.0, (5.0,), (1.0, 1.54, 1.33))
    fit = calibrate_housing(StereoRig(truth.left, truth.right, design), BOARD, detections)
    assert fit.converged and fit.identifiable, fit.reason
    sigma_d = fit.sigmas["distance"]
    assert 0.02 < sigma_d < 0.3
    assert abs(fit.estimates["distance"] - 100.0) < 3 * sigma_d
    a, b = (np.asarray(v) for v in fit.normal_axes)
    error = fit.rig.port.normal - truth.port.normal
    for axis, sigma in zip((a, b), fit.sigmas["normal"]):
        assert sigma < np.radians(30 / 3600)
        assert abs(error @ axis) < 3 * sigma
    # the 2D RMS of the noise, σ·√2 = 0.0707 px, times √(1 − unknowns / residuals) = 0.989
    assert abs(fit.rms_px / (0.05 * np.sqrt(2) * np.sqrt(1 - 75 / 3360)) - 1) < 0.05
    for (_, t), pose in zip(fit.poses, poses):
        assert np.linalg.norm(t - pose.t) < 1.0


def test_housing_free_index_and_extrinsics_without_noise_are_exact():
    truth = _tilted_rig()
    truth = StereoRig(truth.left, truth.right, truth.port.replace(indices=(1.0, 1.54, 1.3345)))
    poses = sample_poses(truth, BOARD, 6, seed=1, water=True)
    detections = _observe(truth, poses, 0.0, np.random.default_rng(0))
    right = truth.right
    nudged = type(right)(right.K, right.size, right.dist,
                         Rotation.from_rotvec([1e-3, 0, 0]).as_matrix() @ right.R,
                         right.t + [0.5, 0, 0])
    start = StereoRig(truth.left, nudged, FlatPort((0, 0, 1.0), 100.0, (5.0,), (1.0, 1.54, 1.33)))
    fit = calibrate_housing(start, BOARD, detections, ("distance", "normal", "n_water", "extrinsics"))
    assert fit.identifiable, fit.reason
    assert abs(fit.estimates["n_water"] - 1.3345) < 1e-8
    assert abs(fit.estimates["distance"] - 100.0) < 1e-5
    np.testing.assert_allclose(fit.rig.right.t, right.t, atol=1e-5)
    assert fit.rms_px < 1e-6


def test_housing_bad_requests():
    truth = _tilted_rig()
    poses = sample_poses(truth, BOARD, 2, seed=2, water=True)
    detections = _observe(truth, poses, 0.05, np.random.default_rng(0))
    with pytest.raises(CalibrationError, match="at least 3"):
        calibrate_housing(truth, BOARD, detections)
    with pytest.raises(CalibrationError, match="estimates"):
        calibrate_housing(truth, BOARD, detections, ("focal",))
    empty = Detections([[np.empty(0, int)] * 2] * 5, [[np.empty((0, 2))] * 2] * 5)
    with pytest.raises(CalibrationError, match="found in 0"):
        calibrate_housing(truth, BOARD, empty)


def test_housing_reports_what_the_boards_cannot_determine():
    """Boards all at one distance and facing the cameras cannot separate the glass thickness
    from the port distance and the water index: no estimate, the reason names a parameter."""
    truth = paper_rig()
    poses = sample_poses(truth, BOARD, 4, seed=4, water=True, distance_range=(1000, 1001),
                         max_tilt_deg=0.0)
    detections = _observe(truth, poses, 0.05, np.random.default_rng(1))
    fit = calibrate_housing(truth, BOARD, detections, ("distance", "thickness", "n_water"))
    assert not fit.identifiable
    assert fit.estimates == {}
    assert "thickness and n_water are correlated" in fit.reason


def test_in_air_opencv_calibration_from_corners():
    """OpenCV's calibrateCamera / stereoCalibrate on 15 in-air views with σ = 0.05 px: focal
    lengths within 0.05 %, principal points within 0.5 px, baseline within 0.1 mm."""
    truth = paper_rig()
    air = board_rig(_Spec(truth), air=True)
    poses = sample_poses(air, BOARD, 15, seed=6, water=False)
    detections = _observe(air, poses, 0.05, np.random.default_rng(2))
    result = calibrate_in_air(BOARD, detections, truth.left.size)
    for est, tru in zip(result.rig.cameras, truth.cameras):
        assert np.all(np.abs(np.diag(est.K)[:2] / np.diag(tru.K)[:2] - 1) < 5e-4)
        assert np.all(np.abs(est.K[:2, 2] - tru.K[:2, 2]) < 0.5)
    baseline = np.linalg.norm(result.rig.right.t - result.rig.left.t)
    assert abs(baseline - 200.0) < 0.1
    assert 0.03 < result.rms_px["left"] < 0.08
    # per view: OpenCV's errors, and the board poses it estimated (in the reference frame)
    assert set(result.rms_px_per) == {(k, v) for k in range(15) for v in (0, 1)}
    assert all(0.01 < r < 0.15 for r in result.rms_px_per.values())
    for (k, view), (R, t) in result.board_poses.items():
        assert np.linalg.norm(t - poses[k].t) < 1.0, (k, view)
        assert np.degrees(Rotation.from_matrix(R @ poses[k].R.T).magnitude()) < 0.1
    with pytest.raises(CalibrationError, match="at least 3"):
        calibrate_in_air(BOARD, Detections(detections.ids[:2], detections.pixels[:2]),
                         truth.left.size)


@pytest.mark.parametrize("lens", ["standard", "k3", "rational"])
def test_stereo_intrinsics_refined_keeps_the_lens_models_coefficients(lens):
    """``stereo_intrinsics="refined"``: OpenCV's stereo fit returns 14 distortion coefficients
    whatever the model; each camera keeps its model's own (it raised 'dist of the
    brown_conrady model must hold 4, 5 or 8 coefficients, got 14')."""
    truth = paper_rig()
    air = board_rig(_Spec(truth), air=True)
    poses = sample_poses(air, BOARD, 10, seed=6, water=False)
    detections = _observe(air, poses, 0.05, np.random.default_rng(2))
    fixed = calibrate_in_air(BOARD, detections, truth.left.size, lens)
    refined = calibrate_in_air(BOARD, detections, truth.left.size, lens,
                               stereo_intrinsics="refined")
    for est, own in zip(refined.rig.cameras, fixed.rig.cameras):
        assert est.dist.shape == own.dist.shape
    baseline = np.linalg.norm(refined.rig.right.t - refined.rig.left.t)
    assert abs(baseline - 200.0) < 0.2


def test_in_air_fisheye_calibration_from_corners():
    """--lens fisheye: cameras with OpenCV's fisheye model, 15 in-air views with σ = 0.05 px,
    recovered by cv2.fisheye.calibrate / stereoCalibrate: focal lengths within 0.1 %, every
    intrinsic within 4 of its σ (the σ computed as calibrateCameraExtended's), baseline within
    0.1 mm."""
    paper = paper_rig()
    dist = np.array([0.06, -0.02, 0.01, -0.004])
    truth = StereoRig(*(Camera(c.K, c.size, dist, c.R, c.t, "fisheye") for c in paper.cameras),
                      paper.port)
    air = board_rig(_Spec(truth), air=True)
    assert all(c.fisheye for c in air.cameras)
    poses = sample_poses(air, BOARD, 15, seed=6, water=False)
    detections = _observe(air, poses, 0.05, np.random.default_rng(2))
    result = calibrate_in_air(BOARD, detections, truth.left.size, "fisheye")
    for name, est, tru in zip(("left", "right"), result.rig.cameras, truth.cameras):
        assert est.fisheye
        assert np.all(np.abs(np.diag(est.K)[:2] / np.diag(tru.K)[:2] - 1) < 1e-3)
        sigma = result.sigmas[name]
        assert list(sigma) == ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"]
        error = np.r_[np.diag(est.K)[:2] - np.diag(tru.K)[:2], est.K[:2, 2] - tru.K[:2, 2],
                      est.dist - dist]
        assert np.all(np.abs(error) < 4 * np.array(list(sigma.values()))), (name, error, sigma)
        assert sigma["cx"] < 1.0 and sigma["k1"] < 0.01
    assert abs(np.linalg.norm(result.rig.right.t - result.rig.left.t) - 200.0) < 0.1
    assert 0.03 < result.rms_px["left"] < 0.08 and result.stereo_rms_px < 0.1
    assert np.abs(result.residuals[0][:, 2:]).max() < 0.3


def test_housing_analytic_jacobian_matches_finite_differences():
    """The Jacobian handed to least_squares, with every housing parameter free (distance, the
    two tilts, thickness, n_water, the right camera's extrinsics) away from the start: against
    SciPy's central differences of the residuals (steps of 1e-3 mm, 1e-6 rad, 1e-4 for the
    index), norm-relative 1e-6 per parameter group (the housing numbers one by one, all pose
    columns together)."""
    from scipy.optimize._numdiff import approx_derivative

    from measure.calibration.flat import HOUSING_PARAMETERS, housing_problem

    truth = _tilted_rig()
    poses = sample_poses(truth, BOARD, 3, seed=2, water=True)
    detections = _observe(truth, poses, 0.05, np.random.default_rng(4))
    names = tuple(HOUSING_PARAMETERS)
    problem = housing_problem(truth, BOARD, detections, names)
    rng = np.random.default_rng(5)
    x = problem.x0 + np.concatenate([[0.3, 0.004, -0.003, 0.2, 0.002],
                                     rng.normal(0, 2e-3, 3), rng.normal(0, 0.3, 3),
                                     rng.normal(0, [2e-3] * 3 + [1.0] * 3, (problem.P, 6)).ravel()])
    analytic = problem.jacobian(x).toarray()
    # steps as in tests/measure/geometry/test_jacobian.py: 1e-3 mm, 1e-6 rad, 1e-4 for the index
    steps = np.concatenate([[1e-3, 1e-6, 1e-6, 1e-3, 1e-4], [1e-6] * 3, [1e-3] * 3,
                            np.tile([1e-6] * 3 + [1e-3] * 3, problem.P)])
    numeric = approx_derivative(problem.residuals, x, method="3-point", abs_step=steps)
    for block in [slice(k, k + 1) for k in range(problem.n_global)] + [slice(problem.n_global, None)]:
        error = np.linalg.norm(analytic[:, block] - numeric[:, block])
        assert error <= 1e-6 * np.linalg.norm(analytic[:, block]), block
