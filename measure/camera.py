"""Pinhole camera with OpenCV intrinsics, lens distortion and a camera-to-reference pose.

Conventions (see DESIGN.md): millimetres; OpenCV camera axes (x right, y down, z forward);
pixels in OpenCV convention (integer coordinates are pixel centres), arrays ``(N, 2)`` as
``(u, v)``; the pose maps camera coordinates to the reference frame, ``X_ref = R @ X_cam + t``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

#: Numbers of OpenCV distortion coefficients this model evaluates:
#: (k1, k2, p1, p2), (k1, k2, p1, p2, k3) and the rational (k1, k2, p1, p2, k3, k4, k5, k6).
SUPPORTED_DISTORTION_LENGTHS = (4, 5, 8)


def _as_rotation(R, name: str) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"{name} must be a finite 3x3 rotation matrix, got shape {R.shape}")
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
        raise ValueError(f"{name} must be a proper rotation (R @ R.T = I, det R = +1)")
    return R


@dataclass(frozen=True)
class Camera:
    """A calibrated camera.

    Parameters
    ----------
    K : (3, 3) intrinsic matrix in pixels (fx, fy, cx, cy; skew allowed).
    size : (width, height) of the image in pixels.
    dist : OpenCV distortion coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]) or None.
    R, t : pose camera-to-reference, ``X_ref = R @ X_cam + t`` (mm). Defaults: identity, zero.
    """

    K: np.ndarray
    size: tuple[int, int]
    dist: np.ndarray | None = None
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __init__(self, K, size, dist=None, R=None, t=None):
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError(f"K must be a finite 3x3 intrinsic matrix, got shape {K.shape}")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise ValueError("K must be upper triangular with positive fx, fy and last row (0, 0, 1)")
        try:
            width, height = (int(s) for s in size)
        except (TypeError, ValueError):
            raise ValueError(f"size must be (width, height), got {size!r}") from None
        if width <= 0 or height <= 0:
            raise ValueError(f"size must be positive (width, height), got {size!r}")
        if dist is not None:
            dist = np.asarray(dist, dtype=np.float64).ravel()
            if dist.size not in SUPPORTED_DISTORTION_LENGTHS or not np.all(np.isfinite(dist)):
                raise ValueError(
                    f"dist must hold 4, 5 or 8 finite OpenCV coefficients, got {dist.size}")
            if not np.any(dist):
                dist = None
        R = np.eye(3) if R is None else _as_rotation(R, "R")
        t = np.zeros(3) if t is None else np.asarray(t, dtype=np.float64).reshape(-1)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(f"t must be a finite 3-vector, got shape {t.shape}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "size", (width, height))
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    # --- frames -------------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """Optical centre in the reference frame (mm)."""
        return self.t

    def to_camera(self, points_ref: np.ndarray) -> np.ndarray:
        """Reference-frame points ``(N, 3)`` to camera-frame points ``(N, 3)``."""
        return (np.asarray(points_ref, dtype=np.float64) - self.t) @ self.R

    # --- distortion ---------------------------------------------------------------------------
    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Apply the OpenCV lens distortion to normalized coordinates ``(N, 2)``."""
        xy = np.asarray(xy, dtype=np.float64)
        if self.dist is None:
            return xy.copy()
        c = np.zeros(8)
        c[: self.dist.size] = self.dist
        k1, k2, p1, p2, k3, k4, k5, k6 = c
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    def undistort(self, xy_distorted: np.ndarray, iterations: int = 8) -> np.ndarray:
        """Invert :meth:`distort` to machine precision.

        OpenCV's iterative ``cv2.undistortPointsIter`` gives the start; Newton steps with a
        central-difference Jacobian of :meth:`distort` then converge to ~1e-16 in normalized
        coordinates (OpenCV's default 5 fixed-point iterations stop near 1e-6).
        """
        xy_distorted = np.asarray(xy_distorted, dtype=np.float64)
        if self.dist is None:
            return xy_distorted.copy()
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        # OpenCV 4 names the iterative form undistortPointsIter; OpenCV 5 folds it into
        # undistortPoints with a criteria argument.
        undistort_iter = getattr(cv2, "undistortPointsIter", cv2.undistortPoints)
        start = undistort_iter(xy_distorted.reshape(-1, 1, 2), np.eye(3), self.dist,
                               R=np.eye(3), P=np.eye(3), criteria=criteria).reshape(-1, 2)
        xy = np.where(np.isfinite(start), start, xy_distorted)
        step = 1e-6
        ex, ey = np.array([step, 0.0]), np.array([0.0, step])
        for _ in range(iterations):
            residual = self.distort(xy) - xy_distorted
            jx = (self.distort(xy + ex) - self.distort(xy - ex)) / (2 * step)
            jy = (self.distort(xy + ey) - self.distort(xy - ey)) / (2 * step)
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            dx = (jy[:, 1] * residual[:, 0] - jy[:, 0] * residual[:, 1]) / det
            dy = (jx[:, 0] * residual[:, 1] - jx[:, 1] * residual[:, 0]) / det
            xy = xy - np.stack([dx, dy], axis=1)
            if np.nanmax(np.abs(residual), initial=0.0) < 1e-15:
                break
        return xy

    # --- pixels <-> rays ----------------------------------------------------------------------
    def normalized(self, uv: np.ndarray) -> np.ndarray:
        """Pixels ``(N, 2)`` to undistorted normalized image coordinates ``(N, 2)``."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        fx, s, cx = self.K[0]
        fy, cy = self.K[1, 1], self.K[1, 2]
        xy = np.empty_like(uv)
        xy[:, 1] = (uv[:, 1] - cy) / fy
        xy[:, 0] = (uv[:, 0] - cx - s * xy[:, 1]) / fx
        return xy if self.dist is None else self.undistort(xy)

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """Unit ray directions ``(N, 3)`` in the reference frame through pixels ``(N, 2)``.

        Every ray starts at :attr:`center`. This is the paper's ζ1 / ξ1 (equations 1-2).
        """
        xy = self.normalized(uv)
        x, y = xy[:, 0], xy[:, 1]
        inverse_norm = 1.0 / np.sqrt(1.0 + x * x + y * y)
        d = np.empty((xy.shape[0], 3))
        np.multiply(x, inverse_norm, out=d[:, 0])
        np.multiply(y, inverse_norm, out=d[:, 1])
        d[:, 2] = inverse_norm
        return d if self._identity_rotation else d @ self.R.T

    @property
    def _identity_rotation(self) -> bool:
        return bool(np.array_equal(self.R, np.eye(3)))

    def project(self, points_ref: np.ndarray) -> np.ndarray:
        """Pinhole projection (no refraction) of reference-frame points ``(N, 3)`` to pixels.

        Lens distortion is applied as ``cv2.projectPoints`` does. Points at or behind the camera
        plane (z_cam <= 0) give NaN.
        """
        X = self.to_camera(np.asarray(points_ref, dtype=np.float64).reshape(-1, 3))
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(X[:, 2] > 0, X[:, 2], np.nan)
            xy = self.distort(X[:, :2] / z[:, None])
        return xy @ self.K[:2, :2].T + self.K[:2, 2]

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether pixels ``(N, 2)`` lie inside the image, ``margin`` pixels from its border.

        The image spans [-0.5, W - 0.5] x [-0.5, H - 0.5] in OpenCV pixel coordinates.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        w, h = self.size
        lo = -0.5 + margin
        return ((uv[:, 0] >= lo) & (uv[:, 0] <= w - 0.5 - margin)
                & (uv[:, 1] >= lo) & (uv[:, 1] <= h - 0.5 - margin))
