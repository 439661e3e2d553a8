"""The covariance of every triangulated point: pixel noise and the rig's covariance, first order.

A point X is measured from four pixel coordinates ``m = (u_L, v_L, u_R, v_R)``; the forward
model (:func:`measure.geometry.projection.project`) gives ``m = f(X, θ)`` with θ the rig's parameters
(named as in :mod:`measure.stereo.rig_covariance`). With ``J = ∂f/∂X`` ``(4, 3)`` at the point,
``W = diag(1/σ²)`` the pixel weights and ``J_θ = ∂f/∂θ`` ``(4, P)``:

* pixel part ``Σ_pix = (JᵀWJ)⁻¹`` — the covariance of the maximum-likelihood point (the
  ``reprojection`` triangulation) for independent Gaussian pixel noise of σ per coordinate;
* rig part ``A Σ_θ Aᵀ`` with ``A = −(JᵀWJ)⁻¹ JᵀW J_θ`` — how an error of the calibration moves
  the point (the same error moves every point: the rig part is correlated between points, and
  what is reported here is each point's marginal 3 × 3 block);
* ``Σ_X = Σ_pix + A Σ_θ Aᵀ``.

The ``optical_path`` triangulation (midpoint of the common perpendicular of the water rays) is
another estimator with the same first-order behaviour where the two rays meet: its linearization
``G`` satisfies ``G J = I`` like ``(JᵀWJ)⁻¹JᵀW`` and differs only in how it spreads the
component of the noise that makes the rays skew; on the paper's rig the two covariances agree
within the Monte Carlo spread (``tests/measure/stereo/test_uncertainty.py`` checks both methods against
≥ 200 noisy trials). The same covariance is therefore attached to both.

The pixel σ of a detection: stated (one number, per point, or per point and view), or estimated
from the detector (:func:`detection_sigma`): the intensity centroid ``ū = Σ w u / F`` of a disk
whose window pixels each carry the background noise σ_n has ``var ū = Σ (u − ū)² var w / F²``;
the weights ``w = max(I − background, 0)`` keep the full variance on the blob (``area`` pixels,
a disk of radius ``r_b``) and ``(1/2 − 1/(2π)) σ_n²`` on the clipped background of the rest of
the window (radius ``r_w``, its pixel count recovered from the SNR), and a disk of radius r has
``Σ (u − ū)² = π r⁴ / 4``. Checked against Monte Carlo of the detector (disks of radius 2.5–6 px:
ratio 0.92–1.00). Noise the background does not show (render noise of a black background, where
σ_n = 0 and the SNR is infinite) needs the stated floor.

Units: mm (points), px (pixels), rad; frame: the reference frame (the left camera's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera
from ..geometry.projection import project
from .rig_covariance import RigCovariance
from .rig import Rig, StereoRig

#: χ²₃(0.95): a point lies inside its 95 % ellipsoid when its Mahalanobis distance² to the truth
#: is at most this (``scipy.stats.chi2.ppf(0.95, 3)``).
CHI2_3_95 = 7.814727903251178

#: Variance of ``max(n, 0)`` for ``n ~ N(0, 1)``: the centroid weights clip the background at 0.
_CLIPPED_VARIANCE = 0.5 - 0.5 / np.pi

_INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class PointCovariance:
    """:func:`point_covariances`' answer: ``total``, ``pixel`` and ``rig`` ``(N, 3, 3)`` mm²
    (``rig`` zeros without a rig covariance); NaN rows where a point has no image."""

    total: np.ndarray
    pixel: np.ndarray
    rig: np.ndarray

    @property
    def sigmas(self) -> np.ndarray:
        """``(N, 3)`` mm: σx, σy, σz (square roots of the diagonal of ``total``)."""
        return np.sqrt(np.einsum("nii->ni", self.total))


def _distortion_terms(camera: Camera, pixels: np.ndarray):
    """d (u, v) / d (fx, fy, cx, cy, k1, k2, p1, p2, k3) ``(N, 2, 9)`` at ``pixels``: the pinhole
    ``u = fx·x_d + s·y_d + cx``, ``v = fy·y_d + cy`` with OpenCV's distortion
    ``x_d = x·radial + 2p1·xy + p2(r² + 2x²)``, ``y_d = y·radial + p1(r² + 2y²) + 2p2·xy``,
    ``radial = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)``; the undistorted
    ``(x, y)`` are recovered from the pixels (:meth:`Camera.undistort`, machine precision)."""
    K = camera.K
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    yd = (pixels[:, 1] - cy) / fy
    xd = (pixels[:, 0] - cx - s * yd) / fx
    x, y = camera.undistort(np.column_stack([xd, yd])).T
    c = np.zeros(8)
    dist = camera.brown_conrady_dist("the intrinsics' σ propagation")
    if dist is not None:
        c[: dist.size] = dist
    r2 = x * x + y * y
    denominator = 1 + r2 * (c[5] + r2 * (c[6] + r2 * c[7]))
    out = np.zeros((pixels.shape[0], 2, 9))
    out[:, 0, 0] = xd
    out[:, 1, 1] = yd
    out[:, 0, 2] = 1.0
    out[:, 1, 3] = 1.0
    # d (x_d, y_d) per distortion coefficient, then through (fx, s; 0, fy)
    d_xd = [x * r2 / denominator, x * r2 ** 2 / denominator, 2 * x * y, r2 + 2 * x * x,
            x * r2 ** 3 / denominator]
    d_yd = [y * r2 / denominator, y * r2 ** 2 / denominator, r2 + 2 * y * y, 2 * x * y,
            y * r2 ** 3 / denominator]
    for k, (dx, dy) in enumerate(zip(d_xd, d_yd)):
        out[:, 0, 4 + k] = fx * dx + s * dy
        out[:, 1, 4 + k] = fy * dy
    return out


def pixel_jacobians(rig: Rig, points, names=(), normal_axes=None):
    """The forward model of both views and its derivatives at ``points`` ``(N, 3)`` mm.

    Returns ``pixels`` ``(N, 4)`` (u_L, v_L, u_R, v_R), ``d_points`` ``(N, 4, 3)`` px/mm and
    ``d_parameters`` ``(N, 4, P)``: d pixel / d each named rig parameter of ``names``
    (:mod:`measure.stereo.rig_covariance`'s grammar, its units), analytic (the port and pose
    derivatives of :class:`measure.geometry.projection.ParameterJacobian`, the intrinsics of
    :func:`_distortion_terms`). ``normal_axes`` ``(2, 3)``: the tilt axes of ``port.tilt[*]``.
    A dome rig (each camera through its own dome,
    :class:`measure.geometry.dome_projection.DomeParameterJacobian`) takes the intrinsics, the right
    camera's pose, each dome's centre (``left.dome_center[k]``,
    ``right.dome_center[k]``: reference frame, mm — that view's own dome) and ``port.index[k]``
    (medium k of both domes); the flat port's ``port.distance``, ``port.tilt[*]`` and
    ``port.thickness[*]`` are refused there, and the domes' names on a flat port. A rig of two
    housings (:class:`measure.geometry.flat_pair.FlatPair`) takes ``left.port.…`` and
    ``right.port.…`` (that camera's port) and ``port.index[k]`` (both). Rows without
    an image are NaN."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    names = tuple(names)
    rig.port.check_parameter_names(names)
    want = bool(names)
    views = [project(cam, rig.view_port(view), points, jacobian=True, parameters=want)
             for view, cam in enumerate(rig.cameras)]
    pixels = np.concatenate([v[0] for v in views], axis=1)
    d_points = np.concatenate([v[1] for v in views], axis=1)
    d_parameters = np.zeros((points.shape[0], 4, len(names)))
    if not want:
        return pixels, d_points, d_parameters
    intrinsics = [None, None]
    for p, name in enumerate(names):
        head, _, tail = name.partition(".")
        own_port = head in ("left", "right") and tail.startswith("port.")
        for view, (camera, rows) in enumerate(zip(rig.cameras, (slice(0, 2), slice(2, 4)))):
            jac = views[view][2]
            column = None
            if own_port:  # a port per camera: that camera's own port
                if head == ("left", "right")[view]:
                    column = _port_column(jac, tail, normal_axes, name)
            elif head in ("left", "right") and tail in _INTRINSICS:
                if head == ("left", "right")[view]:
                    if intrinsics[view] is None:
                        intrinsics[view] = _distortion_terms(camera, views[view][0])
                    column = intrinsics[view][:, :, _INTRINSICS.index(tail)]
            elif tail.startswith("dome_center"):
                if head == ("left", "right")[view]:
                    column = jac.dome_center[:, :, int(tail[-2])]
            elif head == "right" and view == 1:
                k = int(tail[-2])
                column = (jac.rotation if tail.startswith("rotation") else jac.center)[:, :, k]
            else:
                column = _port_column(jac, name, normal_axes, name)
            if column is not None:
                d_parameters[:, rows, p] = column
    return pixels, d_points, d_parameters


def _port_column(jac, name: str, normal_axes, label: str):
    """d pixel / d the port parameter ``name`` (``port.distance``, ``port.tilt[k]``,
    ``port.thickness[k]``, ``port.index[k]``) of one view's parameter Jacobian; None for
    another name. ``label`` names the parameter in errors."""
    tail = name.partition(".")[2]
    if name == "port.distance":
        return jac.distance
    if tail.startswith("tilt"):
        if normal_axes is None:
            raise ValueError(f"{label} needs normal_axes")
        return jac.normal @ np.asarray(normal_axes, dtype=float)[int(tail[-2])]
    if tail.startswith("thickness"):
        k = int(tail[tail.index("[") + 1:-1])
        if k >= jac.thicknesses.shape[2]:
            raise ValueError(f"{label}: the port has {jac.thicknesses.shape[2]} layer(s)")
        return jac.thicknesses[:, :, k]
    if tail.startswith("index"):
        k = int(tail[tail.index("[") + 1:-1])
        if k >= jac.indices.shape[2]:
            raise ValueError(f"{label}: the port has {jac.indices.shape[2]} media")
        return jac.indices[:, :, k]
    return None


def perturbed_rig(rig: Rig, names, delta, normal_axes=None) -> Rig:
    """``rig`` with the named parameters (:mod:`measure.stereo.rig_covariance`) moved by ``delta``
    ``(P,)`` in their units: the definition :func:`pixel_jacobians` differentiates (used by the
    tests and by Monte Carlo checks). A rig of two domes: ``left/right.dome_center[k]`` move
    that dome's centre (reference frame), ``port.index[k]`` medium k of both domes."""
    cams = [rig.left, rig.right]
    K = [c.K.copy() for c in cams]
    dist = [np.zeros(8) if c.brown_conrady_dist("perturbed_rig") is None
            else np.pad(c.dist, (0, 8 - c.dist.size)) for c in cams]
    R, t = rig.right.R.copy(), rig.right.t.copy()
    port_changes = []
    phi = np.zeros(3)
    for name, d in zip(names, np.asarray(delta, dtype=float)):
        head, _, tail = name.partition(".")
        if head in ("left", "right") and tail in _INTRINSICS:
            v = 0 if head == "left" else 1
            k = _INTRINSICS.index(tail)
            if k < 4:
                K[v][(0, 1, 0, 1)[k], (0, 1, 2, 2)[k]] += d
            else:
                dist[v][(0, 1, 2, 3, 4)[k - 4]] += d
        elif tail.startswith("dome_center"):
            port_changes.append((name, d))
        elif tail.startswith("rotation"):
            phi[int(tail[-2])] += d
        elif tail.startswith("center"):
            t[int(tail[-2])] += d
        else:
            port_changes.append((name, d))
    angle = np.linalg.norm(phi)
    if angle > 0:
        import cv2  # Rodrigues: exp([φ]×)

        R = cv2.Rodrigues(phi)[0] @ R
    size = [c.size for c in cams]
    new = [Camera(K[v], size[v], None if not np.any(dist[v]) else dist[v],
                  cams[v].R if v == 0 else R, cams[v].t if v == 0 else t) for v in range(2)]
    return StereoRig(new[0], new[1], rig.port.moved(port_changes, normal_axes))


def pixel_sigmas(pixel_sigma, n: int, allow_zero: bool = False) -> np.ndarray:
    """``(N, 4)`` px: σ of each of a point's four pixel coordinates from a stated σ (a number,
    ``(N,)`` per point, or ``(N, 2)`` per point and view: left, right); positive (or zero with
    ``allow_zero``), ValueError otherwise."""
    sigma = np.asarray(pixel_sigma, dtype=np.float64)
    if sigma.ndim == 0:
        sigma = np.full((n, 2), float(sigma))
    elif sigma.shape == (n,):
        sigma = np.repeat(sigma[:, None], 2, axis=1)
    elif sigma.shape != (n, 2):
        raise ValueError(f"pixel_sigma must be a number, ({n},) or ({n}, 2), got {sigma.shape}")
    finite = np.isfinite(sigma)
    if np.any(sigma[finite] < 0) or (not allow_zero and np.any(sigma[finite] == 0)):
        raise ValueError("pixel_sigma must be positive")
    return np.repeat(sigma, 2, axis=1)


def point_covariances(rig: Rig, points, pixel_sigma, rig_covariance: RigCovariance | None
                      = None) -> PointCovariance:
    """First-order covariance ``(N, 3, 3)`` mm² of triangulated ``points`` ``(N, 3)`` (module
    docs), with its pixel and rig parts. ``pixel_sigma``: px, see :func:`pixel_sigmas`.
    ``rig_covariance`` None: the rig is taken as exact (pixel part only)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    sigma = pixel_sigmas(pixel_sigma, points.shape[0])
    return _covariances(rig, points, 1.0 / (sigma * sigma), rig_covariance)


def point_covariances_full(rig: Rig, points, pixel_covariance,
                           rig_covariance: RigCovariance | None = None) -> PointCovariance:
    """:func:`point_covariances` with a full ``(N, 4, 4)`` px² covariance of each point's four
    pixel coordinates ``(u_L, v_L, u_R, v_R)`` (positive definite; correlated coordinates, a
    σ along a direction: :func:`dense_pixel_covariance`): ``Σ_pix = (JᵀWJ)⁻¹`` with
    ``W = pixel_covariance⁻¹``, the rig part as in the module docs."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    covariance = np.asarray(pixel_covariance, dtype=np.float64)
    if covariance.shape != (points.shape[0], 4, 4):
        raise ValueError(f"pixel_covariance must be ({points.shape[0]}, 4, 4), got "
                         f"{covariance.shape}")
    weight = np.full_like(covariance, np.nan)
    ok = np.all(np.isfinite(covariance), axis=(1, 2))
    weight[ok] = np.linalg.inv(covariance[ok])
    return _covariances(rig, points, weight, rig_covariance)


#: The isotropic part of :func:`dense_pixel_covariance`, a fraction of the σ along the curve.
DENSE_ISOTROPIC_FRACTION = 0.01


def dense_pixel_covariance(sigma_px, direction, isotropic_px=None) -> np.ndarray:
    """``(N, 4, 4)`` px²: the pixel covariance of dense matches (:class:`measure.dense.match.
    DenseMatches`): the left pixel is the grid point (exact) and the matcher moves the right
    pixel along its epipolar curve only, so the right pixel carries ``sigma_px`` ``(N,)`` along
    the unit ``direction`` ``(N, 2)`` (a rank-1 2 × 2 block), plus ``isotropic_px`` (default
    :data:`DENSE_ISOTROPIC_FRACTION` × ``sigma_px``) on all four coordinates, which keeps the
    covariance invertible (the point's σ across its left ray is that small fraction)."""
    sigma = np.asarray(sigma_px, dtype=np.float64).reshape(-1)
    direction = np.asarray(direction, dtype=np.float64).reshape(-1, 2)
    iso = DENSE_ISOTROPIC_FRACTION * sigma if isotropic_px is None else \
        np.broadcast_to(np.asarray(isotropic_px, dtype=np.float64), sigma.shape)
    out = np.zeros((sigma.size, 4, 4))
    out[:, 2:, 2:] = (sigma * sigma)[:, None, None] * direction[:, :, None] * direction[:, None, :]
    out += (iso * iso)[:, None, None] * np.eye(4)
    return out


def dense_point_covariances(rig: Rig, points, sigma_px, direction,
                            rig_covariance: RigCovariance | None = None) -> PointCovariance:
    """:func:`point_covariances_full` with :func:`dense_pixel_covariance` (its default
    isotropic part), the weights written in closed form (no 4 × 4 inverse per point): the left
    block ``I / ε²``, the right one ``(I − s² / (s² + ε²) t tᵀ) / ε²`` for ``s`` = ``sigma_px``
    along the unit ``t`` = ``direction`` and ``ε = DENSE_ISOTROPIC_FRACTION · s``."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    s2 = np.asarray(sigma_px, dtype=np.float64).reshape(-1) ** 2
    t = np.asarray(direction, dtype=np.float64).reshape(-1, 2)
    if s2.shape[0] != points.shape[0] or t.shape[0] != points.shape[0]:
        raise ValueError("sigma_px and direction need one row per point")
    e2 = DENSE_ISOTROPIC_FRACTION ** 2 * s2
    with np.errstate(invalid="ignore", divide="ignore"):
        weight = np.eye(4) / e2[:, None, None]
        weight[:, 2:, 2:] -= ((s2 / (s2 + e2) / e2)[:, None, None] * t[:, :, None]
                              * t[:, None, :])
    weight[~(np.isfinite(s2) & (s2 > 0))] = np.nan
    return _covariances(rig, points, weight, rig_covariance)


def _inverse_3x3(m: np.ndarray) -> np.ndarray:
    """Inverses of ``(N, 3, 3)`` matrices in closed form (columns: cross products of the rows
    over the determinant); non-finite where singular."""
    a, b, c = m[:, 0], m[:, 1], m[:, 2]
    cofactors = np.stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)], axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        return cofactors / np.einsum("ni,ni->n", a, cofactors[:, :, 0])[:, None, None]


def _covariances(rig, points, weight, rig_covariance) -> PointCovariance:
    """The pixel and rig parts with pixel weights ``weight`` ``(N, 4)`` (diagonal) or
    ``(N, 4, 4)``."""
    names = () if rig_covariance is None else rig_covariance.names
    axes = None if rig_covariance is None else rig_covariance.normal_axes
    _, J, Jt = pixel_jacobians(rig, points, names, axes)
    if weight.ndim == 2:
        JW = np.swapaxes(J, 1, 2) * weight[:, None, :]  # (N, 3, 4)
    else:
        JW = np.matmul(np.swapaxes(J, 1, 2), weight)
    normal = np.matmul(JW, J)
    pixel = _inverse_3x3(normal)
    pixel[~np.all(np.isfinite(pixel), axis=(1, 2))] = np.nan
    rig_part = np.zeros_like(pixel)
    if names:
        # A = −(JᵀWJ)⁻¹ JᵀW J_θ  (N, 3, P)
        A = -np.matmul(np.matmul(pixel, JW), Jt)
        rig_part = np.einsum("nip,pq,njq->nij", A, rig_covariance.matrix, A)
    total = pixel + rig_part
    return PointCovariance(total, pixel, rig_part)


def point_covariance(rig: Rig, uv_left, uv_right, points, pixel_sigma,
                     rig_covariance: RigCovariance | None = None) -> np.ndarray:
    """``(N, 3, 3)`` mm²: the covariance of each point triangulated from ``uv_left``,
    ``uv_right`` ``(N, 2)`` px (rows whose pixels or point are not finite are NaN). The
    Jacobians are taken at the point (module docs; the same for the ``reprojection`` and
    ``optical_path`` triangulations)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    total = point_covariances(rig, points, pixel_sigma, rig_covariance).total
    uv = np.concatenate([np.asarray(uv_left, dtype=float).reshape(-1, 2),
                         np.asarray(uv_right, dtype=float).reshape(-1, 2)], axis=1)
    total[~np.all(np.isfinite(uv), axis=1)] = np.nan
    return total


#: Median of χ²₁ (``scipy.stats.chi2.ppf(0.5, 1)``): a point's reprojection residual has one
#: degree of freedom (4 pixel coordinates, 3 unknowns).
CHI2_1_MEDIAN = 0.454936423119572
#: A residual beyond this many times its expected size (χ²₁ exceeds it with probability 8e-6) is
#: a gross error (a wrong match) and left out of the variance factor.
OUTLIER_CHI2_1 = 20.0


#: The largest exponent of :func:`residual_sigma`'s flux model, ``σ ∝ flux^(−p)``.
MAX_FLUX_EXPONENT = 2.0


def residual_sigma(rig: Rig, uv_left, uv_right, points, pixel_sigma=0.0,
                   flux=None) -> dict:
    """The pixel noise the data show beyond ``pixel_sigma`` (px; a number, ``(N,)`` or
    ``(N, 2)``): the a-posteriori variance factor of the triangulation, no truth needed.

    At each point the first-order maximum-likelihood residual of its four pixel coordinates is
    ``r = (I − J (JᵀJ)⁻¹ Jᵀ)(m − f(X))`` (``f`` the forward model, ``J`` its point Jacobian; at
    the optical-path point or the reprojection point alike, since the projector removes the
    part a move of X explains); ``|r|²`` has one degree of freedom and expectation σ² for a
    pixel noise of σ per coordinate. The extra σ₀ every detection gets solves
    ``mean(|r|² / (σ_i² + σ₀²)) = 1`` (0 when the stated σ_i — the mean of the point's four
    stated variances — already explain the residuals) over the residuals within
    :data:`OUTLIER_CHI2_1` times their expected size under the robust start (the same equation
    with the median and ``median(χ²₁)``): a wrong match does not inflate it. What it cannot
    see: an error the two views share (the disks' eccentricity moves both images of a target
    consistently, and so does a calibration error along the rays). Returns ``{"sigma0_px",
    "rms_residual_px", "n"}``.

    ``flux`` ``(N,)`` (each pair's detections' light, e.g. the geometric mean of the two
    fluxes): the extra noise is then not the same for every detection but
    ``σ₀ · (flux / median flux)^(−p)`` — faint (small, oblique, far) targets' centres scatter more
    — with ``p`` in [0, :data:`MAX_FLUX_EXPONENT`] and σ₀ fitted together by maximum
    likelihood of the residuals (``|r|² ~ (σ_i² + σ₀² w²) χ²₁``), no truth needed; the result
    also holds ``"flux_exponent"`` and ``"weights"`` ``(N,)`` (``w``, 1 where the flux is not a
    positive number; NaN for the rows without a residual)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    q, known, ok = _projected_residuals(rig, uv_left, uv_right, points, pixel_sigma)
    if not ok.any():
        return {"sigma0_px": None, "rms_residual_px": None, "n": 0}
    everything = np.ones(q.shape, dtype=bool)
    robust = _extra_variance(q, known, np.median, CHI2_1_MEDIAN, everything)
    inliers = q <= OUTLIER_CHI2_1 * (known + robust)
    if flux is None:
        sigma0 = float(np.sqrt(_extra_variance(q, known, np.mean, 1.0, inliers)))
        return {"sigma0_px": sigma0, "rms_residual_px": float(np.sqrt(np.mean(q))),
                "n": int(ok.sum())}
    light = np.asarray(flux, dtype=np.float64).reshape(-1)[ok]
    positive = np.isfinite(light) & (light > 0)
    relative = np.ones_like(light)
    if positive.any():
        relative[positive] = light[positive] / np.median(light[positive])
    exponent, variance = _flux_exponent(q, known, inliers, relative)
    weights = np.full(points.shape[0], np.nan)
    weights[ok] = relative ** (-exponent)
    return {"sigma0_px": float(np.sqrt(variance)), "flux_exponent": exponent,
            "weights": weights, "rms_residual_px": float(np.sqrt(np.mean(q))),
            "n": int(ok.sum())}


def _projected_residuals(rig, uv_left, uv_right, points, pixel_sigma):
    """``(q, known, ok)``: the squared residuals |r|² (px², one degree of freedom each) and the
    mean stated variances (px²) of the rows ``ok`` whose residual and Jacobian are finite."""
    observed = np.concatenate([np.asarray(uv_left, dtype=float).reshape(-1, 2),
                               np.asarray(uv_right, dtype=float).reshape(-1, 2)], axis=1)
    stated = pixel_sigmas(pixel_sigma, points.shape[0], allow_zero=True)
    predicted, J, _ = pixel_jacobians(rig, points)
    e = observed - predicted
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(J), axis=(1, 2))
    e, J = e[ok], J[ok]
    normal = np.einsum("nki,nkj->nij", J, J)
    step = np.linalg.solve(normal, np.einsum("nki,nk->ni", J, e)[..., None])[..., 0]
    r = e - np.einsum("nki,ni->nk", J, step)
    return np.einsum("nk,nk->n", r, r), np.mean(stated[ok] ** 2, axis=1), ok


def _extra_variance(q, known, statistic, target, rows, w2=None) -> float:
    """The extra variance σ₀² (px², of weight ``w2`` per row, default 1) that brings the
    statistic of the residuals ``rows`` in units of their expected size to ``target``."""
    from scipy.optimize import brentq  # loaded on first use, not with measure

    w2 = np.ones_like(q) if w2 is None else w2

    def excess(variance):  # the statistic of the residuals in units of their expected size
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(statistic(np.where(q[rows] > 0,
                                            q[rows] / (known[rows] + variance * w2[rows]), 0.0)))

    upper = (2.0 * float(statistic(q[rows] / w2[rows]) / target)
             + float(np.max(known / w2)))
    if upper <= 0 or excess(0.0) <= target:
        return 0.0
    # the excess falls from > target at 0 to < target at ``upper``
    return brentq(lambda v: excess(v) - target, 0.0, upper, xtol=1e-12 * upper)


def _flux_exponent(q, known, inliers, relative) -> tuple[float, float]:
    """``(p, σ₀²)``: the extra noise's ``(flux / median flux)^(−p)`` exponent in [0,
    :data:`MAX_FLUX_EXPONENT`] and σ₀² (px²), by maximum likelihood of the inliers' residuals."""
    from scipy.optimize import minimize_scalar  # loaded on first use, not with measure

    def fit(p):  # σ₀² for exponent p, and the negative log-likelihood of the inliers
        w2 = relative ** (-2.0 * p)
        variance = _extra_variance(q, known, np.mean, 1.0, inliers, w2)
        total = known[inliers] + variance * w2[inliers]
        with np.errstate(divide="ignore", invalid="ignore"):
            nll = float(np.sum(np.log(np.where(total > 0, total, np.inf))
                               + np.where(total > 0, q[inliers] / total, 0.0)))
        return variance, nll

    if np.ptp(np.log(relative)) > 0:
        best = minimize_scalar(lambda p: fit(p)[1], bounds=(0.0, MAX_FLUX_EXPONENT),
                               method="bounded", options={"xatol": 1e-3})
        exponent = float(best.x) if fit(best.x)[1] < fit(0.0)[1] else 0.0
    else:
        exponent = 0.0
    return exponent, fit(exponent)[0]


#: An oblique disk's image is an ellipse; its centre scatters more across its minor axis (the
#: direction it is foreshortened in, a few pixels wide) than along it: σ_minor = σ · e^k with e
#: the detection's elongation. k from the rendered truth (the scatter of the detected centres,
#: eccentricity removed, about the simulator's pixels, by maximum likelihood in each
#: detection's axes): 0.256 on ``scenes/cylinder.xml`` (ellipses aligned with the pixel grid,
#: minor axes along u: at e ≥ 1.6, 0.0111 px across against 0.0079 px along), 0.094 on
#: ``sphere_cap.xml``, 0.115 on ``tilted_plane.xml``; the largest is taken. The reprojection
#: residuals cannot measure it where the minor axes lie along the epipolar lines (the one
#: residual degree of freedom of a pair is across them).
MINOR_AXIS_EXPONENT = 0.25


def elongated_pixel_covariance(sigma, elongation, orientation,
                               exponent: float = MINOR_AXIS_EXPONENT) -> np.ndarray:
    """``(N, 4, 4)`` px² of the four pixel coordinates ``(u_L, v_L, u_R, v_R)`` of N pairs from
    each detection's σ ``(N, 2)`` (left, right; the σ along its ellipse's major axis), its
    elongation ``(N, 2)`` (≥ 1) and the major axis' direction ``(N, 2)`` rad from +u towards
    +v: across the minor axis σ · elongation^``exponent`` (:data:`MINOR_AXIS_EXPONENT`); the
    views independent (:func:`point_covariances_full` takes it)."""
    sigma = np.asarray(sigma, dtype=np.float64).reshape(-1, 2)
    elongation = np.asarray(elongation, dtype=np.float64).reshape(-1, 2)
    orientation = np.asarray(orientation, dtype=np.float64).reshape(-1, 2)
    stretch = np.where(np.isfinite(elongation) & (elongation >= 1.0), elongation, 1.0) ** exponent
    out = np.zeros((sigma.shape[0], 4, 4))
    for v in range(2):
        a = np.column_stack([np.cos(orientation[:, v]), np.sin(orientation[:, v])])
        b = np.column_stack([-a[:, 1], a[:, 0]])
        block = (sigma[:, v, None, None] ** 2 * np.einsum("ni,nj->nij", a, a)
                 + (sigma[:, v] * stretch[:, v])[:, None, None] ** 2
                 * np.einsum("ni,nj->nij", b, b))
        out[:, 2 * v:2 * v + 2, 2 * v:2 * v + 2] = block
    return out


def mahalanobis_squared(errors, covariance) -> np.ndarray:
    """``(N,)``: ``eᵀ Σ⁻¹ e`` of errors ``(N, 3)`` under covariances ``(N, 3, 3)`` (NaN where
    either is not finite or Σ is singular)."""
    errors = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
    covariance = np.asarray(covariance, dtype=np.float64).reshape(-1, 3, 3)
    out = np.full(errors.shape[0], np.nan)
    ok = np.all(np.isfinite(errors), axis=1) & np.all(np.isfinite(covariance), axis=(1, 2))
    if ok.any():
        try:
            solved = np.linalg.solve(covariance[ok], errors[ok][..., None])[..., 0]
        except np.linalg.LinAlgError:
            return out
        out[ok] = np.einsum("ni,ni->n", errors[ok], solved)
    return out


def coverage_summary(errors, covariance, dof: int = 3) -> dict:
    """How honest the covariances were, against the truth: ``coverage_95`` (fraction of points
    with Mahalanobis distance² ≤ χ²_dof(0.95); 0.95 expected), ``mahalanobis2_mean`` (``dof``
    expected), and per component (x, y, z) the normalized errors ``e / σ``: mean, standard
    deviation (1 expected) and the fraction beyond 1.96 (0.05 expected). ``n``: the points
    counted. ``dof``: the dimensions the errors span — 3, or 1 for errors along one line (a
    dense match against truth on the same left ray: :data:`DENSE_ISOTROPIC_FRACTION`)."""
    errors = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
    covariance = np.asarray(covariance, dtype=np.float64).reshape(-1, 3, 3)
    d2 = mahalanobis_squared(errors, covariance)
    ok = np.isfinite(d2)
    if not ok.any():
        return {"n": 0, "coverage_95": None, "mahalanobis2_mean": None, "normalized": None}
    z = errors[ok] / np.sqrt(np.einsum("nii->ni", covariance[ok]))
    if dof == 3:
        threshold = CHI2_3_95
    else:
        from scipy.stats import chi2

        threshold = float(chi2.ppf(0.95, dof))
    return {"n": int(ok.sum()), "dof": int(dof),
            "coverage_95": float(np.mean(d2[ok] <= threshold)),
            "mahalanobis2_mean": float(np.mean(d2[ok])),
            "mahalanobis2_median": float(np.median(d2[ok])),
            "normalized": {axis: {"mean": float(np.mean(z[:, k])), "std": float(np.std(z[:, k])),
                                  "beyond_1.96": float(np.mean(np.abs(z[:, k]) > 1.96))}
                           for k, axis in enumerate("xyz")}}


def sigma_summary(covariance) -> dict:
    """``report.json``'s summary of point covariances ``(N, 3, 3)``: per axis the median and the
    largest σ (mm), the median and largest ``σ_P = sqrt(trace)``, and the index of the worst
    point (largest σ_P)."""
    covariance = np.asarray(covariance, dtype=np.float64).reshape(-1, 3, 3)
    sig = np.sqrt(np.einsum("nii->ni", covariance))
    ok = np.all(np.isfinite(sig), axis=1)
    if not ok.any():
        return {"n": 0}
    total = np.sqrt(np.sum(sig[ok] ** 2, axis=1))
    worst = int(np.flatnonzero(ok)[np.argmax(total)])
    return {"n": int(ok.sum()),
            "median_sigma_mm": {a: float(np.median(sig[ok, k])) for k, a in enumerate("xyz")},
            "max_sigma_mm": {a: float(np.max(sig[ok, k])) for k, a in enumerate("xyz")},
            "median_sigma_p_mm": float(np.median(total)), "max_sigma_p_mm": float(total.max()),
            "worst_index": worst}


def detection_sigma(detections, floor_px: float = 0.0) -> np.ndarray:
    """``(N,)`` px: the centroid σ per coordinate of each accepted detection
    (:class:`measure.images.detect.Detections`) from its SNR and size (module docs; the window's pixel
    count ``n_w = (flux / (σ_n·SNR))²``, ``r_w = sqrt(n_w / π)``, ``r_b = sqrt(area / π)``),
    combined in quadrature with ``floor_px`` (what the background noise does not see: render
    noise on a black background, where σ_n = 0 and the SNR is infinite, the lens, the
    eccentricity of the disk). A detection with an infinite SNR gets the floor alone."""
    snr = np.asarray(detections.snr, dtype=np.float64)
    flux = np.asarray(detections.flux, dtype=np.float64)
    area = np.asarray(detections.area, dtype=np.float64)
    sigma_n = float(detections.noise_sigma)
    background_term = np.zeros_like(snr)
    finite = np.isfinite(snr) & (snr > 0) & (sigma_n > 0)
    if finite.any():
        n_window = (flux[finite] / (sigma_n * snr[finite])) ** 2
        r_w4 = (n_window / np.pi) ** 2
        r_b4 = (np.minimum(area[finite], n_window) / np.pi) ** 2
        moment = 0.25 * np.pi * (_CLIPPED_VARIANCE * r_w4 + (1 - _CLIPPED_VARIANCE) * r_b4)
        background_term[finite] = sigma_n * np.sqrt(moment) / flux[finite]
    background_term[(snr <= 0) & np.isfinite(snr)] = np.inf
    return np.sqrt(background_term ** 2 + float(floor_px) ** 2)


__all__ = ["CHI2_1_MEDIAN", "CHI2_3_95", "DENSE_ISOTROPIC_FRACTION", "PointCovariance",
           "coverage_summary", "dense_pixel_covariance", "dense_point_covariances",
           "detection_sigma", "elongated_pixel_covariance",
           "mahalanobis_squared", "perturbed_rig", "pixel_jacobians", "pixel_sigmas",
           "point_covariance", "point_covariances", "point_covariances_full", "residual_sigma",
           "sigma_summary"]
