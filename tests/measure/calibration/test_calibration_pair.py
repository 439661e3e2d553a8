"""Two housings (a :class:`measure.geometry.flat_pair.FlatPair`, each camera behind its own
flat port) from board corners — the Fermat forward model's pixels through each camera's own
port at :func:`synth.products.boards.sample_poses` (no render): both ports come back, and with
pixel noise σ covers the error."""

from __future__ import annotations

import numpy as np
import pytest

from measure import StereoRig
from measure.calibration.air import Detections
from measure.calibration.board import Board
from measure.calibration.housing import calibrate_housing
from measure.geometry.projection import project
from synth.products.boards import sample_poses
from synth.scene.rig import paper_cameras
from synth.scene.windows import flat_pair

INDICES = (1.0, 1.54, 1.33)
BOARD = Board("chessboard", (9, 6), 40.0)


def _rigs():
    """The truth (the committed two-housing scene's ports: 60 and 80 mm from each camera, the
    right one tilted 2° about y) and the design start (70, 70 mm, untilted)."""
    cameras = paper_cameras()
    truth = flat_pair(cameras, (60.0, 80.0), [(0.0, 0.0), (0.0, 2.0)], (5.0, 5.0), INDICES)
    start = flat_pair(cameras, (70.0, 70.0), [(0.0, 0.0), (0.0, 0.0)], (5.0, 5.0), INDICES)
    return StereoRig(*cameras, truth), StereoRig(*cameras, start)


def _corners(rig, noise_px, seed, n_poses=12):
    rng = np.random.default_rng(seed)
    ids, pixels = [], []
    for pose in sample_poses(rig, BOARD, n_poses, seed, True, (400.0, 900.0)):
        world = pose.apply(BOARD.corners())
        views = [project(c, rig.view_port(v), world) for v, c in enumerate(rig.cameras)]
        ids.append([np.arange(len(world))] * 2)
        pixels.append([uv + rng.normal(0.0, noise_px, uv.shape) for uv in views])
    return Detections(ids, pixels)


def _angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def test_exact_corners_give_both_ports_exactly():
    truth, start = _rigs()
    cal = calibrate_housing(start, BOARD, _corners(truth, 0.0, 1),
                            ("distance", "normal", "n_water", "extrinsics"))
    assert cal.identifiable and cal.rms_px < 1e-6, cal.reason
    for v in (0, 1):
        assert abs(cal.rig.port[v].distance - truth.port[v].distance) < 1e-6
        assert _angle_deg(cal.rig.port[v].normal, truth.port[v].normal) < 1e-6
    assert abs(cal.rig.port.n_water - 1.33) < 1e-8
    assert cal.estimates["distance"]["right"] == pytest.approx(truth.port.right.distance)
    assert np.shape(cal.sigmas["normal"]) == (4,)
    names = cal.covariance.names
    assert {"left.port.distance", "right.port.distance", "left.port.tilt[1]",
            "right.port.tilt[0]", "port.index[2]",
            "right.center[0]"} <= set(names)
    # the covariance's names move the rig's FlatPair (measure.stereo.uncertainty)
    cal.rig.port.check_parameter_names(names)


def test_noisy_corners_sigmas_cover_the_error_of_each_port():
    """0.05 px of pixel noise on five seeds of 8 poses: each port's D and both tilts within 3σ (σ from
    s²(JᵀJ)⁻¹, the tilts about the covariance's common axes), σ_D below 0.3 mm."""
    truth, start = _rigs()
    worst = 0.0
    for seed in range(5):
        cal = calibrate_housing(start, BOARD, _corners(truth, 0.05, seed, n_poses=8))
        assert cal.identifiable, cal.reason
        axes = cal.covariance.normal_axes
        sig = cal.covariance.sigmas
        for v, camera in enumerate(("left", "right")):
            est, true = cal.rig.port[v], truth.port[v]
            s = sig[f"{camera}.port.distance"]
            assert 0.005 < s < 0.3
            worst = max(worst, abs(est.distance - true.distance) / s)
            # the tilts a about the axes that move the truth's normal to the estimate's
            away = np.eye(3) - np.outer(est.normal, est.normal)
            a = np.linalg.lstsq(away @ axes.T, est.normal - true.normal, rcond=None)[0]
            for k in range(2):
                worst = max(worst, abs(a[k]) / sig[f"{camera}.port.tilt[{k}]"])
    assert worst < 3.0, worst


def test_the_in_air_jacobian_of_two_housings_is_the_residuals_derivative():
    """d residuals / d the in-air parameters (what carries the in-air covariance into the
    housings' σ) against central differences of the residuals of the moved rig: each port
    stays in the reference frame when the right camera moves."""
    from measure.calibration.flat import housing_problem
    from measure.calibration.housing import apply_air_change

    truth, start = _rigs()
    detections = _corners(truth, 0.0, 1, n_poses=6)
    names = ("distance", "normal")
    problem = housing_problem(start, BOARD, detections, names, pair=True)
    air = ("left.fx", "right.k1", "right.rotation[1]", "right.center[2]")
    analytic = problem.air_jacobian(problem.x0, air)
    for j, h in enumerate((1e-4, 1e-6, 1e-6, 1e-4)):
        step = np.zeros(len(air))
        step[j] = h
        moved = [housing_problem(apply_air_change(start, air, s), BOARD, detections, names,
                                 pair=True).residuals(problem.x0) for s in (step, -step)]
        numeric = (moved[0] - moved[1]) / (2 * h)
        np.testing.assert_allclose(analytic[:, j], numeric, atol=1e-6 * np.abs(numeric).max(),
                                   err_msg=air[j])
