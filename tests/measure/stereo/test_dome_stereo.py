"""A stereo rig of two domes (measure.geometry.dome.DomePair) through the triangulators, the
reprojection-optimal points, the target matcher, the dense plane-sweep warp and the
eccentricity correction; the flat-port calibrations refuse it."""

from __future__ import annotations

import numpy as np
import pytest

from measure import Reason, StereoRig, triangulate
from measure.calibration.air import CalibrationError
from measure.calibration.housing import calibrate_housing
from measure.dense.match import match_dense
from measure.dense.warp import PlaneWarp
from measure.geometry.dome import DomePair, DomePort
from measure.images.eccentricity import correct_eccentricity, outline_centroid_offsets
from measure.stereo.matching import match_targets
from measure.geometry.projection import project
from measure.stereo.reprojection import reprojection_points
from measure.calibration.selfcal import self_calibrate
from synth.products.dense_pairs import PlaneSurface, SpeckleTexture, render_pair, surface_points
from synth.scene.rig import paper_rig

INDICES = (1.0, 1.49, 1.33)


def _dome_rig(decentring_left=(0.0, 0.0, 0.0), decentring_right=(0.0, 0.0, 0.0), size=None):
    rig = paper_rig() if size is None else paper_rig(size=size)
    pair = DomePair(DomePort(rig.left.center + decentring_left, 50.0, 8.0, INDICES),
                    DomePort(rig.right.center + decentring_right, 50.0, 8.0, INDICES))
    return StereoRig(rig.left, rig.right, pair)


DECENTRED = ((1.5, -1.0, 2.0), (-2.0, 0.5, -1.0))


def _points(n=200, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform((-300.0, -200.0, 600.0), (300.0, 200.0, 1500.0), size=(n, 3))


def _pixels(rig, points):
    return project(rig.left, rig.port.left, points), project(rig.right, rig.port.right, points)


@pytest.mark.parametrize("method", ["optical_path", "reprojection"])
def test_exact_pixels_give_the_points_back(method):
    rig = _dome_rig(*DECENTRED)
    points = _points()
    result = triangulate(rig, *_pixels(rig, points), method)
    assert np.all(result.reason == Reason.OK)
    assert np.linalg.norm(result.points - points, axis=1).max() <= 1e-9
    if method == "optical_path":
        assert result.gap.max() <= 1e-9


def test_reprojection_converges_to_the_point_from_a_distant_start():
    rig = _dome_rig(*DECENTRED)
    points = _points(50, seed=1)
    start = points + np.random.default_rng(2).normal(scale=5.0, size=points.shape)
    solved, rms, converged = reprojection_points(rig, *_pixels(rig, points), start)
    assert converged and rms.max() <= 1e-9
    assert np.linalg.norm(solved - points, axis=1).max() <= 1e-9


def test_centred_domes_make_the_pinhole_triangulation_exact():
    """A camera at its dome's centre sees through radial rays only: ``regular`` (which ignores
    the port) and ``su`` are then exact; a decentred dome makes ``regular`` wrong."""
    points = _points()
    centred = _dome_rig()
    for method in ("regular", "su", "optical_path"):
        result = triangulate(centred, *_pixels(centred, points), method)
        assert np.linalg.norm(result.points - points, axis=1).max() <= 1e-9, method
    decentred = _dome_rig(*DECENTRED)
    regular = triangulate(decentred, *_pixels(decentred, points), "regular")
    assert np.linalg.norm(regular.points - points, axis=1).max() > 1.0


def test_a_point_inside_a_dome_or_nan_pixels_give_reasons():
    rig = _dome_rig(*DECENTRED)
    uv_left, uv_right = _pixels(rig, _points(3))
    uv_left[1] = np.nan
    result = triangulate(rig, uv_left, uv_right)
    assert result.reason.tolist() == [Reason.OK, Reason.INVALID_INPUT, Reason.OK]
    assert np.isnan(result.points[1]).all()
    paths = project(rig.left, rig.port.left, rig.port.left.center + (0.0, 0.0, 55.0))
    assert np.isnan(paths).all()


def test_targets_are_matched_through_domes():
    rig = _dome_rig(*DECENTRED)
    rng = np.random.default_rng(3)
    grid = np.stack(np.meshgrid(np.linspace(-300, 300, 7), np.linspace(-200, 200, 5)),
                    axis=-1).reshape(-1, 2)
    points = np.column_stack([grid, np.full(len(grid), 1000.0)])
    uv_left, uv_right = _pixels(rig, points)
    uv_left += rng.normal(scale=0.03, size=uv_left.shape)
    uv_right += rng.normal(scale=0.03, size=uv_right.shape)
    order = rng.permutation(len(points))
    matches = match_targets(rig, uv_left, uv_right[order], gate_mm=0.5,
                            depth_range=(800.0, 1250.0))
    assert len(matches.left) == len(points)
    assert np.array_equal(order[matches.right], matches.left)


def test_the_plane_sweep_warp_follows_the_domes():
    """The exact warp of left pixels at a depth plane gives right pixels that triangulate back
    to the points of that plane (depth along the left optical axis)."""
    rig = _dome_rig(*DECENTRED, size=(320, 268))
    warp = PlaneWarp(rig, "refractive", grid_step_px=8)
    inside = rig.left.in_image(warp.grid_pixels)
    origins, directions = warp.grid_origins[inside], warp.grid_directions[inside]
    points, _ = warp.points_at_depth(origins, directions, 1000.0)
    np.testing.assert_allclose(points @ rig.depth_axis - rig.left.center @ rig.depth_axis,
                               1000.0, rtol=1e-12)
    right = warp.right_pixels(points)
    result = triangulate(rig, warp.grid_pixels[inside], right)
    assert np.linalg.norm(result.points - points, axis=1).max() <= 1e-9


def test_eccentricity_correction_through_domes():
    """Detected disk centroids (the area centroids of the outlines' images through each dome)
    triangulate off the centres; the correction, with each view's dome, brings them back."""
    rig = _dome_rig(*DECENTRED)
    grid = np.stack(np.meshgrid(np.linspace(-300, 300, 5), np.linspace(-200, 200, 4)),
                    axis=-1).reshape(-1, 2)
    centres = np.column_stack([grid, np.full(len(grid), 700.0)])
    normal = np.array([0.0, 0.5, -1.0]) / np.sqrt(1.25)
    uv_left, uv_right = _pixels(rig, centres)
    uv_left += outline_centroid_offsets(rig.left, rig.port.left, centres, normal, 20.0)
    uv_right += outline_centroid_offsets(rig.right, rig.port.right, centres, normal, 20.0)
    before = np.linalg.norm(triangulate(rig, uv_left, uv_right).points - centres, axis=1).max()
    corrected = correct_eccentricity(rig, uv_left, uv_right, 20.0, normals=normal)
    after = np.linalg.norm(corrected.triangulation.points - centres, axis=1).max()
    assert before > 0.1 and after <= 1e-6  # measured 0.296 mm and 5.8e-9 mm


def test_flat_port_calibrations_refuse_domes():
    """Self-calibration is of a flat port; the housing calibration of a dome rig estimates the
    domes' parameters (tests/measure/calibration/test_calibration_dome.py) and refuses a flat port's."""
    rig = _dome_rig()
    with pytest.raises(ValueError, match="DomePair"):
        self_calibrate(rig, *_pixels(rig, _points(10)))
    with pytest.raises(CalibrationError, match="of two domes estimates dome_center"):
        calibrate_housing(rig, None, None, ("distance", "normal"))


def test_dense_matching_through_domes():
    """A speckled plane 1 m away rendered analytically through two decentred domes
    (synth.products.dense_pairs) and matched densely (depths along the left optical axis), against the
    exact forward projection of each matched left pixel's surface point. The speckle is 17 mm
    (~2.4 px at 1 m: a dome does not magnify as a flat port does) on a texture wide enough for
    the dome's wider view. Measured (2026-12-02, the refinement's fourth-order derivative):
    99.4 % of the overlap matched, right-pixel error RMS 0.0080 px, max 0.041 px (with Scharr's
    derivative 0.0099 px, 0.053 px); asserted as for the flat port (tests/measure/
    test_dense.py): 97 %, RMS 0.02 px, max 0.15 px."""
    rig = _dome_rig(*DECENTRED, size=(320, 268))
    surface = PlaneSurface.create((0.0, 0.0, 1000.0), (0.0, 0.0, 1.0))
    texture = SpeckleTexture.random((-1300, 1500, -1100, 1100), 17.0, seed=1)
    left, right = render_pair(rig, surface, texture)
    matches = match_dense(rig, left, right, (900.0, 1100.0))
    grid = np.stack(np.meshgrid(np.arange(320.0), np.arange(268.0)), axis=-1).reshape(-1, 2)
    truth = project(rig.right, rig.port.right, surface_points(rig.left, rig.port.left, surface,
                                                              grid))
    overlap = rig.left.in_image(grid, 7) & rig.right.in_image(truth, 7)
    index = (matches.uv_left[:, 1] * 320 + matches.uv_left[:, 0]).astype(np.int64)
    error = np.hypot(*(matches.uv_right - truth[index]).T)
    assert overlap[index].sum() / overlap.sum() > 0.97
    assert np.sqrt(np.mean(error ** 2)) < 0.02 and error.max() < 0.15
    rows, cols = matches.uv_left[:, 1].astype(int), matches.uv_left[:, 0].astype(int)
    points = triangulate(rig, matches.uv_left, matches.uv_right).points
    assert np.max(np.abs(matches.depth_map[rows, cols] - points @ rig.depth_axis)) < 1e-6
