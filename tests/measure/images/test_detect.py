"""Tests of measure.images.detect: sub-pixel centroids of anti-aliased disks and blob rejection.

Every image is synthesized here: uniform disks at random sub-pixel centres, rendered with
16 x 16 sub-samples per pixel (pixel coverage), so the true centre of each disk is known.
Pixel convention: OpenCV, integer coordinates are pixel centres.
"""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from measure.images.detect import REJECTION_REASONS, Detections, detect_targets

SUBSAMPLES = 16


def render_disks(shape, centers, radii, amps, aspect=1.0, background=0.0):
    """Float64 image of uniform disks (ellipses with ``aspect`` = u-axis / v-axis if != 1).

    Pixel ``(u, v)`` covers ``[u - 0.5, u + 0.5) x [v - 0.5, v + 0.5)``; its value is the
    fraction of its 16 x 16 sub-sample centres inside the shape, times the amplitude.
    Disks are added (overlapping disks add up, like two emitters seen through each other).
    """
    H, W = shape
    img = np.full(shape, float(background))
    off = (np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES - 0.5
    for (u, v), r, a in zip(np.asarray(centers, float), np.broadcast_to(radii, len(centers)),
                            np.broadcast_to(amps, len(centers))):
        ru = r * aspect
        u0, u1 = max(int(np.floor(u - ru)) - 1, 0), min(int(np.ceil(u + ru)) + 2, W)
        v0, v1 = max(int(np.floor(v - r)) - 1, 0), min(int(np.ceil(v + r)) + 2, H)
        if u0 >= u1 or v0 >= v1:
            continue
        du2 = ((np.arange(u0, u1)[:, None] + off - u) / ru) ** 2  # (nu, ss)
        dv2 = ((np.arange(v0, v1)[:, None] + off - v) / r) ** 2  # (nv, ss)
        inside = (dv2[:, None, :, None] + du2[None, :, None, :]) <= 1.0
        img[v0:v1, u0:u1] += a * inside.mean(axis=(2, 3))
    return img


def random_centers(rng, shape, n, margin=12.0, min_sep=20.0):
    """``n`` random sub-pixel centres at least ``min_sep`` apart and ``margin`` from the edges."""
    H, W = shape
    pts = []
    while len(pts) < n:
        p = rng.uniform([margin, margin], [W - 1 - margin, H - 1 - margin])
        if not pts or np.min(np.hypot(*(np.asarray(pts) - p).T)) >= min_sep:
            pts.append(p)
    return np.asarray(pts)


def centroid_errors(det: Detections, truth):
    """Distance from every true centre to the nearest detection, and that detection's index."""
    dist, j = cKDTree(det.centers).query(truth)
    return dist, j


def to_uint(img, dtype):
    info = np.iinfo(dtype)
    return np.clip(np.round(img), info.min, info.max).astype(dtype)


@pytest.fixture(scope="module")
def field():
    """120 disks, radius 3..6 px, amplitude 1000 over a background of 100, noise sigma 1."""
    rng = np.random.default_rng(1234)
    shape = (384, 480)
    centers = random_centers(rng, shape, 120)
    radii = rng.uniform(3.0, 6.0, len(centers))
    clean = render_disks(shape, centers, radii, 1000.0, background=100.0)
    return shape, centers, radii, clean


# ----------------------------------------------------------------------------- accuracy


def test_centroid_accuracy_low_noise_uint16(field):
    shape, centers, radii, clean = field
    rng = np.random.default_rng(100)
    img = to_uint(clean + rng.normal(0.0, 1.0, shape), np.uint16)
    det = detect_targets(img)
    assert det.n_found == len(centers)
    assert det.n_rejected == 0
    dist, j = centroid_errors(det, centers)
    assert len(np.unique(j)) == len(centers)  # one detection per disk
    rms, worst = np.sqrt(np.mean(dist**2)), dist.max()
    # Measured: RMS 0.0031 px, max 0.0066 px (noise-free float64: RMS 0.0030, max 0.0063).
    # The residual is the pixel-sampling bias of the intensity centroid of a uniform disk
    # (amplitude ~ |J1(2 pi r)| / (pi^2 r), a few thousandths of a pixel for r = 3..6).
    assert rms <= 0.02
    assert worst <= 0.06
    # no systematic shift (a half-pixel convention error would show here). Measured 5e-4.
    assert np.all(np.abs((det.centers[j] - centers).mean(axis=0)) < 0.002)


def test_centroid_accuracy_noisy(field):
    shape, centers, radii, clean = field
    rng = np.random.default_rng(101)
    img = clean + rng.normal(0.0, 20.0, shape)  # peak SNR 50
    det = detect_targets(img)
    assert det.n_found == len(centers)
    dist, _ = centroid_errors(det, centers)
    # Measured: RMS 0.0156 px, max 0.042 px (noise-limited); sigma estimated 20.06.
    assert np.sqrt(np.mean(dist**2)) <= 0.03
    assert dist.max() <= 0.08
    assert det.noise_sigma == pytest.approx(20.0, rel=0.05)


def test_window_includes_faint_rim(field):
    """With a high threshold, only the grown window keeps the centroid unbiased."""
    shape, centers, radii, clean = field
    rng = np.random.default_rng(102)
    img = clean + rng.normal(0.0, 1.0, shape)
    high = 100.0 + 600.0  # 60 % of the disk amplitude above the background
    with_rim, _ = centroid_errors(detect_targets(img, threshold=high), centers)
    core_only, _ = centroid_errors(detect_targets(img, threshold=high, window_pad=0), centers)
    # Measured: RMS 0.0030 px with the default window against 0.070 px (max 0.17 px) on the
    # thresholded pixels only.
    assert np.sqrt(np.mean(with_rim**2)) <= 0.01
    assert np.sqrt(np.mean(core_only**2)) >= 0.03


@pytest.mark.parametrize(
    "dtype, background, amplitude, sigma",
    [
        (np.uint8, 10.0, 200.0, 0.5),
        (np.uint16, 200.0, 30000.0, 30.0),
        (np.float32, 0.01, 1.0, 0.001),
        (np.float64, 0.0, 1.0, 0.0),  # noise-free, exactly black background
    ],
)
def test_dtypes(dtype, background, amplitude, sigma):
    rng = np.random.default_rng(7)
    shape = (200, 260)
    centers = random_centers(rng, shape, 40)
    radii = rng.uniform(3.0, 6.0, len(centers))
    img = render_disks(shape, centers, radii, amplitude, background=background)
    img = img + rng.normal(0.0, sigma, shape) if sigma else img
    img = to_uint(img, dtype) if np.issubdtype(dtype, np.integer) else img.astype(dtype)
    det = detect_targets(img)
    assert det.n_found == len(centers)
    assert det.n_rejected == 0
    dist, _ = centroid_errors(det, centers)
    # Measured RMS / max (px): uint8 0.0038 / 0.0093, uint16 0.0030 / 0.0064,
    # float32 0.0030 / 0.0064, float64 noise-free 0.0030 / 0.0066. Sigma estimates: 0.497
    # (uint8: quantized, MAD would say 0), 29.65, 0.000998, 0.
    assert np.sqrt(np.mean(dist**2)) <= 0.02
    assert dist.max() <= 0.06
    assert det.background == pytest.approx(background, abs=0.1 * sigma + 1e-9)
    assert det.noise_sigma == pytest.approx(sigma, rel=0.1, abs=1e-12)
    assert det.centers.dtype == np.float64 and det.centers.shape == (len(centers), 2)


def test_elongated_single_target_is_not_merged():
    """A flat port stretches targets radially by up to ~1.3 at the image edge: keep them."""
    rng = np.random.default_rng(3)
    shape = (160, 200)
    centers = random_centers(rng, shape, 12, min_sep=25.0)
    img = render_disks(shape, centers, 4.0, 1000.0, aspect=1.35) + rng.normal(0, 1.0, shape)
    det = detect_targets(img)
    assert det.n_found == 12 and det.n_rejected == 0
    assert np.all((det.elongation > 1.25) & (det.elongation < 1.45))
    dist, _ = centroid_errors(det, centers)
    assert dist.max() <= 0.06


# ----------------------------------------------------------------------------- rejection


def test_rejections_exact_counts():
    rng = np.random.default_rng(11)
    H, W = 240, 320
    r, amp = 4.5, 1000.0
    good = np.array([[40.3, 40.7], [100.1, 40.2], [160.6, 40.5], [220.2, 41.1], [280.4, 39.8],
                     [40.6, 120.3], [100.2, 119.6], [160.4, 120.9], [40.8, 200.4], [100.5, 199.7]])
    ghosts = np.array([[220.3, 120.2], [280.7, 120.6], [160.2, 200.3]])  # 3 % copies
    pair_overlap = np.array([[220.0, 200.0], [220.0 + 1.5 * r, 200.3]])  # centres 1.5 r apart
    pair_touch = np.array([[270.2, 180.0], [270.2 + 1.0, 180.0 + 2.0 * r + 0.2]])  # touching
    cut = np.array([[1.7, 80.4], [150.3, H - 1 - 1.2]])  # cut by the left and bottom borders
    hot = np.array([[10, 160], [300, 10]])  # single hot pixels

    img = render_disks((H, W), np.vstack([good, pair_overlap, pair_touch, cut]), r, amp)
    img += render_disks((H, W), ghosts, r, 0.03 * amp)
    img[hot[:, 1], hot[:, 0]] += 5000.0
    img = to_uint(100.0 + img + rng.normal(0.0, 1.0, (H, W)), np.uint16)

    det = detect_targets(img)
    assert det.rejected == {"small": 2, "border": 2, "ghost": 3, "merged": 2}
    assert det.n_rejected == 9
    assert det.n_found == len(good)
    dist, j = centroid_errors(det, good)
    assert len(np.unique(j)) == len(good) and dist.max() <= 0.02
    assert det.rejected_centers.shape == (9, 2)
    assert sorted(det.rejected_reasons.tolist()) == sorted(
        ["small"] * 2 + ["border"] * 2 + ["ghost"] * 3 + ["merged"] * 2
    )
    ghost_found = det.rejected_centers[det.rejected_reasons == "ghost"]
    assert cKDTree(ghost_found).query(ghosts)[0].max() <= 0.1


def test_every_target_has_a_ghost():
    """Half of the blobs are ghosts: the flux reference must still be the real targets'."""
    rng = np.random.default_rng(5)
    shape = (200, 300)
    centers = random_centers(rng, shape, 12, margin=25.0, min_sep=40.0)
    ghosts = centers + [12.0, 9.0]
    img = render_disks(shape, centers, 4.0, 1000.0) + render_disks(shape, ghosts, 4.0, 30.0)
    det = detect_targets(img + rng.normal(0.0, 1.0, shape))
    assert det.rejected == {"small": 0, "border": 0, "ghost": 12, "merged": 0}
    assert det.n_found == 12


def test_ring_of_merged_targets_is_one_merged_blob():
    """Targets closer than their diameter on a circle merge into one large ring-shaped blob."""
    shape = (200, 200)
    ang = np.linspace(0, 2 * np.pi, 20, endpoint=False)
    ring = np.column_stack([100.2 + 25 * np.cos(ang), 99.7 + 25 * np.sin(ang)])
    singles = np.array([[30.4, 30.6], [170.2, 30.1], [30.7, 170.3], [170.5, 170.8]])
    img = render_disks(shape, np.vstack([ring, singles]), 4.0, 1000.0)
    det = detect_targets(img)
    assert det.rejected["merged"] == 1 and det.n_rejected == 1
    assert det.n_found == 4


# ----------------------------------------------------------------------------- edge cases


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
def test_black_and_constant_images(dtype):
    for value in (0, 7):
        det = detect_targets(np.full((64, 80), value, dtype=dtype))
        assert det.n_found == 0 and det.n_rejected == 0
        assert det.centers.shape == (0, 2) and det.flux.shape == (0,)
        assert det.rejected == {name: 0 for name in REJECTION_REASONS}


def test_noise_only_image_finds_nothing():
    rng = np.random.default_rng(2)
    det = detect_targets(rng.normal(50.0, 3.0, (300, 300)).astype(np.float32))
    assert det.n_found == 0


@pytest.mark.parametrize("shape", [(32, 32, 3), (32, 32, 1), (64,), ()])
def test_non_2d_image_raises(shape):
    with pytest.raises(ValueError, match="image"):
        detect_targets(np.zeros(shape, np.uint8))


def test_sorted_deterministic_labels_and_quality(field):
    shape, centers, radii, clean = field
    rng = np.random.default_rng(103)
    img = clean + rng.normal(0.0, 1.0, shape)
    det = detect_targets(img, return_labels=True)
    again = detect_targets(img, return_labels=True)
    np.testing.assert_array_equal(det.centers, again.centers)
    u, v = det.centers.T
    assert np.all(np.lexsort((u, v)) == np.arange(det.n_found))
    assert det.labels.shape == shape and det.labels.dtype == np.int32
    assert det.labels.min() >= -1 and det.labels.max() == det.n_found
    # label k + 1 lies under centre k
    iu, iv = np.round(det.centers).astype(int).T
    np.testing.assert_array_equal(det.labels[iv, iu], np.arange(1, det.n_found + 1))
    assert np.all((det.quality > 0.9) & (det.quality <= 1.0))  # round and bright
    assert np.all(det.area >= 4) and np.all(det.peak > 900) and np.all(det.flux > 0)
    n = len(centers)
    assert det.flux.shape == det.area.shape == det.peak.shape == det.quality.shape == (n,)
    # flux is the integrated background-subtracted intensity: amplitude * pi r^2
    _, j = centroid_errors(det, centers)
    np.testing.assert_allclose(det.flux[j], 1000.0 * np.pi * radii**2, rtol=0.01)
    assert detect_targets(img).labels is None


def test_speckle_is_recognized_and_a_fractional_threshold_ignores_it_too():
    """Sparse bright speckle on black (a render of scattering water): median + k·MAD is zero
    and every speckle would be a blob. The automatic threshold recognizes the speckle (specks
    outnumber blobs) and rises to a fraction of the targets' level; a given fraction of the
    way to the targets works as well."""
    from measure.images.levels import SPECKLE_THRESHOLD_FRACTION, fractional_threshold

    rng = np.random.default_rng(0)
    image = np.zeros((400, 400), np.float32)
    yy, xx = np.mgrid[:400, :400]
    centres = [(50, 50), (50, 150), (150, 50), (150, 150)]
    for cy, cx in centres:
        image[(yy - cy) ** 2 + (xx - cx) ** 2 <= 36] = 1.0
    speckle = rng.random((400, 400)) < 0.03  # thousands of specks, blobs once averaged 3 x 3
    image[speckle] += rng.uniform(0, 0.3, speckle.sum()).astype(np.float32)
    automatic = detect_targets(image)
    assert automatic.threshold_rule == "speckle" and automatic.n_found == 4
    assert automatic.threshold == pytest.approx(SPECKLE_THRESHOLD_FRACTION * 1.0, abs=0.08)
    np.testing.assert_allclose(sorted(map(tuple, np.round(automatic.centers))),
                               sorted((x, y) for y, x in centres), atol=0.5)
    noise_only = detect_targets(image, k_sigma=5.0, min_area=1000)  # no blob counts as a target
    assert noise_only.threshold_rule == "noise"
    level = fractional_threshold(image, 0.2)
    assert 0.15 < level < 0.25
    found = detect_targets(image, threshold=level)
    assert found.n_found == 4
    np.testing.assert_allclose(sorted(map(tuple, np.round(found.centers))),
                               sorted((x, y) for y, x in centres), atol=0.5)
    with pytest.raises(ValueError, match="fraction"):
        fractional_threshold(image, 1.0)


@pytest.mark.parametrize("aspect", [2.0, 3.0])
def test_oblique_targets_are_accepted_and_touching_pairs_are_not(aspect):
    """A disk seen at 60° (aspect 2) or 70° (aspect 3) is an ellipse without a waist: accepted
    by default; two touching disks and two disks 1.5 radii apart have one: merged."""
    rng = np.random.default_rng(7)
    shape = (200, 320)
    singles = np.array([[40.3, 50.2], [120.7, 50.6], [200.1, 49.8], [280.4, 50.3]])
    pairs = np.array([[60.2, 140.3], [60.2 + 2.05 * 3.0, 140.1],      # touching
                      [200.6, 140.4], [200.6 + 1.5 * 3.0, 140.6]])    # 1.5 radii apart
    img = render_disks(shape, singles, 3.0, 1000.0, aspect=aspect)
    img += render_disks(shape, pairs, 3.0, 1000.0)
    det = detect_targets(img + rng.normal(0.0, 1.0, shape))
    assert det.rejected["merged"] == 2 and det.n_found == 4
    assert np.all(det.elongation > 0.9 * aspect)
    dist, _ = centroid_errors(det, singles)
    assert dist.max() <= 0.05


def test_a_near_target_larger_than_the_others_is_accepted():
    """Targets over a range of depths image at different sizes: one three times the median area
    (no waist) is a target, not a merged blob."""
    from measure.images.detect import MERGE_AREA_RATIO

    rng = np.random.default_rng(8)
    shape = (160, 260)
    centers = np.array([[40.2, 40.6], [100.3, 40.1], [160.8, 40.4], [220.5, 41.0],
                        [70.4, 110.2], [190.6, 110.7]])
    radii = np.array([3.0, 3.0, 3.0, 3.0, 3.0, 5.5])
    img = render_disks(shape, centers, radii, 1000.0) + rng.normal(0.0, 1.0, shape)
    det = detect_targets(img)
    assert det.n_found == 6 and det.n_rejected == 0
    assert det.area.max() > MERGE_AREA_RATIO * np.median(det.area)  # suspicious, no waist


def test_fireflies_on_lit_targets_never_set_the_threshold():
    """Lit targets in scattering water: brightness spread over a factor 4, a few fireflies far
    brighter than any target sitting on them, specks around. The fireflies never set the
    threshold (they are spikes, not plateaus): every target is found, whichever rule holds."""
    rng = np.random.default_rng(12)
    shape = (480, 480)
    grid = np.arange(20, 470, 30, dtype=float)
    centers = np.array([(u + 0.3, v + 0.6) for v in grid for u in grid])  # 225 targets
    brightness = rng.uniform(0.7, 3.0, len(centers))  # within the ghost test's ratio of 5
    img = render_disks(shape, centers, 4.0, brightness)
    img += rng.exponential(0.002, shape)  # haze
    img[rng.random(shape) < 0.01] += 0.05  # isolated specks
    hot = rng.choice(len(centers), 8, replace=False)
    img[np.round(centers[hot, 1]).astype(int), np.round(centers[hot, 0]).astype(int)] += 300.0
    det = detect_targets(img)
    assert det.threshold < brightness.min() and det.n_found == len(centers)


def test_floor_fraction_keeps_jpeg_ringing_out_of_crowded_targets(tmp_path):
    """Disks 3 radii apart on black, stored as an 8-bit sRGB JPEG (quality 90) and decoded back
    to linear: the ringing around each disk is a few per cent of its level and exactly-zero
    background elsewhere, so the noise threshold (half a level above 0) joins neighbours
    through it; ``floor_fraction=0.05`` keeps every disk apart and the centroids within a
    tenth of a pixel (measured: 266 of 266, 0.0072 px RMS; with no floor 15 of 266)."""
    import cv2

    from eval.core.photos import read_photo

    rng = np.random.default_rng(7)
    shape = (240, 320)
    grid = np.stack(np.meshgrid(np.arange(20, 300, 15.0), np.arange(20, 220, 15.0)), -1)
    centers = grid.reshape(-1, 2) + rng.uniform(-0.5, 0.5, (grid.size // 2, 2))
    linear = render_disks(shape, centers, 5.0, 1.0)
    srgb = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)
    path = tmp_path / "disks.jpg"
    assert cv2.imwrite(str(path), np.rint(srgb * 255).astype(np.uint8),
                       [cv2.IMWRITE_JPEG_QUALITY, 90])
    photo = read_photo(path)
    plain = detect_targets(photo)
    floored = detect_targets(photo, floor_fraction=0.05)
    assert floored.threshold_rule == "floor"
    assert len(floored.centers) == len(centers)
    dist, j = centroid_errors(floored, centers)
    assert len(np.unique(j)) == len(centers) and np.sqrt(np.mean(dist ** 2)) < 0.05
    assert plain.threshold < floored.threshold
    assert len(plain.centers) < len(centers) or centroid_errors(plain, centers)[0].max() > 0.5


def test_floor_fraction_is_checked():
    with pytest.raises(ValueError, match="floor_fraction"):
        detect_targets(np.zeros((20, 20)), floor_fraction=1.0)


@pytest.mark.parametrize("angle_deg", [0.0, 30.0, -60.0, 90.0])
def test_the_major_axis_of_an_oblique_disk(angle_deg):
    """``orientation``: the direction of an ellipse's major axis (drawn 8× supersampled at a
    known angle, semi-axes 6 and 3 px), from +u towards +v, within 1°; a round disk's
    elongation stays near 1."""
    import cv2

    s, shape = 8, (60, 80)
    j, i = np.meshgrid(np.arange(shape[1] * s), np.arange(shape[0] * s))
    x, y = (j + 0.5) / s - 40.3, (i + 0.5) / s - 30.6
    a = np.radians(angle_deg)
    along, across = x * np.cos(a) + y * np.sin(a), -x * np.sin(a) + y * np.cos(a)
    fine = ((along / 6.0) ** 2 + (across / 3.0) ** 2 <= 1.0).astype(np.float32) * 1000.0
    image = cv2.resize(fine, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    det = detect_targets(image + np.random.default_rng(2).normal(0, 1.0, shape))
    assert det.n_found == 1 and det.elongation[0] == pytest.approx(2.0, rel=0.1)
    found = np.degrees(det.orientation[0])
    assert abs((found - angle_deg + 90.0) % 180.0 - 90.0) < 1.0, found
