"""One triangulation entry for any number of views (measure.stereo.rig_triangulation): ideal
pixels of the Fermat forward model in rings of 3–13 cameras with every port mix come back to
≤ 1e-9 mm by both N-view methods; a Rig of two gives the pair methods' results exactly; under
pixel noise the N-view reprojection point is the maximum-likelihood one.

Criterion of the Monte Carlo test (the one of tests/measure/stereo/test_uncertainty.py): per
axis, the RMS of the normalized errors ``(estimate − truth) / σ_ML`` pooled over points and
trials is 1 within 10 %, ``σ_ML`` from the maximum-likelihood covariance ``σ² (JᵀJ)⁻¹`` (J the
exact forward model's derivative over the views that saw the point); its sampling error is
about ``1/sqrt(2·N·T)``, under 1.5 % here."""

from __future__ import annotations

import numpy as np
import pytest

from measure import Rig, triangulate, triangulate_rig
from measure.geometry.camera import BROWN_CONRADY, FISHEYE, Camera
from measure.geometry.dome import DomePair, DomePort
from measure.geometry.port import FlatPort
from measure.geometry.projection import project
from measure.reasons import Reason
from measure.stereo.multiview import View
from measure.stereo.rig_triangulation import reprojection_views
from measure.stereo.uncertainty import CHI2_3_95, mahalanobis_squared
from tests.measure.stereo.test_multiview import GLASS, SIZE, _ports, _ring, _targets

TRIALS = 200


def _seen_pixels(views, points):
    """Each view's ideal pixels of ``points``; NaN outside its image."""
    pixels = np.stack([project(v.camera, v.port, points) for v in views], axis=1)
    inside = (pixels[..., 0] >= -0.5) & (pixels[..., 0] <= SIZE[0] - 0.5) & (
        pixels[..., 1] >= -0.5) & (pixels[..., 1] <= SIZE[1] - 0.5)
    pixels[~inside] = np.nan
    return pixels


def _views(count, mix, rng, model=BROWN_CONRADY):
    cameras = _ring(count, rng, model)
    return [View(c, p) for c, p in zip(cameras, _ports(cameras, mix, rng))]


@pytest.mark.parametrize("method", ["optical_path", "reprojection"])
@pytest.mark.parametrize("count,mix,model", [(3, "own", BROWN_CONRADY), (3, "shared", BROWN_CONRADY),
                                             (4, "dome", BROWN_CONRADY), (5, "air", BROWN_CONRADY),
                                             (7, "mixed", BROWN_CONRADY),
                                             (13, "mixed", BROWN_CONRADY), (4, "mixed", FISHEYE)])
def test_ideal_pixels_come_back_exactly(count, mix, model, method):
    rng = np.random.default_rng(count)
    views = _views(count, mix, rng, model)
    points = _targets(rng)
    pixels = _seen_pixels(views, points)
    seen = np.isfinite(pixels[..., 0]).sum(axis=1)
    result = triangulate_rig(views, pixels, method)
    assert result.method == method
    assert np.array_equal(result.valid, seen >= 2)
    assert (seen >= 2).mean() > 0.9
    np.testing.assert_array_equal(result.views[result.valid], seen[result.valid])
    assert np.all(result.reason[seen < 2] == Reason.TOO_FEW_VIEWS)
    assert np.all(np.isnan(result.points[~result.valid]))
    error = np.linalg.norm(result.points[result.valid] - points[result.valid], axis=1)
    assert error.max() <= 1e-9


def test_a_rig_gives_its_views():
    """A Rig of N (here 7, ports a rig accepts) is triangulated through its views."""
    rng = np.random.default_rng(7)
    cameras = _ring(7, rng)
    rig = Rig(cameras, _ports(cameras, "mixed", rng))
    points = _targets(rng)
    pixels = _seen_pixels(rig.views(), points)
    for method in ("optical_path", "reprojection"):
        by_rig = triangulate_rig(rig, pixels, method)
        by_views = triangulate_rig(rig.views(), pixels, method)
        for name in ("points", "gap", "views", "used", "reason"):
            np.testing.assert_array_equal(getattr(by_rig, name), getattr(by_views, name))
        assert by_rig.valid.mean() > 0.9


def _pair_rig(rng, kind="flat"):
    """A pair (the left camera at the origin) behind one flat port (``kind`` "flat") or a
    decentred dome each ("dome"), with its ideal pixels."""
    left, right = _ring(2, rng)
    to_left = lambda X: (X - left.center) @ left.R  # noqa: E731
    cameras = (Camera(left.K, SIZE, dist=left.dist),
               Camera(right.K, SIZE, dist=right.dist, R=left.R.T @ right.R,
                      t=to_left(right.center[None])[0]))
    if kind == "dome":
        port = DomePair(*(DomePort(c.center + rng.normal(0, 1.5, 3), 60.0, 9.0, GLASS)
                          for c in cameras))
    else:
        port = FlatPort(left.R.T @ np.array([0.0, 0.0, 1.0]), 520.0 - left.center[2], (8.0,),
                        GLASS)
    rig = Rig.stereo_pair(*cameras, port)
    points = to_left(_targets(rng, 200))
    return rig, points, _seen_pixels(rig.views(), points)


@pytest.mark.parametrize("kind", ["flat", "dome"])
@pytest.mark.parametrize("method", ["optical_path", "su", "regular", "reprojection"])
def test_a_rig_of_two_gives_the_pair_methods_exactly(method, kind):
    rng = np.random.default_rng(22)
    rig, _, pixels = _pair_rig(rng, kind)
    pixels = pixels + rng.normal(0.0, 0.3, pixels.shape)  # rays that do not meet
    pixels[:5, 1] = np.nan  # seen by the left camera only
    both = np.isfinite(pixels[..., 0]).all(axis=1)
    assert both.sum() > 150
    pair = triangulate(rig, pixels[:, 0], pixels[:, 1], method)
    entry = triangulate_rig(rig, pixels, method)
    np.testing.assert_array_equal(entry.points, pair.points)
    np.testing.assert_array_equal(entry.gap, pair.gap)
    np.testing.assert_array_equal(entry.reason[both], pair.reason[both])
    assert np.all(entry.reason[~both] == Reason.TOO_FEW_VIEWS)
    np.testing.assert_array_equal(entry.views, np.where(both, 2, 1))
    assert entry.method == method


def _cost_gradient(views, pixels, points):
    """``Jᵀr`` (px²/mm) of the reprojection cost of ``points`` over all views."""
    gradient = np.zeros_like(points)
    for v, view in enumerate(views):
        predicted, d_point = project(view.camera, view.port, points, jacobian=True)
        gradient += np.einsum("nki,nk->ni", d_point, predicted - pixels[:, v])
    return gradient


def test_the_view_reprojection_of_two_views_is_the_pairs():
    """The batched N-view fit on a pair's two views reaches the pair's reprojection point
    (scipy's least_squares on the whole batch) within 1e-8 mm, a stationary point of the cost
    to 1e-9 px²/mm (it stops where the Gauss–Newton step is under 1e-12 of the distance,
    ~2e-9 mm)."""
    rng = np.random.default_rng(23)
    rig, _, pixels = _pair_rig(rng)
    pixels = pixels + rng.normal(0.0, 0.3, pixels.shape)
    start = triangulate(rig, pixels[:, 0], pixels[:, 1]).points
    pair = triangulate(rig, pixels[:, 0], pixels[:, 1], "reprojection").points
    points, converged = reprojection_views(rig.views(), pixels, start)
    ok = np.all(np.isfinite(pair), axis=1)
    assert ok.mean() > 0.9 and np.all(converged[ok])
    assert np.abs(points[ok] - pair[ok]).max() <= 1e-8
    assert np.abs(_cost_gradient(rig.views(), pixels[ok], points[ok])).max() <= 1e-9
    # and it moved: the optical-path start is not the reprojection point
    assert np.abs(start[ok] - pair[ok]).max() > 1e-3


@pytest.mark.parametrize("count,mix,sigma", [(3, "shared", 0.1), (4, "own", 0.3),
                                             (5, "mixed", 0.2)])
def test_noisy_reprojection_is_the_maximum_likelihood_point(count, mix, sigma):
    rng = np.random.default_rng(200 + count)
    views = _views(count, mix, rng)
    points = _targets(rng, 60)
    pixels = _seen_pixels(views, points)
    pixels[rng.random(pixels.shape[:2]) < 0.25] = np.nan  # points of 2 … count views
    seen = np.isfinite(pixels[..., 0])
    keep = seen.sum(axis=1) >= 2
    points, pixels, seen = points[keep], pixels[keep], seen[keep]
    n = points.shape[0]
    assert n >= 45
    # the maximum-likelihood covariance σ² (JᵀJ)⁻¹ over each point's views
    normal = np.zeros((n, 3, 3))
    for v, view in enumerate(views):
        _, d_point = project(view.camera, view.port, points, jacobian=True)
        normal[seen[:, v]] += np.einsum("nki,nkj->nij", d_point, d_point)[seen[:, v]]
    covariance = sigma ** 2 * np.linalg.inv(normal)
    noisy = np.tile(pixels, (TRIALS, 1, 1)) + rng.normal(0.0, sigma, (TRIALS * n, count, 2))
    fit = triangulate_rig(views, noisy, "reprojection")
    optical = triangulate_rig(views, noisy, "optical_path")
    assert fit.valid.all() and optical.valid.all()
    errors = fit.points.reshape(TRIALS, n, 3) - points
    optical_errors = optical.points.reshape(TRIALS, n, 3) - points
    rms, optical_rms = (np.sqrt(np.mean(np.sum(e ** 2, axis=2))) for e in (errors,
                                                                          optical_errors))
    assert rms <= optical_rms, (rms, optical_rms)
    sigma_ml = np.sqrt(np.einsum("nii->ni", covariance))
    ratio = np.sqrt(np.mean((errors / sigma_ml) ** 2, axis=(0, 1)))
    assert np.all(np.abs(ratio - 1.0) <= 0.10), ratio
    d2 = mahalanobis_squared(errors.reshape(-1, 3), np.tile(covariance, (TRIALS, 1, 1)))
    assert 0.93 <= np.mean(d2 <= CHI2_3_95) <= 0.97


def test_methods_that_do_not_apply_are_refused():
    rng = np.random.default_rng(3)
    views = _views(3, "own", rng)
    pixels = _seen_pixels(views, _targets(rng, 5))
    for method in ("su", "regular"):
        with pytest.raises(ValueError, match=rf"'{method}'.*3 views"):
            triangulate_rig(views, pixels, method)
    with pytest.raises(ValueError, match="method must be one of"):
        triangulate_rig(views, pixels, "midpoint")
    with pytest.raises(ValueError, match=r"shape \(N, 3, 2\)"):
        triangulate_rig(views, pixels[:, :2], "optical_path")
    # two views that are not a Rig: the view methods only
    with pytest.raises(ValueError, match=r"'su'.*2 views given as View"):
        triangulate_rig(views[:2], pixels[:, :2], "su")
    assert triangulate_rig(views[:2], pixels[:, :2], "reprojection").valid.all()
