"""Matching detected targets across the N views of a rig, without ground truth.

Every pair of views (i < j) is matched with the refractive epipolar constraint
(:func:`measure.stereo.matching.match_targets` on the pair's rig,
:meth:`measure.stereo.rig.Rig.pair`). The pairwise matches are edges between
detections; a *track* is a connected group of them (the union of the pairwise matches,
``scipy.sparse.csgraph.connected_components``). A track that holds two detections of one view
is a conflict — some pairwise match is wrong, and which cannot be told — and is dropped as
ambiguous, never guessed; so is a track whose rays, all together, do not meet within the
pairwise gate (RMS distance of the optical-path point from its rays above ``gate_mm / 2``:
joined through a chain of pairs that do not agree). A detection that no pair matched stays
alone: it is reported (seen once, or not matched), never triangulated.

Two views are the pair's matching: the rig's one pair is matched with the rig itself (even
with no detection in a view), every match is a track, and no chain check applies (a pair's
track is one match within the gate) — so the tracks' ``pairs[(0, 1)]`` is exactly
:func:`measure.stereo.matching.match_targets` of the rig (what ``eval run`` of a pair uses).

Units: mm; pixels in the OpenCV convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .matching import Matches, match_targets
from .multiview import triangulate_views


@dataclass(frozen=True)
class Tracks:
    """Result of :func:`match_views`.

    ``detections`` ``(T, V)`` int: each track's detection index in every view, −1 where the
    view has none (every track has at least two); ``pairs`` ``{(i, j): Matches}`` the pairwise
    matches; ``n_conflicts`` tracks dropped because they held two detections of one view, and
    ``conflicted`` ``[(view, detection)…]`` the detections they held; ``alone`` per view the
    detections in no track (unmatched or conflicted)."""

    detections: np.ndarray
    pairs: dict
    n_conflicts: int
    conflicted: list
    alone: list

    @property
    def views_per_track(self) -> np.ndarray:
        """``(T,)`` how many views saw each track."""
        return (self.detections >= 0).sum(axis=1)

    def pixels(self, centers) -> np.ndarray:
        """``(T, V, 2)`` the tracks' pixels from the per-view ``centers`` (NaN where a view has
        none): the input of :func:`measure.stereo.multiview.triangulate_views`."""
        n, v = self.detections.shape
        out = np.full((n, v, 2), np.nan)
        for k in range(v):
            seen = self.detections[:, k] >= 0
            out[seen, k] = np.asarray(centers[k], dtype=float).reshape(-1, 2)[
                self.detections[seen, k]]
        return out


def match_views(rig, centers, gate_mm: float = 0.5, depth_range=(None, None),
                **options) -> Tracks:
    """Tracks of the detections ``centers`` (one ``(M_v, 2)`` array per camera of the
    :class:`measure.stereo.rig.Rig` ``rig``) across all views (module docs).
    ``gate_mm``, ``depth_range`` and ``options`` go to every pairwise
    :func:`measure.stereo.matching.match_targets`."""
    centers = [np.asarray(c, dtype=float).reshape(-1, 2) for c in centers]
    n_views = len(centers)
    if n_views != len(rig.cameras):
        raise ValueError(f"{n_views} views of detections for a rig of {len(rig.cameras)} cameras")
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in centers])])
    pairs: dict[tuple[int, int], Matches] = {}
    edges_a, edges_b = [], []
    for i in range(n_views):
        for j in range(i + 1, n_views):
            if n_views > 2 and not (len(centers[i]) and len(centers[j])):
                continue
            m = match_targets(rig if n_views == 2 else rig.pair(i, j), centers[i], centers[j],
                              gate_mm=gate_mm, depth_range=depth_range, **options)
            pairs[(i, j)] = m
            edges_a.append(offsets[i] + m.left)
            edges_b.append(offsets[j] + m.right)
    total = int(offsets[-1])
    a = np.concatenate(edges_a).astype(int) if edges_a else np.zeros(0, int)
    b = np.concatenate(edges_b).astype(int) if edges_b else np.zeros(0, int)
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(total, total))
    _, label = connected_components(graph, directed=False)
    view_of = np.repeat(np.arange(n_views), np.diff(offsets))
    index_of = np.arange(total) - offsets[view_of]
    size = np.bincount(label, minlength=label.max() + 1 if total else 0)
    # a group is a conflict when it holds fewer distinct views than detections
    distinct = np.zeros_like(size)
    pairs_seen = np.unique(np.stack([label, view_of]), axis=1) if total else np.zeros((2, 0), int)
    np.add.at(distinct, pairs_seen[0], 1)
    multi = size >= 2
    conflict = multi & (distinct < size)
    good = np.flatnonzero(multi & ~conflict)
    row_of = np.full(len(size), -1)
    row_of[good] = np.arange(len(good))
    detections = np.full((len(good), n_views), -1, dtype=int)
    in_good = row_of[label] >= 0
    detections[row_of[label[in_good]], view_of[in_good]] = index_of[in_good]
    in_conflict = conflict[label] if total else np.zeros(0, bool)
    conflicted = [(int(v), int(d)) for v, d in zip(view_of[in_conflict], index_of[in_conflict])]
    alone = [index_of[(view_of == v) & ~in_good] for v in range(n_views)]
    order = np.lexsort(detections.T[::-1]) if len(detections) else np.zeros(0, int)
    detections = detections[order]
    n_conflicts = int(conflict.sum())
    # a track joined through a chain (a–b, b–c) must also meet as a whole: its rays within
    # the pairwise gate of one point (a pair's RMS gap is half its common perpendicular)
    if len(detections) and n_views > 2:
        partial = Tracks(detections, pairs, 0, [], alone)
        gap = triangulate_views(rig.views(), partial.pixels(centers)).gap
        apart = ~(gap <= 0.5 * gate_mm)
        if apart.any():
            n_conflicts += int(apart.sum())
            for row in detections[apart]:
                conflicted += [(v, int(d)) for v, d in enumerate(row) if d >= 0]
            alone = [np.union1d(alone[v], detections[apart, v][detections[apart, v] >= 0])
                     for v in range(n_views)]
            detections = detections[~apart]
    return Tracks(detections, pairs, n_conflicts, conflicted, alone)


__all__ = ["Tracks", "match_views"]
