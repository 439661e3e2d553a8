"""Images warped to virtual pinhole cameras, for tools that know no port (COLMAP, SLAM, OpenCV's
stereo matchers): exact for points on one plane, with the error they leave elsewhere.

A flat port (or a decentred dome) makes each camera non-central: no warp of its image can turn
it into a pinhole camera for every depth. :func:`rectify` chooses the plane ``n · X = distance``
(``n`` the rig's depth axis, :attr:`measure.Rig.depth_axis`; mm,
reference frame = the left camera's) and builds, per view, the ``cv2.remap`` maps that send each
pixel of a virtual pinhole camera — where the camera seems to be from the water (its apparent
centre and focal length near the principal point), no distortion, rotated for a row-aligned
stereo pair by ``cv2.stereoRectify`` — to the real pixel that sees the same point of that plane (the Fermat
forward model through the port). A point off the plane lands on the rectified image away from
where the virtual pinhole projects it: :func:`warp_errors` measures that, in pixels and, through
the virtual pair's triangulation, in millimetres.

Pixels follow OpenCV's convention (integer coordinates are pixel centres).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry.camera import Camera
from ..geometry.port import index_matched_port
from ..geometry.projection import project
from .rig import Rig, StereoRig
from .triangulate import triangulate

#: The pixel offset from the principal point at which the port's apparent focal length is
#: measured (px): far enough for round-off to vanish, near enough to be paraxial.
FOCAL_PROBE_PX = 20.0


@dataclass(frozen=True)
class Rectification:
    """``rig`` the refractive rig warped, ``distance_mm`` the plane (``rig.depth_axis · X``)
    the warp is exact on, ``virtual`` the virtual pinhole pair (no port, no distortion,
    row-aligned), ``maps`` per view ``(map_x, map_y)`` float32 ``(H, W)`` for ``cv2.remap``
    (−1 where the virtual pixel's point has no real pixel inside the real image)."""

    rig: Rig
    distance_mm: float
    virtual: Rig
    maps: tuple

    def warp(self, view: int, image: np.ndarray) -> np.ndarray:
        """``image`` of camera ``view`` as its virtual pinhole camera sees it (bilinear; black
        where nothing is seen)."""
        map_x, map_y = self.maps[view]
        return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=0)


def _meet_plane(origins, directions, axis, distance) -> np.ndarray:
    """Where rays ``origins + s · directions`` (s > 0) meet the plane ``axis · X = distance``
    (mm); NaN for rays parallel to it or pointing away."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (distance - origins @ axis) / (directions @ axis)
    s = np.where(s > 0, s, np.nan)
    return origins + directions * s[:, None]


def plane_points(camera: Camera, uv: np.ndarray, axis: np.ndarray, distance: float) -> np.ndarray:
    """Where the pinhole rays of ``camera`` through pixels ``uv`` ``(N, 2)`` meet the plane
    ``axis · X = distance`` (reference frame, mm); NaN for rays parallel to it or pointing away."""
    rays = camera.rays(uv)
    return _meet_plane(np.broadcast_to(camera.center, rays.shape), rays, axis, distance)


def apparent_camera(rig: Rig, view: int):
    """Where camera ``view`` seems to be from the water, and how much the port magnifies it,
    near its principal point: ``(centre (3,) mm, focal scale)``. The centre is the point
    nearest to the water rays of the principal point and of two pixels
    :data:`FOCAL_PROBE_PX` from it (a flat port's lies behind the camera, by about the port
    distance × (n_water − 1) on its axis; a centred dome's is the camera's own); the scale is the
    ratio of the pinhole rays' angles to the water rays' (≈ n_water / n_air behind a flat port)."""
    camera = rig.cameras[view]
    centre_px = camera.K[:2, 2]
    uv = np.array([centre_px, centre_px + [FOCAL_PROBE_PX, 0.0], centre_px + [0.0, FOCAL_PROBE_PX]])
    directions = camera.rays(uv)
    water = rig.trace(view, directions)
    origins, rays = water.origins, water.directions
    # the point nearest to the three lines (least squares)
    projector = np.eye(3)[None] - rays[:, :, None] * rays[:, None, :]
    centre = np.linalg.solve(projector.sum(axis=0), np.einsum("kij,kj->i", projector, origins))
    pinhole = camera.to_camera(camera.center + directions)
    pinhole = pinhole[:, :2] / pinhole[:, 2:3]
    seen = (rays @ camera.R)  # water directions in the camera's axes
    seen = seen[:, :2] / seen[:, 2:3]
    ratios = [np.linalg.norm(pinhole[k] - pinhole[0]) / np.linalg.norm(seen[k] - seen[0])
              for k in (1, 2)]
    return centre, float(np.mean(ratios))


def virtual_pair(rig: Rig) -> Rig:
    """The virtual pinhole pair of :func:`rectify`: each camera where it seems to be from the
    water (:func:`apparent_camera`), its intrinsics without distortion and with the port's
    apparent focal length, rotated by ``cv2.stereoRectify`` (``alpha = 0``) into a row-aligned
    pair; no port."""
    left, right = rig.cameras
    Ks, centres = [], []
    for view, camera in enumerate((left, right)):
        centre, scale = apparent_camera(rig, view)
        K = camera.K.copy()
        K[:2, :2] *= scale
        Ks.append(K)
        centres.append(centre)
    # OpenCV's stereo pose: X_right = R X_left + T (camera frames, the apparent centres)
    R = right.R.T @ left.R
    T = right.R.T @ (centres[0] - centres[1])
    zeros = np.zeros(5)
    R1, R2, P1, P2 = cv2.stereoRectify(Ks[0], zeros, Ks[1], zeros, tuple(left.size), R,
                                       T.reshape(3, 1), alpha=0)[:4]
    cameras = []
    for camera, centre, R_rect, P in ((left, centres[0], R1, P1), (right, centres[1], R2, P2)):
        cameras.append(Camera(P[:3, :3], camera.size, R=camera.R @ R_rect.T, t=centre))
    port = index_matched_port(rig.depth_axis, np.stack([c.center for c in cameras]))
    return StereoRig(cameras[0], cameras[1], port)


def rectify(rig: Rig, distance: float) -> Rectification:
    """The maps that warp both views of ``rig`` to its virtual pinhole pair, exact on the
    plane ``rig.depth_axis · X = distance`` mm (module docs)."""
    distance = float(distance)
    if not np.isfinite(distance) or distance <= rig.port.glass_depth(rig.left):
        raise ValueError(f"distance must lie in the water, beyond the glass "
                         f"({rig.port.glass_depth(rig.left):.6g} mm), got {distance:g} mm")
    virtual = virtual_pair(rig)
    axis = rig.depth_axis
    w, h = rig.left.size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    grid = np.column_stack([u.ravel(), v.ravel()])
    maps = []
    for view, (camera, pinhole) in enumerate(zip(rig.cameras, virtual.cameras)):
        points = plane_points(pinhole, grid, axis, distance)
        real = project(camera, rig.view_port(view), points)
        seen = camera.in_image(real)  # NaN, and pixels outside the real image: nothing seen
        real = np.where(seen[:, None], real, -1.0).astype(np.float32)
        maps.append((real[:, 0].reshape(h, w), real[:, 1].reshape(h, w)))
    return Rectification(rig, distance, virtual, tuple(maps))


def rectified_pixels(rectification: Rectification, view: int, uv: np.ndarray) -> np.ndarray:
    """Where real pixels ``uv`` ``(N, 2)`` of camera ``view`` land on its rectified image: the
    pixel's water ray meets the warp's plane, the virtual camera projects that point (exactly
    what the maps do, inverted)."""
    rig, axis = rectification.rig, rectification.rig.depth_axis
    water = rig.trace(view, rig.cameras[view].rays(uv))
    points = _meet_plane(water.origins, water.directions, axis, rectification.distance_mm)
    return rectification.virtual.cameras[view].project(points)


def warp_errors(rectification: Rectification, points: np.ndarray) -> dict:
    """What the warp does to ``points`` ``(N, 3)`` mm (reference frame): per view the rectified
    pixel minus the virtual pinhole's projection (``offset_px`` ``(N, 2)``, ``error_px``
    ``(N,)``), and the virtual pair's triangulation of the rectified pixels minus the point
    (``error_mm`` ``(N, 3)``); NaN where a view does not see the point."""
    rig = rectification.rig
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    rectified, out = [], {}
    for view in (0, 1):
        real = project(rig.cameras[view], rig.view_port(view), points)
        warped = rectified_pixels(rectification, view, real)
        ideal = rectification.virtual.cameras[view].project(points)
        out[view] = {"offset_px": warped - ideal,
                     "error_px": np.linalg.norm(warped - ideal, axis=1)}
        rectified.append(warped)
    measured = triangulate(rectification.virtual, rectified[0], rectified[1], "optical_path")
    out["error_mm"] = measured.points - points
    return out


def sgbm_points(rectification: Rectification, left, right, num_disparities: int | None = None,
                block_size: int = 7):
    """OpenCV's ``StereoSGBM`` on the rectified pair of ``left``, ``right`` (grey images of
    the real cameras; any real dtype, scaled together to 8 bits) and its points: the pinhole
    triangulation by the virtual pair of each rectified left pixel and its match
    (mm, reference frame). Returns ``(uv_left (N, 2), points (N, 3))`` where ``uv_left`` is the
    *real* left pixel the rectified pixel came from (the maps), so that the points can be set
    beside another matcher's on the same pixels. ``num_disparities`` (a multiple of 16;
    default: what the plane of the warp needs, × 2, at least 64)."""
    scale = 255.0 / max(float(np.nanmax(left)), float(np.nanmax(right)), 1e-30)
    views = [np.clip(np.nan_to_num(rectification.warp(v, np.asarray(image, np.float32))) * scale,
                     0, 255).astype(np.uint8) for v, image in enumerate((left, right))]
    virtual = rectification.virtual
    w, h = virtual.left.size
    if num_disparities is None:
        centre = plane_points(virtual.left, np.array([[w / 2, h / 2]]), rectification.rig.depth_axis,
                              rectification.distance_mm)
        disparity = float(virtual.left.project(centre)[0, 0] - virtual.right.project(centre)[0, 0])
        num_disparities = max(64, int(np.ceil(2 * abs(disparity) / 16.0)) * 16)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=int(num_disparities),
                                 blockSize=block_size, P1=8 * block_size ** 2,
                                 P2=32 * block_size ** 2, uniquenessRatio=10,
                                 speckleWindowSize=100, speckleRange=2,
                                 mode=cv2.STEREO_SGBM_MODE_HH)
    disparity = sgbm.compute(views[0], views[1]).astype(np.float64) / 16.0
    valid = disparity > 0
    rows, cols = np.nonzero(valid)
    q_left = np.column_stack([cols, rows]).astype(np.float64)
    q_right = q_left - np.column_stack([disparity[valid], np.zeros(valid.sum())])
    points = triangulate(virtual, q_left, q_right, "optical_path").points
    map_x, map_y = rectification.maps[0]
    uv_left = np.column_stack([map_x[rows, cols], map_y[rows, cols]]).astype(np.float64)
    keep = (uv_left[:, 0] >= 0) & np.all(np.isfinite(points), axis=1)
    return uv_left[keep], points[keep]


__all__ = ["Rectification", "sgbm_points", "apparent_camera", "plane_points", "rectified_pixels",
           "rectify", "virtual_pair", "warp_errors"]
