"""Stereo matching of detected targets through a flat port or two domes, without ground truth.

For every candidate pair (left detection i, right detection j) the two pixels are back-projected
and traced into the water; a true pair's water rays meet (their common perpendicular is short:
the refractive epipolar constraint) at a point inside the working depth range and in front of
both cameras. A global one-to-one assignment (``scipy.optimize.linear_sum_assignment``) on the
gap lengths picks the pairs among those that pass the gate; a pair is kept only if no other
assignment explains the detections about as well (see :func:`match_targets`). What stays
ambiguous is then looked at again against its neighbours: targets on a surface lie at depths
that vary smoothly across the image, so where the clear pairs around an ambiguous detection lie
on a plane of depth, the candidates that leave that plane (the neighbour's partner, met some
15-20 % nearer or farther) are ruled out (:func:`resolve_by_neighbours`); before that, a clear
pair off the plane of its clear neighbours is dropped too (a row's shifted partner the
assignment kept as clear). Pairs that stay ambiguous are dropped, never guessed.

Units: mm; pixels in the OpenCV convention; reference frame = the left camera's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..geometry.lines import common_perpendicular
from ..reasons import Reason
from .rig import Rig

_NO_PAIR = 1e12  # cost of an impossible pair in the assignment
#: Candidate pairs evaluated at once (memory: about 200 bytes each).
PAIRS_PER_CHUNK = 1 << 20
#: Clear pairs, nearest in the left image, that predict an ambiguous detection's depth.
NEIGHBOURS = 8
#: The neighbours predict a depth only when they lie on a plane of depth over the image to this
#: RMS, relative to the depth (a surface, not a cloud of targets at random depths) ...
NEIGHBOUR_PLANE_RMS = 0.01
#: ... and a candidate pair agrees with the prediction within this fraction of the depth.
NEIGHBOUR_DEPTH_TOLERANCE = 0.05


@dataclass(frozen=True)
class Matches:
    """Result of :func:`match_targets`.

    ``left``, ``right``: ``(M,)`` indices into the two detection arrays, one row per accepted
    pair; ``gap`` ``(M,)`` their common-perpendicular lengths (mm); ``n_candidates``: how many
    (i, j) pairs passed the gate and the depth window; ``n_ambiguous``: assigned pairs dropped
    because a competitor could not be ruled out; ``unmatched_left`` / ``unmatched_right``: indices
    of detections left without a partner.
    """

    left: np.ndarray
    right: np.ndarray
    gap: np.ndarray
    n_candidates: int
    n_ambiguous: int
    unmatched_left: np.ndarray
    unmatched_right: np.ndarray


def _water_rays(rig: Rig, view: int, uv):
    water = rig.trace(view, rig.cameras[view].rays(uv))
    return water.origins, water.directions, water.reason == Reason.OK


def candidate_pairs(rig: Rig, uv_left, uv_right, gate_mm: float,
                    depth_range=(None, None), return_depth: bool = False):
    """``(i, j, gap)``: the pairs (left row i, right row j) whose common-perpendicular length
    (mm) is at most ``gate_mm`` and that are possible, computed in chunks of
    :data:`PAIRS_PER_CHUNK` pairs, so that memory stays bounded by the pairs kept. With
    ``return_depth`` also each pair's depth ``a · X`` of the midpoint (mm; ``a`` =
    :attr:`measure.Rig.depth_axis`: the port normal, or the left optical axis for domes).

    A pair is impossible when a ray has no path into the water, the rays meet behind a camera,
    or the midpoint's depth ``a · X`` is outside ``depth_range``. Either port: the rays are
    traced by :meth:`measure.Rig.trace` (a flat port or each camera's dome).
    """
    uv_left = np.asarray(uv_left, dtype=float).reshape(-1, 2)
    uv_right = np.asarray(uv_right, dtype=float).reshape(-1, 2)
    o1, d1, ok1 = _water_rays(rig, 0, uv_left)
    o2, d2, ok2 = _water_rays(rig, 1, uv_right)
    n_left, n_right = len(uv_left), len(uv_right)
    axis = rig.depth_axis
    rows_per_chunk = max(1, PAIRS_PER_CHUNK // max(1, n_right))
    found_i, found_j, found_gap, found_depth = [], [], [], []
    near, far = depth_range
    for start in range(0, n_left, rows_per_chunk):
        i, j = np.meshgrid(np.arange(start, min(n_left, start + rows_per_chunk)),
                           np.arange(n_right), indexing="ij")
        i, j = i.ravel(), j.ravel()
        with np.errstate(invalid="ignore", divide="ignore"):
            perp = common_perpendicular(o1[i], d1[i], o2[j], d2[j])
            depth = perp.midpoint @ axis
            keep = ok1[i] & ok2[j] & (perp.s1 > 0) & (perp.s2 > 0) & (perp.length <= gate_mm)
            if near is not None:
                keep &= depth >= near
            if far is not None:
                keep &= depth <= far
        found_i.append(i[keep])
        found_j.append(j[keep])
        found_gap.append(perp.length[keep])
        found_depth.append(depth[keep])
    if not found_i:
        found_i, found_j, found_gap, found_depth = [[np.zeros(0, int)]] * 2 + [[np.zeros(0)]] * 2
    result = (np.concatenate(found_i), np.concatenate(found_j), np.concatenate(found_gap))
    return result + (np.concatenate(found_depth),) if return_depth else result


def _assign(cost: np.ndarray, candidate: np.ndarray):
    """Maximum-cardinality, then minimum-gap one-to-one assignment; returns rows, cols, total."""
    rows, cols = linear_sum_assignment(np.where(candidate, cost, _NO_PAIR))
    used = candidate[rows, cols]
    rows, cols = rows[used], cols[used]
    return rows, cols, float(cost[rows, cols].sum())


def match_targets(rig: Rig, uv_left, uv_right, gate_mm: float = 0.5,
                  depth_range=(None, None), ambiguity_margin_mm: float | None = None,
                  resolve_ambiguities: bool = True) -> Matches:
    """Match left and right detections one to one with the refractive epipolar constraint.

    ``gate_mm``: the largest common-perpendicular length of an accepted pair (mm); a few times
    the gap that pixel noise produces at the working distance. ``depth_range``: ``(near, far)``
    bounds on ``a · X`` (mm, ``a`` = :attr:`measure.Rig.depth_axis`) of the triangulated point,
    ``None`` for no bound.

    The candidate pairs form a bipartite graph; within each connected group the assignment
    explains as many detections as possible with the smallest total gap. An assigned pair is
    ambiguous — and dropped — when forbidding it still leaves an assignment of the group with
    as many pairs whose total gap is within ``ambiguity_margin_mm`` (default ``gate_mm / 2``)
    of the best. A row of targets along the baseline (one epipolar plane) is resolved this way
    when its shifted alternative must leave a detection unmatched. With
    ``resolve_ambiguities`` (default) the ambiguous detections are assigned again among the
    candidates that agree with the depth plane of their clear neighbours
    (:func:`resolve_by_neighbours`), with the same ambiguity test; what stays ambiguous is
    dropped.
    """
    if not gate_mm > 0:
        raise ValueError(f"gate_mm must be positive, got {gate_mm}")
    margin = 0.5 * gate_mm if ambiguity_margin_mm is None else float(ambiguity_margin_mm)
    if not margin >= 0:
        raise ValueError(f"ambiguity_margin_mm must be >= 0, got {ambiguity_margin_mm}")
    n_left = len(np.asarray(uv_left).reshape(-1, 2))
    n_right = len(np.asarray(uv_right).reshape(-1, 2))
    pair_i, pair_j, pair_gap, pair_depth = candidate_pairs(rig, uv_left, uv_right, gate_mm,
                                                           depth_range, return_depth=True)
    graph = coo_matrix((np.ones(len(pair_i)), (pair_i, n_left + pair_j)),
                       shape=(n_left + n_right, n_left + n_right))
    _, component = connected_components(graph, directed=False)
    kept = {"rows": [], "cols": [], "gaps": [], "depths": []}
    ambiguous = []  # (rows, cols) left unresolved in each group
    pair_label = component[pair_i]
    order_by_label = np.argsort(pair_label, kind="stable")
    starts = np.unique(pair_label[order_by_label], return_index=True)[1]
    for members in np.split(order_by_label, starts[1:]):
        left_over = _assign_clear(pair_i[members], pair_j[members], pair_gap[members],
                                  pair_depth[members], margin, kept)
        if left_over[0].size:
            ambiguous.append(left_over)
    if resolve_ambiguities:
        ambiguous += _drop_off_their_neighbours(np.asarray(uv_left, float).reshape(-1, 2), kept)
    n_ambiguous = sum(len(rows) for rows, _ in ambiguous)
    if ambiguous and resolve_ambiguities:
        uv_l = np.asarray(uv_left, dtype=float).reshape(-1, 2)
        open_pairs = np.flatnonzero(np.isin(pair_i, np.concatenate([r for r, _ in ambiguous])))
        allowed = np.zeros(len(pair_i), dtype=bool)
        allowed[open_pairs] = resolve_by_neighbours(
            uv_l, np.asarray(kept["rows"], int), np.asarray(kept["depths"], float),
            pair_i[open_pairs], pair_depth[open_pairs])
        for rows, cols in ambiguous:
            members = np.flatnonzero(np.isin(pair_i, rows) & np.isin(pair_j, cols) & allowed)
            if members.size:
                _assign_clear(pair_i[members], pair_j[members], pair_gap[members],
                              pair_depth[members], margin, kept)
        n_ambiguous = len(np.setdiff1d(np.concatenate([r for r, _ in ambiguous]), kept["rows"]))
    keep_rows = np.asarray(kept["rows"], dtype=int)
    keep_cols = np.asarray(kept["cols"], dtype=int)
    order = np.argsort(keep_rows)
    keep_rows, keep_cols = keep_rows[order], keep_cols[order]
    return Matches(keep_rows, keep_cols, np.asarray(kept["gaps"], float)[order],
                   int(len(pair_i)), n_ambiguous, np.setdiff1d(np.arange(n_left), keep_rows),
                   np.setdiff1d(np.arange(n_right), keep_cols))


def _assign_clear(pair_i, pair_j, pair_gap, pair_depth, margin, kept):
    """The assignment of one connected group of candidate pairs: its clear pairs go into
    ``kept`` (lists ``rows``, ``cols``, ``gaps``, ``depths``); returns the left rows and right
    columns of the ambiguous ones (see :func:`match_targets`)."""
    rows_in, cols_in = np.unique(pair_i), np.unique(pair_j)
    r_of, c_of = np.searchsorted(rows_in, pair_i), np.searchsorted(cols_in, pair_j)
    sub_gaps = np.full((len(rows_in), len(cols_in)), np.inf)
    sub_depths = np.full_like(sub_gaps, np.nan)
    sub_gaps[r_of, c_of] = pair_gap
    sub_depths[r_of, c_of] = pair_depth
    sub_candidate = np.isfinite(sub_gaps)
    rows, cols, total = _assign(sub_gaps, sub_candidate)
    unclear_rows, clear_rows, clear_cols = [], [], []
    for r, c in zip(rows, cols):
        clear = True
        if sub_candidate.sum() > 1:
            forbidden = sub_candidate.copy()
            forbidden[r, c] = False
            alt_rows, _, alt_total = _assign(sub_gaps, forbidden)
            clear = len(alt_rows) < len(rows) or alt_total > total + margin
        if clear:
            clear_rows.append(r)
            clear_cols.append(c)
            kept["rows"].append(rows_in[r])
            kept["cols"].append(cols_in[c])
            kept["gaps"].append(sub_gaps[r, c])
            kept["depths"].append(sub_depths[r, c])
        else:
            unclear_rows.append(r)
    if not unclear_rows:
        return np.zeros(0, int), np.zeros(0, int)
    # the rows and columns of the group that no clear pair took part in stay open (the group
    # shares no row or column with another, so its own clear pairs are all that took any)
    return np.delete(rows_in, clear_rows), np.delete(cols_in, clear_cols)


#: Neighbours a clear pair's plane of depth may leave out (the worst first) to lie on a plane:
#: another wrong pair nearby must not shield a wrong pair.
NEIGHBOUR_OUTLIERS = 2


def _drop_off_their_neighbours(uv_left, kept) -> list:
    """Clear pairs whose depth leaves the plane of depth their clear neighbours lie on
    (:data:`NEIGHBOURS` nearest in the left image, up to :data:`NEIGHBOUR_OUTLIERS` of them
    left out; the tolerances of :func:`resolve_by_neighbours`) are taken out of ``kept`` and
    returned as ambiguous groups ``[(rows, no columns)]``: the one-to-one assignment keeps a
    row's shifted partner as clear where the shift leaves another detection unmatched (a grid
    in rows along the baseline, noisy pixels), met 15-70 % nearer or farther than its
    neighbours. Dropped, never reassigned."""
    rows = np.asarray(kept["rows"], int)
    depths = np.asarray(kept["depths"], float)
    if len(rows) <= NEIGHBOURS:
        return []
    uv = uv_left[rows]
    _, nearest = cKDTree(uv).query(uv, k=NEIGHBOURS + 1)
    off = []
    for p, near in enumerate(nearest):
        near = near[near != p][:NEIGHBOURS]
        design = np.column_stack([np.ones(len(near)), uv[near] - uv[p]])
        values = depths[near]
        for _ in range(NEIGHBOUR_OUTLIERS + 1):
            solution = np.linalg.lstsq(design, values, rcond=None)[0]
            residual = values - design @ solution
            if np.sqrt(np.mean(residual ** 2)) <= NEIGHBOUR_PLANE_RMS * abs(solution[0]):
                if abs(depths[p] - solution[0]) > NEIGHBOUR_DEPTH_TOLERANCE * abs(solution[0]):
                    off.append(p)
                break
            worst = np.argmax(np.abs(residual))
            design, values = np.delete(design, worst, 0), np.delete(values, worst)
    drop = set(off)
    for key in ("rows", "cols", "gaps", "depths"):
        kept[key] = [v for p, v in enumerate(kept[key]) if p not in drop]
    return [(np.array([rows[p]]), np.zeros(0, int)) for p in off]


def resolve_by_neighbours(uv_left, clear_rows, clear_depths, pair_i, pair_depth):
    """Which candidate pairs agree with their neighbours (bool per pair).

    For each left detection, the :data:`NEIGHBOURS` clear pairs nearest in the left image give
    a plane of depth over ``(u, v)`` (least squares); where they lie on it within
    :data:`NEIGHBOUR_PLANE_RMS` of the depth, a candidate pair of that detection agrees when
    its depth is within :data:`NEIGHBOUR_DEPTH_TOLERANCE` of the plane's. Detections without
    such neighbours keep all their candidates (nothing is ruled out)."""
    allowed = np.ones(len(pair_i), dtype=bool)
    if len(clear_rows) < NEIGHBOURS:
        return allowed
    rows = np.unique(pair_i)
    tree = cKDTree(uv_left[clear_rows])
    _, nearest = tree.query(uv_left[rows], k=NEIGHBOURS)
    centred = uv_left[clear_rows][nearest] - uv_left[rows][:, None, :]  # (R, K, 2)
    design = np.concatenate([np.ones(centred.shape[:2] + (1,)), centred], axis=2)
    depths = clear_depths[nearest]  # (R, K)
    normal = np.einsum("rki,rkj->rij", design, design)
    rhs = np.einsum("rki,rk->ri", design, depths)
    with np.errstate(invalid="ignore"):
        try:
            solution = np.linalg.solve(normal, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return allowed
        predicted = solution[:, 0]  # the plane at the detection itself
        residual = depths - np.einsum("rki,ri->rk", design, solution)
        rms = np.sqrt(np.mean(residual ** 2, axis=1))
        smooth = np.isfinite(predicted) & (rms <= NEIGHBOUR_PLANE_RMS * np.abs(predicted))
    where = np.searchsorted(rows, pair_i)
    agree = np.abs(pair_depth - predicted[where]) <= NEIGHBOUR_DEPTH_TOLERANCE * np.abs(
        predicted[where])
    return np.where(smooth[where], agree, True)
