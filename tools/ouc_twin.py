"""A digital twin of ``ouc_flat/air``: its 14 board poses rendered with the authors' Bouguet
calibration, and the twin compared with the photos detector by detector.

    python tools/ouc_twin.py $REFSTEREO_REAL_PHOTOS/ouc_flat --out out/ouc_twin [--spp 16]

What is rendered (648 × 486, the camera at the reference frame's origin): the authors'
``Calib_Results_export.json`` — K (fx ≠ fy: rendered on an oversampled square-pixel film and
warped, as every distorted camera is, :func:`synth.rendering.render.render_view_counted`), the
distortion kc (Bouguet's pixels are OpenCV's: the export's poses reproject onto
``cornerSubPix`` corners at a median 0.13–0.33 px) and every photo's pose of the sub-grid the
authors clicked (``omc``, ``Tc``). The board as printed, approximately: the checker extended by
:data:`EXTRA_SQUARES` square beyond the clicked sub-grid on every side (7 × 6 squares for the
5 × 4 sub-grid; the photos show about 8 × 7, the sub-grid not always in the middle), a
white paper margin, a thin black frame line and a grey metal plate, all
diffuse (:data:`LAYOUT`); lit by one spot lamp beside the camera (:data:`LAMP`), no other
light. Stored as a photo would be: exposed so that the brightest white squares reach 255
(a few clip, like the photos' 250), sRGB-encoded, Gaussian noise of :data:`NOISE_DN`, 8 bits.

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

#: Squares of the printed checker beyond the authors' clicked sub-grid, on each side.
EXTRA_SQUARES = 1
#: The board outside the checker, in squares from its edge: white paper to the frame line, the
#: frame line's width, paper beyond it, then the metal plate to the board's edge; reflectances.
#: (Multiples of 1 / TEXELS, so that every edge falls on a texel's edge: nearest-texel lookup.)
LAYOUT = {"paper_to_line": 0.125, "line": 0.0625, "paper_after_line": 0.125, "plate": 1.0,
          "white": 0.8, "black": 0.04, "plate_reflectance": 0.3}
#: The lamp: position and aim, mm in the camera frame, cut-off half-angle (degrees).
LAMP = {"position": (-150.0, -250.0, 0.0), "aim": (0.0, 0.0, 400.0), "angle": 25.0}
NOISE_DN = 1.5
TEXELS = 32
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


def board_texture(n_sq, first_dark: bool):
    """The printed board (reflectance, float32 ``(H, W, 1)``) and its extent in grid
    coordinates (squares): the checker of ``n_sq`` + 2·:data:`EXTRA_SQUARES` squares, the
    margin, the frame line, the plate (:data:`LAYOUT`)."""
    L = LAYOUT
    border = L["paper_to_line"] + L["line"] + L["paper_after_line"] + L["plate"]
    lo = -EXTRA_SQUARES - border
    size = (n_sq[0] + 2 * EXTRA_SQUARES + 2 * border, n_sq[1] + 2 * EXTRA_SQUARES + 2 * border)
    w, h = (int(round(v * TEXELS)) for v in size)
    x = lo + (np.arange(w) + 0.5) / TEXELS
    y = lo + (np.arange(h) + 0.5) / TEXELS
    X, Y = np.meshgrid(x, y)
    # distance outside the checker (squares), 0 inside
    ex = np.maximum(np.maximum(-EXTRA_SQUARES - X, X - n_sq[0] - EXTRA_SQUARES), 0)
    ey = np.maximum(np.maximum(-EXTRA_SQUARES - Y, Y - n_sq[1] - EXTRA_SQUARES), 0)
    out = np.maximum(ex, ey)
    dark = ((np.floor(X) + np.floor(Y)) % 2 == 0) == first_dark
    texture = np.where(dark, L["black"], L["white"])
    line_start = L["paper_to_line"]
    texture = np.where(out > 0, L["white"], texture)
    texture = np.where((out > line_start) & (out <= line_start + L["line"]), L["black"], texture)
    texture = np.where(out > line_start + L["line"] + L["paper_after_line"],
                       L["plate_reflectance"], texture)
    return texture.astype(np.float32)[..., None], (lo, lo + size[0], lo, lo + size[1])


def first_square_dark(photo, K, kc, R, T, square):
    """Whether the sub-grid's square (0, 0) is dark in the photo (its centre against its right
    neighbour's)."""
    centres = np.array([[0.5, 0.5, 0], [1.5, 0.5, 0]]) * square
    uv = cv2.projectPoints(centres, cv2.Rodrigues(R)[0], T, K, kc)[0].reshape(-1, 2)
    values = [photo[int(round(v)), int(round(u))] for u, v in uv]
    return values[0] < values[1]


def render_twin(K, kc, pose, square, first_dark, spp, seed):
    """The linear render (float32 ``(486, 648)``) of one pose."""
    from measure import Camera
    from synth.products.board_light import BoardLight
    from synth.rendering.mitsuba_setup import import_mitsuba
    from synth.rendering.render import render_view_counted, sensor_dict

    mi, _ = import_mitsuba(None)
    _, R, T, n_sq = pose
    texture, (x0, x1, y0, y1) = board_texture(n_sq, first_dark)
    camera = Camera(K, (648, 486), dist=kc)
    square_K = np.array([[K[0, 0], 0, 323.5], [0, K[0, 0], 242.5], [0, 0, 1.0]])
    facing = -1.0 if R[:, 2] @ -T > 0 else 1.0  # local +z must face the camera
    local = np.array([[(x1 - x0) / 2 * square, 0, 0, (x0 + x1) / 2 * square],
                      [0, (y1 - y0) / 2 * square, 0, (y0 + y1) / 2 * square],
                      [0, 0, -facing, 0], [0, 0, 0, 1.0]])
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, T
    lamp = BoardLight("spot", LAMP["position"], LAMP["aim"], 1e6, LAMP["angle"])
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 3},
        "sensor": sensor_dict(mi, Camera(square_K, (648, 486)),
                              {"type": "multijitter", "sample_count": 4, "seed": 0}),
        "board": {"type": "rectangle", "to_world": mi.ScalarTransform4f((M @ local).tolist()),
                  "bsdf": {"type": "diffuse", "reflectance": {
                      "type": "bitmap", "data": mi.TensorXf(texture), "raw": True,
                      "filter_type": "nearest"}}},
        "lamp": lamp.emitter_dict(mi, Camera(square_K, (648, 486)))})
    return render_view_counted(scene, mi, 0, camera, spp, seed, adaptive=False)[0]


def stored(linear, rng):
    """A linear render as the camera would store it (module docs): uint8."""
    white = np.percentile(linear[linear > 0], 99.5) if np.any(linear > 0) else 1.0
    x = np.clip(linear / white, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055) * 255.0
    return np.clip(np.rint(srgb + rng.normal(0.0, NOISE_DN, srgb.shape)), 0, 255).astype(np.uint8)


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
    args = parser.parse_args(argv)
    try:
        K, kc, poses, square = load_export(args.folder)
    except (OSError, KeyError, ValueError) as exc:
        print(f"error: {args.folder}: not the ouc_flat folder ({exc})", file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    rng = np.random.default_rng(0)
    photos, twins = [], []
    for k, pose in enumerate(poses):
        name, R, T, _ = pose
        photo = cv2.imread(os.path.join(args.folder, "air", f"{name}.BMP"), cv2.IMREAD_GRAYSCALE)
        photos.append(photo)
        dark = first_square_dark(photo, K, kc, R, T, square)
        twins.append(stored(render_twin(K, kc, pose, square, dark, args.spp, k), rng))
        cv2.imwrite(os.path.join(args.out, f"twin_{k + 1:02d}.png"), twins[-1])
    rows = [summary(n, p, K, kc, poses, square) for n, p in (("real", photos), ("twin", twins))]
    sheet = np.vstack([np.hstack([photos[k], twins[k]]) for k in (0, 4, 7)])
    cv2.imwrite(os.path.join(args.out, "compare.png"), sheet)
    with open(os.path.join(args.out, "report.json"), "w") as fh:
        json.dump({"rows": rows, "lamp": LAMP, "layout": LAYOUT, "noise_dn": NOISE_DN}, fh,
                  indent=1)
    print("| | found | plain OpenCV RMS | per photo min / median / max | saddle − cornerSubPix "
          "median / p90 / max | white max/min (8-bit) min / median / max |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['name']} | {r['found']}/14 | {r['rms']:.3f} px | "
              + " / ".join(f"{v:.3f}" for v in r["per_photo_rms"]) + " px | "
              + " / ".join(f"{v:.2f}" for v in r["saddle_shift"]) + f" px ({r['corners']}) | "
              + " / ".join(f"{v:.2f}" for v in r["white_ratio"]) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
