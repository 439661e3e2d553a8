"""A twin of one GoPro frame whose board moved during the readout (``gopro_inair``, frame 820):
the board's pose and its motion fitted to the frame's corners under a rolling shutter, the
frame rendered again from them, and the shear measured the same way on both.

    python tools/gopro_twin.py $REFSTEREO_REAL_PHOTOS/gopro_inair --out out/gopro_twin [--frame 820]

The camera is the data owner's (``camera_pkl_export.json``: K and the rational distortion), the
board 10 × 7 squares of 9.35 mm (9 × 6 inner corners). On the frame, the project's detector
(:meth:`measure.calibration.board.Board.detect`) finds the corners; two models are fitted to
them with the camera held: a still board (OpenCV's ``solvePnP``) and a board moving at a
constant velocity while the rows are read (:func:`fit_rolling`: row ``v`` sees the board
translated by ``w · (v / (H − 1) − ½)``, ``w`` (mm, camera frame) the motion over the whole
readout). The **shear** of either image is measured as in docs/calibration.md: the corners'
residuals against the still pose, ``du`` regressed on the row, px per 1000 rows.

The twin (:func:`render`): every pixel's 4 stratified rays through the lens
(``cv2.undistortPoints``) onto the board at its row's instant, the board printed black and
white with a one-square white margin on a dark background, lit evenly; stored as the frame
was (sRGB, white at the board's 99.5th percentile, 1.5 DN of noise, JPEG quality 90). Its
truth is each corner at its own row's instant (a fixed point, to 1e-9 px).

Prints the comparison table of docs/realism.md and writes ``OUT/twin.png``, ``OUT/report.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import cv2
import numpy as np

SQUARES, SQUARE_MM = (10, 7), 9.35
SUB = 2


def load_camera(folder):
    """``(K, dist (8,), size)`` of ``camera_pkl_export.json``."""
    with open(os.path.join(folder, "camera_pkl_export.json")) as fh:
        d = json.load(fh)
    return np.array(d["K"], float), np.array(d["dist_opencv_order"][:8], float), (2704, 1520)


def moved(points, rvec, tvec, w, K, dist, rows, height):
    """Pixels of board points when each is seen at the instant of row ``rows`` (N,): the board
    translated by ``w · (row / (H − 1) − ½)`` mm (camera frame)."""
    R = cv2.Rodrigues(np.asarray(rvec, float))[0]
    cam = points @ R.T + tvec + np.outer(rows / (height - 1) - 0.5, w)
    return cv2.projectPoints(cam, np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2)


def rolling_pixels(points, rvec, tvec, w, K, dist, height):
    """Each point at its own row's instant: the fixed point of ``v = v(t(v))`` (to 1e-9 px)."""
    uv = moved(points, rvec, tvec, np.zeros(3), K, dist, np.zeros(len(points)), height)
    for _ in range(100):
        new = moved(points, rvec, tvec, w, K, dist, uv[:, 1], height)
        done = np.max(np.abs(new - uv)) < 1e-9
        uv = new
        if done:
            break
    return uv


def fit_still(points, uv, K, dist):
    """``(rvec, tvec, RMS px)`` of a still board (``solvePnP``, iterative)."""
    _, rvec, tvec = cv2.solvePnP(points, uv, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    pred = cv2.projectPoints(points, rvec, tvec, K, dist)[0].reshape(-1, 2)
    return rvec.ravel(), tvec.ravel(), float(np.sqrt(np.mean(np.sum((pred - uv) ** 2, 1))))


def fit_rolling(points, uv, K, dist, height, start):
    """``(rvec, tvec, w, RMS px)`` of a board moving during the readout (module docs), least
    squares from the still pose ``start``; the rows are the detected ones (they differ from the
    model's by far less than a row's motion)."""
    from scipy.optimize import least_squares

    def residuals(p):
        return (moved(points, p[:3], p[3:6], p[6:], K, dist, uv[:, 1], height) - uv).ravel()

    fit = least_squares(residuals, np.concatenate([start[0], start[1], np.zeros(3)]))
    rms = float(np.sqrt(np.mean(np.sum(fit.fun.reshape(-1, 2) ** 2, 1))))
    return fit.x[:3], fit.x[3:6], fit.x[6:], rms


def shear(points, uv, K, dist):
    """The image's shear: ``du`` of the still pose's residuals regressed on the row, px per
    1000 rows; and the still pose's RMS."""
    rvec, tvec, rms = fit_still(points, uv, K, dist)
    du = uv[:, 0] - cv2.projectPoints(points, rvec, tvec, K, dist)[0].reshape(-1, 2)[:, 0]
    return float(np.polyfit(uv[:, 1], du, 1)[0] * 1000.0), rms


def render(K, dist, size, rvec, tvec, w, rng) -> np.ndarray:
    """The twin frame (uint8, module docs): the board's pixels cast ray by ray, row by row."""
    width, height = size
    R = cv2.Rodrigues(np.asarray(rvec, float))[0]
    cols, rows = SQUARES
    outline = np.array([[-1, -1], [cols + 1, -1], [cols + 1, rows + 1], [-1, rows + 1]],
                       float) * SQUARE_MM
    ends = [moved(np.column_stack([outline, np.zeros(4)]), rvec, tvec, w, K, dist,
                  np.full(4, r), height) for r in (0, height - 1)]
    lo = np.clip(np.floor(np.vstack(ends).min(0)) - 3, 0, [width, height]).astype(int)
    hi = np.clip(np.ceil(np.vstack(ends).max(0)) + 4, 0, [width, height]).astype(int)
    linear = np.full((height, width), 0.02, np.float32)
    o = (np.arange(SUB) + 0.5) / SUB - 0.5
    for v0 in range(lo[1], hi[1], 64):       # bands of rows: memory, not time
        v1 = min(v0 + 64, hi[1])
        v, u, sv, su = np.meshgrid(np.arange(v0, v1), np.arange(lo[0], hi[0]), o, o,
                                   indexing="ij")
        uu = u + su + rng.uniform(-0.5, 0.5, u.shape) / SUB
        vv = v + sv + rng.uniform(-0.5, 0.5, v.shape) / SUB
        xy = cv2.undistortPoints(np.stack([uu, vv], -1).reshape(-1, 1, 2), K, dist,
                                 criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100,
                                           1e-12)).reshape(-1, 2)
        d = np.column_stack([xy, np.ones(len(xy))])
        t = tvec + np.outer(v.ravel() / (height - 1) - 0.5, w)   # the row's instant
        a, b = d @ R, t @ R
        p = (b[:, 2] / a[:, 2])[:, None] * a - b          # board frame, mm
        i, j = np.floor(p[:, 1] / SQUARE_MM), np.floor(p[:, 0] / SQUARE_MM)
        on_sheet = (i >= -1) & (i <= rows) & (j >= -1) & (j <= cols)
        black = ((i + j) % 2 == 0) & (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
        value = np.where(on_sheet, np.where(black, 0.04, 0.8), 0.02)
        linear[v0:v1, lo[0]:hi[0]] = value.reshape(v1 - v0, hi[0] - lo[0], -1).mean(axis=2)
    x = np.clip(linear / np.percentile(linear[lo[1]:hi[1], lo[0]:hi[0]], 99.5), 0, 1)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055) * 255
    out = np.clip(np.rint(srgb + rng.normal(0, 1.5, srgb.shape)), 0, 255).astype(np.uint8)
    return cv2.imdecode(cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, 90])[1],
                        cv2.IMREAD_GRAYSCALE)


def measure_image(image, board, K, dist, height, truth=None) -> dict:
    """The project's corners on ``image``: the still and rolling fits' RMS, the shear, the
    fitted motion; their error against ``truth`` (px) where given."""
    ids, uv = board.detect(image)
    points = board.corners()[ids]
    rvec, tvec, still = fit_still(points, uv, K, dist)
    r2, t2, w, rolling = fit_rolling(points, uv, K, dist, height, (rvec, tvec))
    row = {"corners": int(len(ids)), "still_rms": still, "rolling_rms": rolling,
           "shear_px_per_1000_rows": shear(points, uv, K, dist)[0], "motion_mm": w.tolist(),
           "pose": (r2.tolist(), t2.tolist())}
    if truth is not None:
        row["error_rms"] = float(np.sqrt(np.mean(np.sum((uv - truth[ids]) ** 2, 1))))
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="the gopro_inair folder")
    parser.add_argument("--out", required=True)
    parser.add_argument("--frame", type=int, default=820)
    args = parser.parse_args(argv)
    from measure.calibration.board import Board

    K, dist, size = load_camera(args.folder)
    photo = cv2.imread(os.path.join(args.folder, "photos", f"calibration_frame{args.frame}.jpg"),
                       cv2.IMREAD_GRAYSCALE)
    if photo is None:
        print(f"error: frame {args.frame} not in {args.folder}/photos", file=sys.stderr)
        return 2
    board = Board("chessboard", SQUARES, SQUARE_MM)
    real = measure_image(photo, board, K, dist, size[1])
    rvec, tvec = (np.array(v) for v in real["pose"])
    w = np.array(real["motion_mm"])
    twin = render(K, dist, size, rvec, tvec, w, np.random.default_rng(0))
    truth = rolling_pixels(board.corners(), rvec, tvec, w, K, dist, size[1])
    rows = {"photo": real, "twin": measure_image(twin, board, K, dist, size[1], truth)}
    os.makedirs(args.out, exist_ok=True)
    cv2.imwrite(os.path.join(args.out, "twin.png"), twin)
    with open(os.path.join(args.out, "report.json"), "w") as fh:
        json.dump(rows, fh, indent=1)
    print("| | corners | still board RMS | moving board RMS | shear (px / 1000 rows) | "
          "fitted motion over the readout (mm) | corners vs truth |")
    print("|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {r['corners']} | {r['still_rms']:.3f} px | {r['rolling_rms']:.3f} px | "
              f"{r['shear_px_per_1000_rows']:+.2f} | "
              + ", ".join(f"{v:+.2f}" for v in r["motion_mm"])
              + (f" | {r['error_rms']:.3f} px |" if "error_rms" in r else " | — |"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
