"""measure.Camera and measure.FlatPort: conventions, distortion, validation."""

import cv2
import numpy as np
import pytest

from measure import Camera, FlatPort, StereoRig
from synth.scene.rig import paper_intrinsics, paper_port

from tests.conftest import rotation

K = paper_intrinsics()
SIZE = (2448, 2048)


def test_projection_matches_cv2_projectPoints_with_distortion():
    dist = np.array([-0.21, 0.08, 4e-4, -3e-4, -0.012])
    R = rotation(0.02, -0.08, 0.01)
    t = np.array([200.0, 5.0, -3.0])
    camera = Camera(K, SIZE, dist=dist, R=R, t=t)
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(-400, 400, 200), rng.uniform(-300, 300, 200),
                              rng.uniform(800, 1500, 200)])
    rvec, _ = cv2.Rodrigues(R.T)
    expected, _ = cv2.projectPoints(points, rvec, -R.T @ t, K, dist)
    np.testing.assert_allclose(camera.project(points), expected.reshape(-1, 2), atol=1e-9)


@pytest.mark.parametrize("dist", [[-0.3, 0.1, 1e-3, -1e-3], [-0.21, 0.08, 4e-4, -3e-4, -0.012],
                                  [0.1, -0.05, 1e-4, 2e-4, 0.01, 0.05, -0.02, 0.01]])
def test_undistort_inverts_distort_to_machine_precision(dist):
    camera = Camera(K, SIZE, dist=dist)
    grid = np.stack(np.meshgrid(np.linspace(-1.1, 1.1, 41), np.linspace(-0.9, 0.9, 41)), -1)
    xy = grid.reshape(-1, 2)
    recovered = camera.undistort(camera.distort(xy))
    assert np.max(np.abs(recovered - xy)) < 1e-13


def test_principal_point_ray_is_the_optical_axis():
    camera = Camera(K, SIZE, R=rotation(0, -np.deg2rad(5), 0), t=(200, 0, 0))
    ray = camera.rays([[K[0, 2], K[1, 2]]])[0]
    np.testing.assert_allclose(ray, [-np.sin(np.deg2rad(5)), 0, np.cos(np.deg2rad(5))], atol=1e-15)


def test_pixel_centre_convention_and_in_image():
    camera = Camera(K, SIZE)
    assert camera.in_image([[-0.5, -0.5]])[0] and camera.in_image([[2447.5, 2047.5]])[0]
    assert not camera.in_image([[-0.51, 10]])[0] and not camera.in_image([[10, 2047.6]])[0]
    # The image centre of a 2448 x 2048 image is at (1223.5, 1023.5) in OpenCV pixels.
    assert K[0, 2] == 1223.5 and K[1, 2] == 1023.5


def test_points_behind_the_camera_project_to_nan():
    uv = Camera(K, SIZE).project([[0, 0, -100.0], [0, 0, 100.0]])
    assert np.isnan(uv[0]).all() and np.isfinite(uv[1]).all()


@pytest.mark.parametrize("kwargs, name", [
    (dict(K=np.eye(2)), "K"),
    (dict(size=(0, 10)), "size"),
    (dict(dist=[0.1, 0.2, 0.3]), "dist"),
    (dict(R=np.diag([1.0, 1.0, -1.0])), "R"),
    (dict(t=[1.0, 2.0]), "t"),
])
def test_bad_camera_parameters_raise_naming_them(kwargs, name):
    args = dict(K=K, size=SIZE)
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        Camera(**args)


def test_port_normalizes_and_computes_interface_offsets():
    port = FlatPort((0, 0, 2.0), 100.0, (5.0, 3.0), (1.0, 1.54, 1.49, 1.33))
    np.testing.assert_array_equal(port.normal, [0, 0, 1])
    np.testing.assert_array_equal(port.offsets, [100.0, 105.0, 108.0])
    assert port.n_interfaces == 3 and port.n_water == 1.33
    bare = FlatPort((0, 0, 1), 50.0, (), (1.0, 1.33))
    assert bare.n_interfaces == 1


@pytest.mark.parametrize("args, name", [
    (((0, 0, 0), 100.0, (5.0,), (1.0, 1.54, 1.33)), "normal"),
    (((0, 0, 1), 100.0, (-5.0,), (1.0, 1.54, 1.33)), "thicknesses"),
    (((0, 0, 1), 100.0, (5.0,), (1.0, 0.9, 1.33)), "indices"),
    (((0, 0, 1), 100.0, (5.0,), (1.0, 1.33)), "indices"),
    (((0, 0, 1), float("nan"), (5.0,), (1.0, 1.54, 1.33)), "distance"),
])
def test_bad_port_parameters_raise_naming_them(args, name):
    with pytest.raises(ValueError, match=name):
        FlatPort(*args)


def test_camera_on_the_water_side_is_rejected():
    left = Camera(K, SIZE)
    right = Camera(K, SIZE, t=(200.0, 0.0, 150.0))
    with pytest.raises(ValueError, match="right camera.*water side"):
        StereoRig(left, right, paper_port())


@pytest.mark.parametrize("k1", [-5.0, -2.0])
def test_a_folding_distortion_names_the_radius_where_it_folds(k1):
    """r_d = r (1 + k1 r²) with k1 < 0 turns back at r = 1/√(-3 k1): the problem names that
    radius (in pixels from the principal point, to the checked grid's step)."""
    import re

    from measure.geometry.camera import DISTORTION_CHECK_STEP_PX

    f = 150.0
    camera = Camera([[f, 0, 159.5], [0, f, 133.5], [0, 0, 1]], (320, 268),
                    dist=(k1, 0, 0, 0, 0))
    problem = camera.distortion_problem()
    assert problem is not None and "folds within the 320x268 image" in problem
    radius = float(re.search(r"about (\d+) px from the principal point", problem).group(1))
    r = 1.0 / np.sqrt(-3.0 * k1)
    fold_px = f * r * (1.0 + k1 * r * r)
    assert abs(radius - fold_px) <= DISTORTION_CHECK_STEP_PX * np.sqrt(2) + 0.5
    # k1 > 0 never folds (r (1 + k1 r²) grows with r): nothing to refuse.
    assert Camera(camera.K, (320, 268), dist=(-k1, 0, 0, 0, 0)).distortion_problem() is None
