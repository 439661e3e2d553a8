"""One triangulation entry for a rig of any number of views: :func:`triangulate_rig`.

``rig``: a :class:`measure.stereo.rig.Rig` (its :meth:`~measure.stereo.rig.Rig.views`) or any
sequence of :class:`measure.stereo.multiview.View` (cameras whose ports a rig would refuse,
e.g. infinite flat planes that cross another camera); ``pixels`` ``(N, V, 2)``, one column per
view in that order, NaN where a view did not see the target. The method is dispatched by what
applies:

* a :class:`~measure.stereo.rig.Rig` of two: the pair methods of
  :func:`measure.stereo.triangulate.triangulate` (``optical_path``, ``su``, ``regular``,
  ``reprojection``) — the same points, gaps and reasons as calling it with the two columns; a
  row missing a view is NaN with ``TOO_FEW_VIEWS``.
* any other rig, or views: ``optical_path`` — the least-squares point of the water rays
  (:func:`measure.stereo.multiview.triangulate_views`) — and ``reprojection`` — the point whose
  images through each view's port (the exact forward model,
  :func:`measure.geometry.projection.project`) are nearest its pixels in least squares over all
  the views that saw it (:func:`reprojection_views`): the maximum-likelihood point for
  independent Gaussian pixel noise of one σ. ``su`` and ``regular`` are pair methods (the
  common perpendicular of two rays, a pair's RigPort): refused (``ValueError``) there.

Frames and units: the rig's reference frame, millimetres; pixels in the OpenCV convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.projection import project
from ..reasons import Reason
from .multiview import triangulate_views
from .rig import Rig
from .triangulate import METHODS, triangulate

#: The methods of a rig of any number of views other than two.
VIEW_METHODS = ("optical_path", "reprojection")
#: A point's fit has converged when its Gauss–Newton step is below this times ``|X| + 1 mm``
#: (relative, as ``scipy.optimize.least_squares``'s ``xtol``).
STEP_TOLERANCE = 1e-12
#: At most this many Levenberg–Marquardt iterations per point (a point still moving then is
#: ``NOT_CONVERGED``).
MAX_ITERATIONS = 60
#: Within this Gauss–Newton step (relative, as :data:`STEP_TOLERANCE`) of the minimum the
#: plain Gauss–Newton step is taken without a test of the cost: there the cost changes less
#: than its own rounding (the forward model solves each path iteratively), and the steps
#: shrink quadratically.
NEWTON_REGION = 1e-7
#: Damping the fit starts with, and its bounds (Marquardt's λ, relative to ``diag(JᵀJ)``).
START_DAMPING, MIN_DAMPING, MAX_DAMPING = 1e-3, 1e-12, 1e12


@dataclass(frozen=True)
class RigTriangulation:
    """Result of :func:`triangulate_rig`: ``points`` ``(N, 3)`` mm in the rig's reference
    frame; ``gap`` ``(N,)`` mm — a rig of two: the pair method's gap (the length of the common
    perpendicular of its two final rays, :class:`measure.Triangulation`), other rigs: the RMS
    distance of the optical-path point from its water rays (for ``reprojection`` as well, as
    the pair's reprojection reports its optical-path gap); ``views`` ``(N,)`` how many views
    it was triangulated from (a pair: how many saw it); ``used`` ``(N, V)`` which;
    ``reason`` ``(N,)`` :class:`measure.Reason` codes, NaN rows where not ``OK``; ``method``."""

    points: np.ndarray
    gap: np.ndarray
    views: np.ndarray
    used: np.ndarray
    reason: np.ndarray
    method: str

    @property
    def valid(self) -> np.ndarray:
        return self.reason == Reason.OK


def triangulate_rig(rig, pixels, method: str = "optical_path") -> RigTriangulation:
    """Triangulate the pixels ``(N, V, 2)`` of the V views of ``rig`` (a Rig or a sequence of
    View; NaN: not seen) with ``method`` (module docs: the pair methods for a Rig of two,
    ``optical_path`` and ``reprojection`` for any other rig or views). ``ValueError`` for a
    method that does not apply (naming it and the number of views) or pixels of another
    shape."""
    pair = isinstance(rig, Rig) and len(rig.cameras) == 2
    views = rig.views() if isinstance(rig, Rig) else list(rig)
    count = len(views)
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if not pair and method not in VIEW_METHODS:
        what = f"{count} views" if isinstance(rig, Rig) else f"{count} views given as View"
        raise ValueError(f"method {method!r} triangulates the two views of a Rig of two, not "
                         f"{what} (there: {', '.join(VIEW_METHODS)})")
    pixels = np.asarray(pixels, dtype=np.float64)
    if pixels.ndim != 3 or pixels.shape[1:] != (count, 2):
        raise ValueError(f"pixels must have shape (N, {count}, 2) for {count} views, "
                         f"got {pixels.shape}")
    if pair:
        return _pair(rig, pixels, method)
    found = triangulate_views(views, pixels)
    points = found.points
    reason = found.reason.copy()
    if method == "reprojection":
        points, converged = reprojection_views(views, pixels, found.points, found.used)
        reason[(reason == Reason.OK) & ~converged] = Reason.NOT_CONVERGED
        points[reason != Reason.OK] = np.nan
    return RigTriangulation(points, found.gap, found.views, found.used, reason, method)


def _pair(rig, pixels, method: str) -> RigTriangulation:
    """The pair method on the two columns; rows missing a view ``TOO_FEW_VIEWS``."""
    seen = np.isfinite(pixels[:, :, 0]) & np.isfinite(pixels[:, :, 1])
    result = triangulate(rig, np.ascontiguousarray(pixels[:, 0]),
                         np.ascontiguousarray(pixels[:, 1]), method)
    reason = result.reason.copy()
    reason[~seen.all(axis=1)] = Reason.TOO_FEW_VIEWS
    return RigTriangulation(result.points, result.gap, seen.sum(axis=1), seen, reason, method)


def reprojection_views(views, pixels, start, used=None) -> tuple[np.ndarray, np.ndarray]:
    """Reprojection-optimal points ``(N, 3)`` mm of ``pixels`` ``(N, V, 2)`` in ``views``
    (:class:`measure.stereo.multiview.View`): each point minimizes the sum over its views of
    ``|project(camera, port, X) − pixel|²`` (px²), from ``start`` ``(N, 3)`` (e.g. the
    optical-path point). ``used`` ``(N, V)``: the views each point takes (default: those with
    a finite pixel). Batched Levenberg–Marquardt on the 3 unknowns of every point at once: one
    analytic Jacobian (``project(..., jacobian=True)``) per view and iteration, the 3 × 3
    normal equations solved for all points together; the points are independent (the result
    of a point does not depend on the others). Also returns ``converged`` ``(N,)`` (the
    Gauss–Newton step below :data:`STEP_TOLERANCE`; a row that is not holds its last iterate,
    which :func:`triangulate_rig` reports as NaN, ``NOT_CONVERGED``); rows with a non-finite
    start, or fewer than two views, stay NaN (converged False)."""
    pixels = np.asarray(pixels, dtype=np.float64)
    start = np.asarray(start, dtype=np.float64).reshape(-1, 3)
    views = list(views)
    seen = np.isfinite(pixels[:, :, 0]) & np.isfinite(pixels[:, :, 1])
    used = seen if used is None else np.asarray(used, bool) & seen
    points = np.full_like(start, np.nan)
    converged = np.zeros(start.shape[0], bool)
    rows = np.flatnonzero(np.all(np.isfinite(start), axis=1) & (used.sum(axis=1) >= 2))
    x = start[rows].copy()
    cost, normal, gradient = reprojection_normal_equations(views, pixels[rows], used[rows], x)
    damping = np.full(rows.size, START_DAMPING)
    active = np.isfinite(cost)
    for iteration in range(MAX_ITERATIONS + 1):
        live = np.flatnonzero(active)
        # converged where the Gauss–Newton step from here is below the tolerance
        newton = _lm_step(normal[live], gradient[live], np.full(live.size, MIN_DAMPING))
        size = np.linalg.norm(newton, axis=1) / (np.linalg.norm(x[live], axis=1) + 1.0)
        done = size <= STEP_TOLERANCE
        converged[rows[live[done]]] = True
        active[live[done]] = False
        live, newton, near = live[~done], newton[~done], size[~done] <= NEWTON_REGION
        if live.size == 0 or iteration == MAX_ITERATIONS:
            break
        step = _lm_step(normal[live], gradient[live], damping[live])
        trial = x[live] + np.where(near[:, None], newton, step)
        trial_cost, trial_normal, trial_gradient = reprojection_normal_equations(
            views, pixels[rows[live]], used[rows[live]], trial)
        # a Gauss–Newton step near the minimum is taken (the cost cannot resolve it); other
        # steps where the cost does not rise; NaN (a trial point with no image) is a rise
        better = (trial_cost <= cost[live]) | (near & np.isfinite(trial_cost))
        take = live[better]
        x[take], cost[take] = trial[better], trial_cost[better]
        normal[take], gradient[take] = trial_normal[better], trial_gradient[better]
        damping[take] = np.maximum(damping[take] / 10, MIN_DAMPING)
        damping[live[~better]] *= 10
        active[live[damping[live] > MAX_DAMPING]] = False  # stuck: no step lowers the cost
    points[rows] = x
    return points, converged


def _lm_step(normal, gradient, damping) -> np.ndarray:
    """Marquardt's step ``−(JᵀJ + λ diag(JᵀJ))⁻¹ Jᵀr`` ``(n, 3)`` mm for each point."""
    diagonal = np.einsum("nii->ni", normal)
    damped = normal + (damping[:, None] * np.maximum(diagonal, 1e-300))[:, :, None] * np.eye(3)
    return -np.linalg.solve(damped, gradient[:, :, None])[:, :, 0]


def reprojection_normal_equations(views, pixels, used, points):
    """The reprojection cost ``Σ |r|²`` (px², NaN where a used view has no image of the point),
    ``JᵀJ`` ``(n, 3, 3)`` and ``Jᵀr`` ``(n, 3)`` of ``points`` ``(n, 3)`` over the ``used``
    views; ``r`` = projection − pixel (px), ``J`` = d r / d point (px/mm)."""
    n = points.shape[0]
    cost = np.zeros(n)
    normal = np.zeros((n, 3, 3))
    gradient = np.zeros((n, 3))
    for v, view in enumerate(views):
        rows = np.flatnonzero(used[:, v])
        if rows.size == 0:
            continue
        predicted, d_point = project(view.camera, view.port, points[rows], jacobian=True)
        residual = predicted - pixels[rows, v]
        cost[rows] += np.einsum("ni,ni->n", residual, residual)
        normal[rows] += np.einsum("nki,nkj->nij", d_point, d_point)
        gradient[rows] += np.einsum("nki,nk->ni", d_point, residual)
    return cost, normal, gradient


__all__ = ["MAX_ITERATIONS", "RigTriangulation", "STEP_TOLERANCE", "VIEW_METHODS",
           "reprojection_normal_equations", "reprojection_views", "triangulate_rig"]
