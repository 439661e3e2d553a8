"""The refracted path through a flat port reduced to its refraction plane (the plane of the
camera centre, the point and the port normal), and its two independent solvers — the Fermat
solver of the paper's section 2.2 (:func:`solve_fermat`, Newton on the travel time with its
analytic gradient and tridiagonal Hessian, started by :func:`snell_start`) and the Snell
solver (:func:`solve_snell`, the 1D root of Snell's invariant with SciPy's bracketing root
finder). :mod:`measure.geometry.projection` reduces points to this problem and turns the
solved paths into pixels. Units mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Newton steps on Snell's invariant that make the start of the Fermat iteration (points whose
#: start is not finite start from the straight line instead: damped Newton).
START_STEPS = 3


@dataclass(frozen=True)
class PlaneProblem:
    """The path problem reduced to the refraction plane.

    ``lateral`` ``(N,)``: distance of the point from the normal through the camera centre (mm);
    ``indices`` ``(K+1,)``; ``heights_columns``: per medium the normal distance travelled in it
    (mm; a scalar where all rows share it — air gap, layers — the water column ``(N,)``), and
    their squares.
    """

    lateral: np.ndarray
    indices: np.ndarray
    heights_columns: list
    heights_squared: list

    @property
    def heights(self) -> np.ndarray:
        """``(N, K+1)`` normal distances travelled in each medium (air gap, layers, water)."""
        n_rows = self.lateral.shape[0]
        return np.column_stack([np.broadcast_to(c, (n_rows,)) for c in self.heights_columns])



def _segments(x, problem):
    """Lateral steps Δ_i and lengths L_i of the K+1 path segments (lists of ``(N,)`` arrays).

    ``x`` is the list of the K lateral positions of the interface points (mm from the camera's
    normal foot). Column lists keep every operation on contiguous vectors.
    """
    steps = [x[0]] + [x[k] - x[k - 1] for k in range(1, len(x))] + [problem.lateral - x[-1]]
    lengths = [np.sqrt(d * d + h2) for d, h2 in zip(steps, problem.heights_squared)]
    return steps, lengths


def _optical_length(lengths, indices):
    """Travel time times c: ``Σ n_i L_i`` (mm)."""
    total = indices[0] * lengths[0]
    for n_i, length in zip(indices[1:], lengths[1:]):
        total = total + n_i * length
    return total


def _fermat_gradient_hessian(x, problem):
    """Analytic ∂t/∂x_k and the tridiagonal Hessian of the travel time (units of c = 1).

    With ``Δ_i`` the lateral step and ``h_i`` the normal height of segment i (length
    ``L_i = sqrt(Δ_i² + h_i²)``): ``t = Σ n_i L_i``, ``∂t/∂x_k = n_k Δ_k/L_k −
    n_{k+1} Δ_{k+1}/L_{k+1}``, ``∂²t/∂x_k² = n_k h²_k/L³_k + n_{k+1} h²_{k+1}/L³_{k+1}`` and
    ``∂²t/∂x_k∂x_{k+1} = −n_{k+1} h²_{k+1}/L³_{k+1}``. Since ``x_k = x(J_k) + μ_k`` these are
    also the derivatives with respect to the paper's μ_k (equations 23-24). Also returns the
    K+1 segment curvatures ``n_i h²_i/L³_i``.
    """
    steps, lengths = _segments(x, problem)
    slope, curvature = [], []
    for n_i, d, length, h2 in zip(problem.indices, steps, lengths, problem.heights_squared):
        inverse = 1.0 / length
        slope.append((n_i * d) * inverse)  # n_i sin θ_i
        inverse *= inverse * inverse
        inverse *= n_i * h2
        curvature.append(inverse)
    k = len(x)
    gradient = [slope[i] - slope[i + 1] for i in range(k)]
    diag = [curvature[i] + curvature[i + 1] for i in range(k)]
    off = [-curvature[i + 1] for i in range(k - 1)]
    return gradient, diag, off, curvature


def _solve_tridiagonal_spd(diag, off, rhs):
    """Solve ``H s = rhs`` for a symmetric tridiagonal H, vectorized over rows (Thomas).

    ``diag``: K arrays, ``off``: K-1 arrays (H[k, k+1]), ``rhs``: K arrays. Returns the solution
    (K arrays) and whether every pivot is positive, i.e. H is positive definite — for K = 2 the
    paper's minimum condition det H > 0 and ∂²t/∂μ1² > 0.
    """
    k = len(diag)
    pivots = [diag[0]]
    y = [rhs[0]]
    for i in range(1, k):
        factor = off[i - 1] / pivots[i - 1]
        pivots.append(diag[i] - factor * off[i - 1])
        y.append(rhs[i] - factor * y[i - 1])
    solution = [None] * k
    solution[-1] = y[-1] / pivots[-1]
    for i in range(k - 2, -1, -1):
        solution[i] = (y[i] - off[i] * solution[i + 1]) / pivots[i]
    positive = pivots[0] > 0
    for pivot in pivots[1:]:
        positive = positive & (pivot > 0)
    return solution, positive


def straight_start(problem: PlaneProblem):
    """Lateral positions of the points J_k where the straight line O→P crosses the interfaces."""
    lateral = problem.lateral
    total_height = sum(problem.heights_columns)
    x, cumulative = [], 0.0
    for height in problem.heights_columns[:-1]:
        cumulative = cumulative + height
        x.append(lateral * (cumulative / total_height))
    return x


def snell_start(problem: PlaneProblem, steps: int = START_STEPS):
    """A start for the Fermat iteration: the path that obeys Snell's law, by a fixed number of
    Newton steps on one unknown per point, ``τ = tan θ_water``.

    Snell's invariant ``n_i sin θ_i = n_w sin θ_w`` written with τ gives ``tan θ_i = n_w τ /
    sqrt(q_i)`` with ``q_i = n_i² + (n_i² − n_w²) τ²`` (one square root per medium), so the
    lateral distance is ``F(τ) = h_w τ + Σ_{i<w} h_i n_w τ / sqrt(q_i) = ℓ`` and ``F'(τ) = h_w +
    Σ h_i n_w n_i² / q_i^{3/2}``. The water column, which is the longest, is linear in τ, so
    Newton's method from the paraxial start ``τ0 = ℓ / (h_w + Σ h_i n_w / n_i)`` converges fast:
    on the paper's volume (rays up to 30° in the water) the relative error of τ goes 3e-2, 1e-4,
    2e-9, 4e-16 in three steps. No convergence test here: the Fermat iteration that follows
    judges convergence (to its own tolerance) and goes on where the start has not got there.
    Returns the lateral positions of the interface points (list of K ``(N,)`` arrays), a mask of
    the rows whose start is finite (not finite: Snell's invariant at or above an index on the
    way, e.g. beyond the critical angle) and the number of steps.
    """
    n = problem.indices
    n_water = n[-1]
    water = problem.heights_columns[-1]
    lateral = problem.lateral
    # per medium before the water: (n_i², n_i² − n_w², h_i n_w, h_i n_w n_i²)
    media = [(n_i * n_i, n_i * n_i - n_water * n_water, h * n_water, h * n_water * n_i * n_i)
             for n_i, h in zip(n[:-1], problem.heights_columns[:-1])]
    tau = lateral / (water + sum(h * (n_water / n_i)
                                 for n_i, h in zip(n[:-1], problem.heights_columns[:-1])))
    if not media:  # no medium before the water (not a FlatPort): the paraxial line is exact
        steps = 0
    for _ in range(steps):
        tau2 = tau * tau
        residual = water * tau
        residual -= lateral
        slope = None
        for n2, b, weight, weight_slope in media:
            inverse = b * tau2
            inverse += n2
            np.sqrt(inverse, out=inverse)
            np.divide(1.0, inverse, out=inverse)  # 1 / sqrt(q_i)
            term = inverse * tau
            term *= weight
            residual += term  # h_i tan θ_i
            np.multiply(inverse, inverse, out=term)
            term *= inverse
            term *= weight_slope
            if slope is None:
                slope = term
                slope += water
            else:
                slope += term
        residual /= slope
        tau -= residual
    x, position = [], None
    tau2 = tau * tau
    for n2, b, weight, _ in media:
        term = b * tau2
        term += n2
        np.sqrt(term, out=term)
        term = (weight * tau) / term
        position = position + term if x else term
        x.append(position)
    ok = np.isfinite(position) if media else np.ones(lateral.shape, dtype=bool)
    return x, ok, steps


def rows_of(problem: PlaneProblem, rows) -> PlaneProblem:
    """The plane problem of a subset of its rows (index array)."""
    def pick(column):
        return column[rows] if isinstance(column, np.ndarray) and column.ndim else column

    return PlaneProblem(problem.lateral[rows], problem.indices,
                         [pick(c) for c in problem.heights_columns],
                         [pick(c) for c in problem.heights_squared])


def solve_fermat(problem: PlaneProblem, start=None, max_iterations: int = 60):
    """Newton on μ (offsets from J_k along ε); returns lateral positions x (list of K ``(N,)``).

    Starts from ``start`` (K arrays, modified in place) or μ = 0, the straight line O→P through
    the points J_k. While a step is large (more than 1e-6 of the lateral scale), a step that
    would lengthen the travel time is halved. A row has converged when its full Newton step is
    at most 1e-15 of the lateral scale (machine precision); that step is taken and the row is
    not moved again (the next iterations work on the rows that are left), so the result of a
    row does not depend on the other rows of its batch. Also returns whether the Hessian is
    positive definite at the solution, the converged mask, the iterations and the segment
    curvatures ``n_i h²_i/L³_i`` (both evaluated where a row takes its last step, at most 1e-15
    of the lateral scale from the solution).
    """
    lateral = problem.lateral
    x = list(straight_start(problem) if start is None else start)
    scale = np.abs(lateral)
    scale += 1.0
    rows = None  # indices of the working rows (None: all)
    work, xs = problem, x
    positive = converged = curvature = None
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (the count is read after the loop)
        gradient, diag, off, segment_curvature = _fermat_gradient_hessian(xs, work)
        step, definite = _solve_tridiagonal_spd(diag, off, gradient)
        largest = np.abs(step[0])
        for s in step[1:]:
            np.maximum(largest, np.abs(s), out=largest)
        now = largest <= 1e-15 * scale  # judged on the full Newton step, never on a damped one
        far = largest > 1e-6 * scale
        if np.any(far):
            # Far from the minimum: halve the steps that would lengthen the travel time (only
            # in the rows that are far: near the minimum the travel time is flat to rounding,
            # and halving there would stall a row short of it).
            limit = _optical_length(_segments(xs, work)[1], work.indices) * (1 + 4e-16)
            factor = np.ones_like(work.lateral)
            for _ in range(40):
                trial = [xi - factor * si for xi, si in zip(xs, step)]
                worse = far & (_optical_length(_segments(trial, work)[1], work.indices) > limit)
                if not worse.any():
                    break
                factor[worse] *= 0.5
            step = [factor * s for s in step]
        for xi, si in zip(xs, step):
            xi -= si
        if rows is None:
            positive, converged, curvature = definite, now, segment_curvature
        else:
            positive[rows] = definite
            converged[rows] = now
            for full, part in zip(curvature, segment_curvature):
                full[rows] = part
            for xi, xw in zip(x, xs):
                xi[rows] = xw
        if now.all():
            break
        keep = np.flatnonzero(~now)  # go on with the rows that are left
        rows = keep if rows is None else rows[keep]
        work = rows_of(work, keep)
        xs = [xi[keep] for xi in xs]
        scale = scale[keep]
    return x, positive & converged, converged, iterations, curvature


def solve_snell(problem: PlaneProblem):
    """Root of ``Σ h_i p / sqrt(n_i² − p²) = lateral`` for the invariant p = n_i sin θ_i."""
    from scipy.optimize import elementwise

    n = problem.indices
    heights = problem.heights
    upper = n.min() * (1.0 - 1e-13)

    def residual(p, lateral, *heights_per_medium):
        total = -lateral
        for n_i, h_i in zip(n, heights_per_medium):
            total = total + h_i * p / np.sqrt(n_i * n_i - p * p)
        return total

    lateral = problem.lateral
    ok = np.isfinite(lateral)
    p = np.full(lateral.shape, np.nan)
    converged = np.zeros(lateral.shape, dtype=bool)
    iterations = 0
    if ok.any():
        result = elementwise.find_root(
            residual, (np.zeros(ok.sum()), np.full(ok.sum(), upper)),
            args=(lateral[ok], *heights[ok].T),
            tolerances=dict(xatol=1e-17, xrtol=1e-15, fatol=0.0, frtol=0.0),
            maxiter=400)
        p[ok] = result.x
        converged[ok] = result.success | (result.x == 0)
        iterations = int(np.max(result.nit, initial=0))
    with np.errstate(invalid="ignore"):
        offsets = heights * p[:, None] / np.sqrt(n * n - (p * p)[:, None])
    x = np.cumsum(offsets, axis=1)[:, :-1]
    return list(x.T), converged, iterations
