"""Two housings (measure.geometry.flat_pair.FlatPair): each camera behind its own flat port —
triangulation against the Fermat forward model through each camera's own port, the rig checks,
and the pixel Jacobians of each port's parameters against central differences of the model."""

from __future__ import annotations

import numpy as np
import pytest

from measure import Camera, FlatPort, StereoRig, triangulate
from measure.geometry.flat_pair import FlatPair
from measure.geometry.projection import project
from measure.stereo.uncertainty import perturbed_rig, pixel_jacobians
from synth.scene.rig import paper_cameras, tilted_port_normal


def _port(camera, distance, tilt_deg, thickness, n_glass):
    """A port ``distance`` mm in front of ``camera`` along its normal, tilted about y from the
    camera's optical axis (the refractive COLMAP fork's FLATPORT, in the reference frame)."""
    normal = camera.R @ tilted_port_normal(0.0, tilt_deg)
    return FlatPort(normal, distance + normal @ camera.center, (thickness,), (1.0, n_glass, 1.33))


def _rig():
    left, right = paper_cameras()
    pair = FlatPair(_port(left, 60.0, 0.0, 5.0, 1.54), _port(right, 80.0, 2.0, 8.0, 1.49))
    return StereoRig(left, right, pair)


def _points(n=300, seed=3):
    rng = np.random.default_rng(seed)
    return rng.uniform((-400.0, -300.0, 500.0), (600.0, 300.0, 2500.0), size=(n, 3))


def test_optical_path_through_two_housings_meets_the_fermat_model():
    rig, points = _rig(), _points()
    uv = [project(camera, rig.view_port(view), points) for view, camera in enumerate(rig.cameras)]
    # each camera has its own port: the right pixels are not those through the left port
    assert np.min(np.linalg.norm(uv[1] - project(rig.right, rig.port.left, points), axis=1)) > 1
    for method in ("optical_path", "reprojection"):
        result = triangulate(rig, uv[0], uv[1], method)
        assert np.all(result.valid)
        assert np.max(np.abs(result.points - points)) <= 1e-9, method
    assert np.max(triangulate(rig, uv[0], uv[1]).gap) <= 1e-9


def test_two_equal_ports_are_the_shared_port():
    """The general per-view path through a pair of the same port agrees with the shared port's
    fused closed form (another code path) on noisy pixels, where the rays do not meet."""
    left, right = paper_cameras()
    port = _port(left, 100.0, 1.0, 5.0, 1.54)
    shared, pair = StereoRig(left, right, port), StereoRig(left, right, FlatPair(port, port))
    rng = np.random.default_rng(0)
    points = _points(200)
    uv = [project(c, port, points) + rng.normal(0.0, 0.3, (200, 2)) for c in (left, right)]
    a, b = triangulate(shared, *uv), triangulate(pair, *uv)
    np.testing.assert_allclose(b.points, a.points, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.gap, a.gap, rtol=0, atol=1e-9)


def test_a_camera_inside_the_other_ports_glass_is_refused():
    left = Camera(np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]]), (640, 480))
    right = Camera(left.K, (640, 480), t=(200.0, 0.0, 62.0))  # in the left port's glass (60–65)
    ports = FlatPair(_port(left, 60.0, 0.0, 5.0, 1.54), _port(right, 30.0, 0.0, 5.0, 1.54))
    with pytest.raises(ValueError, match=r"^right camera centre lies inside the left port's "
                                         r"glass \(normal·centre = 62 mm"):
        StereoRig(left, right, ports)
    with pytest.raises(ValueError, match="^right camera centre lies on the water side"):
        StereoRig(left, right, FlatPair(ports.left, _port(left, 40.0, 0.0, 5.0, 1.54)))


NAMES = ("left.port.distance", "right.port.distance", "left.port.tilt[0]", "right.port.tilt[1]",
         "right.port.thickness[0]", "left.port.index[1]", "port.index[2]", "right.center[0]")


def test_pixel_jacobians_of_each_port_are_the_derivatives_of_the_model():
    rig, points = _rig(), _points(20)
    axes = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    _, _, analytic = pixel_jacobians(rig, points, NAMES, axes)
    for k, name in enumerate(NAMES):
        step = np.zeros(len(NAMES))
        step[k] = 1e-6
        pixels = []
        for sign in (1.0, -1.0):
            moved = perturbed_rig(rig, NAMES, sign * step, axes)
            pixels.append(np.concatenate([project(c, moved.view_port(v), points)
                                          for v, c in enumerate(moved.cameras)], axis=1))
        numeric = (pixels[0] - pixels[1]) / 2e-6
        assert np.max(np.abs(numeric)) > 0.01, name
        np.testing.assert_allclose(analytic[:, :, k], numeric, rtol=0, atol=1e-5, err_msg=name)
    # a left-port parameter moves only the left pixels, and the reverse
    assert not np.any(analytic[:, 2:, 0]) and not np.any(analytic[:, :2, 1])


@pytest.mark.parametrize("rig, names, word", [
    (_rig(), ["port.distance"], "parameters of one shared port"),
    (StereoRig(*paper_cameras(), _port(paper_cameras()[0], 100.0, 0.0, 5.0, 1.54)),
     ["left.port.distance"], "parameters of a port per camera"),
])
def test_covariance_names_of_the_other_kind_are_refused(rig, names, word):
    with pytest.raises(ValueError, match=word):
        pixel_jacobians(rig, _points(3), names)
