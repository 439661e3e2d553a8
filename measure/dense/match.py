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
   least-squares step the ZNCC maximiser. After :data:`SLANT_AFTER_ITERATIONS` steps the
   windows tilt with the surface (``slanted``): window pixel q of p is taken at the depth of
   the plane fitted to p's window of depths (:func:`_surface_slopes`), ``d_p + α_p Δu + β_p Δv``,
   again to first order from q's own sample (:class:`_PlaneMoments`), which removes the
   fronto-parallel window's error on slanted and curved surfaces (its depth was the window's
   texture-weighted mean depth). A pixel whose step is at most
   :data:`REFINE_TOLERANCE_PX` keeps its depth, so only the pixels that moved are projected
   again and only the windows near them are summed again (:func:`_dirty_blocks`).

The heavy per-pixel work runs in row bands (the sweep) or blocks (the refinement) on a thread
pool (NumPy and OpenCV release the GIL); a band's or block's window filters also read the halo
half a window beyond it, so they give the whole image's result (up to the rounding of the
filters' running sums).

The result per pixel is the refined depth parameter d (the depth map, mm along the rig's
:attr:`~measure.StereoRig.depth_axis` — the port normal, or the left optical axis for domes —
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
(:func:`_fit_block`), which is this bound when they agree. ``σ_n`` is stated (one for every
pixel) or estimated from the matched pixels' residuals as a function of intensity (the noise
level function, :func:`_noise_levels`: rendered and photographed noise grows with the
intensity), and each window's pixels then carry their own noise in the sandwich; with too few
matched pixels for the levels, one σ_n from the windows' median residual
``n/(n − 3) · var_f · (1 − ρ²) / (1 + a²)`` (ρ the ZNCC, corrected by the median of
χ²ₙ₋₃ / (n − 3)). Any misfit of the window model and the interpolation count as noise.

Units mm; reference frame = left camera frame; OpenCV pixels ``(u, v)``, integer = pixel centre.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage

from .warp import MODELS, PlaneWarp
from ..stereo.triangulate import StereoRig

#: Gauss–Newton iterations of the refinement (it stops earlier once every step is below
#: :data:`REFINE_TOLERANCE_PX` along the epipolar curve; a pixel whose step is at most that
#: keeps its depth meanwhile).
REFINE_ITERATIONS = 14
REFINE_TOLERANCE_PX = 1e-3
#: The iterations at which the windows tilt with the surface (the first: after that many
#: fronto-parallel Gauss–Newton steps; each sooner if every step falls below the tolerance):
#: each window's depth then follows the plane fitted to the depths of its pixels whose last
#: step was at most :data:`SLOPE_STEP_PX` (:func:`_surface_slopes`), and the iterations go on
#: with those slanted windows; the second fit takes the slopes of the slanted windows' depths.
#: (One fit at 3 of 10 iterations: the full-size sphere 90.0 % measured, F@1 mm 0.939; two,
#: at 3 and 7 of 14: 92.9 %, 0.957; docs/dense.md.)
SLANT_AFTER_ITERATIONS = (3, 7)
SLOPE_STEP_PX = 0.05
#: Most sweep planes :func:`match_dense` accepts by default (the widest committed search, a
#: tilted plane over 693-1500 mm at full size, needs 692; each plane costs ~0.1 s at full size).
MAX_PLANES = 2000
#: Fraction applied of a Gauss–Newton step that reverses the pixel's previous step.
REFINE_DAMPING = 0.5
#: A match counts as converged when its last Gauss–Newton step along the epipolar curve is
#: below this (px).
CONVERGED_STEP_PX = 0.01
#: Largest distance (px along the epipolar curve) the refinement may move a match from the
#: parabola's start: the sweep's peak is within half a plane step (``step_px`` / 2) of the
#: truth when it found the right peak; farther moves are drifts into another peak.
MAX_REFINE_MOVE_PX = 1.0
#: Variance floor of a window (intensity units², images scaled to [0, 1]): flat windows fail.
MIN_WINDOW_VARIANCE = 1e-8
#: Pixels kept clear of the right image border by the interpolated samples (cubic: 2 px).
RIGHT_MARGIN_PX = 2.0
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


def _check_depth_range(rig: StereoRig, depth_range) -> tuple[float, float]:
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


def glass_depth(rig: StereoRig) -> float:
    """How far the glass reaches along :attr:`StereoRig.depth_axis` from the left camera's
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


def _box(image: np.ndarray, window: int) -> np.ndarray:
    return cv2.boxFilter(image, -1, (window, window), normalize=True,
                         borderType=cv2.BORDER_REFLECT)


def _window_inside(mask: np.ndarray, window: int) -> np.ndarray:
    """Pixels whose whole window lies where ``mask`` (bool ``(H, W)``) holds."""
    kernel = np.ones((window, window), np.uint8)
    return cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT,
                     borderValue=0).astype(bool)


def _right_inside(map_u, map_v, size) -> np.ndarray:
    width, height = size
    m = RIGHT_MARGIN_PX
    with np.errstate(invalid="ignore"):
        return (map_u >= m) & (map_u <= width - 1 - m) & (map_v >= m) & (map_v <= height - 1 - m)


def _row_bands(height: int, halo: int, workers: int):
    """Row bands ``(r0, r1, lo, hi)`` covering ``height`` rows: band rows ``[r0, r1)`` and the
    rows ``[lo, hi)`` their window filters read (``halo`` rows more on each side, clipped)."""
    count = min(height, max(1, 4 * workers))
    edges = np.linspace(0, height, count + 1).round().astype(int)
    return [(r0, r1, max(r0 - halo, 0), min(r1 + halo, height))
            for r0, r1 in zip(edges[:-1], edges[1:]) if r1 > r0]


def _chunks(items: np.ndarray, workers: int, chunk: int) -> list[np.ndarray]:
    """``items`` split into at most ``4 · workers`` pieces of at least ``chunk`` items."""
    return np.array_split(items, max(1, min(4 * workers, len(items) // chunk)))


def _in_chunks(function, items: np.ndarray, workers: int, chunk: int = 100_000):
    """``function(items)`` (a tuple of arrays, each with a row per item) evaluated on chunks of
    at least ``chunk`` items on ``workers`` threads and concatenated."""
    with ThreadPoolExecutor(max_workers=workers) as pool:
        parts = list(pool.map(function, _chunks(items, workers, chunk)))
    return tuple(np.concatenate(column) for column in zip(*parts))


@dataclass(frozen=True)
class _Block:
    """A rectangle of output pixels, rows ``[r0, r1)`` × columns ``[c0, c1)``, and the
    rectangle rows ``[lo, hi)`` × columns ``[clo, chi)`` its window filters read (half a window
    more on each side, clipped to the image)."""

    r0: int
    r1: int
    lo: int
    hi: int
    c0: int
    c1: int
    clo: int
    chi: int

    @property
    def out(self):
        return np.s_[self.r0:self.r1, self.c0:self.c1]

    @property
    def read(self):
        return np.s_[self.lo:self.hi, self.clo:self.chi]

    @property
    def inner(self):
        return np.s_[self.r0 - self.lo:self.r1 - self.lo, self.c0 - self.clo:self.c1 - self.clo]


#: Rows and columns of the blocks in which the refinement computes its window sums: blocks this
#: small keep their arrays in the caches (full-size slanted step 0.48 s against 0.62 s for
#: full-width row bands on the 2-core machine).
SUM_BLOCK_SHAPE = (128, 612)


def _tiled_blocks(shape, halo: int, block_shape=SUM_BLOCK_SHAPE) -> list[_Block]:
    """:class:`_Block` s of ``block_shape`` (rows, columns; smaller at the far edges) tiling an
    image of ``shape`` (H, W), each reading ``halo`` px more on every side (clipped)."""
    height, width = shape
    rows, columns = block_shape
    return [_Block(r0, min(r0 + rows, height), max(r0 - halo, 0), min(r0 + rows + halo, height),
                   c0, min(c0 + columns, width), max(c0 - halo, 0),
                   min(c0 + columns + halo, width))
            for r0 in range(0, height, rows) for c0 in range(0, width, columns)]


#: Side (px) of the tiles in which the refinement recomputes only the window sums near the
#: pixels that moved; when more than :data:`SUM_TILE_FULL_SHARE` of the tiles hold such pixels
#: it recomputes the whole image (:func:`_tiled_blocks`).
SUM_TILE_PX = 64
SUM_TILE_FULL_SHARE = 0.5


def _dirty_blocks(moved: np.ndarray, halo: int) -> list[_Block]:
    """Blocks covering every pixel within ``halo`` px (the window's half side) of a ``moved``
    pixel (bool ``(H, W)``): the runs of such :data:`SUM_TILE_PX` tiles along each row of
    tiles, or the whole image (:func:`_tiled_blocks`) when most tiles are."""
    height, width = moved.shape
    tile = SUM_TILE_PX
    near = cv2.dilate(moved.astype(np.uint8), np.ones((2 * halo + 1, 2 * halo + 1), np.uint8))
    tiles_v, tiles_u = -(-height // tile), -(-width // tile)
    padded = np.zeros((tiles_v * tile, tiles_u * tile), np.uint8)
    padded[:height, :width] = near
    dirty = padded.reshape(tiles_v, tile, tiles_u, tile).any(axis=(1, 3))
    if dirty.mean() > SUM_TILE_FULL_SHARE:
        return _tiled_blocks(moved.shape, halo)
    blocks = []
    for i in np.flatnonzero(dirty.any(axis=1)):
        run = np.flatnonzero(dirty[i])
        breaks = np.flatnonzero(np.diff(run) > 1)
        r0, r1 = i * tile, min((i + 1) * tile, height)
        for s, e in zip(np.r_[run[0], run[breaks + 1]], np.r_[run[breaks], run[-1]] + 1):
            c0, c1 = s * tile, min(e * tile, width)
            blocks.append(_Block(r0, r1, max(r0 - halo, 0), min(r1 + halo, height),
                                 c0, c1, max(c0 - halo, 0), min(c1 + halo, width)))
    return blocks


def _workers() -> int:
    return max(1, os.cpu_count() or 1)


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
        mean_r = _box(warped, window)[inner]
        var_r = _box(warped * warped, window)[inner]
        cov = _box(self.left * warped, window)[inner]
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
    mean_l = _box(left, window)
    sigma_l = np.sqrt(np.maximum(_box(left * left, window) - mean_l * mean_l, 0.0))
    left_ok = sigma_l > np.sqrt(MIN_WINDOW_VARIANCE)
    inv_sigma_l = np.zeros_like(sigma_l)
    np.divide(1.0, sigma_l, out=inv_sigma_l, where=left_ok)
    workers = _workers()
    bands = [_SweepBand(left, mean_l, inv_sigma_l, *band, window)
             for band in _row_bands(left.shape[0], window // 2, workers)]
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


def match_dense(rig: StereoRig, left, right, depth_range, *, model: str = "refractive",
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
    residuals (module docs). ``slanted`` (default): after :data:`SLANT_AFTER_ITERATIONS`
    fronto-parallel refinement steps every window tilts with the surface (the plane fitted to
    its pixels' depths, :func:`_surface_slopes`); False keeps the windows fronto-parallel.
    Rejected: score below ``min_score``, best
    plane at an end of the range, a
    window leaving either image, a right pixel leaving the right image, a window whose texture
    is centred more than :data:`MAX_TEXTURE_OFFSET` of its side away from its pixel
    (:func:`texture_offset`: silhouettes), a refinement that does not converge.
    """
    if model not in MODELS:
        raise ValueError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    if int(window) != window or window < 3 or window % 2 == 0:
        raise ValueError(f"window must be an odd whole number >= 3, got {window!r}")
    if not (np.isfinite(step_px) and step_px > 0):
        raise ValueError(f"step_px must be a positive number, got {step_px!r}")
    if noise_sigma is not None and not (np.isfinite(noise_sigma) and noise_sigma > 0):
        raise ValueError(f"noise_sigma must be a positive number, got {noise_sigma!r}")
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
    candidate = (best_index > 0) & (best_index < len(depths) - 1) & np.isfinite(before) \
        & np.isfinite(after) & (best > 0)
    if roi is not None:
        u0, v0, u1, v1 = (int(v) for v in roi)
        inside = np.zeros_like(candidate)
        inside[max(v0, 0):max(v1, 0), max(u0, 0):max(u1, 0)] = True
        candidate &= inside
    start = _start_depth(depths, best_index, best, before, after)
    timings["parabola"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    with np.errstate(invalid="ignore"):
        candidate &= ~(texture_offset(left, window) > MAX_TEXTURE_OFFSET * window)
    timings["texture offset"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    refine_times = {}
    fit = {"noise_levels": noise_sigma is None}
    depth, score, uv_right, converged = _refine(warp, left, right, start, candidate, window,
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


def matching_sigma(fit: dict, window: int, noise_sigma: float | None = None,
                   levels=None) -> dict:
    """The matching σ of refined pixels (module docs) from the refinement's window statistics
    ``fit`` (``(N,)`` arrays: ``gain`` a, ``information`` ``a²·C`` per window pixel (1/mm²),
    ``residual`` ``var_f (1 − ρ²)``, ``rate`` ``(N, 2)`` the curve's ``∂r/∂d`` px/mm, and
    ``weighted`` with ``levels``), images in [0, 1]. ``noise_sigma``: σ_n (same units), one
    for every pixel; None: estimated — with ``levels`` (the noise level function of
    ``_noise_levels``) each window's pixels carry their intensity's noise (``weighted``: ``n``
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


def _gauss_newton_block(block, window, f, mean_f, var_f, g, h, rate_u, rate_v, delta, score,
                        step, speed, final, slant=None):
    """One Gauss–Newton step on the pixels of ``block`` (:class:`_Block`): writes their
    ``score`` (ZNCC at the current depths) and, unless ``final``, their ``step`` (the depth
    step, mm, clipped to 1 px along the curve) and ``speed`` (px/mm). ``slant``: the windows'
    depth slopes (:class:`_PlaneMoments`), None for fronto-parallel windows."""
    read, inner, out = block.read, block.inner, block.out

    def box(image):
        return _box(image, window)[inner]

    g, h, f = g[read], h[read], f[read]
    # g'(q) = g(q) + h(q) (d_p + s_pq − d_q) = w(q) + h(q) δ_p, with δ = d − reference and
    # s_pq the slanted window's depth offset of q from p (0: fronto-parallel; _PlaneMoments)
    u = g - h * delta[read]
    moments = _PlaneMoments(box, block, slant)
    m_h, m_hs = moments.first(h)
    m_hh, m_hhs, m_hhss = moments.second(h * h)
    m_u = box(u) + m_hs
    m_uh, m_uhs = moments.first(u * h)
    m_uu = box(u * u) + 2 * m_uhs + m_hhss
    m_uh = m_uh + m_hhs
    m_fh, m_fhs = moments.first(f * h)
    m_fu = box(f * u) + m_fhs
    delta, mean_f, var_f = delta[out], mean_f[out], var_f[out]
    mean_g = m_u + delta * m_h
    c_gg = m_uu + 2 * delta * m_uh + delta * delta * m_hh - mean_g * mean_g
    c_fg = m_fu + delta * m_fh - mean_f * mean_g
    with np.errstate(invalid="ignore", divide="ignore"):
        score[out] = c_fg / np.sqrt(var_f * np.maximum(c_gg, MIN_WINDOW_VARIANCE))
        if final:
            return
        c_gh = m_uh + delta * m_hh - mean_g * m_h
        c_hh = m_hh - m_h * m_h
        c_fh = m_fh - mean_f * m_h
        determinant = c_gg * c_hh - c_gh * c_gh
        gain = (c_fg * c_hh - c_fh * c_gh) / determinant
        slope = (c_gg * c_fh - c_gh * c_fg) / determinant
        newton = slope / gain
        block_speed = np.hypot(rate_u[out], rate_v[out])
        limit = 1.0 / np.maximum(block_speed, 1e-12)  # at most 1 px along the curve per step
        step[out] = np.clip(np.nan_to_num(newton, nan=0.0), -limit, limit)
        speed[out] = block_speed


class _PlaneMoments:
    """Window means over a slanted window, by box filters.

    The slanted window of pixel p puts its pixel q at the depth ``d_p + s_pq`` with
    ``s_pq = α_p (x_q − x_p) + β_p (y_q − y_p)`` (``α, β``: p's depth slopes, mm per px,
    :func:`_surface_slopes`). For an image ``X`` (the pixels a :class:`_Block` reads),
    :meth:`first` gives the window means of ``X`` and ``X s``, :meth:`second` also of
    ``X s²`` — each expanded into box filters of ``X``, ``X x``, ``X y`` (and ``X x²``,
    ``X x y``, ``X y²``) with the block's own centred coordinates. With ``slant`` None
    (fronto-parallel windows) the ``s`` moments are 0."""

    def __init__(self, box, block, slant):
        self.box = box
        self.slant = slant
        if slant is None:
            return
        alpha, beta = slant
        b = block
        self.x = (np.arange(b.clo, b.chi) - 0.5 * (b.clo + b.chi - 1))[None, :]
        self.y = (np.arange(b.lo, b.hi) - 0.5 * (b.lo + b.hi - 1))[:, None]
        self.xp = self.x[:, b.c0 - b.clo:b.c1 - b.clo]
        self.yp = self.y[b.r0 - b.lo:b.r1 - b.lo]
        self.alpha, self.beta = alpha[b.out], beta[b.out]

    def first(self, image):
        m0 = self.box(image)
        if self.slant is None:
            return m0, 0.0
        mx, my = self.box(image * self.x), self.box(image * self.y)
        return m0, self.alpha * (mx - self.xp * m0) + self.beta * (my - self.yp * m0)

    def second(self, image):
        m0 = self.box(image)
        if self.slant is None:
            return m0, 0.0, 0.0
        x, y, xp, yp, a, b = self.x, self.y, self.xp, self.yp, self.alpha, self.beta
        ix, iy = image * x, image * y
        mx, my = self.box(ix), self.box(iy)
        mxx, mxy, myy = self.box(ix * x), self.box(ix * y), self.box(iy * y)
        dx, dy = mx - xp * m0, my - yp * m0
        dxx = mxx - 2 * xp * mx + xp * xp * m0
        dxy = mxy - xp * my - yp * mx + xp * yp * m0
        dyy = myy - 2 * yp * my + yp * yp * m0
        return m0, a * dx + b * dy, a * a * dxx + 2 * a * b * dxy + b * b * dyy


#: Least share of a window's pixels that must hold a depth for :func:`_surface_slopes` to fit
#: its plane (fewer: the window stays fronto-parallel).
SLOPE_MIN_SHARE = 0.5


def _surface_slopes(depth, use, window, pool=None):
    """Each pixel's depth slopes ``(α, β)`` (mm per px along u and v, each ``(H, W)``): the
    least-squares plane ``d = c + α x + β y`` through the depths ``depth`` of the pixels
    ``use`` (bool ``(H, W)``) in its window, by box filters; 0 where fewer than
    :data:`SLOPE_MIN_SHARE` of the window's pixels are used. ``pool`` (a thread pool), if
    given, shares the blocks (:func:`_tiled_blocks`) out over its threads."""
    alpha, beta = np.zeros(depth.shape), np.zeros(depth.shape)

    def fit(block):
        part_depth, part_use = depth[block.read], use[block.read]
        height, width = part_depth.shape
        m = part_use.astype(np.float64)
        d = np.where(part_use, part_depth, 0.0)
        x = np.broadcast_to((np.arange(width) - 0.5 * (width - 1))[None, :], m.shape)
        y = np.broadcast_to((np.arange(height) - 0.5 * (height - 1))[:, None], m.shape)

        def box(image):
            return _box(np.ascontiguousarray(image, dtype=np.float64), window)[block.inner]

        n, mx, my = box(m), box(m * x), box(m * y)
        mxx, mxy, myy = box(m * x * x), box(m * x * y), box(m * y * y)
        md, mdx, mdy = box(d), box(d * x), box(d * y)
        with np.errstate(invalid="ignore", divide="ignore"):
            sxx, sxy, syy = mxx - mx * mx / n, mxy - mx * my / n, myy - my * my / n
            sxd, syd = mdx - mx * md / n, mdy - my * md / n
            determinant = sxx * syy - sxy * sxy
            a = (sxd * syy - syd * sxy) / determinant
            b = (syd * sxx - sxd * sxy) / determinant
            ok = (n >= SLOPE_MIN_SHARE) & (determinant > 1e-6 * n * n) & np.isfinite(a) \
                & np.isfinite(b)
        alpha[block.out] = np.where(ok, a, 0.0)
        beta[block.out] = np.where(ok, b, 0.0)

    blocks = _tiled_blocks(depth.shape, window // 2)
    list(map(fit, blocks) if pool is None else pool.map(fit, blocks))
    return alpha, beta


#: Intensity bins of :func:`_noise_levels` (quantiles of the matched pixels' intensities) and
#: the least ZNCC of a pixel that enters them.
NOISE_LEVEL_BINS = 16
NOISE_LEVEL_MIN_SCORE = 0.8


def _noise_levels(f, fit, use, window):
    """The images' noise variance as a function of intensity (the noise level function), from
    the centre pixels' own residuals in their windows' fits: ``r² · n/(n − 3) / (1 + a²)``
    (both images' noise, the fit's 3 parameters), averaged in :data:`NOISE_LEVEL_BINS`
    quantile bins of the left intensity over the pixels ``use``; ``(intensities, variances)``
    for ``np.interp`` or None with too few pixels. Rendered images' noise grows with the
    intensity (photon-like), and the speckle's edges, which carry the information, are the
    noisiest pixels: one σ_n for the image understated the scatter 1.18x on a 4-spp render."""
    n = window * window
    r = fit["pixel_residual"][use]
    a = fit["gain"][use]
    values = r * r * n / (n - 3) / (1 + a * a)
    level = f[use]
    ok = np.isfinite(values) & np.isfinite(level)
    if ok.sum() < 10 * NOISE_LEVEL_BINS:
        return None
    values, level = values[ok], level[ok]
    edges = np.quantile(level, np.linspace(0, 1, NOISE_LEVEL_BINS + 1))
    index = np.clip(np.searchsorted(edges, level, side="right") - 1, 0, NOISE_LEVEL_BINS - 1)
    count = np.bincount(index, minlength=NOISE_LEVEL_BINS)
    filled = count > 0
    centres = np.bincount(index, level, NOISE_LEVEL_BINS)[filled] / count[filled]
    variances = np.bincount(index, values, NOISE_LEVEL_BINS)[filled] / count[filled]
    return centres, variances


def _fit_block(block, window, f, mean_f, var_f, g, h, h_true, delta, fit, weight=None,
              slant=None):
    """The window statistics of :func:`matching_sigma` (``fit``: ``gain``, ``information``,
    ``residual`` ``(H, W)``) at the final depths, on the pixels of ``block`` (:class:`_Block`).

    The refinement's fixed point makes the left window ``f`` orthogonal to its regressor ``S``
    (its derivative ``h``, :data:`DERIVATIVE_KERNEL`) once the offset and the gain's regressor
    ``G`` (the right samples extrapolated to the centre's depth, as in :func:`_gauss_newton_block`) are
    projected out: ``Σ S̃ (f − a G(δ) − b) = 0``. Linearised, ``δ̂ − δ = Σ S̃ ε / (a Σ S̃ T̃)``
    with ``T`` the true derivative ``h_true`` (:func:`_curve_derivative`), so
    ``var δ̂ = σ_ε² Σ S̃² / (a Σ S̃ T̃)²`` — the sandwich of the estimator the matcher is; it is
    the Cramér–Rao bound ``σ_ε² / (a² Σ T̃²)`` when ``S ∝ T``. ``information`` is
    ``a² (c_ST − c_GS c_GT / c_GG)² / (c_SS − c_GS² / c_GG)`` (window means: ``n`` times it is
    ``1 / var δ̂`` per unit ``σ_ε²``), ``residual`` ``var_f − c_fG² / c_GG`` (the mean square
    of the affine fit's residual), ``gain`` ``a = c_fG / c_GG`` and ``pixel_residual`` the
    centre pixel's own residual in its window's fit. With ``weight`` (``(H, W)``: each pixel's
    residual variance ``σ_ε,q²``, noise that depends on the intensity) also ``weighted``:
    ``mean(S̃² σ_ε²) / (a² c̃_ST²)``, ``n`` times ``var δ̂`` — the same sandwich with the noise
    of each pixel of the window."""
    read, inner, rows = block.read, block.inner, block.out

    def box(image):
        return _box(image, window)[inner]

    g, h, t, f = g[read], h[read], h_true[read], f[read]
    own_f, own_g = f[inner], g[inner]
    u = g - h * delta[read]
    # the slanted window's samples w = u + h s (see _gauss_newton_block), written u below
    moments = _PlaneMoments(box, block, slant)
    m_h, m_hs = moments.first(h)
    m_hh, m_hhs, m_hhss = moments.second(h * h)
    m_t = box(t)
    m_ht, m_hts = moments.first(h * t)
    m_u = box(u) + m_hs
    m_uh, m_uhs = moments.first(u * h)
    m_uu = box(u * u) + 2 * m_uhs + m_hhss
    m_uh = m_uh + m_hhs
    m_ut = box(u * t) + m_hts
    m_fh, m_fhs = moments.first(f * h)
    m_fu = box(f * u) + m_fhs
    delta, mean_f, var_f = delta[rows], mean_f[rows], var_f[rows]
    mean_g = m_u + delta * m_h
    c_gg = np.maximum(m_uu + 2 * delta * m_uh + delta * delta * m_hh - mean_g * mean_g,
                      MIN_WINDOW_VARIANCE)
    c_fg = m_fu + delta * m_fh - mean_f * mean_g
    c_gs = m_uh + delta * m_hh - mean_g * m_h
    c_gt = m_ut + delta * m_ht - mean_g * m_t
    c_ss = m_hh - m_h * m_h
    c_st = m_ht - m_h * m_t
    gain = c_fg / c_gg
    with np.errstate(invalid="ignore", divide="ignore"):
        cross = c_st - c_gs * c_gt / c_gg
        fit["information"][rows] = gain * gain * cross * cross / (c_ss - c_gs * c_gs / c_gg)
    fit["gain"][rows] = gain
    fit["residual"][rows] = np.maximum(var_f - c_fg * c_fg / c_gg, 0.0)
    fit["pixel_residual"][rows] = own_f - mean_f - gain * (own_g - mean_g)
    if weight is None:
        return
    # S̃_q = A h_q − B u_q − C over the window of p (S = h, G_q = u_q + h_q δ_p)
    w = weight[read]
    beta = c_gs / c_gg
    a_ = 1 - beta * delta
    c_ = a_ * m_h - beta * m_u
    hw, uw = h * w, u * w
    m_hhw, m_hhws, m_hhwss = moments.second(h * hw)
    m_hw, m_hws = moments.first(hw)
    m_uhw, m_uhws = moments.first(u * hw)
    m_uww = box(u * uw) + 2 * m_uhws + m_hhwss
    m_uhw = m_uhw + m_hhws
    m_uw = box(uw) + m_hws
    weighted = (a_ * a_ * m_hhw + beta * beta * m_uww + c_ * c_ * box(w)
                - 2 * a_ * beta * m_uhw - 2 * a_ * c_ * m_hw + 2 * beta * c_ * m_uw)
    with np.errstate(invalid="ignore", divide="ignore"):
        fit["weighted"][rows] = weighted / (gain * gain * cross * cross)


#: Largest map width (px) handed to ``cv2.remap``, which needs maps under 32767 px a side.
_SAMPLE_COLUMNS = 16384


def _sample(image, u, v):
    """``cv2.remap`` (bicubic, constant 0 outside) of ``image`` at the points ``(u, v)`` (each
    ``(N,)``): the same values a full-image map holding these points gives."""
    n = u.size
    rows = max(1, -(-n // _SAMPLE_COLUMNS))
    columns = min(max(n, 1), _SAMPLE_COLUMNS)
    map_u = np.full(rows * columns, -1e6, np.float32)
    map_v = np.full(rows * columns, -1e6, np.float32)
    map_u[:n], map_v[:n] = u, v
    sampled = cv2.remap(image, map_u.reshape(rows, columns), map_v.reshape(rows, columns),
                        cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT)
    return sampled.reshape(-1)[:n]


#: The image derivative of the refinement (∂/∂u; its transpose ∂/∂v): the fourth-order central
#: difference ``(f₋₂ − 8f₋₁ + 8f₁ − f₂) / 12``, 0.97 of the true slope at 1 rad/px. (Scharr's
#: smoothed difference, 0.70-0.84 there, gave the same noise-free fixed point, but its gap to
#: the true slope couples the neighbouring windows' errors: on noisy speckle its matches
#: scattered 1.2x the registration bound, against 1.05x with this kernel; docs/dense.md.)
DERIVATIVE_KERNEL = np.array([[1.0, -8.0, 0.0, 8.0, -1.0]], np.float32) / 12.0

#: Steps (px along the epipolar curve) of the central differences that
#: :func:`_curve_derivative` combines (Richardson: ``(4 D(ε₁) − D(ε₂)) / 3``).
CURVE_DERIVATIVE_STEPS_PX = (0.5, 1.0)


def _curve_derivative(image, u, v, rate_u, rate_v):
    """``∂g/∂d`` (intensity per mm) of the bicubic interpolant of ``image`` at ``(u, v)`` along
    the curve of rate ``(rate_u, rate_v)`` px/mm, each ``(N,)``: Richardson-extrapolated central
    differences of :func:`_sample` (error O(ε⁴); the amplitude at 1 rad/px is 0.998 of the
    truth). The refinement's :data:`DERIVATIVE_KERNEL` is close to it but not the same; the
    sandwich of :func:`_fit_block` takes both."""
    speed = np.hypot(rate_u, rate_v)
    with np.errstate(invalid="ignore", divide="ignore"):
        tu, tv = rate_u / speed, rate_v / speed
    small, large = CURVE_DERIVATIVE_STEPS_PX

    def central(eps):
        return (_sample(image, u + eps * tu, v + eps * tv).astype(np.float64)
                - _sample(image, u - eps * tu, v - eps * tv)) / (2 * eps)

    return (4 * central(small) - central(large)) / 3 * speed


def _refine(warp: PlaneWarp, left, right, start, candidate, window, depth_range, times=None,
            fit=None, slanted=True):
    """Gauss–Newton along the epipolar curve (see the module docstring), all pixels at once.

    A pixel whose step falls to :data:`REFINE_TOLERANCE_PX` or below keeps its depth (its step
    is not applied), so its projection and samples stay valid; only pixels whose depth moved
    are projected and sampled again, and only the windows that hold such a pixel are summed again
    (a kept pixel moves again if its neighbours' moves push its step above the tolerance).

    Returns the refined depth ``(H, W)``, the ZNCC at it, the right pixels ``(H, W, 2)`` and
    whether the pixel converged (last step below 0.01 px, depth inside ``depth_range``, whole
    right window inside the right image). ``times`` (a dict), if given, receives the seconds
    spent in the set-up (rays, nearest candidates), in projecting and sampling, and in the
    window sums and steps. ``fit`` (a dict), if given, receives the window statistics of the
    final depths (:func:`_fit_block`'s ``gain``, ``information``, ``residual``,
    ``pixel_residual`` ``(H, W)`` and ``rate`` ``(H, W, 2)``); with ``fit["noise_levels"]``
    true also ``levels`` (:func:`_noise_levels`, from the candidates of ZNCC ≥
    :data:`NOISE_LEVEL_MIN_SCORE`) and ``weighted`` (a second pass with each pixel's noise)."""
    t_start = time.perf_counter()
    t_project = t_sums = 0.0
    height, width = left.shape
    kernel = np.ones((window, window), np.uint8)
    active = cv2.dilate(candidate.astype(np.uint8), kernel).astype(bool)
    rows, cols = np.nonzero(active)
    # Pixels in the windows of candidates that are no candidates themselves follow their
    # nearest candidate's depth: their own sweep answer may be anything, and through
    # g(d_p) ≈ g(d_q) + ∂g/∂d (d_p − d_q) a wrong d_q would spoil their neighbours' windows.
    if fit is not None:
        fit.update({k: np.full((height, width), np.nan) for k in ("gain", "information",
                                                                   "residual")})
        fit["rate"] = np.full((height, width, 2), np.nan)
    if not candidate.any():
        empty = np.full(left.shape, np.nan)
        return empty, empty, np.full(left.shape + (2,), np.nan), np.zeros(left.shape, bool)
    nearest = ndimage.distance_transform_edt(~candidate, return_distances=False,
                                             return_indices=True)
    followers = np.nonzero(active & ~candidate)
    leaders = (nearest[0][followers], nearest[1][followers])
    follower_du = (followers[1] - leaders[1]).astype(np.float64)
    follower_dv = (followers[0] - leaders[0]).astype(np.float64)
    workers = _workers()
    origins, directions = _in_chunks(
        warp.water_rays, np.stack([cols, rows], axis=1).astype(np.float64), workers)
    gradient_u = cv2.filter2D(right, cv2.CV_32F, DERIVATIVE_KERNEL,
                              borderType=cv2.BORDER_REFLECT)
    gradient_v = cv2.filter2D(right, cv2.CV_32F, DERIVATIVE_KERNEL.T,
                              borderType=cv2.BORDER_REFLECT)
    f = left.astype(np.float64)
    mean_f = _box(f, window)
    var_f = _box(f * f, window) - mean_f * mean_f
    depth = start.astype(np.float64).copy()
    depth[followers] = depth[leaders]
    reference = float(np.median(depth[active])) if rows.size else 0.0
    step_px = np.full((height, width), np.inf)
    uv_right = np.full((height, width, 2), np.nan)
    # samples of the right image (g), of its derivative along the epipolar curve (h) and the
    # curve's rate (px/mm) at every active pixel's depth; 0 elsewhere, like a map off the image
    map_u = np.full((height, width), -1e6, np.float32)
    map_v = np.full((height, width), -1e6, np.float32)
    g = np.zeros((height, width))
    h = np.zeros((height, width))
    rate_u = np.zeros((height, width))
    rate_v = np.zeros((height, width))
    # flat views of the per-pixel images, indexed by the active pixels' flat indices
    at_active = rows * width + cols
    flat = {name: image.reshape(height * width, *image.shape[2:])
            for name, image in (("depth", depth), ("uv", uv_right), ("map_u", map_u),
                                ("map_v", map_v), ("g", g), ("h", h), ("rate_u", rate_u),
                                ("rate_v", rate_v))}
    position = np.full(height * width, -1, np.int64)
    position[at_active] = np.arange(rows.size)

    def project(chunk):
        """Project and sample the active pixels ``chunk`` (indices into rows, cols) at their
        depths, into the per-pixel images (each chunk writes its own pixels)."""
        at = at_active[chunk]
        pixels, rate = warp.right_pixels_at_depth(origins[chunk], directions[chunk],
                                                  flat["depth"][at])
        u_m, v_m = pixels[:, 0].astype(np.float32), pixels[:, 1].astype(np.float32)
        flat["uv"][at] = pixels
        flat["map_u"][at], flat["map_v"][at] = u_m, v_m
        flat["rate_u"][at], flat["rate_v"][at] = rate[:, 0], rate[:, 1]
        flat["g"][at] = _sample(right, u_m, v_m)
        flat["h"][at] = _sample(gradient_u, u_m, v_m) * rate[:, 0] \
            + _sample(gradient_v, u_m, v_m) * rate[:, 1]

    def project_all(mask):
        """:func:`project` the pixels ``mask`` (bool ``(H, W)``) in chunks on the pool."""
        chosen = position[np.flatnonzero(mask)]
        if chosen.size:
            list(pool.map(project, _chunks(chosen, workers, 50_000)))

    def follow(slopes):
        """Followers take their leader's depth (on its slanted window's plane, if any)."""
        depth[followers] = depth[leaders]
        if slopes is not None:
            depth[followers] += slopes[0][leaders] * follower_du \
                + slopes[1][leaders] * follower_dv

    moved = active.copy()  # pixels whose depth changed: project them again
    score = np.full((height, width), np.nan)
    step = np.zeros((height, width))  # the last Gauss–Newton step of every pixel (mm)
    last_change = np.zeros((height, width))
    speed = np.zeros((height, width))
    previous = np.empty((height, width))
    halo = window // 2
    every_block = _tiled_blocks(left.shape, halo)
    slant, settled, fits = None, False, 0
    schedule = SLANT_AFTER_ITERATIONS if slanted else ()
    with ThreadPoolExecutor(max_workers=workers) as pool:
        t_setup = time.perf_counter() - t_start
        blocks = every_block
        for iteration in range(REFINE_ITERATIONS + 1):
            t0 = time.perf_counter()
            if fits < len(schedule) and (iteration >= schedule[fits] or settled):
                # tilt every window with the surface: the plane through its settled depths
                slant = _surface_slopes(depth, candidate & (step_px <= SLOPE_STEP_PX), window,
                                        pool)
                fits, settled = fits + 1, False
                np.copyto(previous, depth)
                follow(slant)
                moved |= active & (depth != previous)
                blocks = every_block  # every window's sums change with its slopes
            final = iteration == REFINE_ITERATIONS
            project_all(moved)
            t1 = time.perf_counter()
            delta = depth - reference
            # only the windows that hold a moved pixel change: the others keep their score,
            # step and speed (the same inputs give the same sums)
            list(pool.map(lambda block: _gauss_newton_block(
                block, window, f, mean_f, var_f, g, h, rate_u, rate_v, delta, score, step,
                speed, final, slant), blocks))
            if final:
                t_project += t1 - t0
                t_sums += time.perf_counter() - t1
                break
            step_px = np.where(active, np.abs(step) * speed, 0.0)
            # converged: keep depth and samples
            change = np.where(step_px > REFINE_TOLERANCE_PX, step, 0.0)
            # a step against the previous one (an oscillation of the coupled windows) is damped
            change = np.where(change * last_change < 0, change * REFINE_DAMPING, change)
            last_change = change
            np.copyto(previous, depth)
            depth += change
            follow(slant)
            np.not_equal(depth, previous, out=moved)
            moved &= active
            blocks = _dirty_blocks(moved, halo)
            t_project += t1 - t0
            t_sums += time.perf_counter() - t1
            if not np.any(step_px[candidate] > REFINE_TOLERANCE_PX):
                if fits == len(schedule):
                    break
                settled = True
        t_fit = time.perf_counter()
        if fit is not None:  # the window statistics of the matching σ at the final depths
            h_curve = np.zeros_like(h)
            h_curve.reshape(-1)[at_active] = _in_chunks(
                lambda at: (_curve_derivative(right, flat["map_u"][at], flat["map_v"][at],
                                              flat["rate_u"][at], flat["rate_v"][at]),),
                at_active, workers)[0]
            delta = depth - reference
            fit.update({k: np.full((height, width), np.nan) for k in ("pixel_residual",
                                                                       "weighted")})
            list(pool.map(lambda block: _fit_block(block, window, f, mean_f, var_f, g, h,
                                                   h_curve, delta, fit, slant=slant),
                          every_block))
            if fit.get("noise_levels"):
                levels = _noise_levels(f, fit, candidate & (score >= NOISE_LEVEL_MIN_SCORE),
                                       window)
                if levels is not None:
                    fit["levels"] = levels
                    gain = np.nan_to_num(fit["gain"])
                    weight = np.interp(f, *levels) + gain * gain * np.interp(g, *levels)
                    weight[~active] = 0.0
                    list(pool.map(lambda block: _fit_block(
                        block, window, f, mean_f, var_f, g, h, h_curve, delta, fit, weight,
                        slant),
                        every_block))
        t_fit = time.perf_counter() - t_fit
    inside = _window_inside(_right_inside(map_u, map_v, warp.rig.right.size), window)
    near, far = depth_range
    with np.errstate(invalid="ignore"):
        moved_px = np.abs(depth - start) * speed
        converged = inside & (step_px < CONVERGED_STEP_PX) & (depth >= near) & (depth <= far) \
            & np.isfinite(score) & (moved_px <= MAX_REFINE_MOVE_PX)
    if fit is not None:
        fit["rate"] = np.stack([rate_u, rate_v], axis=-1)
    if times is not None:
        times.update({"refine set-up": t_setup, "refine projection": t_project,
                      "refine sums": t_sums, "refine sigma": t_fit,
                      "refine checks": time.perf_counter() - t_start - t_setup - t_project
                      - t_sums - t_fit})
    return depth, score, uv_right, converged
