"""A digital twin of ``ouc_flat/air``: its 14 board poses rendered with the authors' Bouguet
calibration, and the twin compared with the photos detector by detector.

    python tools/ouc_twin.py $REFSTEREO_REAL_PHOTOS/ouc_flat --out out/ouc_twin [--spp 16]
        [--exposure fixed|per-photo] [--light point|spot] [--print-jitter MM] [--sag MM]
        [--laminate ALPHA]

What is rendered (648 × 486, the camera at the reference frame's origin): the authors'
``Calib_Results_export.json`` — K (fx ≠ fy: rendered on an oversampled square-pixel film and
warped, as every distorted camera is, :func:`synth.rendering.render.render_view_counted`), the
distortion kc (Bouguet's pixels are OpenCV's: the export's poses reproject onto
``cornerSubPix`` corners at a median 0.13–0.33 px) and every photo's pose of the sub-grid the
authors clicked (``omc``, ``Tc``). The board as the photos show it: the checker of full
squares extending :data:`EXTRA_SQUARES` square beyond the clicked sub-grid on every side, a
sliver of the next squares round it where the print was cut, and the metal plate, all diffuse
(:data:`LAYOUT`), rendered by :func:`synth.products.printed_board.render_board`. The light is
**fitted to the photos** (:func:`fit_lamp`): one point lamp, the exposure and the black
squares' reflectance that best give the levels of the photos' 280 squares (91 of the 140 white
ones clipped, at 245 or above), a matte board and a linear camera assumed (``--exposure
per-photo``: an exposure per photo, as an automatic exposure would set it; ``--light spot``: a
spot lamp whose aim, cut-off and beam are fitted too, :mod:`ouc_light_models`). Stored as
the photos were: cos⁴ vignetting, the edges' blur and the noise measured on the photos
(:data:`BLUR_PX`, :data:`NOISE_DN`), the fitted exposure, linear levels over a dark level,
clipped at 250, 8 bits. ``--print-jitter``:
a ragged print (every square's edges moved by their own Gaussian offsets); ``--sag``: the
board bent along its width; ``--laminate``: a glossy coat (:mod:`synth.products.printed_board`).

What is compared, on the twin and on the photos alike (``cv2.findChessboardCorners`` with the
authors' 6 × 5 inner corners):

* plain OpenCV's calibration: ``cornerSubPix`` 5 × 5, ``calibrateCamera`` (k1 k2 p1 p2), RMS
  per photo and overall;
* a quadratic saddle refinement (Gaussian blur σ = 0.15 × corner spacing, a quadratic fitted by
  Gaussian-weighted least squares within 0.3 × spacing, its stationary point) against
  ``cornerSubPix``: how far it moves each corner (median, 90th percentile, max);
* the white squares' brightness in the stored 8-bit values: max/min per photo.

Writes ``OUT/twin_NN.png`` (the twin photos), ``OUT/compare.png`` (photos beside their twins),
``OUT/report.json`` and prints the table of docs/calibration.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # the repository

#: Full squares of the printed checker beyond the authors' clicked sub-grid, on each side (the
#: photos: a checker of 7 × 6 full squares round the 5 × 4 clicked ones, one on every side).
EXTRA_SQUARES = 1
#: The board outside the full squares, in squares from their edge, and the reflectances. As
#: the photos show it: the print cut through the next row and column of squares, so that a
#: sliver of them (black beside white, white beside black) runs round the checker, 0.16 of a
#: square wide on every side (the median over the photos' white slivers, where their level
#: falls half-way to the plate's: 0.14–0.20); then the bare metal plate, a quarter as bright
#: as the white paper; the black squares 0.12 of the white (the photos' unclipped black /
#: white levels, :func:`fit_lamp`). (Multiples of 1 / TEXELS, so that every edge falls on a
#: texel's edge: nearest-texel lookup.) Not in it: one full white square (a label written on)
#: beside a corner of the sliver ring.
LAYOUT = {"sliver": 0.15625, "plate": 1.0, "white": 0.8, "black": 0.096,
          "plate_reflectance": 0.2}
#: The photos' stored levels: a linear response (the unclipped black / white levels are
#: 0.11–0.14, which sRGB would make 0.01–0.02 in light), a dark level of 2 DN, clipped at 250.
DARK_DN, CLIP_DN = 2.0, 250.0
#: Measured on the photos: the edges' blur (the Gaussian σ an edge's steepest grey-level
#: gradient implies, median of the photos' medians 1.0 px, where the sharp twin gives 0.8 px:
#: the twin is blurred by √(1.0² − 0.8²)) and the noise (the median RMS about a plane fitted
#: to 7 × 7 pixels in the middle of each unclipped square, 1.3 DN).
BLUR_PX, NOISE_DN = 0.6, 1.3
#: Where the lamp fit may place the lamp: within this distance of the camera (mm).
LAMP_BOUND_MM = 5000.0
TEXELS = 128
PATTERN = (6, 5)


def load_export(folder):
    """``(K, kc, poses)``: the Bouguet export's intrinsics (OpenCV pixels), distortion and per
    photo ``(name, R, T mm, (n_sq_x, n_sq_y))``, in the photos' numeric order."""
    with open(os.path.join(folder, "Calib_Results_export.json")) as fh:
        d = json.load(fh)
    K = np.array([[d["fc"][0], 0.0, d["cc"][0]], [0.0, d["fc"][1], d["cc"][1]], [0, 0, 1.0]])
    poses = []
    for name in sorted(d["per_image"], key=lambda n: int(n[2:])):
        p = d["per_image"][name]
        R = cv2.Rodrigues(np.array(p["omc"], float))[0]
        poses.append((name, R, np.array(p["Tc_m"]) * 1000.0, (p["n_sq_x"], p["n_sq_y"])))
    return K, np.array(d["kc"], float), poses, d["dX"][0] * 1000.0


def board_texture(n_sq, first_dark: bool, black=None, jitter=0.0, seed=0):
    """The printed board (reflectance, float32 ``(H, W, 1)``) and its extent in grid
    coordinates (squares): the checker of ``n_sq`` + 2·:data:`EXTRA_SQUARES` full squares,
    the sliver of the next squares round it, the plate (:data:`LAYOUT`; ``black`` the black
    squares' reflectance where given). ``jitter`` (squares): a ragged print, every black
    square drawn with each of its four edges moved by its own Gaussian offset of this σ
    (:func:`ragged_dark`, ``seed``: one print for every photo)."""
    L = LAYOUT
    border = L["sliver"] + L["plate"]
    lo = -EXTRA_SQUARES - border
    size = (n_sq[0] + 2 * EXTRA_SQUARES + 2 * border, n_sq[1] + 2 * EXTRA_SQUARES + 2 * border)
    w, h = (int(round(v * TEXELS)) for v in size)
    x = lo + (np.arange(w) + 0.5) / TEXELS
    y = lo + (np.arange(h) + 0.5) / TEXELS
    X, Y = np.meshgrid(x, y)
    # distance outside the full squares (squares), 0 inside
    ex = np.maximum(np.maximum(-EXTRA_SQUARES - X, X - n_sq[0] - EXTRA_SQUARES), 0)
    ey = np.maximum(np.maximum(-EXTRA_SQUARES - Y, Y - n_sq[1] - EXTRA_SQUARES), 0)
    dark = (((np.floor(X) + np.floor(Y)) % 2 == 0) == first_dark if jitter == 0
            else ragged_dark(X, Y, first_dark, jitter, seed))
    texture = np.where(dark, L["black"] if black is None else black, L["white"])
    texture = np.where(np.maximum(ex, ey) > L["sliver"], L["plate_reflectance"], texture)
    return texture.astype(np.float32)[..., None], (lo, lo + size[0], lo, lo + size[1])


def ragged_dark(X, Y, first_dark: bool, jitter: float, seed: int) -> np.ndarray:
    """Where a ragged print is black at grid points ``(X, Y)`` (squares): the union of the
    black squares, square ``(i, j)`` spanning ``[j + l, j + 1 + r) × [i + t, i + 1 + b)`` with
    its own offsets ``l, r, t, b`` drawn from N(0, ``jitter``²)."""
    rng = np.random.default_rng(seed)
    offsets = rng.normal(0.0, jitter, (64, 64, 4))
    dark = np.zeros(X.shape, bool)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            i, j = np.floor(Y) + di, np.floor(X) + dj
            o = offsets[i.astype(int) % 64, j.astype(int) % 64]
            inside = ((X >= j + o[..., 0]) & (X < j + 1 + o[..., 1])
                      & (Y >= i + o[..., 2]) & (Y < i + 1 + o[..., 3]))
            dark |= inside & ((((i + j) % 2) == 0) == first_dark)
    return dark


def first_square_dark(photo, K, kc, R, T, square):
    """Whether the sub-grid's square (0, 0) is dark in the photo (its centre against its right
    neighbour's)."""
    centres = np.array([[0.5, 0.5, 0], [1.5, 0.5, 0]]) * square
    uv = cv2.projectPoints(centres, cv2.Rodrigues(R)[0], T, K, kc)[0].reshape(-1, 2)
    values = [photo[int(round(v)), int(round(u))] for u, v in uv]
    return values[0] < values[1]


def square_samples(photos, poses, K, kc, square):
    """The photos' squares as the lamp fit sees them: per square of every photo's clicked
    sub-grid, its centre ``P`` (mm, camera frame), the board's normal ``n`` (towards the
    camera), cos⁴ of its ray, whether it is a black square, and the stored level (the mean of
    25 points over its middle half, bilinear) and the photo's index. Arrays over all squares
    of all photos."""
    off = np.linspace(-0.25, 0.25, 5)
    du, dv = np.meshgrid(off, off)
    sub = np.stack([du.ravel(), dv.ravel()], 1)
    cols = {"P": [], "n": [], "cos4": [], "dark": [], "level": [], "photo": []}
    for k, (gray, (_, R, T, (nx, ny))) in enumerate(zip(photos, poses)):
        j, i = np.mgrid[0:nx, 0:ny]
        centres = np.column_stack([j.ravel() + 0.5, i.ravel() + 0.5])
        pts = (centres[:, None, :] + sub[None]).reshape(-1, 2)
        uv = cv2.projectPoints(np.column_stack([pts, np.zeros(len(pts))]) * square,
                               cv2.Rodrigues(R)[0], T, K, kc)[0].reshape(-1, 2).astype(np.float32)
        level = cv2.remap(gray.astype(np.float32), uv[:, :1], uv[:, 1:], cv2.INTER_LINEAR
                          ).reshape(-1, 25).mean(axis=1)
        P = (R @ (np.column_stack([centres, np.zeros(len(centres))]) * square).T).T + T
        parity = (i.ravel() + j.ravel()) % 2
        brighter = 0 if level[parity == 0].mean() > level[parity == 1].mean() else 1
        cols["P"].append(P)
        cols["n"].append(np.tile(R[:, 2] * np.sign(R[:, 2] @ -T), (len(P), 1)))
        cols["cos4"].append((P[:, 2] / np.linalg.norm(P, axis=1)) ** 4)
        cols["dark"].append(parity != brighter)
        cols["level"].append(level)
        cols["photo"].append(np.full(len(P), k))
    return {k: np.concatenate(v) for k, v in cols.items()}


def lamp_levels(params, samples):
    """The stored levels a point lamp at ``params[:3]`` (mm, camera frame) gives the squares
    before clipping: ``DARK_DN + g · ρ · cos θ / r² · cos⁴`` (white ρ = 1, black
    ``exp(params[4])``, ``g = exp(params[3]) · 10⁶``): a matte board, a linear camera."""
    d = params[:3] - samples["P"]
    r = np.linalg.norm(d, axis=1)
    cos = np.maximum(np.sum(samples["n"] * d, axis=1) / r, 1e-3)
    rho = np.where(samples["dark"], np.exp(params[4]), 1.0)
    return DARK_DN + np.exp(params[3]) * 1e6 * rho * cos / r ** 2 * samples["cos4"]


def fit_lamp(samples, per_photo: bool = False):
    """The point lamp, the exposure and the black/white ratio that best give the photos'
    square levels (least squares on their logarithms; a square clipped in the photo (≥ 245)
    only counts when the lamp leaves it below 245), from 12 starting places, the lamp within
    :data:`LAMP_BOUND_MM`. ``per_photo``: each photo its own exposure (a camera's automatic
    exposure). ``(params, exposure of each photo relative to exp(params[3]), RMS of the log
    residuals)``."""
    from scipy.optimize import least_squares

    level, clipped = samples["level"], samples["level"] >= 245
    photo = samples["photo"]
    n = int(photo.max()) + 1 if per_photo else 0

    def model(p):
        gains = np.exp(p[5:])[photo] if per_photo else 1.0
        return DARK_DN + (lamp_levels(p[:5], samples) - DARK_DN) * gains

    def residuals(p):
        m = model(p)
        return np.where(clipped, np.maximum(0.0, np.log(245.0) - np.log(m)),
                        np.log(m) - np.log(level))

    best = None
    bound = LAMP_BOUND_MM / np.sqrt(3)
    lower = [-bound] * 3 + [-np.inf] * (2 + n)
    upper = [bound] * 3 + [np.inf] * (2 + n)
    for x in (-300.0, 0.0, 300.0):
        for y in (-300.0, 300.0):
            for z in (-300.0, 200.0):
                p0 = np.concatenate([[x, y, z, 0.0, np.log(0.1)], np.zeros(n)])
                p0[3] = np.median(np.log(level - DARK_DN + 1) - np.log(lamp_levels(p0, samples)))
                fit = least_squares(residuals, p0, bounds=(lower, upper))
                if best is None or fit.cost < best.cost:
                    best = fit
    gains = np.exp(best.x[5:]) if per_photo else np.ones(int(photo.max()) + 1)
    return best.x[:5], gains, float(np.sqrt(np.mean(best.fun ** 2)))


def lamp_emitter(lamp) -> dict:
    """The Mitsuba emitter (camera frame, intensity 10⁶) of a fitted lamp: ``lamp`` a point
    lamp's position (3,) mm, or a spot's ``(x, y, z, azimuth, elevation, cut-off rad,
    beam / cut-off)`` (:mod:`ouc_light_models`)."""
    lamp = np.asarray(lamp, float)
    intensity = {"type": "rgb", "value": 1e6}
    if lamp.size == 3:
        return {"type": "point", "position": lamp.tolist(), "intensity": intensity}
    from ouc_light_models import axis_vector

    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba(None)
    axis = axis_vector(lamp[3], lamp[4])
    up = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    cutoff = float(np.degrees(lamp[5]))
    return {"type": "spot", "intensity": intensity, "cutoff_angle": cutoff,
            "beam_width": cutoff * float(lamp[6]),
            "to_world": mi.ScalarTransform4f().look_at(
                origin=lamp[:3].tolist(), target=(lamp[:3] + axis).tolist(), up=up.tolist())}


def fitted_light(samples, kind: str, per_photo: bool):
    """The light fitted to the photos' squares: ``(lamp, gain, black/white, exposures, log
    RMS)``, ``lamp`` as :func:`lamp_emitter` takes it, ``gain`` the stored levels per unit of
    rendered radiance (white paper of :data:`LAYOUT`), ``exposures`` each photo's factor on it.
    ``kind`` ``"point"`` (:func:`fit_lamp`) or ``"spot"``
    (:func:`ouc_light_models.fit_light`: a spot lamp's beam; exposures per photo bounded)."""
    if kind == "point":
        params, exposures, log_rms = fit_lamp(samples, per_photo)
        lamp, log_gain, log_black = params[:3], params[3], params[4]
    else:
        from ouc_light_models import LIGHT_PARAMS, fit_light

        params, exposures, log_rms = fit_light(samples, kind, per_photo)
        m = LIGHT_PARAMS[kind]
        lamp, log_gain, log_black = params[:m], params[m], params[m + 1]
    gain = float(np.exp(log_gain)) * np.pi / LAYOUT["white"]
    return lamp, gain, float(np.exp(log_black)), exposures, log_rms


def render_twin(K, kc, pose, square, first_dark, lamp, spp, seed, sag_mm=0.0, black=None,
                jitter_mm=0.0, laminate=None):
    """The linear render (float32 ``(486, 648)``) of one pose: the printed board
    (:func:`board_texture`, bent by ``sag_mm``, its squares' edges ragged by ``jitter_mm``)
    lit by the fitted lamp (:func:`lamp_emitter`: a point lamp at ``lamp`` mm, camera frame,
    or a spot) of intensity 1e6; under a laminate of GGX roughness ``laminate`` where given."""
    from measure import Camera
    from synth.products.printed_board import render_board

    _, R, T, n_sq = pose
    texture, (x0, x1, y0, y1) = board_texture(n_sq, first_dark, black, jitter_mm / square)
    facing = 1.0 if R[:, 2] @ -T > 0 else -1.0   # the printed side's z must point away
    flip = np.diag([1.0, 1.0, -facing])           # from the camera (board frame, mm)
    emitter = lamp_emitter(lamp)
    return render_board(Camera(K, (648, 486), dist=kc), (R @ flip, T), texture,
                        (x0 * square, x1 * square, y0 * square, y1 * square), emitter, spp,
                        seed, sag_mm=sag_mm, laminate_alpha=laminate)


def stored(linear, gain, vignette, rng):
    """A linear render as the camera stored the photos: times cos⁴ of each pixel's ray,
    blurred by :data:`BLUR_PX`, times ``gain`` (stored levels per unit of radiance: the lamp
    fit's exposure), the dark level, :data:`NOISE_DN` of noise, clipped at :data:`CLIP_DN`;
    uint8. ``vignette``: the camera's cos⁴ map
    (:func:`synth.rendering.camera_effects.cos4_map`)."""
    x = linear * vignette
    x = cv2.GaussianBlur(x, (0, 0), BLUR_PX) * gain + DARK_DN
    return np.clip(np.rint(x + rng.normal(0.0, NOISE_DN, x.shape)), 0, CLIP_DN).astype(np.uint8)


def saddle_refine(gray, uv, spacing):
    """The quadratic saddle refinement (module docs) of corners ``(N, 2)``; ``spacing`` (N,) px."""
    out = np.full_like(uv, np.nan)
    image = gray.astype(np.float64)
    for sigma in np.unique(np.round(0.15 * spacing, 1)):
        blurred = cv2.GaussianBlur(image, (0, 0), max(sigma, 0.3))
        for i in np.flatnonzero(np.round(0.15 * spacing, 1) == sigma):
            r = 0.3 * spacing[i]
            n = int(np.ceil(r))
            cu, cv_ = np.rint(uv[i]).astype(int)
            du, dv = np.meshgrid(np.arange(-n, n + 1), np.arange(-n, n + 1))
            inside = (du ** 2 + dv ** 2 <= r * r)
            uu, vv = cu + du[inside], cv_ + dv[inside]
            ok = (uu >= 0) & (vv >= 0) & (uu < gray.shape[1]) & (vv < gray.shape[0])
            x, y = (uu[ok] - uv[i, 0]), (vv[ok] - uv[i, 1])
            weight = np.exp(-(x ** 2 + y ** 2) / (2 * (r / 2) ** 2))
            A = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)]) * weight[:, None]
            a, b, c, d, e, _ = np.linalg.lstsq(A, blurred[vv[ok], uu[ok]] * weight, rcond=None)[0]
            H = np.array([[2 * a, b], [b, 2 * c]])
            if abs(np.linalg.det(H)) > 1e-12:
                out[i] = uv[i] + np.linalg.solve(H, [-d, -e])
    return out


def plain_opencv(photos):
    """Plain OpenCV on 8-bit photos: the classic detector (6 × 5), ``cornerSubPix`` 5 × 5,
    ``calibrateCamera`` (k3 fixed). ``(overall RMS, per-photo RMS {index: px}, corners {index:
    (N, 2)})``."""
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)
    objp = np.zeros((PATTERN[0] * PATTERN[1], 3), np.float32)
    objp[:, :2] = np.mgrid[0:PATTERN[0], 0:PATTERN[1]].T.reshape(-1, 2)
    found = {}
    for k, gray in enumerate(photos):
        ok, corners = cv2.findChessboardCorners(
            gray, PATTERN, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            found[k] = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)
    keys = sorted(found)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
        [objp] * len(keys), [found[k].astype(np.float32) for k in keys], photos[0].shape[::-1],
        None, None, flags=cv2.CALIB_FIX_K3)
    per_photo = {}
    for k, r, t in zip(keys, rvecs, tvecs):
        uv = cv2.projectPoints(objp, r, t, K, dist)[0].reshape(-1, 2)
        per_photo[k] = float(np.sqrt(np.mean(np.sum((uv - found[k]) ** 2, axis=1))))
    return float(rms), per_photo, found


def saddle_shifts(photos, found):
    """How far the saddle refinement moves each ``cornerSubPix`` corner (px), all photos."""
    shifts = []
    for k, uv in found.items():
        grid = uv.reshape(PATTERN[1], PATTERN[0], 2)
        spacing = np.full(len(uv), np.median(np.linalg.norm(np.diff(grid, axis=1), axis=2)))
        moved = saddle_refine(photos[k], uv, spacing)
        shifts.append(np.linalg.norm(moved - uv, axis=1))
    return np.concatenate(shifts)


def white_ratios(photos, K, kc, poses, square):
    """Per photo the stored 8-bit white squares' max/min over the clicked sub-grid (the mean of
    25 points over each square's middle half, located with the Bouguet pose)."""
    out = []
    off = np.linspace(-0.25, 0.25, 5)
    du, dv = np.meshgrid(off, off)
    for gray, (_, R, T, (nx, ny)) in zip(photos, poses):
        j, i = np.mgrid[0:nx, 0:ny]
        centres = np.column_stack([j.ravel() + 0.5, i.ravel() + 0.5])
        pts = (centres[:, None, :] + np.stack([du.ravel(), dv.ravel()], 1)[None]).reshape(-1, 2)
        uv = cv2.projectPoints(np.column_stack([pts, np.zeros(len(pts))]) * square,
                               cv2.Rodrigues(R)[0], T, K, kc)[0].reshape(-1, 2).astype(np.float32)
        levels = cv2.remap(gray.astype(np.float32), uv[:, :1], uv[:, 1:], cv2.INTER_LINEAR
                           ).reshape(-1, 25).mean(axis=1)
        parity = (i.ravel() + j.ravel()) % 2
        white = levels[parity == (0 if levels[parity == 0].mean() > levels[parity == 1].mean()
                                  else 1)]
        out.append(float(white.max() / white.min()))
    return np.array(out)


def summary(name, photos, K, kc, poses, square) -> dict:
    rms, per_photo, found = plain_opencv(photos)
    shifts = saddle_shifts(photos, found)
    ratios = white_ratios(photos, K, kc, poses, square)
    values = np.array(list(per_photo.values()))
    return {"name": name, "found": len(found), "rms": rms,
            "per_photo_rms": [float(values.min()), float(np.median(values)), float(values.max())],
            "saddle_shift": [float(np.median(shifts)), float(np.percentile(shifts, 90)),
                             float(shifts.max())], "corners": int(shifts.size),
            "white_ratio": [float(ratios.min()), float(np.median(ratios)), float(ratios.max())]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="the ouc_flat folder (Calib_Results_export.json, air/)")
    parser.add_argument("--out", required=True)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--sag", type=float, default=0.0, metavar="MM",
                        help="the board bent by this much along its width (default flat)")
    parser.add_argument("--print-jitter", type=float, default=0.0, metavar="MM",
                        help="a ragged print: each square's edges moved by N(0, MM^2) (default 0)")
    parser.add_argument("--exposure", choices=("fixed", "per-photo"), default="fixed",
                        help="one exposure for all photos (default) or one each, fitted with "
                             "the lamp (an automatic exposure)")
    parser.add_argument("--light", choices=("point", "spot"), default="point",
                        help="the fitted lamp: a point lamp (default) or a spot lamp with a "
                             "beam (its aim, cut-off and beam fitted too, "
                             "tools/ouc_light_models.py)")
    parser.add_argument("--laminate", type=float, default=None, metavar="ALPHA",
                        help="a glossy coat of this GGX roughness over the print (default matte)")
    args = parser.parse_args(argv)
    try:
        K, kc, poses, square = load_export(args.folder)
    except (OSError, KeyError, ValueError) as exc:
        print(f"error: {args.folder}: not the ouc_flat folder ({exc})", file=sys.stderr)
        return 2
    from measure import Camera
    from synth.rendering.camera_effects import cos4_map

    os.makedirs(args.out, exist_ok=True)
    photos = [cv2.imread(os.path.join(args.folder, "air", f"{p[0]}.BMP"), cv2.IMREAD_GRAYSCALE)
              for p in poses]
    lamp, gain, black_white, exposures, log_rms = fitted_light(
        square_samples(photos, poses, K, kc, square), args.light, args.exposure == "per-photo")
    black = LAYOUT["white"] * black_white
    print(f"lamp fit ({args.light}): {np.round(lamp, 3).tolist()} (mm, camera frame), "
          f"black/white {black_white:.3f}, log RMS {log_rms:.3f}; exposures "
          + " ".join(f"{e / np.median(exposures):.2f}" for e in exposures))
    vignette = cos4_map(Camera(K, (648, 486), dist=kc)).astype(np.float32)
    rng = np.random.default_rng(0)
    twins = []
    for k, pose in enumerate(poses):
        dark = first_square_dark(photos[k], K, kc, pose[1], pose[2], square)
        linear = render_twin(K, kc, pose, square, dark, lamp, args.spp, k, args.sag, black,
                             args.print_jitter, args.laminate)
        twins.append(stored(linear, gain * exposures[k], vignette, rng))
        cv2.imwrite(os.path.join(args.out, f"twin_{k + 1:02d}.png"), twins[-1])
    rows = [summary(n, p, K, kc, poses, square) for n, p in (("real", photos), ("twin", twins))]
    sheet = np.vstack([np.hstack([photos[k], twins[k]]) for k in (0, 4, 7)])
    cv2.imwrite(os.path.join(args.out, "compare.png"), sheet)
    with open(os.path.join(args.out, "report.json"), "w") as fh:
        json.dump({"rows": rows, "light": args.light, "lamp_mm": np.asarray(lamp).tolist(),
                   "black_white": black_white, "log_rms": log_rms,
                   "exposures": exposures.tolist(), "layout": LAYOUT, "noise_dn": NOISE_DN,
                   "blur_px": BLUR_PX, "sag_mm": args.sag, "print_jitter_mm": args.print_jitter,
                   "laminate_alpha": args.laminate}, fh, indent=1)
    print_table(rows)
    return 0


def print_table(rows) -> None:
    print("| | found | plain OpenCV RMS | per photo min / median / max | saddle − cornerSubPix "
          "median / p90 / max | white max/min (8-bit) min / median / max |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['name']} | {r['found']}/14 | {r['rms']:.3f} px | "
              + " / ".join(f"{v:.3f}" for v in r["per_photo_rms"]) + " px | "
              + " / ".join(f"{v:.2f}" for v in r["saddle_shift"]) + f" px ({r['corners']}) | "
              + " / ".join(f"{v:.2f}" for v in r["white_ratio"]) + " |")


if __name__ == "__main__":
    sys.exit(main())
