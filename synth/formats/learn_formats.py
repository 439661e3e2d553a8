"""Files learned stereo and MVS tools read, written from the truth of a sea scene.

* KITTI 2015 style disparity: a 16-bit PNG, ``png = round(disparity · 256)``, 0 where there is
  no truth (:func:`write_kitti_disparity`; KITTI's devkit reads ``png / 256`` and ``png > 0``).
* SceneFlow style disparity: a single-channel float32 PFM, 0 where there is no truth (SceneFlow
  is dense; its loaders take ``disparity > 0`` as valid) (:func:`write_sceneflow_disparity`).
* COLMAP dense depth maps (``*.geometric.bin``): the text header ``W&H&1&`` and float32
  values, row after row — what ``colmap/scripts/python/read_write_dense.py`` reads — depth
  along the camera's z in metres, 0 where none (:func:`write_colmap_depth`).
* a plain pinhole COLMAP text model (``PINHOLE`` cameras, no port) for upstream COLMAP and
  pycolmap (:func:`write_pinhole_colmap`).
* 8-bit photos: linear renders scaled by one exposure for the pair and encoded with the sRGB
  curve (:func:`photo_8bit`), after isolated Monte-Carlo outliers ("fireflies": a pixel above
  :data:`FIREFLY_RATIO` × the median of its 5 × 5 neighbours) are replaced by that median.

Pixels follow OpenCV (``(0, 0)`` the centre of the top-left pixel) except in COLMAP's text
files, whose top-left pixel centre is ``(0.5, 0.5)``.
"""

from __future__ import annotations

import os

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from measure.geometry.flatport_format import METRES_PER_MM
from synth.formats.calib_formats import COLMAP_PIXEL_OFFSET
from synth.formats.exchange import write_pfm

#: KITTI's disparity PNG scale (codes per pixel of disparity) and its largest code.
KITTI_SCALE, KITTI_MAX = 256.0, 65535
#: A pixel this many times brighter than the median of its 5 × 5 neighbourhood is an outlier.
FIREFLY_RATIO = 4.0
#: The exposure: this quantile of both views maps to :data:`WHITE_LEVEL` before the sRGB curve.
EXPOSURE_QUANTILE, WHITE_LEVEL = 0.995, 0.9


def write_kitti_disparity(path: str, disparity: np.ndarray) -> int:
    """``disparity`` ``(H, W)`` px (NaN, ≤ 0 or beyond 255.996 px: no truth) as a KITTI 16-bit
    PNG at ``path``; returns how many pixels were beyond the PNG's range (written as 0)."""
    d = np.asarray(disparity, np.float64)
    codes = np.round(np.where(np.isfinite(d), d, 0.0) * KITTI_SCALE)
    beyond = int(np.sum(codes > KITTI_MAX))
    codes = np.where((codes >= 1) & (codes <= KITTI_MAX), codes, 0).astype(np.uint16)
    if not cv2.imwrite(path, codes):
        raise OSError(f"cannot write {path}")
    return beyond


def read_kitti_disparity(path: str) -> np.ndarray:
    """A KITTI disparity PNG as float ``(H, W)`` px, NaN where 0."""
    codes = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if codes is None or codes.dtype != np.uint16:
        raise ValueError(f"{path}: not a 16-bit PNG")
    return np.where(codes > 0, codes / KITTI_SCALE, np.nan)


def write_sceneflow_disparity(path: str, disparity: np.ndarray) -> None:
    """``disparity`` ``(H, W)`` px as SceneFlow's PFM (0 where NaN or ≤ 0)."""
    d = np.asarray(disparity, np.float64)
    write_pfm(path, np.where(np.isfinite(d) & (d > 0), d, 0.0).astype(np.float32))


def write_colmap_depth(path: str, depth_mm: np.ndarray) -> None:
    """A COLMAP ``.bin`` depth map of ``depth_mm`` ``(H, W)`` (z in mm; NaN: none) in metres."""
    depth = np.asarray(depth_mm, np.float64) * METRES_PER_MM
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype("<f4")
    h, w = depth.shape
    with open(path, "wb") as handle:
        handle.write(f"{w}&{h}&1&".encode("ascii"))
        handle.write(np.ascontiguousarray(depth).tobytes())


def read_colmap_depth(path: str) -> np.ndarray:
    """A COLMAP ``.bin`` depth map as float32 ``(H, W)`` (its units: metres here)."""
    with open(path, "rb") as handle:
        data = handle.read()
    fields = data.split(b"&", 3)
    w, h, channels = (int(v) for v in fields[:3])
    values = np.frombuffer(fields[3], "<f4")
    if channels != 1 or values.size != w * h:
        raise ValueError(f"{path}: {values.size} values for {w} x {h} x {channels}")
    return values.reshape(h, w).copy()


def _quaternion_translation(camera):
    """COLMAP's world-to-camera ``[qw, qx, qy, qz]`` and ``t`` (m) of ``camera`` (world = the
    reference frame)."""
    R = camera.R.T
    t = -R @ camera.t * METRES_PER_MM
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    quat = [w, x, y, z] if w >= 0 else [-w, -x, -y, -z]
    return [float(v) for v in quat], [float(v) for v in t]


def write_pinhole_colmap(folder: str, cameras, image_names, points=None, pixels=None) -> None:
    """A COLMAP text model of pinhole ``cameras`` (no port, no distortion; K's fx, fy, cx, cy)
    in ``folder``: ``cameras.txt`` (camera k + 1 = ``cameras[k]``, ``PINHOLE``), ``images.txt``
    (world = the reference frame, metres) and ``points3D.txt`` (``points`` ``(N, 3)`` mm seen
    at ``pixels`` ``(N, V, 2)`` OpenCV px in every camera; none if None)."""
    os.makedirs(folder, exist_ok=True)
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[] (fx fy cx cy, COLMAP pixels)"]
    for k, camera in enumerate(cameras, start=1):
        K = camera.K
        fx, fy = float(K[0, 0]), float(K[1, 1])
        cx, cy = float(K[0, 2]) + COLMAP_PIXEL_OFFSET, float(K[1, 2]) + COLMAP_PIXEL_OFFSET
        lines.append(f"{k} PINHOLE {camera.size[0]} {camera.size[1]} {fx!r} {fy!r} {cx!r} {cy!r}")
    with open(os.path.join(folder, "cameras.txt"), "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")
    points = np.zeros((0, 3)) if points is None else np.asarray(points, np.float64)
    pixels = (np.zeros((0, len(cameras), 2)) if pixels is None
              else np.asarray(pixels, np.float64))
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID); world = the reference (left) camera, metres"]
    for k, (camera, name) in enumerate(zip(cameras, image_names), start=1):
        quat, t = _quaternion_translation(camera)
        lines.append(" ".join([str(k), *(repr(v) for v in quat), *(repr(v) for v in t), str(k),
                               name]))
        lines.append(" ".join(f"{float(pixels[i, k - 1, 0]) + COLMAP_PIXEL_OFFSET!r} "
                              f"{float(pixels[i, k - 1, 1]) + COLMAP_PIXEL_OFFSET!r} {i + 1}"
                              for i in range(points.shape[0])))
    with open(os.path.join(folder, "images.txt"), "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")
    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    for i, point in enumerate(points):
        x, y, z = (float(v) * METRES_PER_MM for v in point)
        track = " ".join(f"{k} {i}" for k in range(1, len(cameras) + 1))
        lines.append(f"{i + 1} {x!r} {y!r} {z!r} 128 128 128 0 {track}")
    with open(os.path.join(folder, "points3D.txt"), "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")


def remove_fireflies(image: np.ndarray) -> np.ndarray:
    """``image`` with every pixel above :data:`FIREFLY_RATIO` × its 5 × 5 median replaced by
    that median (float32)."""
    image = np.asarray(image, np.float32)
    median = cv2.medianBlur(image, 5)
    return np.where(image > FIREFLY_RATIO * np.maximum(median, 1e-6), median, image)


def exposure(*images) -> float:
    """The scale that puts :data:`EXPOSURE_QUANTILE` of all ``images`` at
    :data:`WHITE_LEVEL` (1.0 for black images)."""
    values = np.concatenate([np.ravel(i) for i in images])
    top = float(np.quantile(values, EXPOSURE_QUANTILE)) if values.size else 0.0
    return WHITE_LEVEL / top if top > 0 else 1.0


def photo_8bit(image: np.ndarray, scale: float) -> np.ndarray:
    """A linear image times ``scale``, clipped to [0, 1], sRGB-encoded, as ``uint8``."""
    x = np.clip(np.asarray(image, np.float64) * scale, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def write_png(path: str, image: np.ndarray) -> None:
    if not cv2.imwrite(path, image):
        raise OSError(f"cannot write {path}")


__all__ = ["EXPOSURE_QUANTILE", "FIREFLY_RATIO", "KITTI_MAX", "KITTI_SCALE", "WHITE_LEVEL",
           "exposure", "photo_8bit", "read_colmap_depth", "read_kitti_disparity",
           "remove_fireflies", "write_colmap_depth", "write_kitti_disparity",
           "write_pinhole_colmap", "write_png", "write_sceneflow_disparity"]
