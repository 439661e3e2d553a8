"""Warping a refractive pair to virtual pinhole cameras: exact on the chosen plane, and the
error map is what the maps do elsewhere (checked by sampling the maps with cv2.remap)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from measure.geometry.projection import project
from measure.stereo.rectify import plane_points, rectified_pixels, rectify, warp_errors
from synth.scene.rig import paper_rig

SIZE, FOCAL, DISTANCE = (480, 402), 225.0, 1000.0


@pytest.fixture(scope="module")
def rectification():
    return rectify(paper_rig(size=SIZE, focal_px=FOCAL), DISTANCE)


def _sample(maps, uv):
    """The maps at ``uv`` (bilinear, as cv2.remap reads them)."""
    x = uv[:, 0].astype(np.float32).reshape(-1, 1)
    y = uv[:, 1].astype(np.float32).reshape(-1, 1)
    return np.column_stack([cv2.remap(m, x, y, cv2.INTER_LINEAR).ravel() for m in maps])


def _field_points(rectification, z):
    virtual = rectification.virtual.left
    u, v = np.meshgrid(np.linspace(40, SIZE[0] - 40, 9), np.linspace(40, SIZE[1] - 40, 7))
    return plane_points(virtual, np.column_stack([u.ravel(), v.ravel()]),
                        rectification.rig.depth_axis, z)


def test_points_on_the_plane_land_where_the_virtual_pinholes_project_them(rectification):
    """The maps, sampled where each virtual pinhole projects a point of the plane, give the
    pixel where the real camera sees it through the port (the Fermat forward model), and the
    two virtual views put it on the same row."""
    rig = rectification.rig
    points = _field_points(rectification, DISTANCE)
    ideal = [c.project(points) for c in rectification.virtual.cameras]
    for view in (0, 1):
        real = project(rig.cameras[view], rig.view_port(view), points)
        seen = rig.cameras[view].in_image(real, 2.0) & rectification.virtual.cameras[view].in_image(
            ideal[view], 2.0)
        assert seen.sum() > 40
        back = _sample(rectification.maps[view], ideal[view][seen])
        assert np.max(np.linalg.norm(back - real[seen], axis=1)) < 0.05
    assert np.max(np.abs(ideal[0][:, 1] - ideal[1][:, 1])) < 1e-6
    errors = warp_errors(rectification, points)
    assert np.nanmax(errors[0]["error_px"]) < 1e-9 and np.nanmax(errors[1]["error_px"]) < 1e-9
    assert np.nanmax(np.abs(errors["error_mm"])) < 1e-6


@pytest.mark.parametrize("z", [600.0, 1500.0, 2500.0])
def test_the_error_map_is_what_the_maps_do_at_other_distances(rectification, z):
    """Off the plane the warp is not exact: the rectified pixel of a point (the analytic
    inversion behind the error map) is where the maps, sampled, send the real pixel — to
    0.01 px — and it differs from the virtual pinhole's projection."""
    rig = rectification.rig
    points = _field_points(rectification, z)
    errors = warp_errors(rectification, points)
    for view in (0, 1):
        real = project(rig.cameras[view], rig.view_port(view), points)
        rectified = rectified_pixels(rectification, view, real)
        ok = (rig.cameras[view].in_image(real, 2.0)
              & rectification.virtual.cameras[view].in_image(rectified, 2.0))
        assert ok.sum() > 20
        back = _sample(rectification.maps[view], rectified[ok])
        assert np.max(np.linalg.norm(back - real[ok], axis=1)) < 0.01
        assert np.nanmax(errors[view]["error_px"]) > 0.1


def test_a_distance_inside_the_glass_is_refused():
    with pytest.raises(ValueError, match="beyond the glass"):
        rectify(paper_rig(size=SIZE, focal_px=FOCAL), 50.0)


def test_stereo_sgbm_on_a_rectified_pair_beside_the_port_models_dense_matcher():
    """OpenCV's StereoSGBM runs unchanged on the rectified pair of an analytic speckle plane:
    at the warp's distance its depths are within half a pixel of disparity of the truth (what
    an integer-plus-sixteenths matcher can do); on a plane 40 % farther the warp's error adds
    to it, while the port model's dense matcher stays sub-millimetre on the same pixels."""
    from measure import triangulate
    from measure.dense.match import match_dense
    from measure.stereo.rectify import sgbm_points
    from synth.products.dense_pairs import (PlaneSurface, SpeckleTexture, render_pair,
                                            surface_points)

    rig = paper_rig(size=SIZE, focal_px=FOCAL)
    rectification = rectify(rig, DISTANCE)
    texture = SpeckleTexture.random((-1500, 1700, -1300, 1300), 13.0, seed=1)
    virtual = rectification.virtual
    focal, baseline = virtual.left.K[0, 0], np.linalg.norm(virtual.right.t - virtual.left.t)
    medians = {}
    for z in (DISTANCE, 1400.0):
        surface = PlaneSurface.create((100.0, 0.0, z), (0.0, 0.0, 1.0))
        left, right = render_pair(rig, surface, texture, supersample=2)
        uv, points = sgbm_points(rectification, left, right)
        sgbm = np.abs((points - surface_points(rig.left, rig.port, surface, uv)) @ rig.depth_axis)
        dense = match_dense(rig, left, right, (0.6 * z, 1.4 * z))
        measured = triangulate(rig, dense.uv_left, dense.uv_right, "optical_path").points
        error = np.abs((measured - surface_points(rig.left, rig.port, surface, dense.uv_left))
                       @ rig.depth_axis)
        medians[z] = (float(np.median(sgbm)), float(np.median(error)))
        assert len(uv) > 0.5 * SIZE[0] * SIZE[1]
    half_pixel_mm = DISTANCE ** 2 / (focal * baseline) * 0.5
    assert medians[DISTANCE][0] < half_pixel_mm
    assert medians[1400.0][0] > 10 * medians[1400.0][1] and medians[1400.0][1] < 1.0
