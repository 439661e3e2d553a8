"""The water index (and other port parameters) from the measurement itself."""

from __future__ import annotations

import numpy as np
import pytest

from measure.geometry.projection import project
from measure.calibration.selfcal import self_calibrate
from synth.scene.layouts import paper_plane
from synth.scene.rig import paper_rig

N_TRUE = 1.331995  # the paper's 0.15 % deviation from the assumed 1.33


def _pixels(rig, port, points, sigma, rng):
    return [project(c, port, points) + rng.normal(0.0, sigma, (len(points), 2)) if sigma else
            project(c, port, points) for c in rig.cameras]


def test_noise_free_pixels_give_the_true_index_and_points():
    rig = paper_rig()  # assumes n_water = 1.33
    truth = paper_plane(1000.0)
    port = rig.port.replace(indices=(1.0, 1.54, N_TRUE))
    uv = _pixels(rig, port, truth, 0.0, None)
    fit = self_calibrate(rig, uv[0], uv[1])
    assert fit.converged and fit.identifiable
    assert abs(fit.estimates["n_water"] - N_TRUE) < 1e-9
    assert np.max(np.linalg.norm(fit.points - truth, axis=1)) < 1e-6
    assert fit.rms_px < 1e-8 < fit.rms_px_before


def test_monte_carlo_bias_spread_and_reported_sigma():
    """30 trials at σ = 0.1 px: the estimate is unbiased (|mean error| < 3 standard errors) and
    the reported σ matches the observed spread within 2.5 × the spread's own relative standard
    error (1/√(2·29) ≈ 13 %)."""
    rig = paper_rig()
    truth = paper_plane(1000.0)
    port = rig.port.replace(indices=(1.0, 1.54, N_TRUE))
    rng = np.random.default_rng(7)
    estimates, sigmas = [], []
    for _ in range(30):
        uv = _pixels(rig, port, truth, 0.1, rng)
        fit = self_calibrate(rig, uv[0], uv[1])
        estimates.append(fit.estimates["n_water"])
        sigmas.append(fit.sigmas["n_water"])
    errors = np.array(estimates) - N_TRUE
    spread = errors.std(ddof=1)
    assert abs(errors.mean()) < 3 * spread / np.sqrt(len(errors))
    assert abs(np.mean(sigmas) / spread - 1) < 2.5 / np.sqrt(2 * (len(errors) - 1))
    assert 1e-4 < np.mean(sigmas) < 4e-4  # ~2e-4 at 0.1 px with 496 targets at 1 m


def test_joint_index_and_distance_report_their_correlation():
    rig = paper_rig()
    truth = paper_plane(1000.0)
    port = rig.port.replace(indices=(1.0, 1.54, N_TRUE))
    uv = _pixels(rig, port, truth, 0.02, np.random.default_rng(1))
    fit = self_calibrate(rig, uv[0], uv[1], ("n_water", "port_distance"))
    assert fit.labels == ("n_water", "port_distance")
    # strongly but not perfectly correlated on one plane of targets: reported, with sigmas
    assert 0.9 < abs(fit.correlation[0, 1]) < 1.0
    if fit.identifiable:
        assert fit.sigmas["port_distance"] > 0.05 and fit.sigmas["n_water"] > 1e-4


def test_bad_requests():
    rig = paper_rig()
    uv = _pixels(rig, rig.port, paper_plane(1000.0)[:1], 0.0, None)
    with pytest.raises(ValueError, match="estimates"):
        self_calibrate(rig, uv[0], uv[1], ("n_glass",))
    with pytest.raises(ValueError, match="cannot determine"):
        self_calibrate(rig, uv[0], uv[1])


def test_reprojection_method_is_exact_without_noise_and_not_worse_with_it():
    from measure import triangulate

    rig = paper_rig()
    truth = paper_plane(1000.0)
    uv = _pixels(rig, rig.port, truth, 0.0, None)
    result = triangulate(rig, uv[0], uv[1], "reprojection")
    assert np.max(np.abs(result.points - truth)) < 1e-9 and result.method == "reprojection"
    rng = np.random.default_rng(11)
    sq = {"optical_path": [], "reprojection": []}
    for _ in range(5):
        uv = _pixels(rig, rig.port, truth, 0.1, rng)
        for method in sq:
            sq[method].append(np.sum((triangulate(rig, uv[0], uv[1], method).points - truth) ** 2, 1))
    rms = {m: np.sqrt(np.mean(np.concatenate(v))) for m, v in sq.items()}
    # the maximum-likelihood point is at least as good on average (measured gain ~0.7 %)
    assert rms["reprojection"] < rms["optical_path"]


def test_analytic_jacobian_of_the_refinement_matches_finite_differences():
    """The Jacobian handed to least_squares (port parameters with a tilted normal, points)
    against SciPy's own central differences of the residuals (steps 1e-4 for the index, 1e-3 mm,
    1e-6 rad): norm-relative 1e-6 per column block (the port columns, the point columns)."""
    from scipy.optimize._numdiff import approx_derivative

    from measure.calibration.selfcal import refinement_jacobian, refinement_residuals, tilt_basis

    rig = paper_rig()
    truth = paper_plane(1000.0)[::25]
    names = ("n_water", "port_distance", "port_normal")
    basis = tilt_basis(rig.port.normal)
    uv = _pixels(rig, rig.port, truth, 0.0, None)
    observed = np.concatenate(uv, axis=1).ravel()
    x = np.concatenate([[1.3312, 100.4, 0.01, -0.02], (truth + [3.0, -2.0, 5.0]).ravel()])
    analytic = refinement_jacobian(rig, rig.port, names, basis, x).toarray()
    numeric = approx_derivative(lambda v: refinement_residuals(rig, rig.port, names, basis, observed, v),
                                x, method="3-point",
                                abs_step=np.concatenate([[1e-4, 1e-3, 1e-6, 1e-6],
                                                         np.full(3 * len(truth), 1e-3)]))
    for block in (slice(0, 4), slice(4, None)):
        error = np.linalg.norm(analytic[:, block] - numeric[:, block])
        assert error <= 1e-6 * np.linalg.norm(analytic[:, block])
    assert np.count_nonzero(analytic[:, 4:]) == 4 * len(truth) * 3
    from measure.stereo.reprojection import point_block_sparsity  # the structure it promises

    assert np.all((analytic != 0) <= (point_block_sparsity(len(truth), 4).toarray() != 0))


def test_the_rigs_covariance_is_propagated_into_sigma():
    """With a calibration's covariance the fixed rig parameters' uncertainty enters σ: for one
    parameter at a time (left cx, the right camera's centre x, the port distance) the added
    variance is (G σ)², G the estimate's change per unit of that parameter — checked by
    estimating again with the parameter moved (to 2 %). The estimated parameter's own entry
    (port.index[2]) does not enter."""
    from measure import Camera, StereoRig
    from measure.stereo.rig_covariance import RigCovariance

    rig = paper_rig()
    truth = paper_plane(1000.0)
    port = rig.port.replace(indices=(1.0, 1.54, N_TRUE))
    uv = _pixels(rig, port, truth, 0.05, np.random.default_rng(3))
    plain = self_calibrate(rig, uv[0], uv[1], ("n_water", "port_distance"))
    assert plain.propagated == () and plain.sigmas == plain.sigmas_conditional
    K = rig.left.K.copy()
    K[0, 2] += 0.1
    moved = {"left.cx": (0.1, StereoRig(Camera(K, rig.left.size), rig.right, rig.port)),
             "right.center[0]": (0.05, StereoRig(rig.left, Camera(
                 rig.right.K, rig.right.size, None, rig.right.R, rig.right.t + [0.05, 0, 0]),
                 rig.port)),
             "port.thickness[0]": (0.02, StereoRig(rig.left, rig.right, rig.port.replace(
                 thicknesses=(rig.port.thicknesses[0] + 0.02,))))}
    for name, (sigma, other) in moved.items():
        cov = RigCovariance([name, "port.index[2]"], np.diag([sigma ** 2, 1e-6]))
        fit = self_calibrate(rig, uv[0], uv[1], ("n_water", "port_distance"),
                             rig_covariance=cov)
        assert fit.propagated == (name,)
        again = self_calibrate(other, uv[0], uv[1], ("n_water", "port_distance"))
        for key in ("n_water", "port_distance"):
            shift = again.estimates[key] - plain.estimates[key]
            added = np.sqrt(fit.sigmas[key] ** 2 - fit.sigmas_conditional[key] ** 2)
            assert abs(added - abs(shift)) < 0.02 * abs(shift), (name, key, added, shift)
