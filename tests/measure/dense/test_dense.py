"""Dense matching through the flat port (measure.dense.match) on analytic speckle pairs.

The pairs come from synth.products.dense_pairs: the paper's rig scaled to 320 x 268 px (f = 143.8 px,
the same field of view), a speckle texture of ~2.5 px blobs on the surface, each pixel the mean
of 4 x 4 refracted sub-pixel rays. The truth of a matched left pixel is the surface point of its
centre ray and that point's exact (Fermat) projection into the right camera. At this image size
one pixel of disparity is ~25 mm of depth at 1 m (0.04 px/mm), so point errors in mm are ~7.6x
those of the full-size rig for the same pixel error.
"""

from __future__ import annotations

import numpy as np
import pytest

from measure import triangulate
from measure.dense.match import match_dense
from measure.dense.warp import PlaneWarp
from measure.geometry.projection import project
from synth.products.dense_pairs import (CylinderSurface, PlaneSurface, SpeckleTexture, render_pair,
                               surface_points)
from synth.scene.rig import paper_rig

SIZE = (320, 268)
SPECKLE_MM = 13.0  # ~2.5 px at 1 m for f = 143.8 px (5.3 mm per px on the surface)


@pytest.fixture(scope="module")
def small_rig():
    return paper_rig(size=SIZE)


@pytest.fixture(scope="module")
def texture():
    return SpeckleTexture.random((-900, 1100, -800, 800), SPECKLE_MM, seed=1)


def _truth(rig, surface):
    """Every left pixel's true right pixel ``(H*W, 2)`` and the overlap mask: both pixels at
    least 7 px (half a window + margin) inside their images."""
    us, vs = np.meshgrid(np.arange(SIZE[0], dtype=float), np.arange(SIZE[1], dtype=float))
    pixels = np.stack([us.ravel(), vs.ravel()], axis=1)
    right = project(rig.right, rig.port, surface_points(rig.left, rig.port, surface, pixels))
    overlap = rig.left.in_image(pixels, 7) & rig.right.in_image(right, 7)
    return right, overlap


def _evaluate(rig, surface, matches, method):
    right, overlap = _truth(rig, surface)
    index = (matches.uv_left[:, 1] * SIZE[0] + matches.uv_left[:, 0]).astype(np.int64)
    error = np.hypot(*(matches.uv_right - right[index]).T)
    points = triangulate(rig, matches.uv_left, matches.uv_right, method).points
    distance = surface.distance(points)
    fraction = overlap[index].sum() / overlap.sum()
    off_surface = np.isnan(error)  # matched where the left ray misses the surface
    assert off_surface.mean() < 0.01
    return fraction, error[~off_surface], distance[~off_surface]


@pytest.fixture(scope="module")
def front_pair(small_rig, texture):
    surface = PlaneSurface.create((0.0, 0.0, 1000.0), (0.0, 0.0, 1.0))
    return surface, render_pair(small_rig, surface, texture)


@pytest.fixture(scope="module")
def front_matches(small_rig, front_pair):
    _, (left, right) = front_pair
    return match_dense(small_rig, left, right, (900.0, 1100.0))


@pytest.mark.parametrize("size", [SIZE, (2448, 2048)])
@pytest.mark.parametrize("model", ["refractive", "pinhole"])
def test_interpolated_warp_matches_exact_map(size, model):
    """The bilinearly interpolated warp map against the exact one (every pixel of the small
    image; every 7th row and column of the full-size one) at three depths. Measured max:
    0.0010 px (small) and 0.0020 px (full size); tolerance 0.004 px, well below the 0.01 px
    the matcher can afford."""
    rig = paper_rig(size=size)
    warp = PlaneWarp(rig, model)
    stride = 1 if size == SIZE else 7
    us, vs = np.meshgrid(np.arange(0, size[0], stride), np.arange(0, size[1], stride))
    pixels = np.stack([us.ravel(), vs.ravel()], axis=1).astype(float)
    origins, directions = warp.water_rays(pixels)
    for depth in (700.0, 1000.0, 1500.0):
        map_u, map_v = warp.right_map(depth)
        points, _ = warp.points_at_depth(origins, directions, depth)
        exact = warp.right_pixels(points)
        error = np.hypot(map_u[vs, us].ravel() - exact[:, 0], map_v[vs, us].ravel() - exact[:, 1])
        assert np.nanmax(error) < 0.004


def test_fronto_parallel_plane(small_rig, front_pair, front_matches):
    """Plane z = 1 m. Measured (2026-12-02, the refinement's fourth-order derivative): 99.3 % of
    the overlap matched, right-pixel error RMS 0.0067 px, max 0.041 px, points RMS 0.16 mm from
    the plane (max 1.1 mm); with Scharr's derivative it was RMS 0.0082 px, max 0.054 px,
    0.20 mm. Tolerances: 97 %, RMS 0.02 px, max 0.15 px, RMS 0.4 mm (about 2-3x the
    measurement)."""
    surface, _ = front_pair
    fraction, error, distance = _evaluate(small_rig, surface, front_matches, "optical_path")
    assert fraction > 0.97
    assert np.sqrt(np.mean(error ** 2)) < 0.02
    assert error.max() < 0.15
    assert np.sqrt(np.mean(distance ** 2)) < 0.4
    assert np.all(front_matches.score >= 0.8)


def test_depth_map_is_the_triangulated_depth(small_rig, front_matches):
    """The depth map holds N·X of the point that triangulating (uv_left, uv_right) gives back
    (the refined depth parameter and uv_right are one and the same answer; measured 4e-12 mm)."""
    m = front_matches
    points = triangulate(small_rig, m.uv_left, m.uv_right, "optical_path").points
    depth = m.depth_map[m.uv_left[:, 1].astype(int), m.uv_left[:, 0].astype(int)]
    assert np.max(np.abs(depth - points @ small_rig.port.normal)) < 1e-6
    assert np.isnan(m.depth_map).sum() == m.depth_map.size - m.score.size
    assert set(m.timings) >= {"warp maps", "remap", "zncc", "refinement"}


def test_pinhole_model_is_measurably_worse(small_rig, front_pair, front_matches):
    """The same pair matched with the port ignored (straight rays, over its own apparent depth
    range 650-900 mm): its epipolar curves miss the refracted ones, so few windows correlate.
    Measured: 19 % matched (refractive 99 %), right-pixel RMS 0.36 px (refractive 0.007 px).
    Asserted: under half the refractive fraction and over 10x its RMS pixel error."""
    surface, (left, right) = front_pair
    pinhole = match_dense(small_rig, left, right, (650.0, 900.0), model="pinhole")
    fraction_p, error_p, _ = _evaluate(small_rig, surface, pinhole, "regular")
    fraction_r, error_r, _ = _evaluate(small_rig, surface, front_matches, "optical_path")
    assert fraction_p < 0.5 * fraction_r
    assert np.sqrt(np.mean(error_p ** 2)) > 10 * np.sqrt(np.mean(error_r ** 2))


@pytest.mark.parametrize("case", ["tilted", "cylinder"])
def test_slanted_surfaces(small_rig, texture, case):
    """A plane tilted 20 degrees about y, and a vertical cylinder of radius 600 mm whose near
    side is at 900 mm. The square windows assume a constant depth across them, which these
    surfaces break (at 5 mm per px an 11 px window spans up to ~20 mm of depth), and a few
    wrong peaks pass min_score (max errors 2.3 / 2.1 px). Measured (tilted / cylinder,
    2026-12-02, the refinement's fourth-order derivative and its damping of steps that reverse
    the previous one): 98.1 % / 79.9 % matched (92.7 % / 67.5 % before the damping), median
    right-pixel error 0.030 / 0.023 px, 95th percentile 0.095 / 0.123 px, median point distance
    0.72 / 0.47 mm (Scharr's derivative: 98.0 % / 79.0 %, 0.031 / 0.024 px, 0.097 / 0.125 px,
    0.74 / 0.48 mm). Tolerances: 94 % / 72 %, median 0.06 px, 95th percentile 0.2 px, median
    1.5 mm. Matches whose left ray misses the cylinder (windows across its silhouette):
    measured 0.64 %, asserted < 1 % (in ``_evaluate``). With the windows tilted with the surface
    (2026-12-03, the default): 98.1 % / 82.6 % matched, median 0.0054 / 0.0112 px, 95th
    percentile 0.021 / 0.037 px, median point distance 0.128 / 0.225 mm."""
    if case == "tilted":
        tilt = np.radians(20.0)
        surface = PlaneSurface.create((100.0, 0.0, 1000.0), (np.sin(tilt), 0.0, np.cos(tilt)))
        depth_range, least_fraction = (650.0, 1400.0), 0.94
    else:
        surface = CylinderSurface.create((100.0, 0.0, 1500.0), 600.0)
        depth_range, least_fraction = (850.0, 1450.0), 0.72
    left, right = render_pair(small_rig, surface, texture)
    matches = match_dense(small_rig, left, right, depth_range)
    fraction, error, distance = _evaluate(small_rig, surface, matches, "optical_path")
    assert fraction > least_fraction
    assert np.median(error) < 0.06
    assert np.percentile(error, 95) < 0.2
    assert np.median(distance) < 1.5


def _depth_errors(rig, surface, matches):
    """The matched pixels' depth errors (mm along the port normal) against the surface point
    of each left pixel's centre ray."""
    truth = surface_points(rig.left, rig.port, surface, matches.uv_left) @ rig.port.normal
    depth = matches.depth_map[matches.uv_left[:, 1].astype(int), matches.uv_left[:, 0].astype(int)]
    error = depth - truth
    return error[np.isfinite(error)]


def test_slanted_windows_follow_a_tilted_plane(small_rig, texture, front_pair, front_matches):
    """Windows that tilt with the surface (the default) against fronto-parallel ones
    (``slanted=False``), both against the truth. On the plane tilted 20° about y a
    fronto-parallel window's depth is its texture-weighted mean over the window (up to ~20 mm
    across it at 5 mm per px); the slanted window's plane removes that. Measured (2026-12-03):
    median |depth error| 0.741 → 0.131 mm (5.7x), 95th percentile 2.67 → 0.66 mm, 98.2 → 98.1 %
    matched; the fronto-parallel plane 0.108 → 0.105 mm median, RMS 0.162 → 0.159 mm.
    Asserted: the tilted plane's median falls over 3x and its 95th percentile over 2x, and the
    fronto-parallel plane's median and RMS are not worse (2 % allowed for the rounding of the
    filters' sums)."""
    tilt = np.radians(20.0)
    surface = PlaneSurface.create((100.0, 0.0, 1000.0), (np.sin(tilt), 0.0, np.cos(tilt)))
    left, right = render_pair(small_rig, surface, texture)
    slanted = np.abs(_depth_errors(small_rig, surface, match_dense(small_rig, left, right,
                                                                   (650.0, 1400.0))))
    fronto = np.abs(_depth_errors(small_rig, surface, match_dense(
        small_rig, left, right, (650.0, 1400.0), slanted=False)))
    assert np.median(slanted) < np.median(fronto) / 3
    assert np.percentile(slanted, 95) < np.percentile(fronto, 95) / 2
    front, (left, right) = front_pair
    flat = np.abs(_depth_errors(small_rig, front, front_matches))
    flat_fronto = np.abs(_depth_errors(small_rig, front, match_dense(
        small_rig, left, right, (900.0, 1100.0), slanted=False)))
    assert np.median(flat) <= 1.02 * np.median(flat_fronto)
    assert np.sqrt(np.mean(flat ** 2)) <= 1.02 * np.sqrt(np.mean(flat_fronto ** 2))


def test_windows_across_a_silhouette_are_rejected(small_rig, texture, monkeypatch):
    """A cylinder of radius 300 mm (near side at 900 mm) against a black background: the
    windows of background pixels near its silhouette hold only the cylinder's texture, on one
    side, and match its edge. Whether a left ray meets the cylinder is analytic. Measured
    (2026-12-06): with no limit on the texture offset, 1,054 of 21,671 matches are off the
    cylinder, 470 of them 4–6 px outside its image (distance transform); with
    :data:`MAX_TEXTURE_OFFSET` (a quarter of the 11-px window), 559 of 21,056, none farther out
    than 3 px, 120 matches on the cylinder lost (0.6 %), the on-cylinder point RMS 0.745 →
    0.734 mm. Asserted: none beyond 3 px with the limit, over 200 without; on-cylinder matches
    lose at most 2 %."""
    from scipy import ndimage
    import measure.dense.match as dense_match
    surface = CylinderSurface.create((0.0, 0.0, 1200.0), 300.0)
    left, right = render_pair(small_rig, surface, texture)
    width, height = SIZE
    us, vs = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    hit = np.isfinite(surface_points(small_rig.left, small_rig.port, surface, np.stack(
        [us.ravel(), vs.ravel()], axis=1))).all(axis=1).reshape(height, width)
    outside_px = ndimage.distance_transform_edt(~hit)

    def off_and_on(matches):
        cols, rows = matches.uv_left.astype(int).T
        return outside_px[rows, cols], hit[rows, cols].sum()

    limited, on_limited = off_and_on(match_dense(small_rig, left, right, (850.0, 1250.0)))
    monkeypatch.setattr(dense_match, "MAX_TEXTURE_OFFSET", np.inf)
    unlimited, on_unlimited = off_and_on(match_dense(small_rig, left, right, (850.0, 1250.0)))
    assert limited.max() <= 3
    assert (unlimited > 3).sum() > 200
    assert on_limited >= 0.98 * on_unlimited


@pytest.mark.parametrize("change, message", [
    (dict(right=np.zeros((268, 321))), "right is 321x268 px but the camera is 320x268"),
    (dict(left=np.zeros((268, 320, 3))), "left must be a 2D"),
    (dict(depth_range=(1100.0, 900.0)), "near < far"),
    (dict(depth_range=(900.0, np.inf)), "finite"),
    (dict(depth_range=(50.0, 900.0)), "not beyond the port"),
    (dict(depth_range=(900.0,)), "depth_range must be (near, far)"),
    (dict(model="fisheye"), "model must be one of"),
    (dict(window=10), "window must be an odd"),
    (dict(noise_sigma=0.0), "noise_sigma must be a positive"),
])
def test_bad_inputs_are_one_line_errors(small_rig, change, message):
    arguments = dict(left=np.zeros((268, 320), np.uint8), right=np.zeros((268, 320), np.uint8),
                     depth_range=(900.0, 1100.0))
    arguments.update(change)
    options = {k: arguments.pop(k) for k in ("model", "window", "noise_sigma") if k in arguments}
    with pytest.raises(ValueError) as caught:
        match_dense(small_rig, arguments["left"], arguments["right"], arguments["depth_range"],
                    **options)
    assert message in str(caught.value)
    assert "\n" not in str(caught.value)


def test_featureless_pair_matches_nothing(small_rig):
    """Flat images: every window has zero variance, nothing is matched, nothing raises."""
    flat = np.full((268, 320), 100, np.uint16)
    matches = match_dense(small_rig, flat, flat, (900.0, 1100.0))
    assert matches.score.size == 0 and np.all(np.isnan(matches.depth_map))


#: The Monte Carlo pair: the paper's rig at 160 x 134 px (f = 71.9 px; a quarter of the sweep's
#: work of the 320 px pair) and speckle twice as large in mm (the same ~2.5 px blobs).
MC_SIZE, MC_TRIALS, MC_NOISE = (160, 134), 50, 0.02


@pytest.fixture(scope="module")
def monte_carlo():
    """``MC_TRIALS`` matches of one analytic pair (a plane at 1 m tilted 11° about x) with
    independent Gaussian noise of σ_n = ``MC_NOISE`` (texture 0.5 ± 0.15) in both images, the
    σ_n stated; the left pixels matched in every trial, their right pixels ``(T, N, 2)``, the
    predicted σ ``(T, N)``, curve directions ``(N, 2)`` and the estimated σ_n of each trial
    (a second match with σ_n left to the matcher)."""
    rig = paper_rig(size=MC_SIZE)
    texture = SpeckleTexture.random((-900, 1100, -800, 800), 2 * SPECKLE_MM, seed=3)
    surface = PlaneSurface.create((0.0, 0.0, 1000.0), (0.0, 0.2, 1.0))
    left, right = render_pair(rig, surface, texture)
    rng = np.random.default_rng(11)
    width, height = MC_SIZE
    uv = np.full((MC_TRIALS, height, width, 2), np.nan)
    sigma = np.full((MC_TRIALS, height, width), np.nan)
    direction = np.full((height, width, 2), np.nan)
    estimated = []
    for trial in range(MC_TRIALS):
        noisy = [image + rng.normal(0.0, MC_NOISE, image.shape).astype(np.float32)
                 for image in (left, right)]
        matches = match_dense(rig, *noisy, (850.0, 1150.0), noise_sigma=MC_NOISE,
                              roi=(30, 25, 130, 110))
        cols, rows = matches.uv_left.astype(int).T
        uv[trial, rows, cols] = matches.uv_right
        sigma[trial, rows, cols] = matches.sigma_px
        direction[rows, cols] = matches.curve_direction
        if trial < 3:  # σ_n left to the matcher: the noise level and the σ it gives
            free = match_dense(rig, *noisy, (850.0, 1150.0), roi=(30, 25, 130, 110))
            assert free.noise_source == "estimated per intensity"
            np.testing.assert_array_equal(free.uv_right, matches.uv_right)
            estimated.append((free.noise_sigma, np.median(free.sigma_px / matches.sigma_px)))
    every = np.all(np.isfinite(uv[..., 0]), axis=0)
    return uv[:, every], sigma[:, every], direction[every], np.array(estimated)[:, 0], \
        np.array(estimated)[:, 1]


def test_matching_sigma_against_monte_carlo(monte_carlo):
    """The predicted σ of the right pixel along the epipolar curve against the spread of
    ``MC_TRIALS`` noisy matches (module fixture ``monte_carlo``), pooled over the pixels
    matched in every trial: the deviations from each pixel's mean over the trials, divided by
    the predicted σ and by sqrt((T − 1) / T), have a standard deviation of 1 when the σ is
    right. Measured (2026-12-02): 1.067 over 8,500 pixels × 50 trials (fraction beyond 1.96:
    0.067; median predicted σ 0.024 px); the spread across the curve is nil (the matcher moves
    along it only: at most 4.2e-5 px). Asserted: 0.85-1.15, across < 5e-4 px."""
    uv, sigma, direction, _, _ = monte_carlo
    trials = uv.shape[0]
    deviation = uv - uv.mean(axis=0)
    along = np.einsum("tnk,nk->tn", deviation, direction)
    across = np.einsum("tnk,nk->tn", deviation, np.stack([-direction[:, 1], direction[:, 0]], 1))
    z = along / sigma / np.sqrt((trials - 1) / trials)
    assert uv.shape[1] > 3000
    assert 0.85 < z.std() < 1.15
    assert np.abs(across).max() < 5e-4
    np.testing.assert_allclose(np.hypot(*direction.T), 1.0, atol=1e-9)


def test_estimated_image_noise(monte_carlo):
    """σ_n left to the matcher (the noise level function from the matched pixels' residuals by
    intensity) against the σ_n added, and the σ it gives against the σ of the stated σ_n (the
    same matches). It counts the model's misfit too (the noise-free pair's residual), so it
    lies a little above. Measured (2026-12-02) over the first 3 trials: σ_n 1.01-1.02 × the
    added one; the σ per pixel, median ratio to the stated one's 1.018-1.023. Asserted: 0.95-1.2
    both."""
    estimated, ratio = monte_carlo[3:]
    assert np.all((estimated > 0.95 * MC_NOISE) & (estimated < 1.2 * MC_NOISE))
    assert np.all((ratio > 0.95) & (ratio < 1.2))
