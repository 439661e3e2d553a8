"""measure.geometry.dome_projection: the forward projection through a dome, its two solvers and its
analytic Jacobians (through measure.geometry.projection.project / solve_paths)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure import Camera, Reason
from measure.geometry.dome import DomePair, DomePort, trace_through_dome
from measure.geometry.projection import project, solve_paths

INDICES = (1.0, 1.49, 1.33)
K = np.array([[1200.0, 0.5, 640.0], [0.0, 1180.0, 480.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.1, 0.02, 0.001, -0.0005, 0.003])


def _camera(seed=0, dist=DIST):
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(rng.normal(scale=0.05, size=3)).as_matrix()
    return Camera(K, (1280, 960), dist=dist, R=R, t=rng.normal(scale=2.0, size=3))


def _points(camera, n=300, seed=0):
    """Points in front of the camera, 0.3 to 2 m away, inside its image."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform((0, 0), (1279, 959), size=(n, 2))
    return camera.center + camera.rays(uv) * rng.uniform(300.0, 2000.0, size=(n, 1))


def _point_to_ray(points, camera, pixels, dome):
    rays = trace_through_dome(camera.center, camera.rays(pixels), dome)
    offset = points - rays.origins
    along = np.einsum("ij,ij->i", offset, rays.directions)
    return np.linalg.norm(offset - along[:, None] * rays.directions, axis=1)


DECENTRINGS = [np.zeros(3), *np.random.default_rng(7).normal(scale=3.0, size=(4, 3))]


@pytest.mark.parametrize("decentring", DECENTRINGS)
@pytest.mark.parametrize("solver", ["fermat", "shooting"])
def test_backward_of_forward_passes_through_the_point(decentring, solver):
    camera = _camera(1)
    dome = DomePort(camera.center + decentring, 50.0, 8.0, INDICES)
    points = _points(camera)
    paths = solve_paths(camera, dome, points, solver)
    assert np.all(paths.reason == Reason.OK)
    assert np.all(paths.is_minimum)
    assert _point_to_ray(points, camera, paths.pixels, dome).max() <= 1e-9
    # the interface points lie on their spheres
    for k, r in enumerate(dome.radii):
        np.testing.assert_allclose(np.linalg.norm(paths.interface_points[k] - dome.center,
                                                  axis=1), r, rtol=1e-14)


@pytest.mark.parametrize("decentring", DECENTRINGS[1:])
def test_the_two_solvers_agree(decentring):
    camera = _camera(2)
    dome = DomePort(camera.center + decentring, 60.0, 10.0, INDICES)
    points = _points(camera, seed=3)
    fermat = project(camera, dome, points, "fermat")
    shooting = project(camera, dome, points, "shooting")
    assert np.all(np.isfinite(fermat))
    assert np.abs(fermat - shooting).max() <= 1e-9
    # a decentred dome does bend the rays: the pinhole projection is off
    assert np.abs(fermat - camera.project(points)).max() > 1e-2


def test_a_centred_dome_is_the_pinhole_camera():
    """Every ray through the common centre is radial: the dome bends none of them."""
    camera = _camera(3)
    dome = DomePort(camera.center, 50.0, 8.0, INDICES)
    points = _points(camera)
    for solver in ("fermat", "shooting"):
        np.testing.assert_allclose(project(camera, dome, points, solver), camera.project(points),
                                   rtol=0, atol=1e-9)


def test_points_not_in_the_water_and_bad_input_are_nan_with_a_reason():
    camera = _camera(4, dist=None)
    dome = DomePort(camera.center + (1.0, -2.0, 4.0), 50.0, 8.0, INDICES)
    points = np.array([dome.center + (0.0, 0.0, 55.0),  # in the glass
                       dome.center + (0.0, 10.0, 20.0),  # inside the dome
                       [np.nan, 0.0, 500.0],
                       camera.center + (0.0, 0.0, -500.0),  # behind the camera
                       camera.center + (10.0, 20.0, 500.0)])
    for solver in ("fermat", "shooting"):
        paths = solve_paths(camera, dome, points, solver)
        assert paths.reason.tolist() == [Reason.NOT_IN_WATER, Reason.NOT_IN_WATER,
                                         Reason.INVALID_INPUT, Reason.BEHIND_CAMERA, Reason.OK]
        assert np.isnan(paths.pixels[:4]).all() and np.isfinite(paths.pixels[4]).all()
    assert project(camera, dome, np.zeros((0, 3))).shape == (0, 2)


def test_a_camera_outside_its_dome_and_unknown_solvers_are_refused():
    camera = _camera(5)
    with pytest.raises(ValueError, match="camera centre lies outside its dome"):
        project(camera, DomePort(camera.center + (0, 0, 60.0), 50.0, 8.0, INDICES),
                [0, 0, 900.0])
    with pytest.raises(ValueError, match="solver must be one of fermat, shooting"):
        project(camera, DomePort(camera.center, 50.0, 8.0, INDICES), [0, 0, 900.0], "snell")


def _central(function, x0, step):
    columns = []
    for j in range(len(x0)):
        e = np.zeros(len(x0))
        e[j] = step
        columns.append((function(x0 + e) - function(x0 - e)) / (2 * step))
    return np.stack(columns, axis=-1)


def _relative(analytic, numeric):
    return np.abs(analytic - numeric).max() / np.abs(numeric).max()


def _matches(analytic, numeric, centred):
    """Relative agreement; for a centred dome, where the radius, thickness and indices bend
    no ray (their derivatives vanish), both must be zero to rounding instead (the central
    difference to the rounding of pixels near 1e3 px over a 2e-5 step, ~1e-8 px/unit)."""
    if centred:
        return np.abs(analytic).max() <= 1e-9 and np.abs(numeric).max() <= 1e-7
    return _relative(analytic, numeric) <= 1e-6


@pytest.mark.parametrize("centred", [False, True])
def test_analytic_jacobians_match_central_differences(centred):
    camera = _camera(6)
    dome = DomePort(camera.center + (0.0 if centred else np.array([2.0, -1.0, 3.0])), 50.0,
                    8.0, (1.0001, 1.49, 1.33))
    points = _points(camera, n=40, seed=6)
    pixels, d_points, jac = project(camera, dome, points, parameters=True)
    _, d_points_only = project(camera, dome, points, jacobian=True)
    np.testing.assert_array_equal(d_points, d_points_only)
    numeric = _central(lambda p: project(camera, dome, points + p), np.zeros(3), 1e-4)
    assert _relative(d_points, numeric) <= 1e-6
    numeric = _central(lambda c: project(camera, dome.replace(center=c), points), dome.center,
                       1e-5)
    assert _relative(jac.dome_center, numeric) <= 1e-6
    for name in ("radius", "thickness"):
        numeric = _central(lambda v: project(camera, dome.replace(**{name: v[0]}), points),
                           np.array([getattr(dome, name)]), 1e-5)[..., 0]
        assert _matches(getattr(jac, name), numeric, centred), name
    numeric = _central(lambda n: project(camera, dome.replace(indices=tuple(n)), points),
                       np.array(dome.indices), 1e-6)
    assert _matches(jac.indices, numeric, centred)
    numeric = _central(lambda t: project(Camera(K, camera.size, camera.dist, camera.R, t), dome,
                                         points), camera.t, 1e-5)
    assert _relative(jac.center, numeric) <= 1e-6

    def rotated(phi):
        R = Rotation.from_rotvec(phi).as_matrix() @ camera.R
        return project(Camera(K, camera.size, camera.dist, R, camera.t), dome, points)

    assert _relative(jac.rotation, _central(rotated, np.zeros(3), 1e-7)) <= 1e-6


def test_a_point_on_the_line_through_both_centres_is_seen_straight():
    """Camera centre, dome centre and point collinear (the plane of the path undefined): the
    path is the straight line, the pixel the pinhole one."""
    camera = _camera(7)
    dome = DomePort(camera.center + (0.6, -0.4, 1.5), 50.0, 8.0, INDICES)
    axis = (dome.center - camera.center) / np.linalg.norm(dome.center - camera.center)
    points = camera.center + np.outer([400.0, 900.0, 1500.0], axis)
    for solver in ("fermat", "shooting"):
        np.testing.assert_allclose(project(camera, dome, points, solver),
                                   camera.project(points), rtol=0, atol=1e-9)


def test_rows_do_not_depend_on_their_batch_and_empty_batches_work():
    """Chunked batches (more than one chunk of rows) give each row what it gets alone, to a
    few units in the last place of the pixel coordinates' scale (the principal point, ~1000
    px): NumPy's vector loops of the transcendental functions and its one-element path may
    differ in the last bit (NumPy 2.4.6 here: row 39999, the last of the second chunk, y off by
    1.1e-13 px, one ulp at 512–1024); a row mixed up between chunks would be pixels off."""
    camera = _camera(8)
    dome = DomePort(camera.center + (2.0, 1.0, -3.0), 50.0, 8.0, INDICES)
    points = _points(camera, n=40000, seed=8)
    pixels = project(camera, dome, points)
    for k in (0, 12345, 39999):
        np.testing.assert_allclose(project(camera, dome, points[k]), pixels[k:k + 1],
                                   rtol=0, atol=4 * np.spacing(1024.0))
    for solver in ("fermat", "shooting"):
        empty = project(camera, dome, np.zeros((0, 3)), solver, parameters=True)
        assert empty[0].shape == (0, 2) and empty[1].shape == (0, 2, 3)
        assert empty[2].dome_center.shape == (0, 2, 3) and empty[2].radius.shape == (0, 2)


def test_a_dome_pair_is_not_a_port_of_one_camera():
    camera = _camera(9)
    dome = DomePort(camera.center, 50.0, 8.0, INDICES)
    with pytest.raises(ValueError, match=r"DomePair holds one port per camera, domes: pass "
                                         r"rig.view_port\(view\)"):
        project(camera, DomePair(dome, dome), [0.0, 0.0, 900.0])
