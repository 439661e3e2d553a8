"""Pinhole camera with OpenCV intrinsics, lens distortion and a camera-to-reference pose.

Conventions (docs/architecture.md): millimetres; OpenCV camera axes (x right, y down, z forward);
pixels in OpenCV convention (integer coordinates are pixel centres), arrays ``(N, 2)`` as
``(u, v)``; the pose maps camera coordinates to the reference frame, ``X_ref = R @ X_cam + t``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..reasons import Reason

#: Largest |distort(undistort(p)) − p| (px) of a pixel that counts as undistorted: 1000× below
#: any centroid precision (~0.001 px), far above Newton's float64 floor (~1e-13 px).
UNDISTORT_TOLERANCE_PX = 1e-6
#: Pixels between the samples of the image border and interior grid that
#: :meth:`Camera.distortion_problem` checks.
DISTORTION_CHECK_STEP_PX = 4

#: The lens distortion models, named (never guessed from the number of coefficients):
#: OpenCV's Brown–Conrady model of ``cv2.projectPoints`` and OpenCV's fisheye model
#: (Kannala–Brandt, ``cv2.fisheye``: ``θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`` with
#: ``θ = atan(r)``, the distorted point ``(θ_d / r) (x, y)``).
BROWN_CONRADY, FISHEYE = "brown_conrady", "fisheye"
#: Numbers of distortion coefficients each model takes: Brown–Conrady (k1, k2, p1, p2),
#: (k1, k2, p1, p2, k3) and the rational (k1, k2, p1, p2, k3, k4, k5, k6); fisheye k1…k4.
DISTORTION_MODELS = {BROWN_CONRADY: (4, 5, 8), FISHEYE: (4,)}
SUPPORTED_DISTORTION_LENGTHS = DISTORTION_MODELS[BROWN_CONRADY]
#: Most Newton iterations of the fisheye model's inversion θ_d → θ (quadratic convergence from
#: θ = θ_d: 4 for a wide lens over a whole 2448 × 2048 image; OpenCV's
#: ``cv2.fisheye.undistortPoints`` takes 10).
FISHEYE_ITERATIONS = 20
#: Newton iterations of the Brown–Conrady inversion (3 reach 1e-16 for the renders' lenses, 4
#: for the GoPro's rational one; points left unconverged start again from OpenCV's estimate).
NEWTON_ITERATIONS = 12


def _one_of(numbers) -> str:
    """``4, 5 or 8``."""
    words = [str(n) for n in numbers]
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} or {words[-1]}"


def _as_rotation(R, name: str) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"{name} must be a finite 3x3 rotation matrix, got shape {R.shape}")
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
        raise ValueError(f"{name} must be a proper rotation (R @ R.T = I, det R = +1)")
    return R


def _arrays_equal(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.array_equal(a, b))


def _hash_value(value):
    return value.tobytes() if isinstance(value, np.ndarray) else value


class ValueEquality:
    """``==`` and ``hash`` by value for frozen dataclasses with numpy array fields (exact
    equality of the arrays)."""

    __slots__ = ()

    def __eq__(self, other):
        if type(other) is not type(self):
            return NotImplemented
        for name in self.__dataclass_fields__:
            a, b = getattr(self, name), getattr(other, name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if not _arrays_equal(a, b):
                    return False
            elif a != b:
                return False
        return True

    def __hash__(self):
        return hash((type(self).__name__,)
                    + tuple(_hash_value(getattr(self, n)) for n in self.__dataclass_fields__))


@dataclass(frozen=True, eq=False)
class Camera(ValueEquality):
    """A calibrated camera.

    Parameters
    ----------
    K : (3, 3) intrinsic matrix in pixels (fx, fy, cx, cy; skew allowed).
    size : (width, height) of the image in pixels.
    dist : distortion coefficients of ``distortion_model``: Brown–Conrady (k1, k2, p1, p2[, k3[,
        k4, k5, k6]]) or None (an all-zero vector is None: the pinhole); fisheye (k1, k2, k3, k4),
        always kept (with zeros it is the equidistant projection, not the pinhole).
    R, t : pose camera-to-reference, ``X_ref = R @ X_cam + t`` (mm). Defaults: identity, zero.
    distortion_model : :data:`BROWN_CONRADY` (default) or :data:`FISHEYE`.
    """

    K: np.ndarray
    size: tuple[int, int]
    dist: np.ndarray | None = None
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    distortion_model: str = BROWN_CONRADY

    def __init__(self, K, size, dist=None, R=None, t=None, distortion_model=BROWN_CONRADY):
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError(f"K must be a finite 3x3 intrinsic matrix, got shape {K.shape}")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise ValueError("K must be upper triangular with positive fx, fy and last row (0, 0, 1)")
        try:
            width, height = (float(s) for s in size)
        except (TypeError, ValueError):
            raise ValueError(f"size must be (width, height), got {size!r}") from None
        if not all(np.isfinite(v) and v == int(v) and v > 0 for v in (width, height)):
            raise ValueError(f"size must be positive whole numbers of pixels (width, height), "
                             f"got {size!r}")
        width, height = int(width), int(height)
        if distortion_model not in DISTORTION_MODELS:
            raise ValueError(f"distortion model {distortion_model!r}: choose from "
                             f"{', '.join(DISTORTION_MODELS)}")
        if distortion_model == FISHEYE and dist is None:
            dist = np.zeros(4)
        if dist is not None:
            dist = np.asarray(dist, dtype=np.float64).ravel()
            lengths = DISTORTION_MODELS[distortion_model]
            if dist.size not in lengths:
                raise ValueError(f"dist of the {distortion_model} model must hold "
                                 f"{_one_of(lengths)} coefficients, got {dist.size}")
            if not np.all(np.isfinite(dist)):
                raise ValueError(f"dist must be finite, got {dist.tolist()}")
            if distortion_model == BROWN_CONRADY and not np.any(dist):
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
        object.__setattr__(self, "distortion_model", distortion_model)

    # --- frames -------------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        """Optical centre in the reference frame (mm)."""
        return self.t

    def to_camera(self, points_ref: np.ndarray) -> np.ndarray:
        """Reference-frame points ``(N, 3)`` to camera-frame points ``(N, 3)``."""
        return (np.asarray(points_ref, dtype=np.float64) - self.t) @ self.R

    # --- distortion ---------------------------------------------------------------------------
    @property
    def fisheye(self) -> bool:
        """Whether the lens follows OpenCV's fisheye model (:data:`FISHEYE`)."""
        return self.distortion_model == FISHEYE

    def brown_conrady_dist(self, purpose: str) -> np.ndarray | None:
        """:attr:`dist` for code that evaluates OpenCV's Brown–Conrady model only (``purpose``
        names it); ``ValueError`` for a fisheye camera."""
        if self.fisheye:
            raise ValueError(f"{purpose} supports OpenCV's Brown–Conrady lens distortion only, "
                             f"not the fisheye model")
        return self.dist

    def with_pose(self, R, t) -> Camera:
        """This camera (intrinsics, distortion and its model) at another pose."""
        return Camera(self.K, self.size, self.dist, R, t, self.distortion_model)

    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Apply the lens distortion to normalized coordinates ``(N, 2)``."""
        xy = np.asarray(xy, dtype=np.float64)
        if self.dist is None:
            return xy.copy()
        return np.stack(self.distort_columns(xy[:, 0], xy[:, 1]), axis=1)

    def distort_columns(self, x: np.ndarray, y: np.ndarray, jacobian: bool = False):
        """:meth:`distort` on columns: normalized ``x, y`` ``(N,)`` to distorted ``(xd, yd)``.

        With ``jacobian=True`` also the analytic derivatives ``∂xd/∂x``, ``∂xd/∂y`` (which
        equals ``∂yd/∂x``) and ``∂yd/∂y``: ``(xd, yd, dxx, dxy, dyy)``. Without distortion
        ``x, y`` are returned as they are (and the Jacobian is the identity: only two values).
        """
        if self.dist is None:
            return x, y
        if self.fisheye:
            return self._fisheye_columns(x, y, jacobian)
        c = np.zeros(8)
        c[: self.dist.size] = self.dist
        k1, k2, p1, p2, k3, k4, k5, k6 = (float(v) for v in c)
        rational = bool(k4 or k5 or k6)
        tangential = bool(p1 or p2)
        xx, yy, xy = x * x, y * y, x * y
        r2 = xx + yy
        # Horner in place: numerator = 1 + r2 (k1 + r2 (k2 + r2 k3)), likewise the denominator
        numerator = r2 * k3
        numerator += k2
        numerator *= r2
        numerator += k1
        numerator *= r2
        numerator += 1.0
        if rational:
            denominator = r2 * k6
            denominator += k5
            denominator *= r2
            denominator += k4
            denominator *= r2
            denominator += 1.0
            radial = numerator / denominator
        else:
            radial = numerator
        xd = x * radial
        yd = y * radial
        if tangential:
            xd += (2 * p1) * xy + p2 * (r2 + 2 * xx)
            yd += p1 * (r2 + 2 * yy) + (2 * p2) * xy
        if not jacobian:
            return xd, yd
        # d radial / d r2 (by the quotient rule for the rational model)
        slope = r2 * (3 * k3)
        slope += 2 * k2
        slope *= r2
        slope += k1
        if rational:
            slope *= denominator
            slope -= numerator * (k4 + r2 * (2 * k5 + (3 * k6) * r2))
            slope /= denominator * denominator
        slope *= 2.0
        dxy = xy * slope
        dxx = xx * slope
        dxx += radial
        dyy = yy * slope
        dyy += radial
        if tangential:
            dxx += (2 * p1) * y + (6 * p2) * x
            dxy += (2 * p1) * x + (2 * p2) * y
            dyy += (6 * p1) * y + (2 * p2) * x
        return xd, yd, dxx, dxy, dyy

    def _fisheye_columns(self, x, y, jacobian: bool):
        """OpenCV's fisheye model (:data:`FISHEYE`) on columns, as :meth:`distort_columns`;
        ``cv2.fisheye.projectPoints``' scale 1 below r = 1e-8."""
        k1, k2, k3, k4 = self.dist
        r2 = x * x + y * y
        r = np.sqrt(r2)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        small = r < 1e-8
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(small, 1.0, theta_d / np.where(small, 1.0, r))
        xd, yd = x * scale, y * scale
        if not jacobian:
            return xd, yd
        # scale(r) = θ_d / r; d scale / dr / r = (θ_d'(θ) r / (1 + r²) − θ_d) / r³, its limit
        # 2 (k1 − 1/3) at r = 0 (only where r < 1e-8, as the scale)
        d_theta_d = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        with np.errstate(invalid="ignore", divide="ignore"):
            r_safe = np.where(small, 1.0, r)
            slope = np.where(small, 2 * (k1 - 1 / 3),
                             (d_theta_d * r_safe / (1 + r2) - theta_d) / (r_safe * r_safe * r_safe))
        dxx = scale + x * x * slope
        dxy = x * y * slope
        dyy = scale + y * y * slope
        return xd, yd, dxx, dxy, dyy

    def _undistort_fisheye(self, xy_distorted: np.ndarray):
        """``(xy, ok)``: the fisheye model inverted by Newton on ``θ_d(θ) = |xy_d|`` (radial
        only) from θ = θ_d; ``ok`` where θ < π/2, θ_d' > 0 there (no fold) and the round trip
        misses by at most :data:`UNDISTORT_TOLERANCE_PX`."""
        k1, k2, k3, k4 = self.dist
        target = np.hypot(xy_distorted[:, 0], xy_distorted[:, 1])
        theta = np.minimum(target, np.pi / 2)
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            for _ in range(FISHEYE_ITERATIONS):
                t2 = theta * theta
                value = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
                slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
                step = (value - target) / slope
                theta = theta - step
                # quadratic convergence: after a step below 1e-12 rad the error is at rounding
                if not np.nanmax(np.abs(step), initial=0.0) > 1e-12:
                    break
            t2 = theta * theta
            value = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
            slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            miss_px = np.abs(value - target) * np.max(np.diag(self.K)[:2])
            ok = ((miss_px <= UNDISTORT_TOLERANCE_PX) & (slope > 0) & (theta >= 0)
                  & (theta < np.pi / 2))
            scale = np.where(target > 1e-8, np.tan(theta) / np.where(target > 0, target, 1.0),
                             1.0)
        return xy_distorted * scale[:, None], ok

    def undistort(self, xy_distorted: np.ndarray, iterations: int = 8) -> np.ndarray:
        """Invert :meth:`distort` to machine precision.

        Brown–Conrady: Newton steps with the analytic Jacobian of :meth:`distort_columns` from
        one fixed-point step (:meth:`_radial_start`) converge to ~1e-16 in normalized
        coordinates; a point they leave unconverged (or beyond a fold) starts again from
        OpenCV's iterative ``cv2.undistortPoints`` (OpenCV's default 5 fixed-point iterations
        alone stop near 1e-6). Fisheye: Newton on the radial ``θ_d(θ)``
        (:meth:`_undistort_fisheye`).
        """
        return self.undistort_with_reason(xy_distorted, iterations)[0]

    def undistort_with_reason(self, xy_distorted: np.ndarray, iterations: int = 8):
        """:meth:`undistort` and a ``(N,)`` :class:`Reason` array: ``NOT_CONVERGED`` (and NaN)
        where the round trip ``distort(undistort(p))`` misses ``p`` by more than
        :data:`UNDISTORT_TOLERANCE_PX` or the solution lies beyond a fold of the distortion
        (its Jacobian determinant is not positive: another point maps to the same pixel);
        ``INVALID_INPUT`` for non-finite input."""
        xy_distorted = np.asarray(xy_distorted, dtype=np.float64).reshape(-1, 2)
        reason = np.full(xy_distorted.shape[0], Reason.OK, dtype=np.int8)
        reason[~np.all(np.isfinite(xy_distorted), axis=1)] = Reason.INVALID_INPUT
        if self.dist is None or xy_distorted.shape[0] == 0:
            return xy_distorted.copy(), reason
        if self.fisheye:
            xy, ok = self._undistort_fisheye(xy_distorted)
        else:
            xy, ok = self._newton(xy_distorted, self._radial_start(xy_distorted),
                                  NEWTON_ITERATIONS)
            retry = np.flatnonzero(~ok & (reason == Reason.OK))
            if retry.size:
                criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
                # OpenCV 4 names the iterative form undistortPointsIter; OpenCV 5 folds it
                # into undistortPoints with a criteria argument.
                undistort_iter = getattr(cv2, "undistortPointsIter", cv2.undistortPoints)
                target = xy_distorted[retry]
                start = undistort_iter(target.reshape(-1, 1, 2), np.eye(3), self.dist,
                                       R=np.eye(3), P=np.eye(3),
                                       criteria=criteria).reshape(-1, 2)
                start = np.where(np.isfinite(start), start, target)
                xy[retry], ok[retry] = self._newton(target, start, iterations)
        failed = ~ok & (reason == Reason.OK)
        reason[failed] = Reason.NOT_CONVERGED
        xy[reason != Reason.OK] = np.nan
        return xy, reason

    def _radial_start(self, xy_distorted: np.ndarray) -> np.ndarray:
        """Newton's start: the distorted point divided by the radial factor at its own radius
        (OpenCV's first fixed-point step without the tangential terms; it saves one Newton step
        of five for the renders' lens and of six for the GoPro's rational one); the distorted
        point itself where that factor is not positive."""
        c = np.zeros(8)
        c[: self.dist.size] = self.dist
        k1, k2, _, _, k3, k4, k5, k6 = c
        x, y = xy_distorted[:, 0], xy_distorted[:, 1]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        if k4 or k5 or k6:
            radial /= 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = 1.0 / radial
        scale[~(np.isfinite(scale) & (radial > 0))] = 1.0
        return np.column_stack([x * scale, y * scale])

    def _newton(self, target: np.ndarray, start: np.ndarray, iterations: int):
        """``(xy, ok)``: Newton's method on ``distort(xy) = target`` from ``start`` (both
        ``(N, 2)``) with the analytic Jacobian; ``ok`` where the round trip misses by at most
        :data:`UNDISTORT_TOLERANCE_PX`, the Jacobian determinant is positive and the solution
        lies on the pixel's side of the centre."""
        x, y = start[:, 0].copy(), start[:, 1].copy()
        tx, ty = target[:, 0], target[:, 1]
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            for step in range(iterations + 1):
                xd, yd, dxx, dxy, dyy = self.distort_columns(x, y, jacobian=True)
                rx, ry = xd - tx, yd - ty
                if step == iterations or not (np.nanmax(np.abs(rx), initial=0.0) >= 1e-15
                                              or np.nanmax(np.abs(ry), initial=0.0) >= 1e-15):
                    break  # the round trip and the Jacobian of this x are checked below
                det = dxx * dyy - dxy * dxy
                x -= (dyy * rx - dxy * ry) / det
                y -= (dxx * ry - dxy * rx) / det
            miss_px = np.maximum(np.abs(rx), np.abs(ry)) * np.max(np.diag(self.K)[:2])
            # a solution turned to the other side of the centre (where the radial factor is
            # negative, beyond a fold, the Jacobian determinant is positive again) is no ray
            # through this pixel
            ok = ((miss_px <= UNDISTORT_TOLERANCE_PX) & (dxx * dyy - dxy * dxy > 0)
                  & (x * tx + y * ty >= 0))
        return np.column_stack([x, y]), ok

    def distortion_problem(self) -> str | None:
        """Why the lens distortion cannot be inverted over the whole image, or None.

        Checks every pixel :data:`DISTORTION_CHECK_STEP_PX` apart along the border and on an
        interior grid (vectorized): each must undistort with a round trip within
        :data:`UNDISTORT_TOLERANCE_PX` on the monotone side of the distortion."""
        if self.dist is None:
            return None
        w, h = self.size
        step = DISTORTION_CHECK_STEP_PX
        us = np.unique(np.append(np.arange(0, w, step), w - 1)).astype(float)
        vs = np.unique(np.append(np.arange(0, h, step), h - 1)).astype(float)
        grid = np.stack(np.meshgrid(us, vs), axis=-1).reshape(-1, 2)
        _, reason = self.normalized_with_reason(grid)
        bad = np.flatnonzero(reason != Reason.OK)
        if bad.size == 0:
            return None
        u, v = grid[bad[np.argmin(np.abs(grid[bad] - [(w - 1) / 2, (h - 1) / 2]).sum(axis=1))]]
        radius = float(np.hypot(u - self.K[0, 2], v - self.K[1, 2]))
        return (f"the lens distortion {self.dist.tolist()} folds within the {w}x{h} image, "
                f"about {radius:.0f} px from the principal point, and cannot be inverted beyond: "
                f"{bad.size} of {grid.shape[0]} checked pixels have no undistorted position "
                f"(the nearest to the centre is ({u:g}, {v:g}))")

    # --- pixels <-> rays ----------------------------------------------------------------------
    def normalized(self, uv: np.ndarray) -> np.ndarray:
        """Pixels ``(N, 2)`` to undistorted normalized image coordinates ``(N, 2)`` (NaN where
        the distortion cannot be inverted, see :meth:`normalized_with_reason`)."""
        return self.normalized_with_reason(uv)[0]

    def normalized_with_reason(self, uv: np.ndarray):
        """:meth:`normalized` and a ``(N,)`` :class:`Reason` array (``NOT_CONVERGED`` where
        undistortion fails, ``INVALID_INPUT`` for non-finite pixels)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        fx, s, cx = self.K[0]
        fy, cy = self.K[1, 1], self.K[1, 2]
        xy = np.empty_like(uv)
        xy[:, 1] = (uv[:, 1] - cy) / fy
        xy[:, 0] = (uv[:, 0] - cx - s * xy[:, 1]) / fx
        return self.undistort_with_reason(xy)

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """Unit ray directions ``(N, 3)`` in the reference frame through pixels ``(N, 2)``.

        Every ray starts at :attr:`center`. This is the paper's ζ1 / ξ1 (equations 1-2). A pixel
        whose undistortion fails gives NaN (:meth:`rays_with_reason` says why).
        """
        return self.rays_with_reason(uv)[0]

    def rays_with_reason(self, uv: np.ndarray):
        """:meth:`rays` and their ``(N,)`` :class:`Reason` codes."""
        xy, reason = self.normalized_with_reason(uv)
        x, y = xy[:, 0], xy[:, 1]
        inverse_norm = 1.0 / np.sqrt(1.0 + x * x + y * y)
        d = np.empty((xy.shape[0], 3))
        if self._identity_rotation:
            np.multiply(x, inverse_norm, out=d[:, 0])
            np.multiply(y, inverse_norm, out=d[:, 1])
            d[:, 2] = inverse_norm
            return d, reason
        # R (x, y, 1) / |(x, y, 1)| column by column: NumPy's (N, 3) @ (3, 3) took 8 times as
        # long (0.67 s against 0.08 s for 10^6 rays)
        x = x * inverse_norm
        y = y * inverse_norm
        for j, (a, b, c) in enumerate(self.R):
            column = x * a
            column += y * b
            column += inverse_norm * c
            d[:, j] = column
        return d, reason

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

    def in_image(self, uv: np.ndarray, margin_px=0.0) -> np.ndarray:
        """Whether pixels ``(N, 2)`` lie inside the image, at least ``margin_px`` (a scalar or
        ``(N,)``) pixels from its border; NaN pixels are outside.

        The image spans [-0.5, W - 0.5] x [-0.5, H - 0.5] in OpenCV pixel coordinates.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        margin = np.asarray(margin_px, dtype=np.float64)
        w, h = self.size
        lo = -0.5 + margin
        return ((uv[:, 0] >= lo) & (uv[:, 0] <= w - 0.5 - margin)
                & (uv[:, 1] >= lo) & (uv[:, 1] <= h - 0.5 - margin))
