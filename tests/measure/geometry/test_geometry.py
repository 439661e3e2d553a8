"""Refraction, the forward solvers and the triangulators (paper sections 2.1 and 2.2)."""

import cv2
import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from measure import (Camera, FlatPort, Reason, StereoRig, intersect_plane, refract,
                     trace_through_port, triangulate)
from synth.scene.layouts import paper_plane
from measure.geometry.projection import project, solve_paths

from tests.conftest import rotation


def random_rig(draw, distorted: bool):
    """A random stereo rig behind a random (tilted, 0-3 layer) port, and points both cameras see."""
    f = draw(st.floats(600, 2000))
    size = (1280, 1024)
    K = np.array([[f, 0, 639.5 + draw(st.floats(-20, 20))],
                  [0, f, 511.5 + draw(st.floats(-20, 20))], [0, 0, 1]])
    dist = None
    if distorted:
        dist = np.array([draw(st.floats(-0.25, 0.15)), draw(st.floats(-0.05, 0.05)),
                         draw(st.floats(-1e-3, 1e-3)), draw(st.floats(-1e-3, 1e-3)),
                         draw(st.floats(-0.02, 0.02))])
    baseline = draw(st.floats(80, 400))
    toe = draw(st.floats(0, np.deg2rad(8)))
    left = Camera(K, size, dist,
                  R=rotation(draw(st.floats(-0.05, 0.05)), draw(st.floats(-0.05, 0.05)), 0),
                  t=(draw(st.floats(-10, 10)), draw(st.floats(-10, 10)), draw(st.floats(-10, 10))))
    right = Camera(K, size, dist,
                   R=rotation(draw(st.floats(-0.05, 0.05)), -toe, draw(st.floats(-0.05, 0.05))),
                   t=(baseline, draw(st.floats(-20, 20)), draw(st.floats(-20, 20))))
    n_layers = draw(st.integers(0, 3))
    tilt = rotation(draw(st.floats(-0.25, 0.25)), draw(st.floats(-0.25, 0.25)), 0)
    normal = tilt @ np.array([0.0, 0.0, 1.0])
    air_gap = draw(st.floats(30, 200))  # from the nearer camera centre to the port
    port = FlatPort(normal, air_gap + max(normal @ left.t, normal @ right.t),
                    tuple(draw(st.floats(1, 30)) for _ in range(n_layers)),
                    (1.0, *(draw(st.floats(1.0, 1.9)) for _ in range(n_layers)), draw(st.floats(1.3, 1.4))))
    return StereoRig(left, right, port)


@st.composite
def rigs_and_points(draw, distorted=False):
    rig = random_rig(draw, distorted)
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    n = 200
    depth = rng.uniform(rig.port.offsets[-1] + 50, 3000, n)
    # Points near both optical axes, so that both cameras see them.
    middle = 0.5 * (rig.left.center + rig.right.center)
    points = middle + np.column_stack([rng.uniform(-0.35, 0.35, n) * depth,
                                       rng.uniform(-0.3, 0.3, n) * depth, depth])
    points = points[rig.port.water_side(points)]
    return rig, points


def _visible(rig, uv_left, uv_right):
    return rig.left.in_image(uv_left) & rig.right.in_image(uv_right)


def _inside_fold(camera, points):
    """Points whose undistorted image radius lies where the radial distortion still increases.

    Beyond the fold radius a distortion polynomial maps points back into the image (a real lens
    would not see them there); such pixels have no unique ray, so they are not round-trip cases.
    """
    r = np.linspace(0.0, 3.0, 3001)
    radial = camera.distort(np.column_stack([r, np.zeros_like(r)]))[:, 0]
    falling = np.flatnonzero(np.diff(radial) <= 0)
    fold = r[falling[0]] if falling.size else np.inf
    xyz = camera.to_camera(points)
    return np.hypot(xyz[:, 0], xyz[:, 1]) / xyz[:, 2] < 0.95 * fold


@given(rigs_and_points())
def test_round_trip_without_distortion_is_exact(data):
    rig, points = data
    uv_left = project(rig.left, rig.port, points)
    uv_right = project(rig.right, rig.port, points)
    visible = _visible(rig, uv_left, uv_right)
    assume(visible.sum() >= 5)
    result = triangulate(rig, uv_left[visible], uv_right[visible])
    assert np.all(result.reason == Reason.OK)
    assert np.max(np.linalg.norm(result.points - points[visible], axis=1)) <= 1e-9
    assert np.max(result.gap) <= 1e-9


@given(rigs_and_points(distorted=True))
def test_round_trip_with_distortion(data):
    rig, points = data
    uv_left = project(rig.left, rig.port, points)
    uv_right = project(rig.right, rig.port, points)
    # The refracted ray leaves the camera towards I1: that is the direction that must be unique.
    first_left = solve_paths(rig.left, rig.port, points).interface_points[0]
    first_right = solve_paths(rig.right, rig.port, points).interface_points[0]
    visible = (_visible(rig, uv_left, uv_right) & _inside_fold(rig.left, first_left)
               & _inside_fold(rig.right, first_right))
    assume(visible.sum() >= 5)
    result = triangulate(rig, uv_left[visible], uv_right[visible])
    assert np.max(np.linalg.norm(result.points - points[visible], axis=1)) <= 1e-6


@given(rigs_and_points())
def test_snell_invariant_at_every_interface(data):
    rig, points = data
    for solver in ("fermat", "snell"):
        paths = solve_paths(rig.left, rig.port, points, solver)
        ok = paths.reason == Reason.OK
        vertices = np.concatenate([np.broadcast_to(rig.left.center, (1, ok.sum(), 3)),
                                   paths.interface_points[:, ok], points[None, ok]])
        segments = np.diff(vertices, axis=0)
        lengths = np.linalg.norm(segments, axis=2)
        directions = segments / lengths[..., None]
        normal = rig.port.normal
        sines = np.linalg.norm(np.cross(directions, normal), axis=2)
        invariant = np.asarray(rig.port.indices)[:, None] * sines
        # A direction taken from a segment shorter than 1 mm carries the rounding of its end
        # points (~3e-14 mm at 100 mm) amplified beyond 1e-12 (hypothesis found a point 0.04 mm
        # behind the port: 5.6e-12 with the solvers of every version); such points are covered
        # by the round trips and the solver agreement, not by this check.
        conditioned = lengths.min(axis=0) >= 1.0
        assert np.max(np.abs(invariant - invariant[0])[:, conditioned], initial=0.0) < 1e-12
        # Each refraction point lies on its interface plane ...
        np.testing.assert_allclose(paths.interface_points[:, ok] @ normal,
                                   np.broadcast_to(rig.port.offsets[:, None],
                                                   (rig.port.n_interfaces, ok.sum())),
                                   atol=1e-9)
        # ... and incoming ray, normal and outgoing ray are coplanar.
        plane_normals = np.cross(directions[:-1], directions[1:])
        assert np.max(np.abs(plane_normals @ normal)) < 1e-12


@given(rigs_and_points())
def test_trace_through_port_obeys_snell_at_every_interface(data):
    rig, points = data
    uv = project(rig.right, rig.port, points)
    rays = rig.right.rays(uv)
    water = trace_through_port(rig.right.center, rays, rig.port)
    vertices = np.concatenate([np.broadcast_to(rig.right.center, (1, len(rays), 3)),
                               water.interface_points, (water.origins + water.directions)[None]])
    directions = np.diff(vertices, axis=0)
    directions /= np.linalg.norm(directions, axis=2, keepdims=True)
    sines = np.linalg.norm(np.cross(directions, rig.port.normal), axis=2)
    invariant = np.asarray(rig.port.indices)[:, None] * sines
    assert np.max(np.abs(invariant - invariant[0])) < 1e-12
    np.testing.assert_allclose(directions[0], rays, atol=1e-12)


@pytest.mark.parametrize("z", [1000.0, 2000.0])
def test_fermat_and_snell_agree_on_the_paper_targets(rig, z):
    points = paper_plane(z)
    for camera in rig.cameras:
        fermat = solve_paths(camera, rig.port, points, "fermat")
        snell = solve_paths(camera, rig.port, points, "snell")
        assert np.all(fermat.is_minimum)
        assert np.max(np.abs(fermat.pixels - snell.pixels)) <= 1e-9


def test_fermat_degenerate_point_on_the_normal_through_the_camera(rig):
    point = np.array([[0.0, 0.0, 1000.0], [200.0, 0.0, 1500.0]])
    paths = solve_paths(rig.left, rig.port, point[:1])
    np.testing.assert_allclose(paths.pixels[0], rig.left.K[:2, 2], atol=1e-12)
    assert paths.is_minimum[0]
    # The right camera's normal foot: the path runs straight along the normal.
    paths = solve_paths(rig.right, rig.port, point[1:])
    np.testing.assert_allclose(paths.interface_points[:, 0, :2], [[200.0, 0.0]] * 2, atol=1e-12)


def test_points_outside_the_water_project_to_nan_with_a_reason(rig):
    points = np.array([[0.0, 0.0, 50.0], [0.0, 0.0, 102.0], [np.nan, 0, 1000], [10.0, 5.0, 900.0]])
    paths = solve_paths(rig.left, rig.port, points)
    assert list(paths.reason) == [Reason.NOT_IN_WATER, Reason.NOT_IN_WATER, Reason.INVALID_INPUT, Reason.OK]
    assert np.isnan(paths.pixels[:3]).all() and np.isfinite(paths.pixels[3]).all()


def test_regular_triangulation_in_air_matches_cv2_triangulatePoints(air_rig):
    points = paper_plane(1000.0)
    uv_left = air_rig.left.project(points)
    uv_right = air_rig.right.project(points)
    ours = triangulate(air_rig, uv_left, uv_right, "regular").points
    right = air_rig.right
    P1 = air_rig.left.K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = right.K @ np.hstack([right.R.T, (-right.R.T @ right.t)[:, None]])
    homogeneous = cv2.triangulatePoints(P1, P2, uv_left.T.copy(), uv_right.T.copy())
    theirs = (homogeneous[:3] / homogeneous[3]).T
    assert np.max(np.linalg.norm(ours - points, axis=1)) <= 1e-9
    assert np.max(np.linalg.norm(ours - theirs, axis=1)) <= 1e-6
    # In air the pinhole projection and the port-aware projection are the same.
    assert np.max(np.abs(project(right, air_rig.port, points) - uv_right)) <= 1e-9


def test_paper_numbers_ideal(rig):
    points = paper_plane(1000.0)
    uv_left, uv_right = project(rig.left, rig.port, points), project(rig.right, rig.port, points)
    errors = {m: np.linalg.norm(triangulate(rig, uv_left, uv_right, m).points - points, axis=1)
              for m in ("optical_path", "su", "regular")}
    assert errors["optical_path"].max() <= 1e-9
    assert errors["su"].max() > 50.0  # paper: "the maximum dP exceeds 50 mm"
    gap = triangulate(rig, uv_left, uv_right, "regular").gap
    assert np.mean(gap > 1e-6) > 0.9  # paper: more than 90 % of the camera rays do not intersect
    assert errors["regular"].max() > 100.0  # ignoring the port is far worse


def test_total_internal_reflection_and_missed_port_are_nan_rows():
    # A camera in a dense medium (index 1.5) looking into index 1.0: steep rays reflect totally.
    port = FlatPort((0, 0, 1), 100.0, (), (1.5, 1.0))
    directions = np.array([[0.0, 0.0, 1.0], [np.sin(1.0), 0.0, np.cos(1.0)], [1.0, 0.0, -0.1]])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    water = trace_through_port(np.zeros(3), directions, port)
    assert list(water.reason) == [Reason.OK, Reason.TOTAL_INTERNAL_REFLECTION, Reason.MISSES_PORT]
    assert np.isfinite(water.origins[0]).all() and np.isnan(water.origins[1:]).all()


def test_diverging_rays_are_behind_the_cameras_and_bad_pixels_are_flagged(rig):
    uv_left = np.array([[10.0, 1000.0], [np.nan, 3.0], [1223.5, 1023.5]])
    uv_right = np.array([[2400.0, 1000.0], [5.0, 3.0], [1223.5, 1023.5]])
    result = triangulate(rig, uv_left, uv_right)
    assert result.reason[0] == Reason.BEHIND_CAMERA and result.reason[1] == Reason.INVALID_INPUT
    assert np.isnan(result.points[:2]).all() and np.isfinite(result.points[2]).all()


def test_triangulate_rejects_bad_arguments(rig):
    with pytest.raises(ValueError, match="method"):
        triangulate(rig, np.zeros((2, 2)), np.zeros((2, 2)), method="magic")
    with pytest.raises(ValueError, match="uv_right"):
        triangulate(rig, np.zeros((2, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="uv_left"):
        triangulate(rig, np.zeros((2, 3)), np.zeros((2, 2)))


def test_large_batches_give_the_same_bytes_as_small_ones(rig):
    rng = np.random.default_rng(7)
    points = np.column_stack([rng.uniform(-300, 300, 70000), rng.uniform(-300, 300, 70000),
                              rng.uniform(900, 1200, 70000)])
    uv_left = project(rig.left, rig.port, points)
    uv_right = project(rig.right, rig.port, points)
    whole = triangulate(rig, uv_left, uv_right).points
    part = triangulate(rig, uv_left[:1000], uv_right[:1000]).points
    assert np.array_equal(whole[:1000], part)
    np.testing.assert_array_equal(project(rig.left, rig.port, points[:1000]), uv_left[:1000])


@given(rigs_and_points())
def test_closed_form_tracing_equals_refracting_interface_by_interface(data):
    # The paper applies equations 4 and 7 at each interface in turn; trace_through_port uses the
    # closed form that parallel interfaces allow. Both must give the same water rays.
    rig, points = data
    rays = rig.left.rays(project(rig.left, rig.port, points))
    position, direction = np.broadcast_to(rig.left.center, rays.shape), rays
    for k, offset in enumerate(rig.port.offsets):
        position, _ = intersect_plane(position, direction, rig.port.normal, offset)
        direction, tir = refract(direction, rig.port.normal, rig.port.indices[k], rig.port.indices[k + 1])
        assert not tir.any()
    water = trace_through_port(rig.left.center, rays, rig.port)
    np.testing.assert_allclose(water.origins, position, atol=1e-9)
    np.testing.assert_allclose(water.directions, direction, atol=1e-14)
