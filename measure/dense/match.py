"""Dense stereo matching through a flat port or two domes: a refractive plane sweep and a
sub-pixel refinement.

1. Plane sweep (:mod:`measure.dense.warp`): for depth planes ``N·(X − C_left) = d`` spaced so
   that right pixels move about ``step_px`` between planes, the right image is resampled onto
   the left grid (``cv2.remap``) and compared with the left image by zero-normalised
   cross-correlation over ``window × window`` pixels (box filters). A running argmax keeps the
   best score, its plane and the scores of the two neighbouring planes (no cost volume).
2. A parabola through those three scores gives a first sub-plane depth.
3. Gauss–Newton refinement along the refractive epipolar curve, vectorised over all pixels: the
   right position of every left pixel at depth d is the exact forward projection
   (:func:`measure.geometry.projection.project`) of its water ray's point at depth d, with the analytic
   derivative along the curve. Every pixel's window is evaluated at the centre pixel's depth,
   using each neighbour's own sample to first order (``g(d_p) ≈ g(d_q) + g'(d_q) (d_p − d_q)``),
   so all window sums are box filters; the affine photometric model (gain, offset) makes the
   least-squares step the ZNCC maximiser. After :data:`~measure.dense.refine.SLANT_AFTER_ITERATIONS` steps the
   windows tilt with the surface (``slanted``): window pixel q of p is taken at the depth of
   the plane fitted to p's window of depths (:func:`~measure.dense.refine.surface_slopes`), ``d_p + α_p Δu +
   β_p Δv``, again to first order from q's own sample (:class:`~measure.dense.refine.PlaneMoments`), which
   removes the fronto-parallel window's error on slanted and curved surfaces (its depth was the window's
   texture-weighted mean depth). A pixel whose step is at most
   :data:`~measure.dense.refine.REFINE_TOLERANCE_PX` keeps its depth, so only the pixels that moved are
   projected again and only the windows near them are summed again
   (:func:`~measure.dense.blocks.dirty_blocks`).

The heavy per-pixel work runs in row bands (the sweep) or blocks (the refinement) on a thread
pool (NumPy and OpenCV release the GIL); a band's or block's window filters also read the halo
half a window beyond it, so they give the whole image's result (up to the rounding of the
filters' running sums).

The result per pixel is the refined depth parameter d (the depth map, mm along the rig's
:attr:`~measure.Rig.depth_axis` — the port normal, or the left optical axis for domes —
from the left camera centre) and the exact right pixel of the left ray's point at that depth;
triangulating the pair with the same model (``optical_path`` for ``"refractive"``, ``regular``
for ``"pinhole"``) gives back that point.

The matching σ of every pixel (:func:`matching_sigma`): the refinement fits, over the window
``w`` (``n = window²`` pixels) of each left pixel, ``f_q = a·g_q(δ) + b + ε_q`` with
``g_q(δ) ≈ u_q + h_q δ`` (``δ`` the depth step, ``h = ∂g/∂d``, gain ``a`` and offset ``b``
free). Its least-squares (Cramér–Rao) bound is

    σ_d² = σ_n² (1 + a²) / (a² · n · C),    C = c_hh − c_gh² / c_gg

with ``c_xy`` the window's centred means (``c_hh`` = the variance of ``h`` over the window;
the ``c_gh²/c_gg`` term is what the free gain takes away) and ``σ_n²(1 + a²)`` the variance of
the residual ``ε = n_f − a·n_g`` for independent noise ``σ_n`` in both images (the factor 2 of
the textbook form ``σ_s² = 2σ_n² / Σ(∂I/∂s)²`` when ``a = 1`` and the gain is known). The right
pixel's σ along the epipolar curve is ``σ_s = σ_d · |∂r/∂d|`` (px). The refinement's regressor
is not exactly the true derivative, so the σ is the sandwich of its fixed point
(:func:`~measure.dense.refine.fit_block`), which is this bound when they agree. ``σ_n`` is stated (one for
every pixel) or estimated from the matched pixels' residuals as a function of intensity (the noise
level function, :func:`~measure.dense.refine.fit_noise_levels`: rendered and photographed noise grows with the
intensity), and each window's pixels then carry their own noise in the sandwich; with too few
matched pixels for the levels, one σ_n from the windows' median residual
``n/(n − 3) · var_f · (1 − ρ²) / (1 + a²)`` (ρ the ZNCC, corrected by the median of
χ²ₙ₋₃ / (n − 3)). Any misfit of the window model and the interpolation count as noise.

Units mm; reference frame = left camera frame; OpenCV pixels ``(u, v)``, integer = pixel centre.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from .blocks import (MIN_WINDOW_VARIANCE, RIGHT_MARGIN_PX, row_bands, window_mean,
                     worker_count)
from .refine import refine_depths
from .warp import MODELS, PlaneWarp
from ..stereo.rig import Rig

#: Most sweep planes :func:`match_dense` accepts by default (the widest committed search, a
#: tilted plane over 693-1500 mm at full size, needs 692; each plane costs ~0.1 s at full size).
MAX_PLANES = 2000
#: Largest distance, as a fraction of the window's side, between a pixel and the centroid of
#: its window's texture (the left image's squared Sobel gradient, :func:`texture_offset`). A
#: window whose texture lies off to one side is matched by that texture, not by its own pixel:
#: at an object's silhouette against a dark background it measures the object's edge for the
#: background pixels up to half a window away. (Full-size ``speckle_sphere``: 8 486 such pixels
#: off the cap held 97.6 % of the squared point-to-mesh error; at a quarter of the 11-px window,
#: 2.75 px, they go and 86 pixels on the cap with them; docs/dense.md.)
MAX_TEXTURE_OFFSET = 0.25


@dataclass(frozen=True)
class DenseMatches:
    """Result of :func:`match_dense`.

    ``uv_left`` ``(N, 2)`` left pixel centres that got a match; ``uv_right`` ``(N, 2)`` their
    sub-pixel right pixels; ``score`` ``(N,)`` the ZNCC of the refined match; ``depth_map``
    ``(H, W)`` the refined depth ``N·(X − C_left)`` (mm), NaN where unmatched; ``timings``
    seconds per stage; ``n_planes`` the number of sweep planes.

    The matching σ (module docs): ``sigma_px`` ``(N,)`` the σ of each right pixel along its
    epipolar curve (px; the left pixel is the exact grid point), ``curve_direction`` ``(N, 2)``
    the unit direction of the curve there (towards larger depth), ``sigma_depth`` ``(N,)`` the
    σ of the depth parameter (mm), ``noise_sigma`` the image noise σ_n used (in the input
    images' units) and ``noise_source`` ``"estimated per intensity"`` (the matched pixels'
    residuals by intensity: ``noise_levels`` = (intensities, σ) in the input images' units),
    ``"estimated"`` (one σ_n from the windows' median residual, when too few pixels matched
    for the levels) or ``"stated"``.
    """

    uv_left: np.ndarray
    uv_right: np.ndarray
    score: np.ndarray
    depth_map: np.ndarray
    timings: dict = field(default_factory=dict)
    n_planes: int = 0
    sigma_px: np.ndarray | None = None
    curve_direction: np.ndarray | None = None
    sigma_depth: np.ndarray | None = None
    noise_sigma: float | None = None
    noise_source: str | None = None
    noise_levels: tuple | None = None


def _as_image(image, name: str, size) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"{name} must be a 2D (grey) image, got shape {image.shape}")
    if (image.shape[1], image.shape[0]) != tuple(size):
        raise ValueError(f"{name} is {image.shape[1]}x{image.shape[0]} px but the camera is "
                         f"{size[0]}x{size[1]} px")
    if not np.issubdtype(image.dtype, np.number) or np.iscomplexobj(image):
        raise ValueError(f"{name} must hold real numbers, got dtype {image.dtype}")
    image = image.astype(np.float32)
    if not np.all(np.isfinite(image)):
        raise ValueError(f"{name} holds NaN or infinite values")
    return image


def _check_depth_range(rig: Rig, depth_range) -> tuple[float, float]:
    try:
        near, far = (float(v) for v in depth_range)
    except (TypeError, ValueError):
        raise ValueError(f"depth_range must be (near, far) in mm, got {depth_range!r}") from None
    if not (np.isfinite(near) and np.isfinite(far)) or near >= far:
        raise ValueError(f"depth_range must be finite with near < far, got ({near}, {far})")
    water_depth = glass_depth(rig)
    if near <= water_depth:
        where, axis = rig.port.glass_name, rig.port.axis_name
        raise ValueError(f"depth_range starts at {near:g} mm, not beyond {where} ({water_depth:g} "
                         f"mm from the left camera along {axis})")
    return near, far


def glass_depth(rig: Rig) -> float:
    """How far the glass reaches along :attr:`measure.Rig.depth_axis` from the left camera's
    centre (mm): the port's last interface, or the farther of the two domes' outer spheres. A
    depth plane of the sweep must lie beyond it."""
    return rig.port.glass_depth(rig.left)


def texture_offset(image: np.ndarray, window: int) -> np.ndarray:
    """``(H, W)`` px: the distance from each pixel to the centroid of the texture energy (the
    squared Sobel gradient of ``image``) in its ``window`` × ``window`` box; NaN where the box
    has no texture. Near 0 for a window of evenly spread texture, up to about half the window
    where the texture fills only one side of it."""
    image = np.asarray(image, dtype=np.float32)
    energy = (cv2.Sobel(image, cv2.CV_32F, 1, 0) ** 2
              + cv2.Sobel(image, cv2.CV_32F, 0, 1) ** 2).astype(np.float64)
    rows, cols = np.indices(image.shape, dtype=np.float64)
    box = lambda a: cv2.boxFilter(a, -1, (window, window), normalize=False,  # noqa: E731
                                  borderType=cv2.BORDER_REFLECT)
    total = box(energy)
    with np.errstate(invalid="ignore", divide="ignore"):
        du = box(energy * cols) / total - cols
        dv = box(energy * rows) / total - rows
        return np.where(total > 0, np.hypot(du, dv), np.nan)


class _SweepBand:
    """Running-argmax state of one row band of the sweep (see :func:`_sweep`).

    The per-pixel selections use OpenCV's masked copies (``cv2.compare`` masks, ``cv2.copyTo``),
    many times faster than NumPy's masked assignment on masks as mixed as these."""

    def __init__(self, left, mean_l, inv_sigma_l, r0, r1, lo, hi, window):
        self.r0, self.r1, self.lo, self.hi = r0, r1, lo, hi
        self.window = window
        self.kernel = np.ones((window, window), np.uint8)
        self.inner = slice(r0 - lo, r1 - lo)
        self.left = left[lo:hi]
        self.mean_l = mean_l[r0:r1]
        self.inv_sigma_l = inv_sigma_l[r0:r1]
        self.left_ok = cv2.compare(self.inv_sigma_l, 0.0, cv2.CMP_GT)
        shape = (r1 - r0, left.shape[1])
        self.best = np.full(shape, -np.inf, np.float32)
        self.best_index = np.full(shape, -1, np.int32)
        self.before = np.full(shape, -np.inf, np.float32)
        self.after = np.full(shape, -np.inf, np.float32)
        self.previous = np.full(shape, -np.inf, np.float32)
        self.score = np.empty(shape, np.float32)
        self.minus_inf = np.full(shape, -np.inf, np.float32)
        self.index = np.empty(shape, np.int32)

    def plane(self, k, warp, right, coarse):
        """Score plane ``k`` (``coarse``: its coarse-grid right pixels) on this band and update
        the running argmax; returns the seconds spent on the warp map, remap and ZNCC."""
        t0 = time.perf_counter()
        maps = warp.right_map_rows(coarse, self.lo, self.hi)
        t1 = time.perf_counter()
        warped = cv2.remap(right, maps, None, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        width, height = warp.rig.right.size
        m = RIGHT_MARGIN_PX
        inside = cv2.inRange(maps, (m, m), (width - 1 - m, height - 1 - m))
        valid = cv2.erode(inside, self.kernel, borderType=cv2.BORDER_CONSTANT,
                          borderValue=0)[self.inner]
        t2 = time.perf_counter()
        window, inner = self.window, self.inner
        mean_r = window_mean(warped, window)[inner]
        var_r = window_mean(warped * warped, window)[inner]
        cov = window_mean(self.left * warped, window)[inner]
        var_r -= mean_r * mean_r
        np.maximum(var_r, MIN_WINDOW_VARIANCE, out=var_r)
        np.sqrt(var_r, out=var_r)
        mean_r *= self.mean_l
        cov -= mean_r
        cov *= self.inv_sigma_l  # 0 where the left window is flat (masked below)
        score = self.score
        np.divide(cov, var_r, out=score)
        rejected = cv2.compare(cv2.bitwise_and(valid, self.left_ok), 0, cv2.CMP_EQ)
        cv2.copyTo(self.minus_inf, rejected, score)
        cv2.copyTo(score, cv2.compare(self.best_index, k - 1, cv2.CMP_EQ), self.after)
        better = cv2.compare(score, self.best, cv2.CMP_GT)
        cv2.copyTo(self.previous, better, self.before)
        cv2.copyTo(score, better, self.best)
        self.index.fill(k)
        cv2.copyTo(self.index, better, self.best_index)
        cv2.copyTo(self.minus_inf, better, self.after)
        self.previous, self.score = score, self.previous
        return t1 - t0, t2 - t1, time.perf_counter() - t2


def _sweep(warp: PlaneWarp, left, right, depths, window, progress):
    """Running argmax of the ZNCC over the planes: best score, best plane, the scores of the
    planes before and after the best (−inf where missing).

    The left window statistics are computed once. Per plane, the coarse-grid right pixels
    are computed (the next plane's while the bands work on this one), then row bands (each
    with the window's halo rows) interpolate their rows of the warp map, remap, score and merge
    into their share of the running argmax on a thread pool (NumPy and OpenCV release the
    GIL). Stage times: the wall time of the banded work shared out in proportion to the bands'
    own warp map / remap / ZNCC times, plus the wait for the coarse grid under warp maps."""
    mean_l = window_mean(left, window)
    sigma_l = np.sqrt(np.maximum(window_mean(left * left, window) - mean_l * mean_l, 0.0))
    left_ok = sigma_l > np.sqrt(MIN_WINDOW_VARIANCE)
    inv_sigma_l = np.zeros_like(sigma_l)
    np.divide(1.0, sigma_l, out=inv_sigma_l, where=left_ok)
    workers = worker_count()
    bands = [_SweepBand(left, mean_l, inv_sigma_l, *band, window)
             for band in row_bands(left.shape[0], window // 2, workers)]
    times = {"warp maps": 0.0, "remap": 0.0, "zncc": 0.0}
    with ThreadPoolExecutor(max_workers=workers) as pool, \
            ThreadPoolExecutor(max_workers=1) as ahead:
        upcoming = ahead.submit(warp.grid_right_pixels, depths[0])
        for k in range(len(depths)):
            t0 = time.perf_counter()
            coarse = upcoming.result().astype(np.float32)
            if k + 1 < len(depths):
                upcoming = ahead.submit(warp.grid_right_pixels, depths[k + 1])
            t1 = time.perf_counter()
            parts = list(pool.map(lambda band: band.plane(k, warp, right, coarse), bands))
            elapsed = time.perf_counter() - t1
            spent = [sum(column) for column in zip(*parts)]
            total = max(sum(spent), 1e-12)
            times["warp maps"] += t1 - t0 + elapsed * spent[0] / total
            times["remap"] += elapsed * spent[1] / total
            times["zncc"] += elapsed * spent[2] / total
            if progress is not None:
                progress(k + 1, len(depths))

    def gather(name):
        return np.concatenate([getattr(band, name) for band in bands])

    return gather("best"), gather("best_index"), gather("before"), gather("after"), times


def match_dense(rig: Rig, left, right, depth_range, *, model: str = "refractive",
                window: int = 11, min_score: float = 0.8, step_px: float = 0.5, roi=None,
                progress=None, max_planes: int | None = None,
                noise_sigma: float | None = None, slanted: bool = True) -> DenseMatches:
    """Dense matches of a rectification-free stereo pair through the rig's port.

    ``left``, ``right``: 2D grey images of the cameras' sizes (any real dtype; scaled to
    [0, 1] float32 together). ``depth_range``: (near, far) in mm along the rig's depth axis
    (the port normal; for a :class:`measure.geometry.dome.DomePair` the left optical axis) from the left
    camera centre, beyond the port (beyond both domes). ``model``: ``"refractive"`` (through
    ``rig.port``) or
    ``"pinhole"`` (the port ignored: straight rays). ``window``: odd side of the square ZNCC
    window (px). ``min_score``: the least ZNCC kept. ``step_px``: right-pixel motion between
    sweep planes. ``roi``: optional ``(u0, v0, u1, v1)`` left-image box (px, end exclusive)
    outside which nothing is matched. ``progress``: optional callable ``(done, total)`` per
    sweep plane. ``max_planes`` (default :data:`MAX_PLANES`): a depth range that needs more sweep
    planes is refused
    (ValueError naming the count) before any image work. ``noise_sigma``: the images' noise σ_n
    (their units) for the matching σ; None (default): estimated from the matched windows'
    residuals (module docs). ``slanted`` (default): after :data:`~measure.dense.refine.SLANT_AFTER_ITERATIONS`
    fronto-parallel refinement steps every window tilts with the surface (the plane fitted to
    its pixels' depths, :func:`~measure.dense.refine.surface_slopes`); False keeps the windows
    fronto-parallel. Rejected: score below ``min_score``, best
    plane at an end of the range, a
    window leaving either image, a right pixel leaving the right image, a window whose texture
    is centred more than :data:`MAX_TEXTURE_OFFSET` of its side away from its pixel
    (:func:`texture_offset`: silhouettes), a refinement that does not converge.
    """
    _check_options(model, window, step_px, noise_sigma)
    window = int(window)
    near, far = _check_depth_range(rig, depth_range)
    left = _as_image(left, "left", rig.left.size)
    right = _as_image(right, "right", rig.right.size)
    scale = max(float(left.max()), float(right.max()), 1e-30)
    left /= scale
    right /= scale
    timings = {}
    t0 = time.perf_counter()
    warp = PlaneWarp(rig, model)
    depths = warp.sweep_depths(near, far, step_px)
    max_planes = MAX_PLANES if max_planes is None else int(max_planes)
    if len(depths) > max_planes:
        raise ValueError(f"depth range {near:g}-{far:g} mm needs {len(depths)} sweep planes, more "
                         f"than {max_planes}: narrow it")
    timings["plane spacing"] = time.perf_counter() - t0

    best, best_index, before, after, sweep_times = _sweep(warp, left, right, depths, window,
                                                          progress)
    timings.update(sweep_times)
    t0 = time.perf_counter()
    candidate = _sweep_candidates(best, best_index, before, after, len(depths), roi)
    start = _start_depth(depths, best_index, best, before, after)
    timings["parabola"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    with np.errstate(invalid="ignore"):
        candidate &= ~(texture_offset(left, window) > MAX_TEXTURE_OFFSET * window)
    timings["texture offset"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    refine_times = {}
    fit = {"noise_levels": noise_sigma is None}
    depth, score, uv_right, converged = refine_depths(warp, left, right, start, candidate, window,
                                                (near, far), refine_times, fit, slanted)
    timings["refinement"] = time.perf_counter() - t0
    timings.update(refine_times)
    keep = candidate & converged & (score >= min_score)
    rows, cols = np.nonzero(keep)
    depth_map = np.where(keep, depth, np.nan)
    t0 = time.perf_counter()
    stated = None if noise_sigma is None else float(noise_sigma) / scale
    levels = fit.get("levels")
    sigma = matching_sigma({k: v[keep] for k, v in fit.items() if isinstance(v, np.ndarray)},
                           window, stated, levels)
    timings["matching sigma"] = time.perf_counter() - t0
    return DenseMatches(np.stack([cols, rows], axis=1).astype(np.float64), uv_right[keep],
                        score[keep].astype(np.float64), depth_map, timings, len(depths),
                        sigma["sigma_px"], sigma["direction"], sigma["sigma_depth"],
                        sigma["noise_sigma"] * scale, sigma["source"],
                        None if levels is None else (levels[0] * scale,
                                                     np.sqrt(levels[1]) * scale))


def _check_options(model, window, step_px, noise_sigma) -> None:
    """ValueError for an option of :func:`match_dense` outside its range."""
    if model not in MODELS:
        raise ValueError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    if int(window) != window or window < 3 or window % 2 == 0:
        raise ValueError(f"window must be an odd whole number >= 3, got {window!r}")
    if not (np.isfinite(step_px) and step_px > 0):
        raise ValueError(f"step_px must be a positive number, got {step_px!r}")
    if noise_sigma is not None and not (np.isfinite(noise_sigma) and noise_sigma > 0):
        raise ValueError(f"noise_sigma must be a positive number, got {noise_sigma!r}")


def _sweep_candidates(best, best_index, before, after, planes: int, roi) -> np.ndarray:
    """Bool ``(H, W)``: the pixels the refinement starts from — the sweep's best plane inside
    the range (not at an end of its ``planes``), its neighbours' scores known, a positive
    score, and inside ``roi`` (``(u0, v0, u1, v1)`` px, end exclusive) when given."""
    candidate = (best_index > 0) & (best_index < planes - 1) & np.isfinite(before) \
        & np.isfinite(after) & (best > 0)
    if roi is not None:
        u0, v0, u1, v1 = (int(v) for v in roi)
        inside = np.zeros_like(candidate)
        inside[max(v0, 0):max(v1, 0), max(u0, 0):max(u1, 0)] = True
        candidate &= inside
    return candidate


def matching_sigma(fit: dict, window: int, noise_sigma: float | None = None,
                   levels=None) -> dict:
    """The matching σ of refined pixels (module docs) from the refinement's window statistics
    ``fit`` (``(N,)`` arrays: ``gain`` a, ``information`` ``a²·C`` per window pixel (1/mm²),
    ``residual`` ``var_f (1 − ρ²)``, ``rate`` ``(N, 2)`` the curve's ``∂r/∂d`` px/mm, and
    ``weighted`` with ``levels``), images in [0, 1]. ``noise_sigma``: σ_n (same units), one
    for every pixel; None: estimated — with ``levels`` (the noise level function of
    ``fit_noise_levels``) each window's pixels carry their intensity's noise (``weighted``: ``n``
    times ``var d``; the reported σ_n is the median level's), else one σ_n from the median
    residual. Returns ``sigma_px``, ``sigma_depth`` (mm), ``direction`` ``(N, 2)``,
    ``noise_sigma`` and ``source``."""
    n = window * window
    gain = np.asarray(fit["gain"], dtype=np.float64)
    rate = np.asarray(fit["rate"], dtype=np.float64).reshape(-1, 2)
    speed = np.hypot(rate[:, 0], rate[:, 1])
    if noise_sigma is None and levels is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            weighted = np.asarray(fit["weighted"], dtype=np.float64)
            sigma_depth = np.where(weighted > 0, np.sqrt(weighted / n), np.inf)
            direction = rate / speed[:, None]
        return {"sigma_px": sigma_depth * speed, "sigma_depth": sigma_depth,
                "direction": direction, "noise_sigma": float(np.sqrt(np.median(levels[1]))),
                "source": "estimated per intensity"}
    if noise_sigma is None:
        per_pixel = n / (n - 3) * np.asarray(fit["residual"]) / (1 + gain * gain)
        per_pixel = per_pixel[np.isfinite(per_pixel)]
        dof = n - 3  # median of χ²_dof / dof (Wilson–Hilferty; 1e-5 relative at dof 118)
        correction = (1 - 2 / (9 * dof)) ** 3
        noise_sigma = float(np.sqrt(np.median(per_pixel) / correction)) if per_pixel.size \
            else float("nan")
        source = "estimated"
    else:
        source = "stated"
    with np.errstate(invalid="ignore", divide="ignore"):
        information = np.asarray(fit["information"], dtype=np.float64)
        sigma_depth = noise_sigma * np.sqrt((1 + gain * gain) / (n * information))
        sigma_depth = np.where(information > 0, sigma_depth, np.inf)
        direction = rate / speed[:, None]
    return {"sigma_px": sigma_depth * speed, "sigma_depth": sigma_depth,
            "direction": direction, "noise_sigma": float(noise_sigma), "source": source}


def _start_depth(depths, best_index, best, before, after):
    """Depth from the parabola through the best plane's score and its neighbours' (mm)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        curvature = before - 2.0 * best + after
        offset = np.where(curvature < 0, 0.5 * (before - after) / curvature, 0.0)
    offset = np.clip(np.nan_to_num(offset, nan=0.0, posinf=0.0, neginf=0.0), -0.5, 0.5)
    position = np.clip(best_index + offset, 0, len(depths) - 1)
    return np.interp(position, np.arange(len(depths)), depths)
