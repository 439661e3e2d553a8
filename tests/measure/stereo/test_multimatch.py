"""Matching across N views (measure.stereo.multimatch) on the forward model's pixels: four
cameras behind one port, the paper's 496 targets at 1 m, detections shuffled per view."""

from __future__ import annotations

import numpy as np

from measure.geometry.camera import Camera
from measure.geometry.port import FlatPort
from measure.geometry.projection import project
from measure.stereo.multimatch import match_views
from measure.stereo.multirig import MultiRig
from measure.stereo.multiview import triangulate_views

K = np.array([[1100.0, 0, 1223.5], [0, 1100.0, 1023.5], [0, 0, 1.0]])
SIZE = (2448, 2048)
PORT = FlatPort((0, 0, 1), 100.0, (5.0,), (1.0, 1.54, 1.33))


def _paper_targets(z=1000.0):
    """Li et al. 2024 section 3.1: the centre and 15 circles of 33 points, radius 40 … 600 mm."""
    angles = 2 * np.pi * np.arange(33) / 33
    rings = [np.column_stack([r * np.cos(angles), r * np.sin(angles)]) for r in range(40, 601, 40)]
    xy = np.vstack([[[0.0, 0.0]]] + rings)
    return np.column_stack([xy, np.full(len(xy), z)])


def _row(n):
    out = []
    for k in range(n):
        a = -np.radians(5.0 * k)
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        out.append(Camera(K, SIZE, R=R, t=(200.0 * k, 0.0, 0.0)))
    return out


def test_four_views_match_every_target_seen_twice_and_none_wrong():
    cameras = _row(4)
    rig = MultiRig(cameras, [PORT] * 4)
    points = _paper_targets()
    assert len(points) == 496
    rng = np.random.default_rng(3)
    centers, truth = [], []
    for k, camera in enumerate(cameras):
        uv = project(camera, PORT, points)
        inside = np.all((uv >= 0) & (uv <= np.array(SIZE) - 1), axis=1)
        if k:
            inside[7] = False  # target 7: seen by cam0 only
        ids = rng.permutation(np.flatnonzero(inside))
        truth.append(ids)
        centers.append(uv[ids] + rng.normal(0, 0.02, (len(ids), 2)))
    tracks = match_views(rig, centers, gate_mm=0.5, depth_range=(800.0, 1250.0))
    ids = np.where(tracks.detections >= 0,
                   np.stack([t[np.maximum(d, 0)] for t, d in zip(truth, tracks.detections.T)],
                            axis=1), -1)
    first = ids.max(axis=1)
    assert np.all((ids == first[:, None]) | (ids < 0)), "a track joins different targets"
    seen = np.bincount(np.concatenate(truth), minlength=len(points))
    assert sorted(first) == sorted(np.flatnonzero(seen >= 2))
    np.testing.assert_array_equal(tracks.views_per_track, seen[first])
    assert tracks.n_conflicts == 0
    assert 7 not in first and list(truth[0][tracks.alone[0]]) == [7]
    assert set(seen[first]) == {2, 3, 4}  # the outer cameras miss some targets
    result = triangulate_views(rig.views(), tracks.pixels(centers))
    error = np.linalg.norm(result.points - points[first], axis=1)
    # noise of 0.02 px: a pair's depth error at 1 m is a few hundredths of a mm
    assert np.all(result.valid) and error.max() < 0.5


def test_conflicts_and_chains_that_do_not_meet_are_dropped(monkeypatch):
    """Pairwise matches given by hand (the union's logic alone): a group with two detections of
    one view is dropped, and so is a chain a–b, b–c whose rays do not meet as a whole; a
    consistent track of three views is kept."""
    import measure.stereo.multimatch as multimatch
    from measure.stereo.matching import Matches

    cameras = _row(3)
    rig = MultiRig(cameras, [PORT] * 3)
    points = np.array([[0.0, 0.0, 1000.0], [150.0, 100.0, 1000.0], [300.0, -100.0, 1000.0]])
    centers = [project(c, PORT, points) for c in cameras]
    given = {(0, 1): ([0, 1], [0, 1]), (0, 2): ([0, 1], [0, 1]), (1, 2): ([0, 1], [0, 2])}

    def fake(pair_rig, uv_a, uv_b, **_):
        i = next(k for k, c in enumerate(cameras) if c == pair_rig.left)
        j = next(k for k, c in enumerate(cameras) if c == pair_rig.right)
        a, b = given[(i, j)]
        empty = np.zeros(0, int)
        return Matches(np.array(a), np.array(b), np.zeros(len(a)), len(a), 0, empty, empty)

    monkeypatch.setattr(multimatch, "match_targets", fake)
    tracks = multimatch.match_views(rig, centers, gate_mm=0.5)
    # target 0: 0–0–0 in all pairs: kept; target 1: (0,2) says a1–c1 and (1,2) b1–c2, so
    # {a1, b1, c1, c2} holds two detections of view 2: a conflict
    np.testing.assert_array_equal(tracks.detections, [[0, 0, 0]])
    assert tracks.n_conflicts == 1 and sorted(tracks.conflicted) == [(0, 1), (1, 1), (2, 1), (2, 2)]
    given = {(0, 1): ([0, 1], [0, 1]), (0, 2): ([0], [0]), (1, 2): ([0, 1], [0, 2])}
    tracks = multimatch.match_views(rig, centers, gate_mm=0.5)
    # a1–b1 and b1–c2 chain into one group of one detection per view, but target 1's rays
    # and target 2's do not meet: dropped
    np.testing.assert_array_equal(tracks.detections, [[0, 0, 0]])
    assert tracks.n_conflicts == 1 and sorted(tracks.alone[2]) == [1, 2]


def test_two_views_are_the_pairs_matching():
    """A pair is N = 2 of tracks: match_views of two views gives match_targets' matches, the
    same arrays, the tracks its pairs in the left detections' order — with noise that leaves
    some pairs near the gate and some ambiguous, and with an empty view."""
    from measure.stereo.matching import match_targets

    cameras = _row(2)
    rig = MultiRig(cameras, [PORT] * 2)
    points = _paper_targets()
    rng = np.random.default_rng(5)
    centers = []
    for camera in cameras:
        uv = project(camera, PORT, points)
        inside = np.flatnonzero(np.all((uv >= 0) & (uv <= np.array(SIZE) - 1), axis=1))
        ids = rng.permutation(inside)
        centers.append(uv[ids] + rng.normal(0, 0.4, (len(ids), 2)))
    options = dict(gate_mm=0.5, depth_range=(800.0, 1250.0))
    pair = match_targets(rig, centers[0], centers[1], **options)
    tracks = match_views(rig, centers, **options)
    assert 0 < pair.n_ambiguous and 300 < len(pair.left) and pair.gap.max() > 0.45
    ours = tracks.pairs[(0, 1)]
    for name in ("left", "right", "gap", "unmatched_left", "unmatched_right"):
        np.testing.assert_array_equal(getattr(ours, name), getattr(pair, name), err_msg=name)
    assert (ours.n_candidates, ours.n_ambiguous) == (pair.n_candidates, pair.n_ambiguous)
    np.testing.assert_array_equal(tracks.detections, np.column_stack([pair.left, pair.right]))
    assert tracks.n_conflicts == 0
    empty = match_views(rig, [centers[0], np.zeros((0, 2))], **options)
    assert len(empty.detections) == 0 and len(empty.pairs[(0, 1)].left) == 0
