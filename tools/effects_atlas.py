"""An atlas of what each effect of a real photo does to a chessboard calibration: the project's
detector (:meth:`measure.calibration.board.Board.detect`) beside plain OpenCV
(``findChessboardCorners`` + ``cornerSubPix`` 5 × 5), both against the renders' truth.

    python tools/effects_atlas.py --out out/atlas [--poses 10] [--spp 4] [--effects a,b]

One camera (640 × 480, fx = fy = 600 px, principal point (320, 240), k1 −0.1, k2 0.05), a
9 × 7-square chessboard of 30 mm (8 × 6 inner corners) printed with a one-square white margin
on matte paper (reflectances 0.04 / 0.8), ``--poses`` poses drawn once (centre 350–600 mm
away, tilted 10–40°, the corners inside the image), cast by :class:`RayCaster` (16 stratified
rays per pixel through the true lens onto the board, lit by a point lamp) and stored as an
8-bit sRGB photo (white at the 99.5th percentile of the board, 1 DN of Gaussian noise) — the
baseline. Then each effect alone at three or four strengths (:data:`EFFECTS`):

* ``light``: a point lamp beside the camera instead of one 2 m behind it (white squares'
  max/min measured and reported);
* ``vignetting``: cos⁴ of each pixel's ray times a lens falloff ``1 − F (r / r_corner)²``;
* ``defocus``: the linear image convolved with a disc of radius r px (a thin lens's blur
  circle, the same over the board);
* ``motion``: the board moving in its plane during the exposure, a blur of L px at its centre
  (the average of 8 images across the exposure; the truth at mid-exposure);
* ``rolling``: a rolling shutter, the board moving during a readout so that the image shears
  by S px over the frame's height (every row cast at its own instant; the truth of each corner
  at its own row's instant);
* ``laminate``: a glossy coat (GGX roughness α) with the lamp beside the camera, rendered by
  Mitsuba at ``--spp`` (:mod:`synth.products.printed_board`) beside Mitsuba's matte print
  under that lamp;
* ``sag``: the board bent by s mm along its width (the truth bent with it);
* ``noise``: Gaussian noise σ DN and JPEG quality q.

Each condition: the corners' error against the truth (RMS over the corners found, px), and a
calibration (k1 k2 p1 p2, k3 fixed) from each detector's corners: fx and principal-point
errors against the truth, fx's error over its σ (OpenCV's ``stdDeviationsIntrinsics``) and the
RMS. Writes ``OUT/atlas.json``, ``OUT/atlas.png`` and prints the table of docs/realism.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import cv2
import numpy as np

SIZE = (640, 480)
K_TRUE = np.array([[600.0, 0, 320.0], [0, 600.0, 240.0], [0, 0, 1]])
DIST_TRUE = np.array([-0.1, 0.05, 0.0, 0.0, 0.0])
SQUARES, SQUARE_MM = (9, 7), 30.0
NOISE_DN = 1.0
#: A lamp far behind the camera: the baseline's nearly even light (radiant intensity scaled
#: so that the board's radiance is about the same wherever the lamp is).
FAR_LAMP_MM = (0.0, 0.0, -2000.0)
#: Effects and their three strengths (the units of each in the module docs).
EFFECTS = {
    "light": [(-200.0, -150.0, 0.0), (-300.0, -200.0, 300.0), (-400.0, -100.0, 400.0)],
    "vignetting": [0.3, 0.5, 0.7],
    "defocus": [1.0, 2.0, 3.0],
    "motion": [1.0, 2.0, 4.0],
    "rolling": [2.0, 5.0, 10.0],
    "laminate": [None, 0.3, 0.15, 0.05],
    "sag": [0.5, 1.0, 2.0, 4.0],
    "noise": [(2.0, 95), (4.0, 80), (8.0, 60)],
}
UNITS = {"light": "lamp at X,Y,Z mm", "vignetting": "falloff F", "defocus": "disc radius px",
         "motion": "blur px", "rolling": "shear px / frame", "laminate": "GGX α",
         "sag": "mm", "noise": "σ DN, JPEG q"}
MOTION_STEPS = 8
PATTERN = (SQUARES[0] - 1, SQUARES[1] - 1)


def setup():
    """``(camera, board, texture, extent)``: the atlas's camera, board and printed sheet."""
    from measure import Camera
    from measure.calibration.board import Board
    from synth.products.board_light import BoardLight

    board = Board("chessboard", SQUARES, SQUARE_MM)
    outline = board.outline()
    extent = (outline[:, 0].min(), outline[:, 0].max(), outline[:, 1].min(), outline[:, 1].max())
    texture = BoardLight().reflectance(board.pattern(32))
    return Camera(K_TRUE, SIZE, dist=DIST_TRUE), board, texture, extent


def draw_poses(n: int, board, seed: int = 1) -> list:
    """``n`` board poses ``(R, t)`` (board → camera, mm): centre 350–600 mm away, tilted 10 to
    40° about a random axis in the board's plane, turned up to 20° about its normal, the
    corners (and 10 px round them) inside the image."""
    rng = np.random.default_rng(seed)
    w, h = board.size_mm
    corners = board.corners()
    poses = []
    while len(poses) < n:
        axis = rng.normal(size=2)
        tilt = np.radians(rng.uniform(10, 40)) * np.append(axis / np.linalg.norm(axis), 0)
        R = cv2.Rodrigues(tilt)[0] @ cv2.Rodrigues(np.array([0, 0, rng.uniform(-0.35, 0.35)]))[0]
        z = rng.uniform(350, 600)
        centre = np.array([rng.uniform(-0.25, 0.25) * z, rng.uniform(-0.2, 0.2) * z, z])
        t = centre - R @ np.array([w / 2, h / 2, 0])
        uv = project(corners, (R, t))
        if np.all((uv > 10) & (uv < np.array(SIZE) - 10)):
            poses.append((R, t))
    return poses


def project(points, pose) -> np.ndarray:
    """Board points ``(N, 3)`` mm to the true camera's pixels ``(N, 2)`` (OpenCV)."""
    R, t = pose
    return cv2.projectPoints(np.asarray(points, float), cv2.Rodrigues(R)[0], np.asarray(t, float),
                             K_TRUE, DIST_TRUE)[0].reshape(-1, 2)


def lamp(position) -> dict:
    """A point lamp at ``position`` (mm, camera frame), its intensity scaled by its distance to
    500 mm ahead so that the board's whites stay about as bright (linear units)."""
    r = np.linalg.norm(np.subtract(position, (0, 0, 500.0))) / 1000.0
    return {"type": "point", "position": [float(v) for v in position],
            "intensity": {"type": "rgb", "value": float(np.pi / 0.8 * 1e6 * r * r)}}


class RayCaster:
    """The board's image by casting each pixel's rays (``sub`` × ``sub`` per pixel, stratified
    and jittered: a box filter) through the true camera (``cv2.undistortPoints``) onto the
    board — a plane or the bent sheet of :func:`synth.products.printed_board.sag_z` — lit by a point lamp: a
    matte print's radiance ``ρ · cos θ / r²`` (Lambert, no interreflection: one surface). The
    rays are the camera's, computed once; each row may see the board at its own instant
    (``row_shift``), so a rolling shutter is exact, not banded. Linear float32 ``(H, W)``."""

    def __init__(self, extent, sub: int = 4, seed: int = 0):
        w, h = SIZE
        rng = np.random.default_rng(seed)   # stratified: one random point in each cell
        o = (np.arange(sub) + 0.5) / sub - 0.5
        u = np.broadcast_to(np.arange(w)[None, :, None, None] + o[None, None, None, :],
                            (h, w, sub, sub)) + rng.uniform(-0.5, 0.5, (h, w, sub, sub)) / sub
        v = np.broadcast_to(np.arange(h)[:, None, None, None] + o[None, None, :, None],
                            (h, w, sub, sub)) + rng.uniform(-0.5, 0.5, (h, w, sub, sub)) / sub
        pts = np.stack([u, v], -1).reshape(-1, 1, 2).astype(np.float64)
        xy = cv2.undistortPoints(pts, K_TRUE, DIST_TRUE,
                                 criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50,
                                           1e-12)).reshape(-1, 2)
        s2 = sub * sub
        self.d = np.column_stack([xy, np.ones(len(xy))]).reshape(h, w, s2, 3)  # rays, camera
        self.sub, self.extent = sub, extent

    def render(self, pose, lamp_mm, sag_mm: float = 0.0, row_shift=None) -> np.ndarray:
        """The image of the board at ``pose`` (board → camera, mm); ``row_shift`` ``(H, 3)``
        mm: the board's translation (camera frame) while row v is exposed."""
        R, t = pose
        w, h = SIZE
        (u0, u1), (v0, v1) = self._box(pose, sag_mm, row_shift)
        d = self.d[v0:v1, u0:u1].reshape(-1, 3)
        if row_shift is None:
            t = np.broadcast_to(t, (len(d), 3))
        else:
            t = t + np.repeat(row_shift[v0:v1], (u1 - u0) * self.sub ** 2, axis=0)
        a = d @ R                           # R^T d, per ray
        b = (t @ R)                         # R^T t
        lam = self._hit(a, b, sag_mm)
        p = lam[:, None] * a - b            # board frame (mm)
        x0, x1, y0, y1 = self.extent
        inside = (p[:, 0] >= x0) & (p[:, 0] < x1) & (p[:, 1] >= y0) & (p[:, 1] < y1) & (lam > 0)
        i, j = np.floor(p[:, 1] / SQUARE_MM), np.floor(p[:, 0] / SQUARE_MM)
        dark = ((i + j) % 2 == 0) & (i >= 0) & (j >= 0) & (i < SQUARES[1]) & (j < SQUARES[0])
        rho = np.where(dark, 0.04, 0.8)
        X = lam[:, None] * d                # camera frame
        normal = (np.broadcast_to(R[:, 2], X.shape) if sag_mm == 0
                  else self._normal(p, sag_mm) @ R.T)
        to_lamp = np.asarray(lamp_mm, float) - X
        r = np.linalg.norm(to_lamp, axis=1)
        cos = np.abs(np.sum(normal * to_lamp, axis=1)) / r
        facing = np.sign(np.sum(normal * to_lamp, axis=1)) == np.sign(np.sum(normal * -X, axis=1))
        scale = (np.linalg.norm(np.subtract(lamp_mm, (0, 0, 500.0))) / 1000.0) ** 2 * 1e6 / 0.8
        value = np.where(inside & facing, rho * cos / r ** 2 * scale, 0.0)
        image = np.zeros((h, w), np.float32)
        image[v0:v1, u0:u1] = value.reshape(v1 - v0, u1 - u0, -1).mean(axis=2)
        return image

    def _box(self, pose, sag, row_shift):
        """The pixel box ``((u0, u1), (v0, v1))`` that holds the board's image (its sheet's
        outline, nearer by the sag, moved by the largest row shift) and 3 px round it."""
        x0, x1, y0, y1 = self.extent
        xs, ys = np.meshgrid(np.linspace(x0, x1, 9), np.linspace(y0, y1, 9))
        pts = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
        pts = np.vstack([pts, pts - [0, 0, abs(sag)]])
        shifts = [np.zeros(3)] if row_shift is None else [row_shift[0], row_shift[-1]]
        R, t = pose
        cam = np.vstack([(R @ pts.T).T + t + s for s in shifts])
        uv = cv2.projectPoints(cam, np.zeros(3), np.zeros(3), K_TRUE, DIST_TRUE)[0].reshape(-1, 2)
        w, h = SIZE
        lo = np.clip(np.floor(uv.min(axis=0)) - 3, 0, [w, h]).astype(int)
        hi = np.clip(np.ceil(uv.max(axis=0)) + 4, 0, [w, h]).astype(int)
        return (lo[0], hi[0]), (lo[1], hi[1])

    def _hit(self, a, b, sag):
        """Each ray's λ where it meets the board (ray ``λ a − b`` in the board frame)."""
        if sag == 0:
            return b[:, 2] / a[:, 2]
        x0, x1 = self.extent[:2]
        xc, hw = (x0 + x1) / 2, (x1 - x0) / 2
        # a_z λ − b_z = −sag + sag ((a_x λ − b_x − xc) / hw)²
        k = sag / hw ** 2
        e = b[:, 0] + xc
        A = k * a[:, 0] ** 2
        B = -2 * k * a[:, 0] * e - a[:, 2]
        C = k * e ** 2 - sag + b[:, 2]
        disc = np.sqrt(np.maximum(B * B - 4 * A * C, 0))
        flat = b[:, 2] / a[:, 2]
        roots = np.stack([(-B - disc) / (2 * A), (-B + disc) / (2 * A)])
        nearest = roots[np.argmin(np.abs(roots - flat), axis=0), np.arange(len(flat))]
        return np.where(np.abs(A) > 1e-15, nearest, flat)

    def _normal(self, p, sag):
        """The sheet's unit normal (board frame) at board points ``p``."""
        x0, x1 = self.extent[:2]
        xc, hw = (x0 + x1) / 2, (x1 - x0) / 2
        dzdx = 2 * sag * (p[:, 0] - xc) / hw ** 2
        n = np.column_stack([-dzdx, np.zeros(len(p)), np.ones(len(p))])
        return n / np.linalg.norm(n, axis=1)[:, None]


def stored(linear, rng, noise_dn: float = NOISE_DN, jpeg: int | None = None) -> np.ndarray:
    """A linear image as a camera stores it: over its white (the 99.5th percentile of the lit
    pixels), sRGB-encoded, Gaussian noise of ``noise_dn``, 8 bits, and a JPEG of quality
    ``jpeg`` decoded again where given. uint8 ``(H, W)``."""
    lit = linear[linear > 0]
    x = np.clip(linear / (np.percentile(lit, 99.5) if lit.size else 1.0), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055) * 255.0
    out = np.clip(np.rint(srgb + rng.normal(0.0, noise_dn, srgb.shape)), 0, 255).astype(np.uint8)
    if jpeg is not None:
        out = cv2.imdecode(cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, jpeg])[1],
                           cv2.IMREAD_GRAYSCALE)
    return out


def vignetting(falloff: float) -> np.ndarray:
    """cos⁴ of each pixel's ray (through the true lens) times ``1 − F (r / r_corner)²``."""
    w, h = SIZE
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xy = cv2.undistortPoints(np.stack([u, v], -1).reshape(-1, 1, 2), K_TRUE, DIST_TRUE)
    cos4 = 1.0 / (1.0 + np.sum(xy.reshape(h, w, 2) ** 2, axis=2)) ** 2
    r2 = ((u - K_TRUE[0, 2]) ** 2 + (v - K_TRUE[1, 2]) ** 2) / (
        max(K_TRUE[0, 2], w - K_TRUE[0, 2]) ** 2 + max(K_TRUE[1, 2], h - K_TRUE[1, 2]) ** 2)
    return (cos4 * (1.0 - falloff * r2)).astype(np.float32)


def defocus(linear, radius_px: float) -> np.ndarray:
    """The linear image convolved with a uniform disc of ``radius_px`` (area-weighted on an
    8× finer grid at its rim)."""
    n = int(np.ceil(radius_px))
    fine = (np.arange(-(2 * n + 1) * 4, (2 * n + 1) * 4) + 0.5) / 8   # centred on pixel 0
    X, Y = np.meshgrid(fine, fine)
    disc = (X ** 2 + Y ** 2 <= radius_px ** 2).astype(np.float64)
    kernel = disc.reshape(2 * n + 1, 8, 2 * n + 1, 8).sum(axis=(1, 3))
    return cv2.filter2D(linear, -1, (kernel / kernel.sum()).astype(np.float32),
                        borderType=cv2.BORDER_CONSTANT)


def moving(pose, shift_px: float, fraction):
    """The pose moved along the camera's x by ``fraction`` (scalar or (H,)) of a motion that
    moves the board's centre's image by ``shift_px``: the translation (mm) per fraction."""
    R, t = pose
    centre = R @ np.array([SQUARES[0] * SQUARE_MM / 2, SQUARES[1] * SQUARE_MM / 2, 0]) + t
    step = shift_px * centre[2] / K_TRUE[0, 0]
    return np.outer(np.atleast_1d(fraction), [step, 0.0, 0.0])


def rolling_truth(points, pose, shift_px: float) -> np.ndarray:
    """Pixels of board points with a rolling shutter: each at the instant of its own row
    (``fraction = v / (H − 1) − ½`` of the shift; fixed-point iteration to 1e-9 px)."""
    R, t = pose
    uv = project(points, pose)
    for _ in range(50):
        frac = uv[:, 1] / (SIZE[1] - 1) - 0.5
        new = np.array([project(p[None], (R, t + d))[0]
                        for p, d in zip(points, moving(pose, shift_px, frac))])
        done = np.max(np.abs(new - uv)) < 1e-9
        uv = new
        if done:
            break
    return uv


def condition(effect, strength, poses, caster, base, ctx, seed):
    """The stored images (uint8) and their truths ``(48, 2)`` of one effect at one strength
    (``None``: the baseline), one per pose; ``base`` the baseline's linear renders."""
    from synth.products.printed_board import bent_points, render_board

    rng = np.random.default_rng(seed)
    corners = ctx["board"].corners()
    images, truths = [], []
    h = SIZE[1]
    for k, pose in enumerate(poses):
        truth = project(corners, pose)
        noise, jpeg = NOISE_DN, None
        if effect is None:
            linear = base[k]
        elif effect == "light":
            linear = caster.render(pose, strength)
        elif effect == "vignetting":
            linear = base[k] * ctx["vignetting"][strength]
        elif effect == "defocus":
            linear = defocus(base[k], strength)
        elif effect == "motion":
            fractions = (np.arange(MOTION_STEPS) + 0.5) / MOTION_STEPS - 0.5
            linear = np.mean([caster.render((pose[0], pose[1] + d), FAR_LAMP_MM)
                              for d in moving(pose, strength, fractions)], axis=0)
        elif effect == "rolling":
            shift = moving(pose, strength, np.arange(h) / (h - 1) - 0.5)
            linear = caster.render(pose, FAR_LAMP_MM, row_shift=shift)
            truth = rolling_truth(corners, pose, strength)
        elif effect == "laminate":
            linear = render_board(ctx["camera"], pose, ctx["texture"], ctx["extent"],
                                  lamp(LAMINATE_LAMP_MM), ctx["spp"], seed + k,
                                  laminate_alpha=strength)
        elif effect == "sag":
            linear = caster.render(pose, FAR_LAMP_MM, sag_mm=strength)
            truth = project(bent_points(corners, ctx["extent"], strength), pose)
        elif effect == "noise":
            linear, (noise, jpeg) = base[k], strength
        images.append(stored(linear, rng, noise, jpeg))
        truths.append(truth)
    return images, truths


#: The lamp of the laminate: beside the camera, where a board facing it mirrors it.
LAMINATE_LAMP_MM = (-60.0, -40.0, 0.0)


def opencv_corners(image):
    """Plain OpenCV: the classic detector and ``cornerSubPix`` 5 × 5; ``(48, 2)`` or None."""
    ok, c = cv2.findChessboardCorners(image, PATTERN, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                      | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)
    return cv2.cornerSubPix(image, c, (5, 5), (-1, -1), criteria).reshape(-1, 2).astype(float)


def evaluate(images, truths, board) -> dict:
    """Per detector (``project``, ``opencv``): boards found, the corners' RMS error against
    the truth (px), and the calibration from its corners (fx, principal point errors px, fx's
    error over its σ, RMS px)."""
    corners = board.corners().astype(np.float32)
    out = {}
    for name in ("project", "opencv"):
        obj, img, errors = [], [], []
        for image, truth in zip(images, truths):
            if name == "project":
                ids, uv = board.detect(image)
                if len(ids) == 0:
                    continue
            else:
                uv = opencv_corners(image)
                if uv is None:
                    continue
                ids = np.arange(len(uv))
                if np.mean(np.linalg.norm(uv - truth, axis=1)) > np.mean(
                        np.linalg.norm(uv[::-1] - truth, axis=1)):
                    uv = uv[::-1]       # OpenCV numbered the grid from the other end
            errors.append(np.linalg.norm(uv - truth[ids], axis=1))
            obj.append(corners[ids])
            img.append(uv.astype(np.float32))
        out[name] = calibrated(obj, img, errors, len(images))
    return out


def calibrated(obj, img, errors, n_images) -> dict:
    """The numbers of :func:`evaluate` for one detector."""
    row = {"found": len(img), "of": n_images}
    if len(img) < 3:
        return row
    e = np.concatenate(errors)
    rms, K, _, _, _, std, _, _ = cv2.calibrateCameraExtended(
        obj, img, SIZE, None, None, flags=cv2.CALIB_FIX_K3,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    row.update(corner_rms=float(np.sqrt(np.mean(e ** 2))), corner_max=float(e.max()),
               fx_err=float(K[0, 0] - K_TRUE[0, 0]), fx_sigma=float(std.ravel()[0]),
               pp_err=float(np.hypot(K[0, 2] - K_TRUE[0, 2], K[1, 2] - K_TRUE[1, 2])),
               rms=float(rms))
    return row


def white_ratio(images, truths) -> list:
    """The median and the largest over the images of the white squares' max/min (stored 8-bit
    values at the squares' centres, a 5 × 5 mean)."""
    ratios = []
    for image, truth in zip(images, truths):
        g = truth.reshape(PATTERN[1], PATTERN[0], 2)
        centres = (g[:-1, :-1] + g[:-1, 1:] + g[1:, :-1] + g[1:, 1:]).reshape(-1, 2) / 4
        i, j = np.mgrid[0:PATTERN[1] - 1, 0:PATTERN[0] - 1]
        white = ((i + j) % 2 == 1).ravel()      # square (i+1, j+1): white when i + j is odd
        blurred = cv2.blur(image.astype(np.float32), (5, 5))
        m = centres[white].astype(np.float32)
        v = cv2.remap(blurred, m[:, :1], m[:, 1:], cv2.INTER_LINEAR).ravel()
        ratios.append(v.max() / max(v.min(), 1.0))
    return [float(np.median(ratios)), float(np.max(ratios))]


def label(effect, strength) -> str:
    if effect is None:
        return "baseline"
    if effect == "light":
        return "lamp at " + ",".join(f"{v:g}" for v in strength)
    if effect == "noise":
        return f"σ {strength[0]:g} DN, JPEG {strength[1]}"
    if effect == "laminate" and strength is None:
        return "matte (Mitsuba)"
    return f"{strength:g} {UNITS[effect]}"


def table(rows) -> str:
    """The markdown table of docs/realism.md."""
    head = ("| effect | strength | project: found · corner RMS / max · fx err (σ) · pp err · "
            "RMS | OpenCV: found · corner RMS / max · fx err (σ) · pp err · RMS |\n"
            "|---|---|---|---|\n")
    lines = []
    for r in rows:
        cells = []
        for name in ("project", "opencv"):
            d = r[name]
            if "rms" not in d:
                cells.append(f"{d['found']}/{d['of']}")
                continue
            cells.append(f"{d['found']}/{d['of']} · {d['corner_rms']:.3f} / {d['corner_max']:.2f}"
                         f" · {d['fx_err']:+.2f} ({abs(d['fx_err']) / d['fx_sigma']:.1f}σ) · "
                         f"{d['pp_err']:.2f} · {d['rms']:.3f}")
        extra = (" (whites {:.2f}× median, {:.2f}× max)".format(*r["white_ratio"])
                 if r["effect"] == "light" else "")
        lines.append(f"| {r['effect'] or '—'} | {r['label']}{extra} | {cells[0]} | {cells[1]} |")
    return head + "\n".join(lines)


def figure(rows, path) -> None:
    """One column per effect: the corners' RMS against the truth (top, log scale) and the
    calibrated fx's error over its σ (bottom), both detectors, against the effect's strength."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    effects = [e for e in EFFECTS if any(r["effect"] == e for r in rows)]
    fig, axes = plt.subplots(2, len(effects), figsize=(2.3 * len(effects), 5.0), squeeze=False)
    for col, effect in enumerate(effects):
        sel = [r for r in rows if r["effect"] == effect]
        if effect != "laminate":          # the laminate's own zero is Mitsuba's matte print
            sel = [rows[0]] + sel
        for name, style, text in (("project", "o-", "project"),
                                  ("opencv", "s--", "OpenCV cornerSubPix")):
            x = range(len(sel))
            axes[0, col].semilogy(x, [r[name].get("corner_rms", np.nan) for r in sel], style,
                                  label=text)
            axes[1, col].plot(x, [abs(r[name].get("fx_err", np.nan)) / r[name].get(
                "fx_sigma", np.nan) for r in sel], style, label=text)
        for ax in axes[:, col]:
            ax.set_xticks(range(len(sel)))
            ax.set_xticklabels(["0" if r["effect"] is None else short(r) for r in sel],
                               fontsize=7)
            ax.grid(True, which="both", alpha=0.3)
        axes[1, col].axhline(3.0, color="grey", lw=0.8)
        axes[0, col].set_title(f"{effect}\n({UNITS[effect]})", fontsize=8)
    axes[0, 0].set_ylabel("corner RMS vs truth (px)")
    axes[1, 0].set_ylabel("|fx error| / σ(fx)")
    axes[0, 0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def short(row) -> str:
    s = row["strength"]
    if row["effect"] == "light":
        return f"{row['white_ratio'][0]:.1f}×"
    if row["effect"] == "noise":
        return f"{s[0]:g}/q{s[1]}"
    return "matte" if s is None else f"{s:g}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--poses", type=int, default=10)
    parser.add_argument("--spp", type=int, default=4, help="Mitsuba's (the laminate only)")
    parser.add_argument("--effects", default=",".join(EFFECTS))
    args = parser.parse_args(argv)
    effects = [e for e in args.effects.split(",") if e]
    unknown = [e for e in effects if e not in EFFECTS]
    if unknown:
        print(f"error: unknown effect(s) {', '.join(unknown)}: choose from "
              f"{', '.join(EFFECTS)}", file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    camera, board, texture, extent = setup()
    ctx = {"camera": camera, "board": board, "texture": texture, "extent": extent,
           "spp": args.spp, "vignetting": {f: vignetting(f) for f in EFFECTS["vignetting"]}}
    poses = draw_poses(args.poses, board)
    caster = RayCaster(extent, sub=4)
    started = time.time()
    base = [caster.render(p, FAR_LAMP_MM) for p in poses]
    rows = []
    for effect, strength in [(None, None)] + [(e, s) for e in effects for s in EFFECTS[e]]:
        images, truths = condition(effect, strength, poses, caster, base, ctx, len(rows) * 101)
        row = {"effect": effect, "strength": strength, "label": label(effect, strength),
               "white_ratio": white_ratio(images, truths), **evaluate(images, truths, board)}
        rows.append(row)
        print(f"{row['label']}: project {row['project'].get('corner_rms', np.nan):.3f} px, "
              f"OpenCV {row['opencv'].get('corner_rms', np.nan):.3f} px "
              f"({time.time() - started:.0f} s)", flush=True)
        if effect is not None and strength == EFFECTS[effect][-1]:
            cv2.imwrite(os.path.join(args.out, f"{effect}.png"), images[0])
    with open(os.path.join(args.out, "atlas.json"), "w") as fh:
        json.dump({"rows": rows, "poses": args.poses, "size": SIZE, "spp": args.spp,
                   "subsamples": caster.sub ** 2}, fh, indent=1, default=list)
    figure(rows, os.path.join(args.out, "atlas.png"))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
