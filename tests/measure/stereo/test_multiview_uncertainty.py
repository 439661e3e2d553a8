"""Point covariances of N views (measure.stereo.multiview_uncertainty) against Monte Carlo:
rings of 3–5 cameras behind shared, own and mixed ports (a dome, a camera in air), σ = 0.1 px
per coordinate, 200 seeded trials; and for two views against the pair's analytic covariance
(measure.stereo.uncertainty, the maximum-likelihood bound).

Criterion (the one of tests/measure/stereo/test_uncertainty.py): per axis, the RMS of the
normalized errors ``(estimate − truth) / σ_predicted`` pooled over points and trials is 1 within
10 % (its sampling error is about ``1/sqrt(2·N·T)``, under 1.5 % here; a variance off by a
factor 2 is 41 %), and 93–97 % of the estimates lie inside their 95 % ellipsoid."""

from __future__ import annotations

import numpy as np
import pytest

from measure.geometry.camera import Camera
from measure.geometry.port import FlatPort
from measure.geometry.projection import project
from measure.stereo.multiview import View, triangulate_views
from measure.stereo.multiview_uncertainty import (point_jacobians, view_pixel_sigmas,
                                                  view_point_covariances, view_residual_sigma)
from measure.stereo.triangulate import StereoRig
from measure.stereo.uncertainty import CHI2_3_95, mahalanobis_squared, point_covariances
from tests.measure.stereo.test_multiview import GLASS, K, SIZE, _ports, _ring, _targets

SIGMA_PX = 0.1
TRIALS = 200


def _seen_pixels(cameras, ports, points):
    pixels = np.stack([project(c, p, points) for c, p in zip(cameras, ports)], axis=1)
    inside = (pixels[..., 0] >= -0.5) & (pixels[..., 0] <= SIZE[0] - 0.5) & (
        pixels[..., 1] >= -0.5) & (pixels[..., 1] <= SIZE[1] - 0.5)
    pixels[~inside] = np.nan
    return pixels


@pytest.mark.parametrize("count,mix", [(3, "shared"), (4, "own"), (5, "mixed")])
def test_covariance_matches_monte_carlo(count, mix):
    rng = np.random.default_rng(100 + count)
    cameras = _ring(count, rng)
    views = [View(c, p) for c, p in zip(cameras, _ports(cameras, mix, rng))]
    points = _targets(rng, 60)
    pixels = _seen_pixels(cameras, [v.port for v in views], points)
    # a view of some targets hidden: points of 2 … count views
    pixels[rng.random(pixels.shape[:2]) < 0.25] = np.nan
    found, covariance = view_point_covariances(views, pixels, SIGMA_PX)
    ok = np.all(np.isfinite(covariance), axis=(1, 2))
    assert ok.mean() > 0.8
    np.testing.assert_allclose(found[ok], points[ok], atol=1e-8)
    n = int(ok.sum())
    noisy = np.tile(pixels[ok], (TRIALS, 1, 1)) + rng.normal(0.0, SIGMA_PX, (TRIALS * n, count, 2))
    estimates = triangulate_views(views, noisy).points.reshape(TRIALS, n, 3)
    errors = estimates - points[ok]
    sigma = np.sqrt(np.einsum("nii->ni", covariance[ok]))
    ratio = np.sqrt(np.mean((errors / sigma) ** 2, axis=(0, 1)))
    assert np.all(np.abs(ratio - 1.0) <= 0.10), ratio
    d2 = mahalanobis_squared(errors.reshape(-1, 3), np.tile(covariance[ok], (TRIALS, 1, 1)))
    assert 0.93 <= np.mean(d2 <= CHI2_3_95) <= 0.97


def test_two_views_agree_with_the_pairs_analytic_covariance():
    """A pair behind one flat port: the rays' point's covariance is the pair's (JᵀWJ)⁻¹ of
    measure.stereo.uncertainty within 1 % (the midpoint of the common perpendicular and the
    maximum-likelihood point move alike with noise that keeps the rays meeting and differ only
    in how they spread the part that makes them skew: 0.6 % at most on these 40 targets)."""
    rng = np.random.default_rng(7)
    left, right = _ring(2, rng)
    # the pair's frame: the left camera at the origin
    to_left = lambda X: (X - left.center) @ left.R  # noqa: E731
    port = FlatPort([0.0, 0.0, 1.0], 520.0, (8.0,), GLASS)
    rig = StereoRig(Camera(K, SIZE, dist=left.dist),
                    Camera(K, SIZE, dist=right.dist, R=left.R.T @ right.R,
                           t=to_left(right.center[None])[0]),
                    FlatPort(left.R.T @ port.normal, port.distance - port.normal @ left.center,
                             port.thicknesses, port.indices))
    points = to_left(_targets(rng, 40))
    pixels = np.stack([project(c, rig.view_port(v), points)
                       for v, c in enumerate(rig.cameras)], axis=1)
    views = [View(c, rig.view_port(v)) for v, c in enumerate(rig.cameras)]
    _, covariance = view_point_covariances(views, pixels, SIGMA_PX)
    analytic = point_covariances(rig, points, SIGMA_PX).pixel
    np.testing.assert_allclose(covariance, analytic, rtol=0.01,
                               atol=0.01 * np.abs(analytic).max())


def test_unseen_views_add_nothing_and_shapes_are_checked():
    rng = np.random.default_rng(3)
    cameras = _ring(3, rng)
    views = [View(c, p) for c, p in zip(cameras, _ports(cameras, "own", rng))]
    points = _targets(rng, 4)
    pixels = _seen_pixels(cameras, [v.port for v in views], points)
    pixels[0, 2] = np.nan  # target 0 seen by two views
    pixels[1, 1:] = np.nan  # target 1 by one: no point, no covariance
    _, G = point_jacobians(views, pixels)
    assert np.all(G[0, :, 2] == 0) and np.all(np.isnan(G[1]))
    sigma = np.full((4, 3), SIGMA_PX)
    sigma[0, 2] = np.nan  # no σ where the view did not see it: still a covariance
    sigma[2, 0] = np.nan  # no σ where it did: none
    _, covariance = view_point_covariances(views, pixels, sigma)
    assert np.all(np.isfinite(covariance[[0, 3]])) and np.all(np.isnan(covariance[[1, 2]]))
    two = view_point_covariances(views[:2], pixels[[0], :2], SIGMA_PX)[1]
    np.testing.assert_allclose(covariance[0], two[0], rtol=1e-6)
    with pytest.raises(ValueError, match=r"shape \(N, 3, 2\)"):
        view_point_covariances(views, pixels[:, :2], SIGMA_PX)
    # no target at all: empty answers, not an error
    assert view_point_covariances(views, np.zeros((0, 3, 2)), SIGMA_PX)[1].shape == (0, 3, 3)
    assert view_residual_sigma(views, np.zeros((0, 3, 2)), np.zeros((0, 3)))["n"] == 0
    with pytest.raises(ValueError, match="positive"):
        view_pixel_sigmas(-1.0, 4, 3)
    with pytest.raises(ValueError, match=r"\(4,\) or \(4, 3\)"):
        view_pixel_sigmas(np.ones(5), 4, 3)


def test_residual_sigma_recovers_the_pixel_noise_and_ignores_a_wrong_match():
    """The residuals of 300 targets in 4 cameras (a port each) with σ = 0.3 px of noise give
    σ₀ = 0.3 px within 5 % (its sampling error about 2 %) with nothing stated; beyond a stated
    0.3 px an extra variance within 5 % of the stated one (what the sampling leaves); one
    target's pixel in one view 15 px off changes σ₀ by less than 2 %."""
    rng = np.random.default_rng(31)
    cameras = _ring(4, rng)
    views = [View(c, p) for c, p in zip(cameras, _ports(cameras, "own", rng))]
    points = _targets(rng, 300)
    pixels = _seen_pixels(cameras, [v.port for v in views], points)
    noisy = pixels + rng.normal(0.0, 0.3, pixels.shape)
    found = triangulate_views(views, noisy).points
    alone = view_residual_sigma(views, noisy, found)
    assert abs(alone["sigma0_px"] - 0.3) <= 0.015 and alone["n"] > 250, alone
    stated = view_residual_sigma(views, noisy, found, 0.3)
    assert stated["sigma0_px"] ** 2 <= 0.05 * 0.3 ** 2, stated
    wrong = noisy.copy()
    row = int(np.flatnonzero(np.all(np.isfinite(noisy[:, :, 0]), axis=1))[0])
    wrong[row, 1, 0] += 15.0
    moved = view_residual_sigma(views, wrong, triangulate_views(views, wrong).points)
    assert abs(moved["sigma0_px"] - alone["sigma0_px"]) <= 0.02 * alone["sigma0_px"], moved
