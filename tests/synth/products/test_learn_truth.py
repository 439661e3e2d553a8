"""The truth of sea scenes from the exact forward model: each truth point projects back onto its
pixel by the Fermat solver (independent of the ray tracing that found it), the correspondence
is seen by the other camera's own ray, and the rectified pair is an exact pinhole pair on the
warp's plane and not off it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from measure.geometry.projection import project
from synth.products import learn_truth as lt
from synth.products.learn_scene import median_distance, scene_checks
from synth.products.truth_maps import MeshTracer
from synth.scene.sea_draw import SeaRanges, draw_scene
from synth.scene.sea_write import MESH_FILE, write_sea_scene
from synth.scene.surfaces import SurfaceMesh, write_ply

SMALL = (160, 128)


@pytest.fixture(scope="module", params=["flat", "per-camera", "dome"])
def drawn(request, tmp_path_factory):
    folder = tmp_path_factory.mktemp(request.param)
    scene = draw_scene(21, SeaRanges(size=SMALL, ports=(request.param,)))
    floor = write_sea_scene(str(folder), scene, spp=4)
    tracer = MeshTracer(str(folder / MESH_FILE), floor.mesh.vertices, floor.mesh.triangles)
    left = lt.view_truth(tracer, scene.rig, 0)
    return scene, tracer, left


def test_truth_points_project_back_onto_their_pixels(drawn):
    scene, tracer, left = drawn
    for view, truth in ((0, left), (1, lt.view_truth(tracer, scene.rig, 1))):
        assert truth.valid.mean() > 0.5
        rows, cols = np.nonzero(truth.valid)
        uv = np.column_stack([cols, rows]).astype(float)
        error = lt.fermat_round_trip(scene.rig, view, truth.points[rows, cols], uv)
        assert error.max() < 1e-6
        camera = scene.rig.cameras[view]
        offset = truth.points[rows, cols] - camera.center
        normals = truth.normals[rows, cols]
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
        water = scene.rig.trace(view, camera.rays(uv))
        assert np.all(np.einsum("ij,ij->i", normals, water.directions) < 0)  # facing the ray
        np.testing.assert_allclose(truth.range[rows, cols], np.linalg.norm(offset, axis=1))
        np.testing.assert_allclose(truth.z[rows, cols], offset @ camera.R[:, 2])


def test_the_right_camera_sees_the_left_point_where_the_flow_says(drawn):
    scene, tracer, left = drawn
    flow, seen, occluded = lt.flow_truth(tracer, scene.rig, left)
    assert seen.mean() > 0.3 and not np.any(seen & occluded)
    rows, cols = np.nonzero(seen)
    uv_right = np.column_stack([cols, rows]) + flow[rows, cols]
    hits, _ = lt.pixel_hits(tracer, scene.rig, 1, uv_right)
    assert np.max(np.linalg.norm(hits - left.points[rows, cols], axis=1)) < 1e-6
    # an occluded pixel's point is not what the right camera's ray meets first (or it is
    # outside the right image)
    rows, cols = np.nonzero(occluded)
    if rows.size:
        uv_right = np.column_stack([cols, rows]) + flow[rows, cols]
        inside = scene.rig.right.in_image(uv_right)
        hits, _ = lt.pixel_hits(tracer, scene.rig, 1, uv_right[inside])
        assert np.all(np.linalg.norm(hits - left.points[rows, cols][inside], axis=1) > 1e-3)


def test_every_scene_passes_its_checks(drawn):
    scene, tracer, left = drawn
    right = lt.view_truth(tracer, scene.rig, 1)
    flow, seen, _ = lt.flow_truth(tracer, scene.rig, left)
    rect = lt.rectified_truth(tracer, scene.rig, median_distance(scene, left))
    checks = scene_checks(scene, tracer, left, right, flow, seen, rect,
                          np.random.default_rng(0))
    assert checks["passed"], checks
    assert checks["left_round_trip_max_px"] < 1e-4  # float32 points
    assert checks["rectified_vs_flow_max_px"] < 1e-3  # float32 flow


def _plane_tracer(tmp_path, axis, distance):
    """A square of 20 m on the plane ``axis · X = distance``, facing the cameras."""
    axis = np.asarray(axis, float)
    a = np.cross(axis, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(axis, a)
    centre = axis * distance
    corners = np.array([centre + 1e4 * (sa * a + sb * b)
                        for sa, sb in ((-1, -1), (1, -1), (-1, 1), (1, 1))])
    triangles = np.array([[0, 1, 2], [1, 3, 2]])
    mesh = SurfaceMesh(corners, triangles, corners[:, :2], "plane")
    path = str(tmp_path / "plane.ply")
    write_ply(path, mesh, corners[:, :2].min(axis=0), corners[:, :2].max(axis=0))
    return MeshTracer(path, corners.astype(np.float32).astype(float), triangles)


@pytest.mark.parametrize("port, offset", [("flat", 0), ("per-camera", 0), ("dome", 0),
                                          ("flat", 37)])
def test_on_the_warp_plane_the_rectified_pair_is_a_pinhole_pair(tmp_path, port, offset):
    """A plane at the warp's distance: the residual and the row error vanish, and the virtual
    pinhole pair (its right principal point moved by the disparity offset) triangulates every
    disparity (cv2.triangulatePoints) onto the plane. A plane 1.5 times as far leaves a
    residual behind a flat port (non-central cameras)."""
    scene = draw_scene(8, SeaRanges(size=SMALL, ports=(port,)))
    axis, distance = scene.rig.depth_axis, 1200.0
    tracer = _plane_tracer(tmp_path, axis, distance)
    rect = lt.rectified_truth(tracer, scene.rig, distance, offset)
    if offset:
        plain = lt.rectified_truth(tracer, scene.rig, distance)
        np.testing.assert_allclose(rect.disparity, plain.disparity - offset, atol=1e-9)
    seen = np.isfinite(rect.disparity) & ~rect.occluded
    assert seen.mean() > 0.5
    assert np.nanmax(rect.residual[seen]) < 1e-6 and np.nanmax(np.abs(rect.row_error[seen])) < 1e-6
    rows, cols = np.nonzero(seen)
    left_uv = np.column_stack([cols, rows]).astype(float)
    right_uv = left_uv - np.column_stack([rect.disparity[rows, cols], 0 * rows])
    P = [c.K @ np.hstack([c.R.T, (-c.R.T @ c.t)[:, None]]) for c in rect.rectification.virtual.cameras]
    X = cv2.triangulatePoints(P[0], P[1], left_uv.T, right_uv.T)
    X = (X[:3] / X[3]).T
    np.testing.assert_allclose(X @ axis, distance, atol=1e-6 * distance)
    farther = lt.rectified_truth(_plane_tracer(tmp_path, axis, 1.5 * distance), scene.rig,
                                 distance)
    if port != "dome":
        assert np.nanmax(farther.residual) > 0.01


def test_truth_does_not_depend_on_where_it_is_asked(drawn):
    """The rectified truth of a pixel is the same whether asked alone or on the whole grid."""
    scene, tracer, left = drawn
    rect = lt.rectified_truth(tracer, scene.rig, median_distance(scene, left))
    q = np.array([[40.0, 30.0], [100.0, 90.0]])
    alone = lt.rectified_truth_at(tracer, rect.rectification, q)[0]
    np.testing.assert_array_equal(alone, rect.disparity[[30, 90], [40, 100]])
    assert np.array_equal(np.isnan(alone), np.isnan(rect.disparity[[30, 90], [40, 100]]))
    _ = project  # the forward model the module docs name


@pytest.mark.slow
def test_the_renderer_agrees_with_the_correspondence_truth(tmp_path):
    """Rendered through the port by Mitsuba (which knows nothing of the truth), the right image
    sampled at each left pixel + its flow looks like the left image (a Lambertian floor looks
    the same from both cameras): zero-normalised correlation over the pixels the right camera
    sees, far above the same with the flow off by 3 px."""
    from synth.products.learn_scene import render_pair

    scene = draw_scene(2, SeaRanges(size=(240, 192), ports=("per-camera",), waters=("clear",),
                                    lights=("lamps",)))
    floor = write_sea_scene(str(tmp_path), scene, spp=16)
    tracer = MeshTracer(str(tmp_path / MESH_FILE), floor.mesh.vertices, floor.mesh.triangles)
    left = lt.view_truth(tracer, scene.rig, 0)
    flow, seen, _ = lt.flow_truth(tracer, scene.rig, left)
    (image_left, image_right), _ = render_pair(str(tmp_path), scene, 16)
    h, w = seen.shape
    grid = np.mgrid[0:h, 0:w][::-1].astype(np.float32)

    def zncc(shift):
        map_x = (grid[0] + np.nan_to_num(flow[..., 0]) + shift).astype(np.float32)
        map_y = (grid[1] + np.nan_to_num(flow[..., 1])).astype(np.float32)
        warped = cv2.remap(image_right, map_x, map_y, cv2.INTER_LINEAR)
        inner = seen & (cv2.erode(seen.astype(np.uint8), np.ones((5, 5))) > 0)
        a, b = image_left[inner], warped[inner]
        a, b = a - a.mean(), b - b.mean()
        return float((a @ b) / np.sqrt((a @ a) * (b @ b)))

    exact, off = zncc(0.0), zncc(3.0)
    assert exact > 0.85 and off < exact - 0.2


def test_the_disparity_offset_leaves_the_margin(drawn):
    scene, tracer, left = drawn
    points = left.points.reshape(-1, 3)
    offset = lt.disparity_offset(scene.rig, points)
    rect = lt.rectified_truth(tracer, scene.rig, 1500.0, offset)
    virtual = rect.rectification.virtual
    finite = points[np.all(np.isfinite(points), axis=1)]
    d = virtual.left.project(finite)[:, 0] - virtual.right.project(finite)[:, 0]
    assert offset == 0 or lt.OFFSET_MARGIN_PX <= d.min() < lt.OFFSET_MARGIN_PX + 1
