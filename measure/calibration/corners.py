"""Chessboard corners found by OpenCV, refined to their point of symmetry and checked.

A chessboard's inner corner is an X-junction: two straight edges crossing, four squares around
it, the two dark ones opposite each other and the two light ones opposite each other. Its image
is point-symmetric about the corner up to the light that falls on the board: the junction
``P`` seen under an illumination that changes across it is ``B(x) + (W(x) − B(x)) S(x)`` with
``S`` the blurred two-level pattern (even about the corner) and ``B``, ``W`` the dark and light
levels, each varying linearly over the corner's neighbourhood (a lamp, a spot light,
vignetting: on a lamp-lit real board the two light squares of one corner differ by up to half
their contrast).

:func:`refine_corners` splits the image about the current estimate ``q`` into its even part
``E(d) = (I(q + d) + I(q − d)) / 2`` and odd part ``O(d) = (I(q + d) − I(q − d)) / 2``. A corner
displaced by ``δ`` from ``q`` gives ``O ≈ −δ · ∇E``; the illumination's gradients give odd
parts ``d · h`` and ``(d · k) E(d)`` that are smooth, while ``∇E`` lives on the edges, so
the weighted least squares of ``O`` on ``[−∇E, d, d E]`` separates them: ``δ`` is the step,
whatever the squares' levels. (Fitting a quadratic and taking its saddle point — what this
project did before — reads the illumination's gradient as a displacement, σ² × gradient /
curvature: median 0.18 px, up to 6.7 px on a lamp-lit real board; docs/calibration.md.)

:func:`check_grid` decides whether a grid a detector returned is the board: every corner must
be an X-junction (:func:`x_junctions`: four alternating sectors around it, opposite ones
alike — a T-junction on a frame line printed round the board is not) and lie where the
homography of its eight grid neighbours puts it (:func:`neighbour_residuals`: a grid with two
numberings, or a corner that jumped to another feature, does not). A grid with a whole border
row or column off, or more than :data:`MAX_BAD_FRACTION` of its corners off, is refused (the
caller tries the next detector); otherwise the corners that fail are dropped one by one.

Pixels follow OpenCV (integer coordinates are pixel centres); ``uv`` arrays are ``(N, 2)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Refinement window: half side as a fraction of the distance to the nearest corner (Gaussian
#: weights of σ half the half side), the image blurred by :data:`REFINE_BLUR` × the median
#: corner spacing (at least :data:`REFINE_MIN_BLUR_PX`) first; measured on rendered boards
#: (full size, in air and behind the paper port) and on OUC's lamp-lit real board: a wider
#: window and less blur were better on both (docs/calibration.md).
REFINE_HALF_WINDOW, REFINE_BLUR, REFINE_MIN_BLUR_PX = 0.5, 0.025, 0.7
#: Samples per half side of the window (the window is sampled on a grid scaled to each corner).
REFINE_SAMPLES = 16
#: Newton steps at most, and the last step (px) below which a corner has converged.
REFINE_ITERATIONS, REFINE_TOLERANCE_PX = 12, 1e-3
#: Ring of :func:`x_junctions`: its radius as a fraction of the corner spacing, its samples, the
#: fewest antipodal samples of one class, and the least contrast against the grid's median.
RING_RADIUS, RING_SAMPLES, RING_SYMMETRY, RING_CONTRAST = 0.35, 48, 0.8, 0.05
RING_FLOOR = 0.01
#: :func:`neighbour_residuals` above max(:data:`NEIGHBOUR_TOLERANCE` × the spacing,
#: :data:`NEIGHBOUR_FLOOR_PX`) is off the grid (real photos, 3 × 3 neighbourhoods: 99th
#: percentile 0.3–1.5 px at spacings of 30–110 px, the wide GoPro lens the largest).
NEIGHBOUR_TOLERANCE, NEIGHBOUR_FLOOR_PX = 0.15, 1.5
#: A grid with more than this fraction of its corners failing a check is not the board.
MAX_BAD_FRACTION = 0.25


def corner_spacing(uv: np.ndarray) -> np.ndarray:
    """``(N,)`` each corner's distance to its nearest other corner, px (inf for one corner)."""
    from scipy.spatial import cKDTree

    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if len(uv) < 2:
        return np.full(len(uv), np.inf)
    distance, _ = cKDTree(uv).query(uv, k=2)
    return distance[:, 1]


def _sample(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float32 image at ``points`` ``(..., 2)`` (edges replicated)."""
    maps = np.asarray(points, np.float32)
    return cv2.remap(image, np.ascontiguousarray(maps[..., 0]), np.ascontiguousarray(maps[..., 1]),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)


@dataclass(frozen=True)
class _Blurred:
    """The part of the image round the corners, blurred for the refinement, and its gradients
    (float32); ``origin`` (x, y) px of its top-left pixel in the image."""

    image: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    origin: np.ndarray

    def sample(self, which: str, points) -> np.ndarray:
        """Bilinear samples of ``image``, ``gx`` or ``gy`` at image pixels ``points``."""
        return _sample(getattr(self, which), np.asarray(points, np.float64) - self.origin)


def _blurred(image, spacing, uv) -> _Blurred:
    """The image blurred by :data:`REFINE_BLUR` × the median spacing (at least
    :data:`REFINE_MIN_BLUR_PX`), only round the corners ``uv``: their bounding box grown by the
    largest spacing and the blur's reach (a 12-megapixel photo's board is a fraction of it; the
    whole image blurred took 0.27 s a blur)."""
    sigma = max(REFINE_BLUR * float(np.median(spacing)), REFINE_MIN_BLUR_PX)
    image = np.asarray(image)
    h, w = image.shape[:2]
    margin = float(np.max(spacing)) + 4 * sigma + 4
    lo = np.floor(np.min(uv, axis=0) - margin).astype(int).clip(0, [w - 1, h - 1])
    hi = np.ceil(np.max(uv, axis=0) + margin).astype(int).clip(0, [w - 1, h - 1])
    crop = np.asarray(image[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1], np.float32)
    blurred = cv2.GaussianBlur(crop, (0, 0), sigma)
    return _Blurred(blurred, cv2.Sobel(blurred, cv2.CV_32F, 1, 0, ksize=3, scale=0.125),
                    cv2.Sobel(blurred, cv2.CV_32F, 0, 1, ksize=3, scale=0.125),
                    lo.astype(np.float64))


def _window() -> tuple[np.ndarray, np.ndarray]:
    """Half of a symmetric window (``d`` and ``−d`` give one equation): offsets ``(K, 2)`` in
    units of the half side and their Gaussian weights ``(K,)``."""
    m = REFINE_SAMPLES
    j, i = np.mgrid[-m:m + 1, -m:m + 1]
    half = (i > 0) | ((i == 0) & (j > 0))
    d = np.column_stack([j[half], i[half]]).astype(np.float64) / m
    r2 = np.sum(d * d, axis=1)
    return d, np.exp(-r2 / (2 * 0.5 ** 2)) * (r2 <= 1)


def _symmetry_fit(blurred: _Blurred, uv, half):
    """One least-squares fit per corner (module docs): ``(step (N, 2), odd residual (N, K),
    centred even part (N, K), weights (K,))``; NaN steps where the fit is singular."""
    unit, weight = _window()
    d = unit[None] * half[:, None, None]                                   # (N, K, 2) px
    plus, minus = uv[:, None, :] + d, uv[:, None, :] - d
    ip, im = blurred.sample("image", plus), blurred.sample("image", minus)
    even, odd = (ip + im) / 2, (ip - im) / 2
    gx = (blurred.sample("gx", plus) - blurred.sample("gx", minus)) / 2
    gy = (blurred.sample("gy", plus) - blurred.sample("gy", minus)) / 2
    centred = even - (even @ weight / weight.sum())[:, None]
    ux, uy = np.broadcast_to(unit[:, 0], even.shape), np.broadcast_to(unit[:, 1], even.shape)
    A = np.stack([-gx, -gy, ux, uy, ux * centred, uy * centred], axis=-1)
    normal = np.einsum("k,nki,nkj->nij", weight, A, A)
    rhs = np.einsum("k,nki,nk->ni", weight, A, odd)
    step = np.full((len(uv), 2), np.nan)
    residual = np.full(odd.shape, np.nan)
    ok = np.isfinite(normal).all(axis=(1, 2)) & (np.linalg.cond(normal) < 1e12)
    if ok.any():
        x = np.linalg.solve(normal[ok], rhs[ok][..., None])[..., 0]
        step[ok] = x[:, :2]
        residual[ok] = odd[ok] - np.einsum("nki,ni->nk", A[ok], x)
    return step, residual, centred, weight


def refine_corners(image: np.ndarray, uv: np.ndarray, spacing=None):
    """Chessboard corners ``(N, 2)`` refined to the point about which the image is symmetric
    once the light's gradients are taken out (module docs), and whether each converged
    ``(N,)``. ``image``: one channel, linear values (any scale); ``spacing`` ``(N,)`` the local
    corner spacing, px (default :func:`corner_spacing`). A corner converged when its last step
    is below :data:`REFINE_TOLERANCE_PX` and it stayed within its window; the others keep their
    input position."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    spacing = corner_spacing(uv) if spacing is None else np.asarray(spacing, np.float64)
    converged = np.zeros(len(uv), bool)
    if len(uv) == 0 or not np.all(np.isfinite(spacing)):
        return uv.copy(), converged
    half = REFINE_HALF_WINDOW * spacing
    blurred = _blurred(image, spacing, uv)
    out, active = uv.copy(), np.ones(len(uv), bool)
    for _ in range(REFINE_ITERATIONS):
        step = _symmetry_fit(blurred, out[active], half[active])[0]
        moved = np.linalg.norm(step, axis=1)
        good = np.isfinite(moved) & (moved < half[active])
        index = np.flatnonzero(active)
        out[index[good]] += step[good]
        converged[index[good & (moved < REFINE_TOLERANCE_PX)]] = True
        active[index[~good]] = False
        active &= ~converged
        if not active.any():
            break
    converged &= np.linalg.norm(out - uv, axis=1) < half
    return np.where(converged[:, None], out, uv), converged


def x_junctions(image: np.ndarray, uv: np.ndarray, spacing=None) -> np.ndarray:
    """``(N,)`` whether each corner is an X-junction: on a ring of :data:`RING_RADIUS` × its
    spacing round it, the blurred image split into dark and light (below) changes class exactly
    four times, at least :data:`RING_SYMMETRY` of the antipodal samples are of one class (the
    two dark squares opposite each other), and the ring's contrast is at least
    :data:`RING_CONTRAST` of the median corner's (a corner in the dark part of a lamp-lit board
    has a tenth of the contrast of one in its light). The two classes are split at the
    geometric mean of the ring's 5th and 95th percentiles (the 5th at least :data:`RING_FLOOR`
    of the 95th)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if len(uv) == 0:
        return np.zeros(0, bool)
    spacing = corner_spacing(uv) if spacing is None else np.asarray(spacing, np.float64)
    blurred = _blurred(image, spacing, uv)
    angle = np.linspace(0, 2 * np.pi, RING_SAMPLES, endpoint=False)
    ring = np.column_stack([np.cos(angle), np.sin(angle)])
    values = blurred.sample("image",
                            uv[:, None, :] + RING_RADIUS * spacing[:, None, None] * ring[None])
    low, high = np.percentile(values, 5, axis=1), np.percentile(values, 95, axis=1)
    # split at the geometric mean of the dark and light levels: a lamp can make one light
    # square half as bright as the other, which the middle of the range would cut in two
    split = np.sqrt(np.maximum(low, RING_FLOOR * high) * np.maximum(high, 0))
    light = values > split[:, None]
    changes = np.count_nonzero(light != np.roll(light, 1, axis=1), axis=1)
    symmetric = np.mean(light == np.roll(light, RING_SAMPLES // 2, axis=1), axis=1)
    contrast = high - low
    return ((changes == 4) & (symmetric >= RING_SYMMETRY)
            & (contrast >= RING_CONTRAST * np.median(contrast)))


def neighbour_residuals(uv: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """``(rows·cols,)`` how far (px) each corner of a grid (``uv`` row by row, NaN where a
    corner is missing) lies from where the homography of its grid neighbours (the 3 × 3 block
    round it, itself left out; a DLT, batched) puts it; NaN with fewer than 6 neighbours."""
    grid = np.asarray(uv, dtype=np.float64).reshape(rows, cols, 2)
    offsets = np.array([(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)])
    gi, gj = (g.ravel() for g in np.mgrid[0:rows, 0:cols])
    ni, nj = gi[:, None] + offsets[:, 0], gj[:, None] + offsets[:, 1]
    valid = (ni >= 0) & (ni < rows) & (nj >= 0) & (nj < cols)
    target = grid[np.clip(ni, 0, rows - 1), np.clip(nj, 0, cols - 1)]            # (N, 8, 2)
    valid &= np.isfinite(target).all(axis=2)
    count = valid.sum(axis=1)
    target = np.where(valid[..., None], target, 0.0)
    mean = target.sum(axis=1) / np.maximum(count, 1)[:, None]
    scale = np.sqrt(np.sum(np.where(valid[..., None], target - mean[:, None], 0) ** 2, axis=(1, 2))
                    / np.maximum(count, 1)) + 1e-12
    u = np.where(valid, (target[..., 0] - mean[:, :1]) / scale[:, None], 0)
    v = np.where(valid, (target[..., 1] - mean[:, 1:]) / scale[:, None], 0)
    x = np.broadcast_to(offsets[:, 1].astype(np.float64), u.shape)
    y = np.broadcast_to(offsets[:, 0].astype(np.float64), u.shape)
    zero, one = np.zeros_like(u), np.ones_like(u)
    A = np.concatenate([np.stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u], -1),
                        np.stack([zero, zero, zero, x, y, one, -v * x, -v * y, -v], -1)], axis=1)
    A *= np.concatenate([valid, valid], axis=1)[..., None]
    H = np.linalg.svd(A)[2][:, -1].reshape(-1, 3, 3)
    centre = H[:, :, 2]                                  # the homography at offset (0, 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        predicted = centre[:, :2] / centre[:, 2:3] * scale[:, None] + mean
        residual = np.linalg.norm(predicted - grid.reshape(-1, 2), axis=1)
    residual[count < 6] = np.nan
    return residual


@dataclass(frozen=True)
class GridCheck:
    """What :func:`check_grid` found: ``keep`` ``(N,)`` the corners that pass; ``reason``
    None when the grid is the board, else why it is not."""

    keep: np.ndarray
    reason: str | None

    @property
    def valid(self) -> bool:
        return self.reason is None


def check_grid(image: np.ndarray, uv: np.ndarray, converged: np.ndarray, rows: int,
               cols: int) -> GridCheck:
    """Whether refined corners ``uv`` (``rows × cols``, row by row) are a chessboard's grid
    (module docs), and which of them to keep."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    spacing = corner_spacing(uv)
    x_ok = x_junctions(image, uv, spacing) & np.asarray(converged, bool)
    grid = np.where(x_ok[:, None], uv, np.nan)
    tolerance = np.maximum(NEIGHBOUR_TOLERANCE * spacing, NEIGHBOUR_FLOOR_PX)
    on_grid = ~(neighbour_residuals(grid, rows, cols) > tolerance)
    # a corner that failed may have pulled its neighbours' homographies: check again without it
    grid[~on_grid] = np.nan
    on_grid = ~(neighbour_residuals(grid, rows, cols) > tolerance) & on_grid
    keep = x_ok & on_grid
    bad = ~keep.reshape(rows, cols)
    if min(rows, cols) > 1 and (bad[0].all() or bad[-1].all() or bad[:, 0].all()
                                or bad[:, -1].all()):
        return GridCheck(keep, "a whole border row or column of the grid is not X-junctions "
                               "(the grid is shifted onto another feature)")
    if bad.mean() > MAX_BAD_FRACTION:
        return GridCheck(keep, f"{int(bad.sum())} of {bad.size} corners are not X-junctions on "
                               f"one grid")
    return GridCheck(keep, None)


__all__ = ["GridCheck", "MAX_BAD_FRACTION", "check_grid", "corner_spacing",
           "neighbour_residuals", "refine_corners", "x_junctions"]
