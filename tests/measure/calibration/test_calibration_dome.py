"""Housing calibration of a rig of two domes from board corners (no render): each camera's
decentring recovered, its analytic Jacobian against finite differences, σ that covers the
error."""

from __future__ import annotations

import numpy as np
import pytest

from measure import StereoRig
from measure.calibration.board import Board
from measure.calibration.air import CalibrationError, Detections
from measure.calibration.dome import dome_offset, dome_problem
from measure.calibration.housing import calibrate_housing
from measure.geometry.projection import project
from synth.products.boards import sample_poses
from synth.scene.rig import paper_cameras
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
        uv = [project(truth.cameras[v], truth.view_port(v), world) for v in (0, 1)]
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


# ---------------------------------------------------------------------------------------------
# the in-air calibration's covariance behind domes
# ---------------------------------------------------------------------------------------------
SIZE, FOCAL = (480, 402), 225.0
SMALL_BOARD = Board("chessboard", (7, 6), 60.0)


def _observe(rig, poses, sigma, rng):
    corners = SMALL_BOARD.corners()
    ids, pixels = [], []
    for pose in poses:
        world = pose.apply(corners)
        ids.append([np.arange(len(world))] * 2)
        pixels.append([project(c, rig.view_port(v), world) + rng.normal(0, sigma, (len(world), 2))
                       for v, c in enumerate(rig.cameras)])
    return Detections(ids, pixels)


@pytest.fixture(scope="module")
def chain():
    """An in-air calibration (8 poses, σ = 0.05 px) and corners behind two decentred domes
    (10 poses, σ = 0.05 px) of small cameras; the start: the in-air cameras in centred domes."""
    from measure.calibration.air import calibrate_in_air

    cameras = paper_cameras(SIZE, FOCAL)
    air_rig = StereoRig(*cameras, dome_pair(cameras, 50.0, 8.0, (0.0, 0.0, 0.0),
                                            (1.0, 1.0, 1.0)))
    poses = sample_poses(air_rig, SMALL_BOARD, 8, 3, False, (450.0, 650.0))
    air = calibrate_in_air(SMALL_BOARD, _observe(air_rig, poses, 0.05,
                                                 np.random.default_rng(1)), SIZE)
    truth = StereoRig(*cameras, dome_pair(cameras, 50.0, 8.0, OFFSET, INDICES))
    water = sample_poses(truth, SMALL_BOARD, 10, 4, True, (450.0, 900.0))
    detections = _observe(truth, water, 0.05, np.random.default_rng(2))
    start = StereoRig(air.rig.left, air.rig.right,
                      dome_pair(air.rig.cameras, 50.0, 8.0, (0.0, 0.0, 0.0), INDICES))
    return {"air": air, "truth": truth, "detections": detections, "start": start}


def test_dome_air_jacobian_matches_finite_differences(chain):
    """d residuals / d in-air parameters (intrinsics; the right camera's pose with its dome
    moving along) against the residuals of the rig with those parameters moved."""
    from measure.calibration.housing import apply_air_change
    from measure.calibration.covariance import AIR_NAMES

    start, detections = chain["start"], chain["detections"]
    names = ("dome_center",)
    problem = dome_problem(start, SMALL_BOARD, detections, names)
    x = problem.x0.copy()
    x[:6] += [1.5, -0.4, 0.8, 2.2, 0.3, -0.6]  # decentred: the lever arm of the rotation
    J = problem.air_jacobian(x, AIR_NAMES)
    steps = {"fx": 1e-3, "cx": 1e-3, "k1": 1e-6, "p2": 1e-7, "rotation": 1e-7, "center": 1e-4}
    for j, name in enumerate(AIR_NAMES):
        h = next(v for k, v in steps.items() if k in name) if any(
            k in name for k in steps) else 1e-4
        delta = np.zeros(len(AIR_NAMES))
        delta[j] = h
        plus = dome_problem(apply_air_change(start, AIR_NAMES, delta), SMALL_BOARD, detections,
                            names).residuals(x)
        minus = dome_problem(apply_air_change(start, AIR_NAMES, -delta), SMALL_BOARD,
                             detections, names).residuals(x)
        fd = (plus - minus) / (2 * h)
        np.testing.assert_allclose(J[:, j], fd, rtol=0, atol=1e-4 * max(1.0, np.abs(fd).max()),
                                   err_msg=name)
    assert np.abs(J[:, AIR_NAMES.index("right.rotation[1]")]).max() > 0


@pytest.mark.parametrize("mode", ["propagate", "prior"])
def test_dome_sigma_includes_the_in_air_covariance(chain, mode):
    """With the in-air covariance the decentring's σ grows over the conditional σ, the joint
    covariance names each dome's centre (reference frame) beside the in-air parameters, and
    σ of the reference-frame centre of the left dome equals σ of its decentring (the left
    camera is the reference frame)."""
    from measure.calibration.covariance import AIR_NAMES

    air, truth = chain["air"], chain["truth"]
    fit = calibrate_housing(chain["start"], SMALL_BOARD, chain["detections"],
                            air_covariance=air.covariance, uncertainty=mode)
    assert fit.identifiable and fit.uncertainty == mode, fit.reason
    dome_names = tuple(f"{v}.dome_center[{k}]" for v in ("left", "right") for k in range(3))
    assert fit.covariance.names == AIR_NAMES + dome_names
    sigma = np.asarray(fit.sigmas["dome_center"])
    conditional = np.asarray(fit.sigmas_conditional["dome_center"])
    assert np.all(sigma > conditional)
    np.testing.assert_allclose([fit.covariance.sigmas[n] for n in dome_names[:3]], sigma[:3],
                               rtol=1e-9)
    estimate = np.concatenate([fit.estimates["dome_center"][v] for v in ("left", "right")])
    assert np.all(np.abs(estimate - np.tile(OFFSET, 2)) < 4 * sigma)
    centres = np.concatenate([fit.rig.port.left.center, fit.rig.port.right.center])
    true_centres = np.concatenate([truth.port.left.center, truth.port.right.center])
    sig_centres = np.array([fit.covariance.sigmas[n] for n in dome_names])
    assert np.all(np.abs(centres - true_centres) < 4 * sig_centres)


def test_dome_propagation_predicts_how_the_domes_move_with_the_intrinsics(chain):
    """The joint covariance's cross terms: the dome centres (reference frame) move by
    Cov(M, air) Σ_air⁻¹ δ when the in-air parameters move by δ (re-run adjustment, 5 %)."""
    from measure.calibration.housing import apply_air_change
    from measure.calibration.covariance import AIR_NAMES

    air, start = chain["air"], chain["start"]
    fit = calibrate_housing(start, SMALL_BOARD, chain["detections"],
                            air_covariance=air.covariance, uncertainty="propagate")
    cov, a = fit.covariance, len(AIR_NAMES)
    sigma_air = cov.matrix[:a, :a]
    delta = np.sqrt(np.diag(sigma_air)) * np.random.default_rng(3).choice([-1.0, 1.0], a)
    predicted = cov.matrix[a:, :a] @ np.linalg.solve(sigma_air, delta)
    moved = calibrate_housing(apply_air_change(start, AIR_NAMES, delta), SMALL_BOARD,
                              chain["detections"])
    actual = np.concatenate([moved.rig.port.left.center - fit.rig.port.left.center,
                             moved.rig.port.right.center - fit.rig.port.right.center])
    np.testing.assert_allclose(actual, predicted, rtol=0,
                               atol=0.05 * np.abs(actual).max())


def test_dome_without_an_in_air_covariance_is_conditional(chain):
    fit = calibrate_housing(chain["start"], SMALL_BOARD, chain["detections"])
    assert fit.uncertainty == "conditional" and fit.sigmas == fit.sigmas_conditional
    assert fit.covariance.names == tuple(f"{v}.dome_center[{k}]" for v in ("left", "right")
                                         for k in range(3))
