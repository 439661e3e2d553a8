"""Stereo matching without ground truth: the refractive epipolar constraint and ambiguity."""

import numpy as np
import pytest

from measure.stereo.matching import match_targets
from synth.scene.layouts import paper_plane
from measure.geometry.projection import project


def _pixels(rig, points, sigma, seed):
    rng = np.random.default_rng(seed)
    uv_left = project(rig.left, rig.port, points) + rng.normal(0, sigma, (len(points), 2))
    uv_right = project(rig.right, rig.port, points) + rng.normal(0, sigma, (len(points), 2))
    return uv_left, uv_right


@pytest.mark.parametrize("z", [1000.0, 2000.0])
def test_all_paper_targets_matched_without_ground_truth(rig, z):
    points = paper_plane(z)
    uv_left, uv_right = _pixels(rig, points, 0.03, seed=1)
    order = np.random.default_rng(2).permutation(len(points))
    matches = match_targets(rig, uv_left, uv_right[order], gate_mm=0.5,
                            depth_range=(0.8 * z, 1.25 * z))
    assert len(matches.left) == len(points)
    assert np.array_equal(order[matches.right], matches.left)  # every pair correct


def test_row_along_the_baseline_is_resolved_or_dropped_never_guessed(rig):
    # Targets on the X axis lie in the plane of both camera centres and the port normal: every
    # left ray meets every right ray. With no depth bound nothing tells them apart: all dropped.
    points = paper_plane(1000.0)
    row = points[np.abs(points[:, 1]) < 1e-9]
    uv_left, uv_right = _pixels(rig, row, 0.0, seed=0)
    unbounded = match_targets(rig, uv_left, uv_right, gate_mm=0.5, depth_range=(105.0, None))
    assert len(unbounded.left) == 0 and unbounded.n_ambiguous == len(row)
    # A working range keeps a rival for each target (its neighbour, met ~17 % nearer), but the
    # shifted assignment must leave a detection unmatched, so the row is resolved.
    bounded = match_targets(rig, uv_left, uv_right, gate_mm=0.5, depth_range=(800.0, 1250.0))
    assert bounded.n_candidates > len(row)
    assert np.array_equal(bounded.left, bounded.right) and len(bounded.left) == len(row)


def test_a_true_swap_ambiguity_is_dropped(rig):
    # Two left detections and two right detections where both pairings fit equally well:
    # duplicate each view's pixels of one target; nothing tells the copies apart.
    point = np.array([[50.0, 20.0, 1000.0]])
    uv_left, uv_right = _pixels(rig, point, 0.0, seed=0)
    matches = match_targets(rig, np.vstack([uv_left, uv_left + 1e-4]),
                            np.vstack([uv_right, uv_right + 1e-4]), gate_mm=0.5)
    assert len(matches.left) == 0 and matches.n_ambiguous == 2


def test_targets_seen_in_one_view_only_stay_unmatched(rig):
    points = paper_plane(1000.0)[:60]
    uv_left, uv_right = _pixels(rig, points, 0.02, seed=3)
    matches = match_targets(rig, uv_left, uv_right[10:], gate_mm=0.5, depth_range=(800, 1250))
    assert set(matches.unmatched_left) == set(range(10))
    assert np.array_equal(matches.right + 10, matches.left)


def test_bad_gate_is_rejected(rig):
    with pytest.raises(ValueError, match="gate_mm"):
        match_targets(rig, np.zeros((1, 2)), np.zeros((1, 2)), gate_mm=0)


@pytest.mark.parametrize("depth_range", [(105.0, None), (500.0, 2000.0)])
def test_ambiguities_on_a_surface_are_resolved_by_the_neighbours(rig, depth_range):
    """With a wide working range a target's neighbour on the same epipolar plane is a rival
    (24 of the paper's 496 are ambiguous with no upper bound). Its clear neighbours lie on a
    plane of depth; only the true partner agrees with it: every target matched, none wrong."""
    points = paper_plane(1000.0)
    uv_left, uv_right = _pixels(rig, points, 0.03, seed=1)
    plain = match_targets(rig, uv_left, uv_right, gate_mm=0.5, depth_range=depth_range,
                          resolve_ambiguities=False)
    assert plain.n_ambiguous >= 20
    matches = match_targets(rig, uv_left, uv_right, gate_mm=0.5, depth_range=depth_range)
    assert len(matches.left) == len(points) and matches.n_ambiguous == 0
    assert np.array_equal(matches.left, matches.right)


def test_targets_at_random_depths_are_not_resolved_by_neighbours(rig):
    """Neighbours at random depths predict nothing: the row along the baseline stays dropped
    (the rule never guesses where there is no surface)."""
    rng = np.random.default_rng(4)
    row = paper_plane(1000.0)
    row = row[np.abs(row[:, 1]) < 1e-9]
    others = np.column_stack([rng.uniform(-500, 500, 200), rng.uniform(-400, 400, 200),
                              rng.uniform(700, 1400, 200)])
    points = np.vstack([row, others])
    uv_left, uv_right = _pixels(rig, points, 0.0, seed=0)
    matches = match_targets(rig, uv_left, uv_right, gate_mm=0.5, depth_range=(105.0, None))
    assert np.array_equal(matches.left, matches.right)  # whatever is matched is right
    assert not np.isin(np.arange(len(row)), matches.left).any()  # the row stays dropped


@pytest.mark.parametrize("seed", [4, 7])
def test_a_clear_pair_off_its_neighbours_plane_is_dropped(seed):
    """A 9 × 9 grid at 1 m seen by the small rig (320 × 268 px, as small_grid.xml renders it)
    with 0.05 px of noise and no depth window: the one-to-one assignment kept a few shifted
    partners (met 69 % farther or 30 % nearer) as clear pairs — 2 and 8 wrong with these seeds.
    Each is off the plane of depth its clear neighbours lie on, so it is dropped, and the
    cleaner neighbourhood resolves most of the ambiguous ones: none wrong, 60+ matched."""
    from measure import StereoRig
    from synth.scene.layouts import grid_plane
    from synth.scene.rig import paper_cameras, paper_port

    left, right = paper_cameras((320, 268), 143.79)
    rig = StereoRig(left, right, paper_port())
    points = grid_plane(1000.0, 320.0, 80.0)
    uv_left, uv_right = _pixels(rig, points, 0.05, seed)
    matches = match_targets(rig, uv_left, uv_right, gate_mm=0.5)
    assert np.array_equal(matches.left, matches.right)
    assert len(matches.left) >= 60
