"""The levels of a target image: its background and noise, and the threshold that separates
the targets from them — over noise, over a speckled background, or a fraction of the way to the
targets' level (:func:`fractional_threshold`). Stages 1 and 2 of
:func:`measure.images.detect.detect_targets` (its module docs describe them). Image units
throughout (linear radiometry); pixels ``(u, v)`` in OpenCV's convention."""

from __future__ import annotations

import cv2
import numpy as np

#: Percentile of the image taken as the targets' level by :func:`fractional_threshold` (robust
#: to a few hot pixels).
TARGET_LEVEL_PERCENTILE = 99.99
#: A background is speckle when, at the noise threshold, the blobs' levels fall into two
#: populations at least this many decades apart ...
SPECKLE_GAP_DECADES = 0.5
#: ... the faint one outnumbering the bright one by more than this factor ...
SPECKLE_BLOB_RATIO = 2.0
#: ... counting at least this many blobs (a few specks in a clean image change nothing) ...
SPECKLE_MIN_SPECKS = 200
#: ... while the bright blobs are flat-topped: their 90th-percentile pixel is at least this
#: fraction of their peak (median over the bright blobs).
SPECKLE_PLATEAU_RATIO = 0.5
#: Side (px) of the mean filter applied before the speckle is looked for and cut.
SPECKLE_FILTER_PX = 3
#: On a speckled background the threshold is this fraction of the way from the background to
#: the targets' level (the median peak of the bright blobs).
SPECKLE_THRESHOLD_FRACTION = 0.25


#: At most this many pixels are used to estimate the background and the noise.
STATS_SAMPLE_PIXELS = 1 << 18


def fractional_threshold(image, fraction: float) -> float:
    """An absolute threshold (image units) ``fraction`` of the way from the background (the
    image's median) to the targets' level (its :data:`TARGET_LEVEL_PERCENTILE` th percentile).

    For images whose background is not Gaussian noise — e.g. renders of scattering water, where
    the haze is sparse speckle on black and the automatic level (median + k·MAD) is zero."""
    if not (np.isfinite(fraction) and 0 < fraction < 1):
        raise ValueError(f"fraction must be in (0, 1), got {fraction!r}")
    f = np.asarray(image, dtype=np.float32)
    f = f[np.isfinite(f)]
    if f.size == 0:
        raise ValueError("the image has no finite pixel")
    background = float(np.median(f))
    return background + float(fraction) * (float(np.percentile(f, TARGET_LEVEL_PERCENTILE))
                                            - background)


def as_image(image) -> tuple[np.ndarray, bool]:
    """The image as a C-contiguous float32 array, and whether its values are integer levels.

    Finite values beyond float32's range are refused (they would become infinite and the
    target would be lost as 'non-finite')."""
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(
            f"image must be a 2D single-channel array (H, W), got shape {img.shape}; "
            "convert colour images first, e.g. a weighted sum of the linear channels"
        )
    if img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"image must not be empty, got shape {img.shape}")
    if img.dtype == np.bool_:
        img = img.view(np.uint8)
    if not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)):
        raise ValueError(f"image must have an integer or real floating dtype, got {img.dtype}")
    integer = bool(np.issubdtype(img.dtype, np.integer))
    if np.issubdtype(img.dtype, np.floating) and np.finfo(img.dtype).max > np.finfo(np.float32).max:
        with np.errstate(invalid="ignore"):
            largest = np.nanmax(np.abs(np.where(np.isfinite(img), img, 0.0)))
        if largest > np.finfo(np.float32).max:
            raise ValueError(f"image values up to {largest:.3g} exceed float32's range "
                             f"({np.finfo(np.float32).max:.3g}); scale the image first")
    f = np.ascontiguousarray(img, dtype=np.float32)
    return f, integer


def background_and_sigma(f: np.ndarray, integer: bool) -> tuple[float, float]:
    """Background level and noise sigma from a regular subsample of the finite pixels.

    Median and ``1.4826 * MAD``, re-estimated three times on the pixels within 4 sigma of the
    background (this drops the targets, which would otherwise inflate sigma by a few per cent
    per per cent of image they cover). For integer images whose noise is below about one grey
    level, the MAD is quantized (it is 0 when most pixels equal the median), so sigma is then
    the standard deviation of the pixels within ``max(4 sigma, 3)`` levels of the background,
    with Sheppard's correction for rounding (``var - 1/12``).
    """
    step = max(1, int(np.ceil(np.sqrt(f.size / STATS_SAMPLE_PIXELS))))
    sample = f[::step, ::step].ravel()
    sample = sample[np.isfinite(sample)].astype(np.float64)
    if sample.size == 0:
        return 0.0, 0.0
    bg = float(np.median(sample))
    sigma = 1.4826 * float(np.median(np.abs(sample - bg)))
    for _ in range(3):
        if sigma <= 0:
            break
        core = sample[np.abs(sample - bg) <= 4.0 * sigma]
        bg = float(np.median(core))
        sigma = 1.4826 * float(np.median(np.abs(core - bg)))
    if integer and sigma < 1.5:
        core = sample[np.abs(sample - bg) <= max(4.0 * sigma, 3.0)]
        sigma = float(np.sqrt(max(core.var() - 1.0 / 12.0, 0.0)))
    return bg, sigma


def _widest_gap(values: np.ndarray) -> tuple[float, float]:
    """``(split, width)``: the middle and the width of the widest gap between consecutive
    sorted ``values`` above their median (the speckle's levels are many and continuous, the
    targets' few and decades above them: a class-variance split such as Otsu's lands inside
    the speckle when it outnumbers the targets a hundred to one)."""
    upper = np.sort(values[values >= np.median(values)])
    if upper.size < 2:
        return (float(upper[0]) if upper.size else 0.0), 0.0
    gaps = np.diff(upper)
    k = int(np.argmax(gaps))
    return 0.5 * float(upper[k] + upper[k + 1]), float(gaps[k])


def _blob_levels(f, labels, n_lab, quantiles):
    """``(len(quantiles), n_lab - 1)``: each quantile's pixel value (0: smallest, 1: the peak)
    of each blob (labels ``1 … n_lab - 1``), from one sort of the blobs' pixels."""
    idx = np.flatnonzero(labels)
    lab = labels.ravel()[idx]
    val = f.ravel()[idx]
    order = np.lexsort((val, lab))
    lab, val = lab[order], val[order]
    blobs = np.arange(1, n_lab)
    start = np.searchsorted(lab, blobs)
    end = np.searchsorted(lab, blobs, side="right")
    pick = start + np.floor(np.asarray(quantiles, float)[:, None] * (end - start - 1))
    return val[np.clip(pick.astype(np.int64), 0, max(val.size - 1, 0))]


def _speckle_threshold(f, original, bg, thr, min_area):
    """The threshold on a speckled background (module docs), or None when the background is
    not speckle. ``f`` is the image whose blobs are looked at (the averaged one); the bright
    blobs' plateau is measured on ``original``, where a firefly is a spike."""
    mask = (f > np.float32(thr)).view(np.uint8)
    n_lab, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8,
                                                                ltype=cv2.CV_32S)
    if n_lab - 1 < SPECKLE_MIN_SPECKS:
        return None
    large = stats[1:, cv2.CC_STAT_AREA] >= min_area
    if int(large.sum()) < SPECKLE_MIN_SPECKS:
        return None
    peak = _blob_levels(f, labels, n_lab, [1.0])[0][large] - bg
    log_peak = np.log10(np.maximum(peak, np.finfo(np.float32).tiny))
    split, width = _widest_gap(log_peak)
    bright = log_peak > split
    faint = peak.size - int(bright.sum())
    if (width < SPECKLE_GAP_DECADES or not bright.any() or faint < SPECKLE_MIN_SPECKS
            or faint <= SPECKLE_BLOB_RATIO * bright.sum()):
        return None
    spike, plateau = _blob_levels(original, labels, n_lab, [1.0, 0.9])[:, large][:, bright]
    floor = float(np.median(original))
    if np.median((plateau - floor) / np.maximum(spike - floor, 1e-30)) < SPECKLE_PLATEAU_RATIO:
        return None
    return bg + SPECKLE_THRESHOLD_FRACTION * float(np.median(peak[bright]))


def _noise_threshold(f, bg, sigma, integer, k_sigma) -> float:
    """``background + max(k_sigma * sigma, floor)`` (module docs, stage 2)."""
    if integer:
        floor = 0.5
    else:
        top = float(f.max()) - bg
        floor = 1e-6 * top if top > 0 else 0.0
    return bg + max(k_sigma * sigma, floor)


def _speckle_levels(f, min_area, k_sigma):
    """``(filtered image, threshold)`` on a speckled background, or None (module docs)."""
    filtered = cv2.blur(f, (SPECKLE_FILTER_PX, SPECKLE_FILTER_PX))
    bg, sigma = background_and_sigma(filtered, False)
    noise_threshold = _noise_threshold(filtered, bg, sigma, False, k_sigma)
    threshold = _speckle_threshold(filtered, f, bg, noise_threshold, min_area)
    return None if threshold is None else (filtered, threshold)


def image_levels(f, integer, background, threshold, k_sigma, min_area=4, floor_fraction=0.0):
    """Stage 1-2: background, noise sigma, threshold (image units) and the rule that set it;
    non-finite pixels set to the background. Returns ``(f, bg, sigma, thr, rule, mask_image)``
    where ``mask_image`` is the image the threshold applies to (``f``, or its average on a
    speckled background)."""
    finite = np.isfinite(f)
    bg, sigma = background_and_sigma(f, integer)
    if background is not None:
        bg = float(background)
        if not np.isfinite(bg):
            raise ValueError(f"background must be finite, got {background!r}")
    if not bool(finite.all()):
        f = np.where(finite, f, np.float32(bg))
    if threshold is None:
        thr, rule, mask_image = _noise_threshold(f, bg, sigma, integer, k_sigma), "noise", f
        speckle = _speckle_levels(f, min_area, k_sigma)
        if speckle is not None and speckle[1] > thr:
            (mask_image, thr), rule = speckle, "speckle"
        if floor_fraction > 0:
            level = float(np.percentile(f, TARGET_LEVEL_PERCENTILE))
            floor = bg + floor_fraction * (level - bg)
            if floor > thr:
                thr, rule, mask_image = floor, "floor", f
    else:
        thr, rule, mask_image = float(threshold), "given", f
        if not np.isfinite(thr):
            raise ValueError(f"threshold must be finite, got {threshold!r}")
    return f, bg, sigma, thr, rule, mask_image
