"""Circle grids: OpenCV's symmetric and asymmetric grids of dots (``cv2.findCirclesGrid``), the
dots' centres measured on the linear image, and their eccentricity.

:func:`find_circle_grid` runs OpenCV's grid finder with a blob detector sized to the image
(dark dots on a light board first, then light dots on a dark one; without and then with
``CALIB_CB_CLUSTERING`` for boards seen at an angle). :func:`refine_dot_centres` then measures
each dot where a lamp or vignetting cannot pull it: the window round the dot is divided by the
board's own brightness there (a plane fitted to the ring of board outside the dot), and the
centre is the centroid of the dot's darkness ``1 − I / board`` (of its brightness for light
dots) — a multiplicative light across the window cancels to first order, where a plain grey
centroid moves by R²/4 × ∇L/L (0.1 px for a 10-px dot under a 10 % change over 20 px).

The centroid of a dot's image is not the image of its centre (perspective, a port): the
eccentricity, :mod:`measure.images.eccentricity`, corrected in the calibration where the dots'
diameter is known (:func:`corrected_for_eccentricity`: the offsets predicted at the fitted
poses, through the port where there is one, subtracted, fitted again).

Pixels in OpenCV's convention; the board frame of :mod:`measure.calibration.board`, mm.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Window of :func:`refine_dot_centres` in dot radii: the dot inside :data:`DOT_INSIDE`, the
#: board's ring between :data:`RING_INNER` and :data:`RING_OUTER` (capped at half the spacing).
DOT_INSIDE, RING_INNER, RING_OUTER = 1.25, 1.45, 1.9
#: Samples per window radius, and refinement passes.
DOT_SAMPLES, DOT_PASSES = 24, 3


def _blob_detector(image_shape, pattern, light: bool):
    """A ``SimpleBlobDetector`` for dots no larger than a grid cell of the image."""
    params = cv2.SimpleBlobDetector_Params()
    cells = max(pattern[0] * pattern[1], 1)
    params.minArea = 8.0
    params.maxArea = float(image_shape[0] * image_shape[1]) / cells
    params.minDistBetweenBlobs = 2.0
    params.blobColor = 255 if light else 0
    return cv2.SimpleBlobDetector_create(params)


def find_circle_grid(view: np.ndarray, pattern, asymmetric: bool = False):
    """``(centres (cols·rows, 2), light)`` of the grid OpenCV finds in ``view`` (uint8, as
    stored), or None. ``pattern`` = (dots per row, rows), OpenCV's ``patternSize``;
    ``light``: light dots on a dark board."""
    kind = cv2.CALIB_CB_ASYMMETRIC_GRID if asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    for light in (False, True):
        detector = _blob_detector(view.shape, pattern, light)
        for flags in (kind, kind | cv2.CALIB_CB_CLUSTERING):
            found, centres = cv2.findCirclesGrid(view, tuple(pattern), flags=flags,
                                                 blobDetector=detector)
            if found:
                return centres.reshape(-1, 2).astype(np.float64), light
    return None


def _sample(image, points):
    maps = np.asarray(points, np.float32)
    return cv2.remap(image, np.ascontiguousarray(maps[..., 0]), np.ascontiguousarray(maps[..., 1]),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)


def dot_radii(image: np.ndarray, uv: np.ndarray, spacing, light: bool = False) -> np.ndarray:
    """``(N,)`` each dot's radius (px): the area of the window (± half its spacing) darker
    (lighter, ``light``) than the middle of the window's 5th and 95th percentiles, as a disk."""
    m = DOT_SAMPLES
    j, i = np.mgrid[-m:m + 1, -m:m + 1]
    unit = np.column_stack([j.ravel(), i.ravel()]).astype(np.float64) / m
    half = 0.5 * np.asarray(spacing, np.float64)
    values = _sample(np.asarray(image, np.float32), np.asarray(uv, np.float64)[:, None, :]
                     + unit[None] * half[:, None, None])
    low, high = np.percentile(values, 5, axis=1), np.percentile(values, 95, axis=1)
    inside = (values > ((low + high) / 2)[:, None]) if light else (
        values < ((low + high) / 2)[:, None])
    return np.sqrt(inside.mean(axis=1) * (2 * half) ** 2 / np.pi)


def refine_dot_centres(image: np.ndarray, uv: np.ndarray, spacing,
                       light: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Dot centres ``(N, 2)`` measured on the linear ``image`` (module docs) from a start
    ``uv``, and whether each is usable ``(N,)`` (a ring of board round it, and a centroid
    within its radius of the start). ``spacing`` ``(N,)`` px: each dot's distance to its
    nearest neighbour (caps the window); the radii are :func:`dot_radii`."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    radii = np.minimum(dot_radii(image, uv, spacing, light),
                       0.45 * np.asarray(spacing, np.float64))
    outer = np.minimum(RING_OUTER * radii, 0.5 * np.asarray(spacing, np.float64))
    m = DOT_SAMPLES
    j, i = np.mgrid[-m:m + 1, -m:m + 1]
    unit = np.column_stack([j.ravel(), i.ravel()]).astype(np.float64) / m   # in outer radii
    r = np.linalg.norm(unit, axis=1)
    image = np.asarray(image, np.float32)
    out, ok = uv.copy(), np.ones(len(uv), bool)
    for _ in range(DOT_PASSES):
        d = unit[None] * outer[:, None, None]                                 # (N, K, 2) px
        values = _sample(image, out[:, None, :] + d)
        rad = r[None] * outer[:, None] / radii[:, None]                       # in dot radii
        ring = (rad >= RING_INNER) & (r[None] <= 1)
        A = np.stack([np.ones_like(values), d[..., 0], d[..., 1]], axis=-1)
        normal = np.einsum("nk,nki,nkj->nij", ring, A, A)
        rhs = np.einsum("nk,nki,nk->ni", ring, A, values)
        good = np.abs(np.linalg.det(normal)) > 1e-12
        plane = np.zeros((len(uv), 3))
        plane[good] = np.linalg.solve(normal[good], rhs[good][..., None])[..., 0]
        board = np.einsum("nki,ni->nk", A, plane)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = values / board
        weight = np.clip((ratio - 1) if light else (1 - ratio), 0, None) * (rad <= DOT_INSIDE)
        total = weight.sum(axis=1)
        good &= np.isfinite(total) & (total > 0) & np.all(board > 0, axis=1)
        step = np.einsum("nk,nkc->nc", np.where(good[:, None], weight, 0), d) / np.where(
            good, total, 1)[:, None]
        out[good] += step[good]
        ok &= good
    ok &= np.linalg.norm(out - uv, axis=1) < radii
    return np.where(ok[:, None], out, uv), ok


def eccentricity_offsets(camera, port, board, R, t, ids) -> np.ndarray:
    """``(M, 2)`` px: where the centroid of each dot's image lies from the image of its centre
    (:func:`measure.images.eccentricity.outline_centroid_offsets`, the area centroid: the dots
    are measured against the board's own brightness), for the dots ``ids`` of ``board``
    (diameter ``board.circle_mm``) at the board pose ``(R, t)`` (board to the reference frame
    of ``camera``) seen through ``port`` (None: in air)."""
    from ..images.eccentricity import outline_centroid_offsets

    centres = board.corners()[np.asarray(ids, int)] @ np.asarray(R).T + np.asarray(t)
    normals = np.repeat(np.asarray(R)[:, 2][None], len(centres), axis=0)
    return outline_centroid_offsets(camera, port, centres, normals, board.circle_mm / 2,
                                    shading=False)


#: Fits of :func:`corrected_for_eccentricity`: the offsets are predicted at the poses of one
#: fit and subtracted before the next (the offsets change by less than 1e-3 px between the
#: second and third on the synthetic grids of the tests).
ECCENTRICITY_FITS = 3


def corrected_for_eccentricity(fit, detections, board, views_of):
    """``fit(detections)`` with the dots' eccentricity taken out (module docs): fitted,
    each dot's offset predicted at the fitted poses (``views_of(result)`` → ``{(pose, view):
    (camera, port, R, t)}``, the board pose in the camera's reference frame) and subtracted
    from the detections, fitted again (:data:`ECCENTRICITY_FITS` fits in all). A board
    without ``circle_mm`` is fitted once. Returns ``(result, corrected detections)``."""
    result = fit(detections)
    if board.kind not in ("circles", "acircles") or board.circle_mm <= 0:
        return result, detections
    for _ in range(ECCENTRICITY_FITS - 1):
        pixels = [list(v) for v in detections.pixels]
        for (k, v), (camera, port, R, t) in views_of(result).items():
            offsets = eccentricity_offsets(camera, port, board, R, t, detections.ids[k][v])
            pixels[k][v] = detections.pixels[k][v] - np.nan_to_num(offsets)
        corrected = type(detections)([list(v) for v in detections.ids], pixels)
        result = fit(corrected)
    return result, corrected


__all__ = ["ECCENTRICITY_FITS", "corrected_for_eccentricity", "dot_radii",
           "eccentricity_offsets", "find_circle_grid", "refine_dot_centres"]
