"""Detection of bright disk targets in one image, with sub-pixel intensity centroids.

The images are those of small emissive disks seen through a flat port (rendered or real):
bright blobs on a dark background, linear radiometry, possibly with Monte-Carlo render noise,
faint ghost reflections from inside the glass, targets cut by the image border and, where
targets crowd, several targets merged into one blob. :func:`detect_targets` finds the blobs,
measures each one and rejects the ones whose centroid would not be a target's centre.

Conventions (docs/architecture.md): pixels in OpenCV convention -- integer coordinates are pixel
centres, ``(0, 0)`` is the centre of the top-left pixel; arrays of pixels are ``(N, 2)`` as
``(u, v)`` = (column, row). Only numpy, scipy and OpenCV are used; nothing here looks at ground
truth.

Pipeline
--------
1. **Background and noise.** ``background`` is the median of the image (on a regular subsample
   of at most about 260 000 pixels); the noise ``sigma`` is ``1.4826 * MAD``, both
   re-estimated after clipping at 4 sigma (see :func:`measure.images.levels.background_and_sigma`,
   which also handles integer images whose noise is below one grey level). This assumes the targets cover well
   under half of the image and that the background is uniform (pass ``background`` otherwise
   only if it is a constant you know, e.g. a camera black level).
2. **Threshold** (absolute, in image units) when not given:
   ``background + max(k_sigma * sigma, floor)`` where ``floor`` is half a grey level for integer
   images and ``1e-6 * (max - background)`` for float images, so that a noise-free render with
   an exactly black background (``sigma == 0``) keeps every lit pixel. Pixels strictly above the
   threshold are foreground. ``floor_fraction`` (default 0) raises it to at least
   ``background + floor_fraction * (target level − background)`` (the target level as in
   :func:`fractional_threshold`; rule ``"floor"``): photos stored as 8-bit JPEG carry
   compression ringing of a few per cent of a target's level around every target, on a
   background whose noise estimate cannot see it (a black background is mostly exactly 0).

   **Speckled backgrounds.** Renders of scattering water (and the fireflies of lights seen
   through it) have a background whose upper tail is not Gaussian: most pixels sit near the
   median, but a few per cent are Monte-Carlo speckle one or two orders of magnitude above
   ``k_sigma * sigma``. The threshold above then cuts tens of thousands of blobs out of the haze
   (and merges the targets into them). This is recognized on the image averaged over 3 × 3 pixels
   (:data:`~measure.images.levels.SPECKLE_FILTER_PX`: a matched filter for disks a few pixels
   wide — it divides the per-pixel speckle by about 3 and keeps the targets' plateau), by its
   effect: the peaks (above the background) of the blobs of at least ``min_area`` pixels fall
   into two populations at the widest gap of their logarithms; the background is taken for
   speckle when that gap spans at least :data:`~measure.images.levels.SPECKLE_GAP_DECADES`, the
   faint population outnumbers the bright one by more than
   :data:`~measure.images.levels.SPECKLE_BLOB_RATIO` and counts at least
   :data:`~measure.images.levels.SPECKLE_MIN_SPECKS` blobs, and the bright blobs are flat-topped
   like targets (their 90th-percentile pixel at least
   :data:`~measure.images.levels.SPECKLE_PLATEAU_RATIO` of their peak; a firefly on a lit target
   is a lone spike, and a handful of them never makes the targets "speckle"). The threshold is
   then ``background +`` :data:`~measure.images.levels.SPECKLE_THRESHOLD_FRACTION` ``* target
   level``, the target level being the median peak of the bright population, and the blobs are
   cut from the averaged image (their centroids, fluxes and shapes are measured on the image
   itself). Nothing here uses the truth; ``Detections.threshold_rule`` says which rule set the
   threshold.
3. **Blobs.** ``cv2.connectedComponentsWithStats`` with 8-connectivity on the foreground mask.
   ``area`` is the number of foreground pixels of a blob.
4. **Centroid window.** The faint anti-aliased rim of a disk lies below any useful threshold,
   and leaving it out biases the centroid. Each blob (``small`` blobs excepted) is therefore
   grown by ``window_pad`` pixels (Chebyshev distance, square structuring element) into the
   background; a background pixel that is within reach of two blobs goes to one of them only
   (the higher label), never to both.
5. **Measures**, vectorized over blobs with ``np.bincount`` on the window pixels:
   ``w = max(I - background, 0)``; centre ``= sum(w * (u, v)) / sum(w)``;
   ``flux = sum(I - background)`` over the window (not clipped, so noise does not bias it);
   ``peak = max(I - background)``; the weighted second moments give the ellipse axes and the
   ``elongation = major / minor >= 1``; ``snr = flux / (sigma * sqrt(window pixels))``.
6. **Rejection**, each blob gets the first reason that applies, in this order:

   ``"small"``
       fewer than ``min_area`` foreground pixels (noise, hot pixels, fireflies).
   ``"border"``
       a foreground pixel lies in the outer ``border_margin`` rows/columns of the image: the
       target is (or may be) cut by the border.
   ``"ghost"``
       a faint copy of a target (a reflection inside the port): its *brightness* ``flux / area``
       (mean background-subtracted intensity per foreground pixel) is below
       ``ghost_ratio * reference``. The reference is the median brightness of the *bright
       population*: blobs at least half as bright as the 90th percentile of all remaining
       blobs, so that it is the real targets' even when nearly every target has a ghost (then
       half of the blobs are ghosts and a plain median fails). Brightness and not integrated
       flux is compared because the surface brightness of an emissive disk does not depend on
       its distance or apparent size, while its flux does (a smaller, farther target is not a
       ghost) and a merged blob has several times the flux of a target (with flux, one large
       merged blob among few targets made every real target a "ghost"). A blob with no
       positive signal at all (possible only with a ``threshold`` below the background) is
       counted here too.
   ``"merged"``
       two or more targets in one blob, told apart from a single target by its **shape**: a
       blob that is suspicious — ``area > merge_area_ratio * reference_area`` (median area of
       the non-ghost blobs) **or** ``elongation > merge_elongation`` — is merged only if its
       outline has a **waist** (a convexity defect at least :data:`WAIST_DEPTH_PX` deep) or a
       **hole**. The outline is the level half way up to the blob's plateau (the 75th
       percentile of its pixels, so that a firefly on it does not count), on the blob's patch
       upsampled :data:`WAIST_UPSAMPLING` times (bilinear), so that the pixel staircase does not
       count as a waist: a single disk seen obliquely (an ellipse of any elongation) measured
       at most 0.30 px on the committed sphere and cylinder scenes, two touching disks of
       2.75 px radius 1.5 px, two disks 1.3 radii apart 0.5 px. So a target seen at 60° or more
       (elongation 2 and beyond), or a near target twice the median area in a scene spanning
       depth, is accepted; two touching disks, chains, clusters and rings are not. Two disks
       overlapping by more than that (centres below about ``1.3 r`` apart) look like one
       slightly larger ellipse and cannot be told apart from one target by shape. Counting
       local maxima is deliberately not used: emissive disks are flat-topped, and with noise a
       single disk has many local maxima.

Quality
-------
``quality = (1 / elongation) * snr / (snr + 10)``, in ``[0, 1]``: 1 for a round blob far above
the noise, about 0.5 for a round blob at ``snr = 10`` or a bright blob stretched 2:1. It is a
ranking heuristic, not a probability; ``snr`` and ``elongation`` are returned as well. With a
noise-free background (``sigma == 0``) ``snr`` is ``inf`` and its factor is 1.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import cv2
import numpy as np

from .levels import as_image, fractional_threshold, image_levels

__all__ = ["Detections", "Rejection", "detect_targets", "fractional_threshold",
           "REJECTION_REASONS"]

#: Default elongation (major / minor axis) beyond which a blob's shape is examined for merged
#: targets (a waist or a hole; see the module docs).
MERGE_ELONGATION = 1.6
#: Default area, in medians of the blobs' areas, beyond which a blob's shape is examined.
MERGE_AREA_RATIO = 2.5
#: A suspicious blob (large or elongated) is merged targets when its half-peak outline has a
#: convexity defect at least this deep (px; see the module docs for what was measured).
WAIST_DEPTH_PX = 0.45
#: Upsampling of a suspicious blob's patch before its half-peak outline is traced.
WAIST_UPSAMPLING = 4
#: The ``floor_fraction`` the project's commands use (``detect_targets`` itself defaults to 0):
#: JPEG ringing around a target is 2–5 % of its level (``eval measure``), and on a render's
#: exactly black background a single Monte Carlo sample of a ghost (1/spp of the target level)
#: in the 3.7-px gap between two targets of the paper plane's innermost circle joined them (2 of
#: 496 lost at 100 spp seed 0 and 144 spp seed 1; ``synth check``, ``eval run``). At 5 %
#: neither joins two targets and the centroids stay where they were (0.0066 → 0.0067 px RMS;
#: the centroid window still takes the rim).
FLOOR_FRACTION = 0.05


class Rejection(IntEnum):
    """Why a blob is not a target, in the order in which the reasons are tested."""

    SMALL = 0
    BORDER = 1
    GHOST = 2
    MERGED = 3


#: Rejection reasons (names), in the order in which they are tested.
REJECTION_REASONS = tuple(reason.name.lower() for reason in Rejection)
#: Reason code of an accepted blob.
_ACCEPTED = -1

#: ``snr`` at which the SNR factor of ``quality`` is one half.
_SNR_HALF_QUALITY = 10.0


@dataclass(frozen=True, eq=False)
class Detections:
    """Accepted targets of one image, sorted by ``v`` then ``u``, and what was rejected.

    Attributes
    ----------
    centers : (N, 2) float64 sub-pixel ``(u, v)`` centres, OpenCV pixel convention.
    flux : (N,) background-subtracted intensity summed over the centroid window (image units).
    area : (N,) int64 number of foreground (above-threshold) pixels.
    peak : (N,) largest background-subtracted pixel value.
    snr : (N,) ``flux / (sigma * sqrt(window pixels))``; ``inf`` when ``sigma == 0``.
    elongation : (N,) major/minor axis ratio (>= 1) of the weighted second moments.
    orientation : (N,) rad, the direction of the major axis of those moments, from +u towards
        +v, in ``(-π/2, π/2]`` (0 for a round blob; an oblique disk's minor axis is the
        direction it is foreshortened in).
    quality : (N,) ``(1 / elongation) * snr / (snr + 10)`` in ``[0, 1]`` (see module docs).
    rejected : ``{reason: count}`` for every reason of :data:`REJECTION_REASONS` (zeros included).
    rejected_centers : (M, 2) centroids of the rejected blobs, sorted by ``v`` then ``u``.
    rejected_reasons : (M,) reason of each rejected blob (str).
    background, noise_sigma, threshold : the levels used (image units; with the ``speckle``
        rule the threshold applies to the image averaged over 3 × 3 pixels).
    threshold_rule : ``"noise"`` (background + k_sigma noise sigmas, or the floor),
        ``"speckle"`` (a speckled background: a fraction of the targets' level, see the module
        docs), ``"floor"`` (``floor_fraction`` of the targets' level) or ``"given"`` (the
        caller's ``threshold``).
    labels : ``None`` unless ``return_labels``; then an int32 image: 0 background,
        ``k + 1`` on the centroid window of accepted target ``k``, -1 on rejected blobs
        (their windows, and the pixels of ``small`` blobs).
    """

    centers: np.ndarray
    flux: np.ndarray
    area: np.ndarray
    peak: np.ndarray
    snr: np.ndarray
    elongation: np.ndarray
    quality: np.ndarray
    rejected: dict
    rejected_centers: np.ndarray
    rejected_reasons: np.ndarray
    background: float
    noise_sigma: float
    threshold: float
    labels: np.ndarray | None = None
    threshold_rule: str = "noise"
    orientation: np.ndarray | None = None

    @property
    def n_found(self) -> int:
        """Number of accepted targets."""
        return int(self.centers.shape[0])

    @property
    def n_rejected(self) -> int:
        """Number of rejected blobs (all reasons)."""
        return int(sum(self.rejected.values()))


def _bright_median(values: np.ndarray) -> float:
    """Median of the values that are at least half their 90th percentile (see module docs)."""
    if values.size == 0:
        return 0.0
    p90 = np.percentile(values, 90.0)
    bright = values[values >= 0.5 * p90]
    return float(np.median(bright)) if bright.size else float(np.median(values))


def _sorted_vu(centers: np.ndarray) -> np.ndarray:
    """Order sorting centres by v, then u (NaN last)."""
    return np.lexsort((centers[:, 0], centers[:, 1]))


@dataclass(frozen=True)
class _Blobs:
    """Stage 3: connected components of the foreground. Blob ``k`` has label ``k + 1``;
    ``core`` is the label image without the ``small`` blobs."""

    n_labels: int
    labels: np.ndarray
    core: np.ndarray
    x0: np.ndarray
    y0: np.ndarray
    width: np.ndarray
    height: np.ndarray
    area: np.ndarray
    small: np.ndarray
    plain_centroids: np.ndarray

    @property
    def n(self) -> int:
        return self.n_labels - 1


def _label_blobs(f, thr, min_area) -> _Blobs:
    mask = (f > np.float32(thr)).view(np.uint8)
    n_lab, labels, stats, cv_centroids = cv2.connectedComponentsWithStats(
        mask, connectivity=8, ltype=cv2.CV_32S
    )
    area = stats[1:, cv2.CC_STAT_AREA].astype(np.int64)
    small = area < min_area
    if small.any():
        lut = np.arange(n_lab, dtype=np.int32)
        lut[1:][small] = 0
        core = lut[labels]
    else:
        core = labels
    return _Blobs(n_lab, labels, core, stats[1:, cv2.CC_STAT_LEFT].astype(np.int64),
                  stats[1:, cv2.CC_STAT_TOP].astype(np.int64),
                  stats[1:, cv2.CC_STAT_WIDTH].astype(np.int64),
                  stats[1:, cv2.CC_STAT_HEIGHT].astype(np.int64), area, small, cv_centroids[1:])


def _centroid_windows(blobs: _Blobs, window_pad: int) -> np.ndarray:
    """Stage 4: each blob grown by ``window_pad`` pixels into the background (label image)."""
    core = blobs.core
    if window_pad <= 0 or blobs.n <= 0:
        return core
    ksize = 2 * window_pad + 1
    kernel = np.ones((ksize, ksize), np.uint8)
    if blobs.n_labels <= 65535:
        grown = cv2.dilate(core.astype(np.uint16), kernel).astype(np.int32)
    else:  # float32 holds labels exactly up to 2**24
        grown = cv2.dilate(core.astype(np.float32), kernel).astype(np.int32)
    return np.where(core > 0, core, grown)


@dataclass(frozen=True)
class _Measures:
    """Stage 5: per-blob measures over the centroid windows (see module docs)."""

    centers: np.ndarray
    flux: np.ndarray
    peak: np.ndarray
    snr: np.ndarray
    elongation: np.ndarray
    quality: np.ndarray
    no_weight: np.ndarray
    orientation: np.ndarray


def _measure_blobs(f, window, blobs: _Blobs, bg, sigma) -> _Measures:
    n, W = blobs.n, f.shape[1]
    idx = np.flatnonzero(window)
    lab = window.ravel()[idx] - 1  # blob index 0..n-1
    val = f.ravel()[idx].astype(np.float64) - bg
    w = np.maximum(val, 0.0)
    # coordinates relative to each blob's bounding-box corner, for well-conditioned moments
    du = (idx % W) - blobs.x0[lab]
    dv = (idx // W) - blobs.y0[lab]

    def per_blob(weights):
        return np.bincount(lab, weights=weights, minlength=n)[:n]

    s0 = per_blob(w)
    su = per_blob(w * du)
    sv = per_blob(w * dv)
    suu = per_blob(w * du * du)
    svv = per_blob(w * dv * dv)
    suv = per_blob(w * du * dv)
    flux = per_blob(val)
    n_window = np.bincount(lab, minlength=n)[:n]
    peak = np.full(n, -np.inf)
    np.maximum.at(peak, lab, val)

    with np.errstate(invalid="ignore", divide="ignore"):
        mu = su / s0
        mv = sv / s0
        cuu = suu / s0 - mu * mu
        cvv = svv / s0 - mv * mv
        cuv = suv / s0 - mu * mv
        half_tr = 0.5 * (cuu + cvv)
        disc = np.sqrt(np.maximum(0.25 * (cuu - cvv) ** 2 + cuv * cuv, 0.0))
        lam1 = half_tr + disc
        lam2 = np.maximum(half_tr - disc, 0.0)
        elongation = np.sqrt(lam1 / lam2)
        elongation = np.where(np.isfinite(elongation), np.maximum(elongation, 1.0), np.inf)
        orientation = 0.5 * np.arctan2(2.0 * cuv, cuu - cvv)
        orientation = np.where(np.isfinite(orientation), orientation, 0.0)
        if sigma > 0:
            snr = flux / (sigma * np.sqrt(np.maximum(n_window, 1)))
        else:
            snr = np.where(flux > 0, np.inf, 0.0)
        snr_pos = np.clip(snr, 0.0, None)
        snr_factor = np.where(np.isinf(snr_pos), 1.0, snr_pos / (snr_pos + _SNR_HALF_QUALITY))
        quality = snr_factor / elongation
    centers = np.column_stack([blobs.x0 + mu, blobs.y0 + mv])
    # blobs without a weighted centroid (small blobs have no window): OpenCV's plain centroid
    no_weight = ~(s0 > 0)
    centers[no_weight] = blobs.plain_centroids[no_weight]
    peak[np.isinf(peak)] = np.nan
    return _Measures(centers, flux, peak, snr, elongation, quality, no_weight, orientation)


def _classify(f, blobs: _Blobs, measures: _Measures, border_margin, ghost_ratio,
              merge_area_ratio, merge_elongation) -> np.ndarray:
    """Stage 6: the :class:`Rejection` code of each blob, ``-1`` for an accepted one."""
    H, W = f.shape
    area = blobs.area
    reason = np.full(blobs.n, _ACCEPTED, dtype=np.int64)
    reason[blobs.small] = Rejection.SMALL
    if border_margin > 0:
        border = ((blobs.x0 < border_margin) | (blobs.y0 < border_margin)
                  | (blobs.x0 + blobs.width > W - border_margin)
                  | (blobs.y0 + blobs.height > H - border_margin))
        reason[(reason == _ACCEPTED) & border] = Rejection.BORDER
    # a blob with no positive signal (only possible with a threshold below the background)
    reason[(reason == _ACCEPTED) & measures.no_weight] = Rejection.GHOST

    cand = reason == _ACCEPTED
    brightness = measures.flux / area  # mean background-subtracted intensity per fg pixel
    ref_brightness = _bright_median(brightness[cand])
    reason[cand & (brightness < ghost_ratio * ref_brightness)] = Rejection.GHOST

    cand = reason == _ACCEPTED
    ref_area = float(np.median(area[cand])) if cand.any() else 0.0
    suspicious = cand & ((area > merge_area_ratio * ref_area)
                         | (measures.elongation > merge_elongation))
    for k in np.flatnonzero(suspicious):  # a few blobs: the shape test of each
        if _has_waist_or_hole(f, blobs.labels, k, blobs.x0[k], blobs.y0[k], blobs.width[k],
                              blobs.height[k]):
            reason[k] = Rejection.MERGED
    return reason


def _has_waist_or_hole(f, labels, k, x0, y0, width, height) -> bool:
    """Whether blob ``k`` (label ``k + 1``) has a waist or a hole (module docs, "merged")."""
    H, W = f.shape
    ya, yb = max(y0 - 2, 0), min(y0 + height + 2, H)
    xa, xb = max(x0 - 2, 0), min(x0 + width + 2, W)
    patch = f[ya:yb, xa:xb]
    own = labels[ya:yb, xa:xb] == k + 1
    floor = float(patch[~own].min()) if (~own).any() else 0.0
    # half way up to the blob's plateau (its 75th percentile: robust to a firefly on it, and
    # to the doubled overlap where two rendered disks add up)
    level = 0.5 * (float(np.percentile(patch[own], 75)) + floor)
    up = cv2.resize(np.where(own | (patch < level), patch, patch.min()).astype(np.float32), None,
                    fx=WAIST_UPSAMPLING, fy=WAIST_UPSAMPLING, interpolation=cv2.INTER_LINEAR)
    mask = np.pad((up > level).view(np.uint8), 1)
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return False
    if hierarchy is not None and (hierarchy[0][:, 3] >= 0).any():
        return True  # a hole: a ring of targets
    outline = max(contours, key=len)
    if len(outline) < 4:
        return False
    try:
        defects = cv2.convexityDefects(outline, cv2.convexHull(outline, returnPoints=False))
    except cv2.error:  # a self-touching outline: OpenCV refuses it, a waist it is
        return True
    if defects is None or not len(defects):
        return False
    depth_px = float(np.asarray(defects).reshape(-1, 4)[:, 3].max()) / 256.0 / WAIST_UPSAMPLING
    return depth_px >= WAIST_DEPTH_PX


def _frozen(a):
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


def detect_targets(
    image,
    *,
    threshold: float | None = None,
    background: float | None = None,
    k_sigma: float = 5.0,
    min_area: int = 4,
    border_margin: int = 1,
    window_pad: int = 2,
    ghost_ratio: float = 0.2,
    merge_area_ratio: float = MERGE_AREA_RATIO,
    merge_elongation: float = MERGE_ELONGATION,
    floor_fraction: float = 0.0,
    return_labels: bool = False,
) -> Detections:
    """Detect bright disk targets and measure their sub-pixel intensity centroids.

    Parameters
    ----------
    image : (H, W) array, uint8 / uint16 / any integer or float dtype, linear radiometry.
        Colour (H, W, 3) images are refused (ValueError): the channel weights are the caller's
        choice. Non-finite pixels are treated as background; finite values beyond float32's
        range are refused (ValueError).
    threshold : absolute foreground level in image units (pixels ``> threshold`` are
        foreground); default ``background + max(k_sigma * sigma, floor)`` (see module docs).
    background : background level in image units; default the median of the image.
    k_sigma : threshold in noise sigmas above the background when ``threshold`` is None.
    min_area : blobs with fewer foreground pixels are rejected as ``"small"``.
    border_margin : blobs with a foreground pixel within this many pixels of the image edge
        (i.e. in rows/columns ``< border_margin`` or ``>= size - border_margin``) are rejected
        as ``"border"``. 0 disables the test.
    window_pad : the centroid window is the blob grown by this many pixels (0: blob only).
    ghost_ratio : blobs with ``flux / area < ghost_ratio * reference`` are ``"ghost"``.
    merge_area_ratio, merge_elongation : ``area > merge_area_ratio * reference_area`` or
        ``elongation > merge_elongation`` makes a blob suspicious; a suspicious blob with a
        waist or a hole is ``"merged"`` (module docs).
    floor_fraction : in [0, 1); with ``threshold`` None the threshold is at least this fraction
        of the way from the background to the targets' level (module docs, stage 2).
    return_labels : also return the label image (``Detections.labels``).

    Returns
    -------
    Detections
        Accepted targets sorted by ``v`` then ``u``, their measures, and the rejection counts.
    """
    f, integer = as_image(image)
    _check_options(k_sigma, min_area, border_margin, window_pad, ghost_ratio, merge_area_ratio,
                   merge_elongation, floor_fraction)
    f, bg, sigma, thr, rule, mask_image = image_levels(f, integer, background, threshold, k_sigma,
                                                  min_area, floor_fraction)
    blobs = _label_blobs(mask_image, thr, min_area)
    window = _centroid_windows(blobs, window_pad)
    measures = _measure_blobs(f, window, blobs, bg, sigma)
    reason = _classify(f, blobs, measures, border_margin, ghost_ratio, merge_area_ratio,
                       merge_elongation)

    centers = measures.centers
    accepted, rej = (order[_sorted_vu(centers[order])] for order in
                     (np.flatnonzero(reason == _ACCEPTED), np.flatnonzero(reason != _ACCEPTED)))
    counts = np.bincount(reason[rej], minlength=len(Rejection))
    return Detections(
        centers=_frozen(centers[accepted].astype(np.float64)),
        flux=_frozen(measures.flux[accepted]),
        area=_frozen(blobs.area[accepted]),
        peak=_frozen(measures.peak[accepted]),
        snr=_frozen(measures.snr[accepted]),
        elongation=_frozen(measures.elongation[accepted]),
        orientation=_frozen(measures.orientation[accepted]),
        quality=_frozen(measures.quality[accepted]),
        rejected={name: int(c) for name, c in zip(REJECTION_REASONS, counts)},
        rejected_centers=_frozen(centers[rej].astype(np.float64)),
        rejected_reasons=_frozen(np.array([REJECTION_REASONS[r] for r in reason[rej]], dtype=str)),
        background=bg,
        noise_sigma=sigma,
        threshold=thr,
        labels=_output_labels(blobs, window, accepted, rej) if return_labels else None,
        threshold_rule=rule,
    )


def _check_options(k_sigma, min_area, border_margin, window_pad, ghost_ratio, merge_area_ratio,
                   merge_elongation, floor_fraction) -> None:
    """ValueError for an option of :func:`detect_targets` outside its range."""
    if min_area < 1 or border_margin < 0 or window_pad < 0:
        raise ValueError("min_area must be >= 1, border_margin and window_pad >= 0")
    if not (k_sigma > 0 and ghost_ratio >= 0 and merge_area_ratio > 0 and merge_elongation >= 1):
        raise ValueError(
            "k_sigma and merge_area_ratio must be > 0, ghost_ratio >= 0, merge_elongation >= 1"
        )
    if not 0 <= floor_fraction < 1:
        raise ValueError(f"floor_fraction must be in [0, 1), got {floor_fraction!r}")


def _output_labels(blobs: _Blobs, window, accepted, rejected) -> np.ndarray:
    """The label image of :attr:`Detections.labels`: each centroid window labelled with its
    accepted target's index + 1 (in the output order ``accepted``), -1 on rejected blobs
    (``small`` ones included), 0 elsewhere."""
    lut = np.zeros(blobs.n_labels, dtype=np.int32)
    lut[1:][rejected] = -1
    lut[1 + accepted] = np.arange(1, accepted.size + 1, dtype=np.int32)
    labels = lut[window]
    if blobs.small.any():
        labels[(blobs.labels > 0) & (window == 0)] = -1
    return labels
