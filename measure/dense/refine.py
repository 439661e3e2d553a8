"""The refinement of dense matches: Gauss–Newton along the epipolar curve, all pixels at once
(:func:`refine_depths`), with windows slanted along the surface (:func:`surface_slopes`), and
the window statistics of the matching σ (:func:`fit_block`, :func:`fit_noise_levels`).

The model and its σ are described in :mod:`measure.dense.match`, which sweeps the depths this
module starts from. Units mm (depths along the rig's depth axis), images scaled to [0, 1];
OpenCV pixels ``(u, v)``, integer = pixel centre.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
from scipy import ndimage

from .blocks import (MIN_WINDOW_VARIANCE, dirty_blocks, in_chunks, right_inside,
                     split_in_chunks, tiled_blocks, window_inside, window_mean, worker_count)
from .warp import PlaneWarp

#: Gauss–Newton iterations of the refinement (it stops earlier once every step is below
#: :data:`REFINE_TOLERANCE_PX` along the epipolar curve; a pixel whose step is at most that
#: keeps its depth meanwhile).
REFINE_ITERATIONS = 14
REFINE_TOLERANCE_PX = 1e-3
#: The iterations at which the windows tilt with the surface (the first: after that many
#: fronto-parallel Gauss–Newton steps; each sooner if every step falls below the tolerance):
#: each window's depth then follows the plane fitted to the depths of its pixels whose last
#: step was at most :data:`SLOPE_STEP_PX` (:func:`surface_slopes`), and the iterations go on
#: with those slanted windows; the second fit takes the slopes of the slanted windows' depths.
#: (One fit at 3 of 10 iterations: the full-size sphere 90.0 % measured, F@1 mm 0.939; two,
#: at 3 and 7 of 14: 92.9 %, 0.957; docs/dense.md.)
SLANT_AFTER_ITERATIONS = (3, 7)
SLOPE_STEP_PX = 0.05
#: Fraction applied of a Gauss–Newton step that reverses the pixel's previous step.
REFINE_DAMPING = 0.5
#: A match counts as converged when its last Gauss–Newton step along the epipolar curve is
#: below this (px).
CONVERGED_STEP_PX = 0.01
#: Largest distance (px along the epipolar curve) the refinement may move a match from the
#: parabola's start: the sweep's peak is within half a plane step (``step_px`` / 2) of the
#: truth when it found the right peak; farther moves are drifts into another peak.
MAX_REFINE_MOVE_PX = 1.0


def gauss_newton_block(block, window, f, mean_f, var_f, g, h, rate_u, rate_v, delta, score,
                        step, speed, final, slant=None):
    """One Gauss–Newton step on the pixels of ``block`` (:class:`~measure.dense.blocks.Block`): writes their
    ``score`` (ZNCC at the current depths) and, unless ``final``, their ``step`` (the depth
    step, mm, clipped to 1 px along the curve) and ``speed`` (px/mm). ``slant``: the windows'
    depth slopes (:class:`PlaneMoments`), None for fronto-parallel windows."""
    read, inner, out = block.read, block.inner, block.out

    def box(image):
        return window_mean(image, window)[inner]

    g, h, f = g[read], h[read], f[read]
    # g'(q) = g(q) + h(q) (d_p + s_pq − d_q) = w(q) + h(q) δ_p, with δ = d − reference and
    # s_pq the slanted window's depth offset of q from p (0: fronto-parallel; PlaneMoments)
    u = g - h * delta[read]
    moments = PlaneMoments(box, block, slant)
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


class PlaneMoments:
    """Window means over a slanted window, by box filters.

    The slanted window of pixel p puts its pixel q at the depth ``d_p + s_pq`` with
    ``s_pq = α_p (x_q − x_p) + β_p (y_q − y_p)`` (``α, β``: p's depth slopes, mm per px,
    :func:`surface_slopes`). For an image ``X`` (the pixels a :class:`~measure.dense.blocks.Block` reads),
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


#: Least share of a window's pixels that must hold a depth for :func:`surface_slopes` to fit
#: its plane (fewer: the window stays fronto-parallel).
SLOPE_MIN_SHARE = 0.5


def surface_slopes(depth, use, window, pool=None):
    """Each pixel's depth slopes ``(α, β)`` (mm per px along u and v, each ``(H, W)``): the
    least-squares plane ``d = c + α x + β y`` through the depths ``depth`` of the pixels
    ``use`` (bool ``(H, W)``) in its window, by box filters; 0 where fewer than
    :data:`SLOPE_MIN_SHARE` of the window's pixels are used. ``pool`` (a thread pool), if
    given, shares the blocks (:func:`~measure.dense.blocks.tiled_blocks`) out over its threads."""
    alpha, beta = np.zeros(depth.shape), np.zeros(depth.shape)

    def fit(block):
        part_depth, part_use = depth[block.read], use[block.read]
        height, width = part_depth.shape
        m = part_use.astype(np.float64)
        d = np.where(part_use, part_depth, 0.0)
        x = np.broadcast_to((np.arange(width) - 0.5 * (width - 1))[None, :], m.shape)
        y = np.broadcast_to((np.arange(height) - 0.5 * (height - 1))[:, None], m.shape)

        def box(image):
            return window_mean(np.ascontiguousarray(image, dtype=np.float64), window)[block.inner]

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

    blocks = tiled_blocks(depth.shape, window // 2)
    list(map(fit, blocks) if pool is None else pool.map(fit, blocks))
    return alpha, beta


#: Intensity bins of :func:`fit_noise_levels` (quantiles of the matched pixels' intensities) and
#: the least ZNCC of a pixel that enters them.
NOISE_LEVEL_BINS = 16
NOISE_LEVEL_MIN_SCORE = 0.8


def fit_noise_levels(f, fit, use, window):
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


def fit_block(block, window, f, mean_f, var_f, g, h, h_true, delta, fit, weight=None,
              slant=None):
    """The window statistics of :func:`~measure.dense.match.matching_sigma` (``fit``: ``gain``,
    ``information``, ``residual`` ``(H, W)``) at the final depths, on the pixels of ``block``
    (:class:`~measure.dense.blocks.Block`).

    The refinement's fixed point makes the left window ``f`` orthogonal to its regressor ``S``
    (its derivative ``h``, :data:`DERIVATIVE_KERNEL`) once the offset and the gain's regressor
    ``G`` (the right samples extrapolated to the centre's depth, as in :func:`gauss_newton_block`) are
    projected out: ``Σ S̃ (f − a G(δ) − b) = 0``. Linearised, ``δ̂ − δ = Σ S̃ ε / (a Σ S̃ T̃)``
    with ``T`` the true derivative ``h_true`` (:func:`curve_derivative`), so
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
        return window_mean(image, window)[inner]

    g, h, t, f = g[read], h[read], h_true[read], f[read]
    own_f, own_g = f[inner], g[inner]
    u = g - h * delta[read]
    # the slanted window's samples w = u + h s (see gauss_newton_block), written u below
    moments = PlaneMoments(box, block, slant)
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
SAMPLE_COLUMNS = 16384


def sample_at(image, u, v):
    """``cv2.remap`` (bicubic, constant 0 outside) of ``image`` at the points ``(u, v)`` (each
    ``(N,)``): the same values a full-image map holding these points gives."""
    n = u.size
    rows = max(1, -(-n // SAMPLE_COLUMNS))
    columns = min(max(n, 1), SAMPLE_COLUMNS)
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
#: :func:`curve_derivative` combines (Richardson: ``(4 D(ε₁) − D(ε₂)) / 3``).
CURVE_DERIVATIVE_STEPS_PX = (0.5, 1.0)


def curve_derivative(image, u, v, rate_u, rate_v):
    """``∂g/∂d`` (intensity per mm) of the bicubic interpolant of ``image`` at ``(u, v)`` along
    the curve of rate ``(rate_u, rate_v)`` px/mm, each ``(N,)``: Richardson-extrapolated central
    differences of :func:`sample_at` (error O(ε⁴); the amplitude at 1 rad/px is 0.998 of the
    truth). The refinement's :data:`DERIVATIVE_KERNEL` is close to it but not the same; the
    sandwich of :func:`fit_block` takes both."""
    speed = np.hypot(rate_u, rate_v)
    with np.errstate(invalid="ignore", divide="ignore"):
        tu, tv = rate_u / speed, rate_v / speed
    small, large = CURVE_DERIVATIVE_STEPS_PX

    def central(eps):
        return (sample_at(image, u + eps * tu, v + eps * tv).astype(np.float64)
                - sample_at(image, u - eps * tu, v - eps * tv)) / (2 * eps)

    return (4 * central(small) - central(large)) / 3 * speed


def refine_depths(warp: PlaneWarp, left, right, start, candidate, window, depth_range,
                  times=None, fit=None, slanted=True):
    """Gauss–Newton along the epipolar curve (see :mod:`measure.dense.match`), all pixels at once.

    A pixel whose step falls to :data:`REFINE_TOLERANCE_PX` or below keeps its depth (its step
    is not applied), so its projection and samples stay valid; only pixels whose depth moved
    are projected and sampled again, and only the windows that hold such a pixel are summed again
    (a kept pixel moves again if its neighbours' moves push its step above the tolerance).

    ``left``, ``right``: float32 images in [0, 1]; ``start``: the sweep's depths (mm, ``(H, W)``);
    ``candidate``: the pixels to refine (bool ``(H, W)``). Returns the refined depth ``(H, W)``
    (mm), the ZNCC at it, the right pixels ``(H, W, 2)`` and whether the pixel converged (last
    step below :data:`CONVERGED_STEP_PX`, depth inside ``depth_range``, whole right window
    inside the right image). ``times`` (a dict), if given, receives the seconds spent in the
    set-up (rays, nearest candidates), in projecting and sampling, in the window sums and
    steps, in the σ statistics and in the checks. ``fit`` (a dict), if given, receives the
    window statistics of the final depths (:func:`fit_block`'s ``gain``, ``information``,
    ``residual``, ``pixel_residual`` ``(H, W)`` and ``rate`` ``(H, W, 2)``); with
    ``fit["noise_levels"]`` true also ``levels`` (:func:`fit_noise_levels`, from the candidates
    of ZNCC ≥ :data:`NOISE_LEVEL_MIN_SCORE`) and ``weighted`` (a second pass with each
    pixel's noise)."""
    t_start = time.perf_counter()
    height, width = left.shape
    if fit is not None:
        fit.update({k: np.full((height, width), np.nan) for k in ("gain", "information",
                                                                   "residual")})
        fit["rate"] = np.full((height, width, 2), np.nan)
    if not candidate.any():
        empty = np.full(left.shape, np.nan)
        return empty, empty, np.full(left.shape + (2,), np.nan), np.zeros(left.shape, bool)
    state = _Refinement(warp, left, right, start, candidate, window)
    with ThreadPoolExecutor(max_workers=state.workers) as pool:
        t_setup = time.perf_counter() - t_start
        t_project, t_sums = state.iterate(pool, SLANT_AFTER_ITERATIONS if slanted else ())
        t_fit = time.perf_counter()
        if fit is not None:  # the window statistics of the matching σ at the final depths
            state.fit_statistics(pool, fit)
        t_fit = time.perf_counter() - t_fit
    converged = state.converged(depth_range)
    if fit is not None:
        fit["rate"] = np.stack([state.rate_u, state.rate_v], axis=-1)
    if times is not None:
        times.update({"refine set-up": t_setup, "refine projection": t_project,
                      "refine sums": t_sums, "refine sigma": t_fit,
                      "refine checks": time.perf_counter() - t_start - t_setup - t_project
                      - t_sums - t_fit})
    return state.depth, state.score, state.uv_right, converged


class _Refinement:
    """The state of :func:`refine_depths`: the active pixels (the candidates and the pixels of
    their windows, which follow their nearest candidate's depth), their water rays, and per
    pixel ``(H, W)`` the depth (mm), the right pixel and the samples there — of the right image
    (``g``), of its derivative along the epipolar curve (``h``) and the curve's rate (px/mm); 0
    elsewhere, like a map off the image — and the last Gauss–Newton step, speed and score."""

    def __init__(self, warp: PlaneWarp, left, right, start, candidate, window):
        height, width = left.shape
        self.warp, self.right, self.start, self.window = warp, right, start, window
        self.candidate = candidate
        kernel = np.ones((window, window), np.uint8)
        self.active = active = cv2.dilate(candidate.astype(np.uint8), kernel).astype(bool)
        rows, cols = np.nonzero(active)
        # Pixels in the windows of candidates that are no candidates themselves follow their
        # nearest candidate's depth: their own sweep answer may be anything, and through
        # g(d_p) ≈ g(d_q) + ∂g/∂d (d_p − d_q) a wrong d_q would spoil their neighbours' windows.
        nearest = ndimage.distance_transform_edt(~candidate, return_distances=False,
                                                 return_indices=True)
        self.followers = followers = np.nonzero(active & ~candidate)
        self.leaders = leaders = (nearest[0][followers], nearest[1][followers])
        self.follower_du = (followers[1] - leaders[1]).astype(np.float64)
        self.follower_dv = (followers[0] - leaders[0]).astype(np.float64)
        self.workers = worker_count()
        self.origins, self.directions = in_chunks(
            warp.water_rays, np.stack([cols, rows], axis=1).astype(np.float64), self.workers)
        self.gradient_u = cv2.filter2D(right, cv2.CV_32F, DERIVATIVE_KERNEL,
                                       borderType=cv2.BORDER_REFLECT)
        self.gradient_v = cv2.filter2D(right, cv2.CV_32F, DERIVATIVE_KERNEL.T,
                                       borderType=cv2.BORDER_REFLECT)
        self.f = f = left.astype(np.float64)
        self.mean_f = window_mean(f, window)
        self.var_f = window_mean(f * f, window) - self.mean_f * self.mean_f
        self.depth = depth = start.astype(np.float64).copy()
        depth[followers] = depth[leaders]
        self.reference = float(np.median(depth[active])) if rows.size else 0.0
        self.step_px = np.full((height, width), np.inf)
        self.uv_right = np.full((height, width, 2), np.nan)
        self.map_u = np.full((height, width), -1e6, np.float32)
        self.map_v = np.full((height, width), -1e6, np.float32)
        self.g, self.h = np.zeros((height, width)), np.zeros((height, width))
        self.rate_u, self.rate_v = np.zeros((height, width)), np.zeros((height, width))
        # flat views of the per-pixel images, indexed by the active pixels' flat indices
        self.at_active = rows * width + cols
        self.flat = {name: getattr(self, attr).reshape(height * width, *getattr(self, attr)
                                                      .shape[2:])
                     for name, attr in (("depth", "depth"), ("uv", "uv_right"),
                                        ("map_u", "map_u"), ("map_v", "map_v"), ("g", "g"),
                                        ("h", "h"), ("rate_u", "rate_u"), ("rate_v", "rate_v"))}
        self.position = np.full(height * width, -1, np.int64)
        self.position[self.at_active] = np.arange(rows.size)
        self.score = np.full((height, width), np.nan)
        self.step = np.zeros((height, width))  # the last Gauss–Newton step of every pixel (mm)
        self.speed = np.zeros((height, width))
        self.slant = None
        self.every_block = tiled_blocks(left.shape, window // 2)

    def project(self, chunk) -> None:
        """Project and sample the active pixels ``chunk`` (indices into the active pixels) at
        their depths, into the per-pixel images (each chunk writes its own pixels)."""
        flat, at = self.flat, self.at_active[chunk]
        pixels, rate = self.warp.right_pixels_at_depth(self.origins[chunk],
                                                       self.directions[chunk], flat["depth"][at])
        u_m, v_m = pixels[:, 0].astype(np.float32), pixels[:, 1].astype(np.float32)
        flat["uv"][at] = pixels
        flat["map_u"][at], flat["map_v"][at] = u_m, v_m
        flat["rate_u"][at], flat["rate_v"][at] = rate[:, 0], rate[:, 1]
        flat["g"][at] = sample_at(self.right, u_m, v_m)
        flat["h"][at] = sample_at(self.gradient_u, u_m, v_m) * rate[:, 0] \
            + sample_at(self.gradient_v, u_m, v_m) * rate[:, 1]

    def project_all(self, pool, mask) -> None:
        """:meth:`project` the pixels ``mask`` (bool ``(H, W)``) in chunks on ``pool``."""
        chosen = self.position[np.flatnonzero(mask)]
        if chosen.size:
            list(pool.map(self.project, split_in_chunks(chosen, self.workers, 50_000)))

    def follow(self) -> None:
        """Followers take their leader's depth (on its slanted window's plane, if any)."""
        depth, leaders, slopes = self.depth, self.leaders, self.slant
        depth[self.followers] = depth[leaders]
        if slopes is not None:
            depth[self.followers] += slopes[0][leaders] * self.follower_du \
                + slopes[1][leaders] * self.follower_dv

    def sums(self, pool, blocks, final) -> None:
        """The window sums and Gauss–Newton steps of ``blocks`` (:func:`gauss_newton_block`)."""
        delta = self.depth - self.reference
        list(pool.map(lambda block: gauss_newton_block(
            block, self.window, self.f, self.mean_f, self.var_f, self.g, self.h, self.rate_u,
            self.rate_v, delta, self.score, self.step, self.speed, final, self.slant), blocks))

    def iterate(self, pool, schedule) -> tuple[float, float]:
        """Up to :data:`REFINE_ITERATIONS` steps, the windows slanted at the iterations of
        ``schedule`` (or sooner, once every step is below the tolerance); returns the seconds
        spent projecting and in the sums."""
        t_project = t_sums = 0.0
        depth, active, halo = self.depth, self.active, self.window // 2
        moved = active.copy()  # pixels whose depth changed: project them again
        last_change = np.zeros(depth.shape)
        previous = np.empty(depth.shape)
        settled, fits, blocks = False, 0, self.every_block
        for iteration in range(REFINE_ITERATIONS + 1):
            t0 = time.perf_counter()
            if fits < len(schedule) and (iteration >= schedule[fits] or settled):
                # tilt every window with the surface: the plane through its settled depths
                self.slant = surface_slopes(
                    depth, self.candidate & (self.step_px <= SLOPE_STEP_PX), self.window, pool)
                fits, settled = fits + 1, False
                np.copyto(previous, depth)
                self.follow()
                moved |= active & (depth != previous)
                blocks = self.every_block  # every window's sums change with its slopes
            final = iteration == REFINE_ITERATIONS
            self.project_all(pool, moved)
            t1 = time.perf_counter()
            # only the windows that hold a moved pixel change: the others keep their score,
            # step and speed (the same inputs give the same sums)
            self.sums(pool, blocks, final)
            t_project += t1 - t0
            if final:
                t_sums += time.perf_counter() - t1
                break
            self.step_px = np.where(active, np.abs(self.step) * self.speed, 0.0)
            last_change = self.apply_steps(last_change, previous, moved)
            blocks = dirty_blocks(moved, halo)
            t_sums += time.perf_counter() - t1
            if not np.any(self.step_px[self.candidate] > REFINE_TOLERANCE_PX):
                if fits == len(schedule):
                    break
                settled = True
        return t_project, t_sums

    def apply_steps(self, last_change, previous, moved) -> np.ndarray:
        """Each pixel's step applied (none below the tolerance: it keeps depth and samples; a
        step against its previous one, an oscillation of the coupled windows, damped); the
        followers follow, ``moved`` set to the pixels whose depth changed. Returns the steps."""
        change = np.where(self.step_px > REFINE_TOLERANCE_PX, self.step, 0.0)
        change = np.where(change * last_change < 0, change * REFINE_DAMPING, change)
        np.copyto(previous, self.depth)
        self.depth += change
        self.follow()
        np.not_equal(self.depth, previous, out=moved)
        moved &= self.active
        return change

    def fit_statistics(self, pool, fit) -> None:
        """``fit``'s window statistics (:func:`fit_block`) at the final depths; with
        ``fit["noise_levels"]`` also the noise levels and the second, weighted pass."""
        flat, at_active, window = self.flat, self.at_active, self.window
        h_curve = np.zeros_like(self.h)
        h_curve.reshape(-1)[at_active] = in_chunks(
            lambda at: (curve_derivative(self.right, flat["map_u"][at], flat["map_v"][at],
                                         flat["rate_u"][at], flat["rate_v"][at]),),
            at_active, self.workers)[0]
        delta = self.depth - self.reference
        shape = self.depth.shape
        fit.update({k: np.full(shape, np.nan) for k in ("pixel_residual", "weighted")})

        def blocks_pass(weight=None):
            list(pool.map(lambda block: fit_block(
                block, window, self.f, self.mean_f, self.var_f, self.g, self.h, h_curve, delta,
                fit, weight, self.slant), self.every_block))

        blocks_pass()
        if not fit.get("noise_levels"):
            return
        levels = fit_noise_levels(self.f, fit,
                                  self.candidate & (self.score >= NOISE_LEVEL_MIN_SCORE), window)
        if levels is not None:
            fit["levels"] = levels
            gain = np.nan_to_num(fit["gain"])
            weight = np.interp(self.f, *levels) + gain * gain * np.interp(self.g, *levels)
            weight[~self.active] = 0.0
            blocks_pass(weight)

    def converged(self, depth_range) -> np.ndarray:
        """Bool ``(H, W)``: last step below :data:`CONVERGED_STEP_PX`, depth inside
        ``depth_range`` (mm), the whole right window inside the right image, a score, and moved
        at most :data:`MAX_REFINE_MOVE_PX` from the sweep's start."""
        inside = window_inside(right_inside(self.map_u, self.map_v, self.warp.rig.right.size),
                               self.window)
        near, far = depth_range
        with np.errstate(invalid="ignore"):
            moved_px = np.abs(self.depth - self.start) * self.speed
            return inside & (self.step_px < CONVERGED_STEP_PX) & (self.depth >= near) \
                & (self.depth <= far) & np.isfinite(self.score) \
                & (moved_px <= MAX_REFINE_MOVE_PX)
