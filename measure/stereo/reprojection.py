"""Reprojection-optimal triangulation through the port: the point whose images (the exact
forward model, :func:`measure.geometry.projection.project`) lie nearest the two detected pixels — the
maximum-likelihood point for Gaussian pixel noise. Units mm, pixels in the OpenCV convention."""

from __future__ import annotations

import numpy as np

from ..geometry.projection import project


def _view_port(port, view: int):
    """The port of camera ``view``: ``port`` itself, or its dome for a
    :class:`measure.geometry.dome.DomePair` (one dome per camera)."""
    return port.view(view)


def stereo_residuals(rig, port, points, observed) -> np.ndarray:
    """Reprojection residuals ``(4N,)`` px of ``points`` ``(N, 3)`` through ``port`` against
    ``observed`` = rows ``(u_left, v_left, u_right, v_right)`` flattened; a point with no image
    gets a large residual (1e3 px) instead of NaN, so the optimizer steers away from it.
    ``port``: a flat port (both views) or a :class:`measure.geometry.dome.DomePair` (one dome each)."""
    predicted = np.concatenate([project(rig.left, _view_port(port, 0), points),
                                project(rig.right, _view_port(port, 1), points)],
                               axis=1).ravel()
    r = predicted - observed
    return np.where(np.isfinite(r), r, 1e3)


def stereo_projections(rig, port, points, parameters: bool = False):
    """Both views' pixels and analytic derivatives for :func:`stereo_residuals`: returns the
    predicted ``(u_left, v_left, u_right, v_right)`` rows ``(N, 4)``, d residual / d point
    ``(N, 4, 3)`` and, with ``parameters``, the two views' :class:`~measure.geometry.projection.
    ParameterJacobian` (:class:`~measure.geometry.dome_projection.DomeParameterJacobian` for a
    :class:`measure.geometry.dome.DomePair`; else None). Rows without an image are NaN."""
    left = project(rig.left, _view_port(port, 0), points, jacobian=True, parameters=parameters)
    right = project(rig.right, _view_port(port, 1), points, jacobian=True, parameters=parameters)
    predicted = np.concatenate([left[0], right[0]], axis=1)
    d_points = np.concatenate([left[1], right[1]], axis=1)
    return predicted, d_points, ((left[2], right[2]) if parameters else None)


def block_arrow_jacobian(d_points, d_parameters=None):
    """The sparse Jacobian of residuals grouped by point: ``d_points`` ``(N, R, 3)`` (R rows per
    point, each touching its point's 3 columns) and ``d_parameters`` ``(N, R, P)`` (every row
    touches the P shared parameter columns, which come first), as a CSR matrix
    ``(N·R) × (P + 3N)`` with the structure of :func:`point_block_sparsity`. Non-finite entries
    (rows of points with no image, whose residual is a constant) become 0."""
    from scipy.sparse import csr_matrix

    n, rows, _ = d_points.shape
    n_params = 0 if d_parameters is None else d_parameters.shape[2]
    point_columns = n_params + 3 * np.arange(n)[:, None, None] + np.arange(3)
    point_columns = np.broadcast_to(point_columns, (n, rows, 3))
    if n_params:
        data = np.concatenate([d_parameters, d_points], axis=2)
        columns = np.concatenate([np.broadcast_to(np.arange(n_params), (n, rows, n_params)),
                                  point_columns], axis=2)
    else:
        data, columns = d_points, point_columns
    width = n_params + 3
    data = np.where(np.isfinite(data), data, 0.0).reshape(-1)
    return csr_matrix((data, columns.reshape(-1), np.arange(0, n * rows * width + 1, width)),
                      shape=(n * rows, n_params + 3 * n))


def point_block_sparsity(n: int, n_params: int = 0):
    """Jacobian structure of :func:`stereo_residuals` over ``n_params`` shared parameters (all
    rows) followed by the points' coordinates (each point's 3 columns touch its 4 rows)."""
    from scipy.sparse import lil_matrix

    sparsity = lil_matrix((4 * n, n_params + 3 * n), dtype=np.int8)
    if n_params:
        sparsity[:, :n_params] = 1
    rows = np.repeat(np.arange(4 * n), 3)
    cols = n_params + 3 * np.repeat(np.arange(n), 12) + np.tile(np.arange(3), 4 * n)
    sparsity[rows, cols] = 1
    return sparsity


def reprojection_points(rig, uv_left, uv_right, start):
    """Reprojection-optimal points ``(N, 3)`` mm: each point minimizes its 4 reprojection
    residuals through ``rig.port`` (``least_squares`` with the analytic, block-diagonal sparse
    Jacobian of :func:`block_arrow_jacobian`),
    starting from ``start`` ``(N, 3)`` (e.g. the optical-path triangulation). Also returns the
    per-point reprojection RMS ``(N,)`` px and whether the fit converged. Rows with non-finite
    input or start stay NaN."""
    from scipy.optimize import least_squares

    uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
    uv_right = np.asarray(uv_right, dtype=np.float64).reshape(-1, 2)
    start = np.asarray(start, dtype=np.float64).reshape(-1, 3)
    points = np.full_like(start, np.nan)
    rms = np.full(start.shape[0], np.nan)
    keep = np.all(np.isfinite(start), axis=1) & np.all(np.isfinite(uv_left), axis=1) & np.all(
        np.isfinite(uv_right), axis=1)
    n = int(keep.sum())
    if n == 0:
        return points, rms, True
    observed = np.concatenate([uv_left[keep], uv_right[keep]], axis=1).ravel()

    def residuals(x):
        return stereo_residuals(rig, rig.port, x.reshape(n, 3), observed)

    def jacobian(x):  # analytic, block diagonal: each point's 3 columns touch its 4 rows
        return block_arrow_jacobian(stereo_projections(rig, rig.port, x.reshape(n, 3))[1])

    fit = least_squares(residuals, start[keep].ravel(), jac=jacobian, method="trf",
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=100,
                        tr_solver="lsmr", tr_options={"atol": 1e-14, "btol": 1e-14})
    points[keep] = fit.x.reshape(n, 3)
    rms[keep] = np.sqrt(np.mean(fit.fun.reshape(n, 4) ** 2, axis=1))
    return points, rms, bool(fit.success)


__all__ = ["block_arrow_jacobian", "point_block_sparsity", "reprojection_points",
           "stereo_projections", "stereo_residuals"]
