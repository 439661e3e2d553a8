"""The flat interface in front of one camera, estimated from a known object (after Agrawal et
al., "A Theory of Multi-Layer Flat Refractive Geometry", CVPR 2012: the interface's normal and
distance are determined by the images of a known object through it).

Unknowns: the port's distance ``D`` (mm) and its normal, tilted from the starting normal
``n₀`` by ``(a₀, a₁)`` rad about the two axes of :func:`measure.calibration.selfcal.tilt_basis`
(``n = normalize(n₀ + a₀ e₀ + a₁ e₁)``, as the rig covariance's ``port.tilt[k]``), and the
object's pose in each of F frames (``X_ref = R · X_obj + t``). The layers' thicknesses and the
indices stay as given. Start: the given port (a design value) and each frame's pose from
:func:`measure.stereo.pose.estimate_pose` through it; then one ``least_squares`` over
everything on the refractive reprojection error, with the analytic Jacobian (the port's from
``project(..., parameters=True)``, the poses' as in :mod:`measure.stereo.pose`). Agrawal et
al.'s closed-form start (the axis from a linear "flat refraction constraint", the distance from
a polynomial) is not implemented: a housing's design values are a start within reach.

Where this differs from :func:`measure.calibration.housing.calibrate_housing`: one camera, any
known object (not only a board), no in-air stereo calibration. Units mm, rad, px.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .selfcal import tilt_basis
from ..geometry.port import require_flat_port
from ..geometry.projection import project
from ..reasons import Reason
from ..stereo.multiview import View
from ..stereo.pose import (DEGENERATE_CONDITION, TOLERANCE, estimate_poses, exp_so3, left_jacobian,
                           skew)

#: The names of the interface's parameters, in the order of :attr:`InterfaceEstimate.covariance`.
INTERFACE_NAMES = ("port.distance", "port.tilt[0]", "port.tilt[1]")


@dataclass(frozen=True)
class InterfaceEstimate:
    """``port`` (the given port with the estimated distance and normal), ``R`` ``(F, 3, 3)``
    and ``t`` ``(F, 3)`` the object's poses, ``covariance`` ``(3, 3)`` of
    ``(D mm, tilt₀ rad, tilt₁ rad)`` about ``normal_axes`` ``(2, 3)`` (the axes ⟂ the start
    normal; the marginal of the joint covariance with the poses), ``rms_px``, ``sigma_px`` (the
    pixel σ the covariance holds: stated, or from the residuals), ``reason``."""

    port: object
    R: np.ndarray
    t: np.ndarray
    covariance: np.ndarray
    normal_axes: np.ndarray
    rms_px: float
    sigma_px: float
    reason: int

    @property
    def valid(self) -> bool:
        return self.reason == Reason.OK


def estimate_interface(view: View, object_points, pixels, pixel_sigma=None,
                       max_nfev: int = 200) -> InterfaceEstimate:
    """The distance and normal of ``view.port`` (a :class:`measure.FlatPort`, the start) and
    the object's poses from ``pixels`` ``(F, M, 2)`` of ``object_points`` ``(M, 3)`` (module
    docs). NaN results with a reason where a frame has no starting pose (its reason), the
    refinement does not converge (``NOT_CONVERGED``) or the data do not fix the interface
    (``DEGENERATE``)."""
    port = require_flat_port(view.port, "estimate_interface needs a flat port (a FlatPort)")
    camera = view.camera
    object_points = np.asarray(object_points, dtype=np.float64)
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim != 3 or pixels.shape[1:] != (object_points.shape[0], 2):
        raise ValueError(f"pixels must have shape (F, {object_points.shape[0]}, 2), got "
                         f"{pixels.shape}")
    frames = pixels.shape[0]
    axes = np.array(tilt_basis(port.normal))
    nan = InterfaceEstimate(port, np.full((frames, 3, 3), np.nan), np.full((frames, 3), np.nan),
                            np.full((3, 3), np.nan), axes, np.nan, np.nan, int(Reason.OK))
    starts = estimate_poses(view, object_points, pixels, pixel_sigma)
    if not starts.valid.all():
        first = int(starts.reason[~starts.valid][0])
        return InterfaceEstimate(**{**nan.__dict__, "reason": first})
    sigma = 1.0 if pixel_sigma is None else float(pixel_sigma)
    seen = [np.flatnonzero(np.all(np.isfinite(pixels[f]), axis=1)) for f in range(frames)]
    rows = np.concatenate([np.full(s.size, f) for f, s in enumerate(seen)])
    points = np.concatenate([s for s in seen])
    observed = np.concatenate([pixels[f][s] for f, s in enumerate(seen)])
    R0 = starts.R
    n_params = 3 + 6 * frames

    def unpack(x):
        m = port.normal + x[1] * axes[0] + x[2] * axes[1]
        length = np.linalg.norm(m)
        moved = port.replace(distance=x[0], normal=m / length)
        phi = x[3:].reshape(frames, 6)[:, :3]
        t = x[3:].reshape(frames, 6)[:, 3:]
        R = np.stack([exp_so3(phi[f]) @ R0[f] for f in range(frames)])
        return moved, length, phi, R, t

    cache = {}

    def evaluate(x):
        key = x.tobytes()
        if key not in cache:
            moved, length, phi, R, t = unpack(x)
            X = np.einsum("nij,nj->ni", R[rows], object_points[points]) + t[rows]
            try:
                uv, d_points, jac = project(camera, moved, X, parameters=True)
            except ValueError:  # the camera ended up on the water side
                uv = np.full((X.shape[0], 2), np.nan)
                d_points = jac = None
            cache[key] = (moved, length, phi, R, t, X, uv, d_points, jac)
        return cache[key]

    def residual(x):
        uv = evaluate(x)[6]
        r = ((uv - observed) / sigma).ravel()
        return np.where(np.isfinite(r), r, 1e8)

    def jacobian(x):
        moved, length, phi, R, t, X, uv, d_points, jac = evaluate(x)
        J = np.zeros((observed.shape[0], 2, n_params))
        if jac is None:
            return J.reshape(-1, n_params)
        J[:, :, 0] = jac.distance
        J[:, :, 1:3] = (jac.normal / length) @ axes.T
        d_phi = -skew(X - t[rows])  # (n, 3, 3), then J_l(φ) per frame
        for f in range(frames):
            mine = rows == f
            block = d_points[mine] @ (d_phi[mine] @ left_jacobian(phi[f]))
            J[mine, :, 3 + 6 * f:6 + 6 * f] = block
            J[mine, :, 6 + 6 * f:9 + 6 * f] = d_points[mine]
        J /= sigma
        J = J.reshape(-1, n_params)
        return np.where(np.isfinite(J), J, 0.0)

    x0 = np.concatenate([[port.distance, 0.0, 0.0],
                         np.column_stack([np.zeros((frames, 3)), starts.t]).ravel()])
    try:
        result = least_squares(residual, x0, jac=jacobian, method="trf", x_scale="jac",
                               xtol=TOLERANCE, ftol=TOLERANCE, gtol=TOLERANCE,
                               max_nfev=max_nfev)
    except ValueError:
        return InterfaceEstimate(**{**nan.__dict__, "reason": int(Reason.NOT_CONVERGED)})
    moved, length, phi, R, t, X, uv, _, _ = evaluate(result.x)
    r = uv - observed
    if result.status <= 0 or not np.all(np.isfinite(r)):
        return InterfaceEstimate(**{**nan.__dict__, "reason": int(Reason.NOT_CONVERGED)})
    J = result.jac.copy()
    for f in range(frames):  # rotations applied on the left of each R itself
        cols = slice(3 + 6 * f, 6 + 6 * f)
        J[:, cols] = np.linalg.solve(left_jacobian(phi[f]).T, J[:, cols].T).T
    normal = J.T @ J
    scale = np.sqrt(np.diag(normal))
    if not np.all(scale > 0):
        return InterfaceEstimate(**{**nan.__dict__, "reason": int(Reason.DEGENERATE)})
    eig = np.linalg.eigvalsh(normal / np.outer(scale, scale))
    if eig[0] <= eig[-1] / DEGENERATE_CONDITION:
        return InterfaceEstimate(**{**nan.__dict__, "reason": int(Reason.DEGENERATE)})
    covariance = np.linalg.inv(normal)[:3, :3]
    rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
    if pixel_sigma is None:
        dof = r.size - n_params
        sigma_px = float(np.sqrt(np.sum(r * r) / dof)) if dof > 0 else np.nan
        covariance = covariance * sigma_px ** 2
    else:
        sigma_px = float(pixel_sigma)
    # the tilts reported about the start normal's axes: at the solution the normal is m/|m|
    return InterfaceEstimate(moved, R, t, 0.5 * (covariance + covariance.T), axes, rms,
                             sigma_px, int(Reason.OK))


__all__ = ["INTERFACE_NAMES", "InterfaceEstimate", "estimate_interface"]
