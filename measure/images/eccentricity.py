"""Eccentricity of circular targets seen through a flat port, and its correction.

The centroid of a disk's image is not the image of the disk's centre: the projection through
the port (and, for a tilted camera, the perspective) is not affine, so the image of the outline
is a slightly egg-shaped curve whose area centroid sits beside the centre's pixel — up to about
0.01 px for the paper's 2.5 mm targets at 1 m, growing with the radius squared. Photogrammetry
calls this the eccentricity error of circular targets.

Model: the outline of a disk of radius ``r`` (mm) centred at ``X`` with unit normal ``n`` is
sampled at ``K`` points, each projected through the port with the exact forward model
(:func:`measure.geometry.projection.project`); the area centroid of the projected polygon (shoelace
formula, relative to the centre's pixel for precision) is the predicted image centroid. The
eccentricity offset is ``centroid − project(X)`` (px, OpenCV convention). A uniformly bright disk
has an intensity centroid equal to this area centroid — but behind a flat port the image is not
uniformly bright: each interface transmits the unpolarized Fresnel fraction of its incidence
angle, which falls towards the edge of the field, so the intensity centroid sits nearer the image
centre. To first order it moves by ``C · ∇ln T`` (``C`` the 2 × 2 second central moments of the
outline's image, from the same polygon; ``∇ln T`` the gradient in pixels of the log of the
port's transmittance at the centre's pixel, the port's ``transmittance``; a dome's is not
modelled): 0.0011 px inward for the 10 mm markers of a docking frame at 1.14 m near the edge
of the paper's field, 1e-4 px for its 2.5 mm targets at 1 m.

Correction (:func:`correct_eccentricity`): triangulate, estimate each target's normal from its
neighbours (a plane through its ``k`` nearest triangulated targets) or take a given one, predict
the offsets in both images, subtract them from the detected centres, triangulate again; repeat.
Units: mm, pixels in the OpenCV convention, reference frame = the left camera's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..geometry.camera import Camera
from ..geometry.port import FlatPort
from ..geometry.projection import project
from ..stereo.rig import Rig
from ..stereo.triangulate import Triangulation, triangulate

#: Points on each disk outline. The polygon's centroid converges quadratically: for the paper's
#: targets 64 points differ from 512 by up to 1e-5 px, 128 points by ~2.5e-6 px.
OUTLINE_POINTS = 128
#: Neighbours (including the target itself) whose plane gives a target's normal.
NORMAL_NEIGHBOURS = 8


def disk_basis(normals: np.ndarray):
    """Two unit vectors ``(N, 3)`` spanning each disk's plane."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(n, u)


def outline_centroid_offsets(camera: Camera, port: FlatPort | None, centres, normals,
                             radius_mm, n_points: int = OUTLINE_POINTS,
                             shading: bool = True) -> np.ndarray:
    """Eccentricity offsets ``(N, 2)`` px: the centroid of each disk's image (its outline's
    area centroid, moved by the flat port's transmittance gradient: module docs) minus the
    centre's pixel. ``centres`` ``(N, 3)`` mm, ``normals`` ``(N, 3)`` (any sign),
    ``radius_mm`` scalar or ``(N,)``. NaN where the centre or any outline point has no image.
    ``shading`` False: the area centroid alone (a dot measured against the board's own
    brightness round it, :mod:`measure.calibration.circles`, does not see the port's
    transmittance)."""
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    normals = np.broadcast_to(np.asarray(normals, dtype=np.float64), centres.shape)
    radius = np.broadcast_to(np.asarray(radius_mm, dtype=np.float64), centres.shape[:1])
    n = centres.shape[0]
    if n == 0:
        return np.zeros((0, 2))
    u, v = disk_basis(normals)
    angle = 2.0 * np.pi * np.arange(n_points) / n_points
    outline = (centres[:, None, :] + radius[:, None, None]
               * (np.cos(angle)[None, :, None] * u[:, None, :]
                  + np.sin(angle)[None, :, None] * v[:, None, :]))
    centre_px = project(camera, port, centres)
    pts = project(camera, port, outline.reshape(-1, 3)).reshape(n, n_points, 2)
    pts = pts - centre_px[:, None, :]  # relative to the centre's pixel: no cancellation
    x, y = pts[..., 0], pts[..., 1]
    x1, y1 = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    cross = x * y1 - x1 * y
    area = 0.5 * cross.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cx = ((x + x1) * cross).sum(axis=1) / (6.0 * area)
        cy = ((y + y1) * cross).sum(axis=1) / (6.0 * area)
        # second moments of the polygon (Green's theorem), then central ones
        ixx = (cross * (x * x + x * x1 + x1 * x1)).sum(axis=1) / (12.0 * area) - cx * cx
        iyy = (cross * (y * y + y * y1 + y1 * y1)).sum(axis=1) / (12.0 * area) - cy * cy
        ixy = ((cross * (x * y1 + 2 * x * y + 2 * x1 * y1 + x1 * y)).sum(axis=1)
               / (24.0 * area) - cx * cy)
    steps = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    around = (centre_px[:, None, :] + steps[None]).reshape(-1, 2)
    transmittance = None if port is None or not shading else port.transmittance(camera, around)
    if transmittance is not None:
        log_t = np.log(transmittance).reshape(n, 4)
        gx, gy = 0.5 * (log_t[:, 0] - log_t[:, 1]), 0.5 * (log_t[:, 2] - log_t[:, 3])
        cx, cy = cx + ixx * gx + ixy * gy, cy + ixy * gx + iyy * gy
    return np.column_stack([cx, cy])


def local_normals(points, k: int = NORMAL_NEIGHBOURS, toward=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Unit normals ``(N, 3)`` of the plane through each point's ``k`` nearest neighbours
    (itself included; SVD of the centred neighbourhood), turned towards ``toward`` (the
    cameras). With fewer than 3 finite points the normal points from the point to ``toward``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    toward = np.asarray(toward, dtype=np.float64)
    normals = toward - points
    finite = np.all(np.isfinite(points), axis=1)
    if finite.sum() >= 3:
        good = points[finite]
        k = int(min(k, good.shape[0]))
        _, index = cKDTree(good).query(good, k=k)
        hood = good[index] - good[index].mean(axis=1, keepdims=True)
        normal = np.linalg.svd(hood)[2][:, -1, :]
        flip = np.einsum("ij,ij->i", normal, toward - good) < 0
        normal[flip] *= -1.0
        normals[finite] = normal
    with np.errstate(invalid="ignore"):
        return normals / np.linalg.norm(normals, axis=1, keepdims=True)


@dataclass(frozen=True)
class EccentricityCorrection:
    """Result of :func:`correct_eccentricity`: the final ``triangulation`` of the corrected
    pixels, the corrected pixels ``uv_left`` / ``uv_right`` ``(N, 2)``, the offsets removed
    ``offset_left`` / ``offset_right`` ``(N, 2)`` px (NaN where none could be predicted: those
    pixels are left as detected), the ``normals`` used and the number of ``iterations``."""

    triangulation: Triangulation
    uv_left: np.ndarray
    uv_right: np.ndarray
    offset_left: np.ndarray
    offset_right: np.ndarray
    normals: np.ndarray
    iterations: int


def correct_eccentricity(rig: Rig, uv_left, uv_right, radius_mm, method: str = "optical_path",
                         normals=None, iterations: int = 2) -> EccentricityCorrection:
    """Remove the eccentricity offsets from matched detections and triangulate again.

    ``uv_left``/``uv_right`` ``(N, 2)`` detected centres (px); ``radius_mm`` the targets'
    radius; ``normals`` ``(N, 3)`` or ``(3,)`` when the surface is known, else estimated from
    the triangulated neighbours each iteration (:func:`local_normals`). The offsets are
    predicted with ``rig`` (what the measurement believes) and the method's points.
    """
    uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
    uv_right = np.asarray(uv_right, dtype=np.float64).reshape(-1, 2)
    if not (np.all(np.isfinite(np.asarray(radius_mm, float))) and np.all(np.asarray(radius_mm) > 0)):
        raise ValueError(f"radius_mm must be positive and finite, got {radius_mm!r}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations}")
    result = triangulate(rig, uv_left, uv_right, method)
    corrected_left, corrected_right = uv_left, uv_right
    zero = np.zeros_like(uv_left)
    offset_left, offset_right = zero, zero
    toward = 0.5 * (rig.left.center + rig.right.center)
    used = np.zeros((uv_left.shape[0], 3))
    for _ in range(iterations):
        used = (local_normals(result.points, toward=toward) if normals is None
                else np.broadcast_to(np.asarray(normals, dtype=np.float64), result.points.shape))
        offset_left = outline_centroid_offsets(rig.left, rig.view_port(0), result.points, used,
                                               radius_mm)
        offset_right = outline_centroid_offsets(rig.right, rig.view_port(1), result.points, used,
                                                radius_mm)
        corrected_left = uv_left - np.nan_to_num(offset_left)
        corrected_right = uv_right - np.nan_to_num(offset_right)
        result = triangulate(rig, corrected_left, corrected_right, method)
    return EccentricityCorrection(result, corrected_left, corrected_right, offset_left,
                                  offset_right, np.asarray(used), iterations)


__all__ = ["EccentricityCorrection", "OUTLINE_POINTS", "correct_eccentricity", "disk_basis", "local_normals",
           "outline_centroid_offsets"]
