"""The full covariance of a calibration: OpenCV's in-air calibration (both cameras' intrinsics
and the stereo pose) and the housing with it propagated or as a prior — on corners projected
with the forward model plus Gaussian noise (no rendering)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure import FlatPort, StereoRig
from measure.calibration.board import Board
from measure.calibration.air import Detections, calibrate_in_air
from measure.calibration.housing import calibrate_housing
from measure.calibration.covariance import (AIR_NAMES, intrinsics_jacobian, left_jacobian,
                                            stereo_to_rig)
from measure.geometry.camera import Camera
from measure.geometry.projection import project
from synth.products.boards import board_rig, sample_poses
from synth.scene.rig import paper_cameras, paper_rig

BOARD = Board("chessboard", (7, 6), 60.0)
SIZE, FOCAL = (480, 402), 225.0


class _Spec:  # what board_rig needs of a SceneSpec
    def __init__(self, cameras):
        self.cameras = cameras
        self.extra_cameras = ()


def _observe(rig, poses, sigma, rng):
    corners = BOARD.corners()
    ids, pixels = [], []
    for pose in poses:
        world = pose.apply(corners)
        ids.append([np.arange(len(world))] * 2)
        pixels.append([project(c, rig.port, world) + rng.normal(0, sigma, (len(world), 2))
                       for c in rig.cameras])
    return Detections(ids, pixels)


def _air_rig():
    return board_rig(_Spec(paper_cameras(SIZE, FOCAL)), air=True)


def test_in_air_sigmas_are_opencvs_and_the_names_are_the_rigs():
    """The diagonal of the full covariance of each camera's intrinsics equals OpenCV's
    stdDeviationsIntrinsics (the same normal matrix, the same s²) to 1e-6 relative."""
    rig = _air_rig()
    poses = sample_poses(rig, BOARD, 8, seed=3, water=False, distance_range=(450, 650))
    air = calibrate_in_air(BOARD, _observe(rig, poses, 0.05, np.random.default_rng(1)), SIZE)
    cov = air.covariance
    assert cov.names == AIR_NAMES
    sigmas = cov.sigmas
    for cam in ("left", "right"):
        for key, sigma in air.sigmas[cam].items():
            assert sigmas[f"{cam}.{key}"] == pytest.approx(sigma, rel=1e-6), (cam, key)
    # the two cameras' intrinsics come from different corners: uncorrelated
    assert np.all(cov.matrix[:8, 8:16] == 0)
    # the stereo pose depends on both cameras' intrinsics
    assert np.any(cov.matrix[16:, :16] != 0)


def test_in_air_stereo_pose_sigma_matches_monte_carlo():
    """The stereo pose's σ (right camera's centre and rotation, the intrinsics' error
    included) against the scatter of 60 calibrations with fresh noise (σ = 0.1 px): the ratio
    within 0.75–1.33 (the scatter of a 60-sample standard deviation is 9 %)."""
    rig = _air_rig()
    poses = sample_poses(rig, BOARD, 6, seed=8, water=False, distance_range=(450, 650))
    rng = np.random.default_rng(7)
    centres, rotations, sigmas = [], [], []
    for _ in range(60):
        air = calibrate_in_air(BOARD, _observe(rig, poses, 0.1, rng), SIZE)
        centres.append(air.rig.right.t)
        rotations.append(Rotation.from_matrix(air.rig.right.R @ rig.right.R.T).as_rotvec())
        sigmas.append(np.sqrt(np.diag(air.covariance.matrix))[16:])
    spread = np.concatenate([np.std(rotations, axis=0), np.std(centres, axis=0)])
    ratio = np.mean(sigmas, axis=0) / spread
    assert np.all((ratio > 0.75) & (ratio < 1.33)), ratio


def test_stereo_to_rig_matches_finite_differences():
    om, T = np.array([0.01, -0.08, 0.02]), np.array([-199.0, 1.5, 17.0])

    def rig_pose(om, T):
        R = Rotation.from_rotvec(om).as_matrix()
        return R.T, -R.T @ T

    R0, c0 = rig_pose(om, T)
    numeric = np.zeros((6, 6))
    h = 1e-6
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        Rp, cp = rig_pose(om + d[:3], T + d[3:])
        Rm, cm = rig_pose(om - d[:3], T - d[3:])
        phi_p = Rotation.from_matrix(Rp @ R0.T).as_rotvec()
        phi_m = Rotation.from_matrix(Rm @ R0.T).as_rotvec()
        numeric[:, k] = np.concatenate([phi_p - phi_m, cp - cm]) / (2 * h)
    np.testing.assert_allclose(stereo_to_rig(om, T), numeric, atol=1e-6)
    w = np.array([0.3, -0.2, 0.5])
    d = np.array([1e-7, 2e-7, -1e-7])
    moved = Rotation.from_rotvec(w + d).as_matrix() @ Rotation.from_rotvec(w).as_matrix().T
    np.testing.assert_allclose(Rotation.from_matrix(moved).as_rotvec(), left_jacobian(w) @ d,
                               atol=1e-12)


def test_intrinsics_jacobian_matches_finite_differences():
    """d pixel / d intrinsics through the port (the refracted path fixed by the camera's
    centre and pose) against central differences of the forward model (px per px, per unit)."""
    rig = paper_rig()
    camera = Camera(rig.left.K, rig.left.size, [0.05, -0.02, 1e-3, -2e-3, 0.0])
    points = np.array([[100.0, -50.0, 900.0], [-300.0, 200.0, 1200.0], [0.0, 0.0, 1000.0]])
    analytic = intrinsics_jacobian(camera, project(camera, rig.port, points))
    steps = [1e-3] * 4 + [1e-6] * 4
    for j, h in enumerate(steps):
        moved = []
        for sign in (1, -1):
            K, dist = camera.K.copy(), camera.dist.copy()
            if j < 4:
                K[((0, 0), (1, 1), (0, 2), (1, 2))[j]] += sign * h
            else:
                dist[j - 4] += sign * h
            moved.append(project(Camera(K, camera.size, dist), rig.port, points))
        numeric = (moved[0] - moved[1]) / (2 * h)
        np.testing.assert_allclose(analytic[:, :, j], numeric, rtol=1e-5, atol=1e-6 * np.abs(
            numeric).max())


@pytest.fixture(scope="module")
def chain():
    """An in-air calibration (8 poses) and underwater corners (8 poses) of a 1°-tilted port,
    σ = 0.05 px."""
    rig = _air_rig()
    poses = sample_poses(rig, BOARD, 8, seed=3, water=False, distance_range=(450, 650))
    air = calibrate_in_air(BOARD, _observe(rig, poses, 0.05, np.random.default_rng(1)), SIZE)
    normal = Rotation.from_rotvec([0, np.radians(1.0), 0]).apply([0, 0, 1.0])
    truth = StereoRig(rig.left, rig.right, FlatPort(normal, 100.0, (5.0,), (1.0, 1.54, 1.33)))
    water = sample_poses(truth, BOARD, 8, seed=4, water=True, distance_range=(600, 1000))
    detections = _observe(truth, water, 0.05, np.random.default_rng(2))
    start = StereoRig(air.rig.left, air.rig.right, FlatPort((0, 0, 1.0), 100.0, (5.0,),
                                                            (1.0, 1.54, 1.33)))
    return {"air": air, "truth": truth, "detections": detections, "start": start}


def test_housing_propagation_predicts_how_the_port_moves_with_the_intrinsics(chain):
    """The cross-covariance of the housing and the in-air parameters is −G Σ_air, so the housing
    moves by Cov(h, air) Σ_air⁻¹ δ when the in-air parameters move by δ: checked by running the
    adjustment again with the intrinsics and the stereo pose moved by 1 σ (to 5 % of the
    move)."""
    from measure.calibration.housing import apply_air_change

    air, start = chain["air"], chain["start"]
    fit = calibrate_housing(start, BOARD, chain["detections"], air_covariance=air.covariance,
                            uncertainty="propagate")
    assert fit.identifiable and fit.uncertainty == "propagate", fit.reason
    cov = fit.covariance
    assert cov.names == AIR_NAMES + ("port.distance", "port.tilt[0]", "port.tilt[1]")
    # more than the conditional σ, and the joint matrix read back by name
    assert fit.sigmas["distance"] > fit.sigmas_conditional["distance"]
    assert cov.sigmas["port.distance"] == pytest.approx(fit.sigmas["distance"], rel=1e-9)
    a = len(AIR_NAMES)
    sigma_air = cov.matrix[:a, :a]
    delta = np.sqrt(np.diag(sigma_air)) * np.random.default_rng(3).choice([-1.0, 1.0], a)
    predicted = cov.matrix[a, :a] @ np.linalg.solve(sigma_air, delta)
    moved = calibrate_housing(apply_air_change(start, AIR_NAMES, delta), BOARD, chain["detections"])
    actual = moved.estimates["distance"] - fit.estimates["distance"]
    assert abs(actual - predicted) < 0.05 * abs(actual), (actual, predicted)


def test_housing_with_the_in_air_prior(chain):
    """The in-air parameters freed under their in-air covariance: σ between the conditional
    σ and the propagated one (the underwater corners add to what air knew), the estimates
    within 3 σ of the truth, the intrinsics refined."""
    air, start, truth = chain["air"], chain["start"], chain["truth"]
    propagated = calibrate_housing(start, BOARD, chain["detections"],
                                   air_covariance=air.covariance, uncertainty="propagate")
    prior = calibrate_housing(start, BOARD, chain["detections"], air_covariance=air.covariance,
                              uncertainty="prior")
    assert prior.identifiable and prior.uncertainty == "prior"
    s = prior.sigmas["distance"]
    assert prior.sigmas_conditional["distance"] <= s <= propagated.sigmas["distance"]
    assert abs(prior.estimates["distance"] - truth.port.distance) < 3 * s
    assert not np.array_equal(prior.rig.left.K, air.rig.left.K)
    assert prior.covariance.names == propagated.covariance.names


def test_housing_without_an_in_air_covariance_is_conditional(chain):
    fit = calibrate_housing(chain["start"], BOARD, chain["detections"],
                            ("distance", "normal", "extrinsics"))
    assert fit.uncertainty == "conditional"
    assert fit.sigmas == fit.sigmas_conditional
    assert fit.covariance.names == ("port.distance", "port.tilt[0]", "port.tilt[1]",
                                    "right.rotation[0]", "right.rotation[1]",
                                    "right.rotation[2]", "right.center[0]", "right.center[1]",
                                    "right.center[2]")
    # extrinsics free: the in-air stereo pose no longer enters, the intrinsics do
    both = calibrate_housing(chain["start"], BOARD, chain["detections"],
                             ("distance", "normal", "extrinsics"),
                             air_covariance=chain["air"].covariance, uncertainty="propagate")
    assert both.covariance.names[:16] == AIR_NAMES[:16]
    assert len(both.covariance.names) == 16 + 9
