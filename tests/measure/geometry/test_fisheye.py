"""OpenCV's fisheye model (Kannala–Brandt) in :class:`measure.geometry.camera.Camera` against
OpenCV's own ``cv2.fisheye.projectPoints`` and ``cv2.fisheye.undistortPoints``."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from measure.geometry.camera import FISHEYE, Camera
from measure.reasons import Reason

K = np.array([[820.0, 0.0, 1351.5], [0.0, 818.0, 759.5], [0.0, 0.0, 1.0]])
SIZE = (2704, 1520)
#: a wide lens: k1…k4 of OpenCV's fisheye model
DIST = np.array([0.052, 0.011, 0.006, -0.012])


def _camera(dist=DIST):
    return Camera(K, SIZE, dist=dist, distortion_model=FISHEYE)


def _points(rng, n=2000):
    """Points in front of the camera up to 70° off its axis."""
    theta = rng.uniform(0, np.radians(70), n)
    phi = rng.uniform(0, 2 * np.pi, n)
    depth = rng.uniform(100, 3000, n)
    return np.column_stack([np.tan(theta) * np.cos(phi), np.tan(theta) * np.sin(phi),
                            np.ones(n)]) * depth[:, None]


def test_projection_is_opencvs():
    points = _points(np.random.default_rng(1))
    ours = _camera().project(points)
    theirs = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                                       DIST)[0].reshape(-1, 2)
    assert np.max(np.abs(ours - theirs)) < 1e-9


def test_pixels_come_back_as_opencvs_rays():
    camera = _camera()
    pixels = cv2.fisheye.projectPoints(_points(np.random.default_rng(2)).reshape(-1, 1, 3),
                                       np.zeros(3), np.zeros(3), K, DIST)[0].reshape(-1, 2)
    xy, reason = camera.normalized_with_reason(pixels)
    assert np.all(reason == Reason.OK)
    theirs = cv2.fisheye.undistortPoints(pixels.reshape(-1, 1, 2), K, DIST,
                                         criteria=(3, 100, 1e-15)).reshape(-1, 2)
    assert np.max(np.abs(xy - theirs) / (1 + np.hypot(*theirs.T))[:, None]) < 1e-8
    # ours to machine precision: the round trip through OpenCV's forward model
    back = cv2.fisheye.projectPoints(np.column_stack([xy, np.ones(len(xy))]).reshape(-1, 1, 3),
                                     np.zeros(3), np.zeros(3), K, DIST)[0].reshape(-1, 2)
    assert np.max(np.abs(back - pixels)) < 1e-9


def test_jacobian_is_the_derivative():
    camera = _camera()
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-1.5, 1.5, (2, 500))
    x[:3], y[:3] = (0.0, 1e-9, 0.3), (0.0, 0.0, -2e-9)  # the centre and next to it
    _, _, dxx, dxy, dyy = camera.distort_columns(x, y, jacobian=True)
    h = 1e-6
    for dx, dy, a, b in ((h, 0, dxx, dxy), (0, h, dxy, dyy)):
        plus = camera.distort_columns(x + dx, y + dy)
        minus = camera.distort_columns(x - dx, y - dy)
        np.testing.assert_allclose((plus[0] - minus[0]) / (2 * h), a, atol=1e-7)
        np.testing.assert_allclose((plus[1] - minus[1]) / (2 * h), b, atol=1e-7)


def test_zero_coefficients_are_the_equidistant_projection_not_the_pinhole():
    camera = Camera(K, SIZE, distortion_model=FISHEYE)
    assert camera.dist is not None and not np.any(camera.dist)
    theta = np.radians([10.0, 40.0, 60.0])
    pixels = camera.project(np.column_stack([np.tan(theta), np.zeros(3), np.ones(3)]))
    np.testing.assert_allclose(pixels[:, 0] - K[0, 2], K[0, 0] * theta, rtol=1e-14)


def test_a_folding_lens_is_refused_beyond_its_fold():
    camera = _camera(np.array([-0.4, 0.0, 0.0, 0.0]))  # θ_d(θ) peaks at θ = 0.913 rad
    theta = np.array([0.5, 0.85, 1.0])
    theta_d = theta * (1 - 0.4 * theta ** 2)
    pixels = np.column_stack([K[0, 2] + K[0, 0] * theta_d, np.full(3, K[1, 2])])
    xy, reason = camera.normalized_with_reason(pixels)
    np.testing.assert_allclose(np.arctan(xy[:2, 0]), theta[:2], rtol=1e-12)
    # θ = 1.0 lies beyond the fold: its pixel belongs to θ = 0.81 on the monotone side
    assert reason[2] == Reason.OK and np.arctan(xy[2, 0]) < 0.913
    assert camera.distortion_problem() is not None


@pytest.mark.parametrize("dist", [None, (0.1, 0.0, 0.0, 0.0, 0.0)])
def test_the_model_is_named_not_guessed(dist):
    if dist is None:
        assert Camera(K, SIZE, dist=(0.1, 0.0, 0.0, 0.0)).distortion_model == "brown_conrady"
        with pytest.raises(ValueError, match="choose from"):
            Camera(K, SIZE, distortion_model="kb8")
    else:
        with pytest.raises(ValueError, match="must hold 4"):
            Camera(K, SIZE, dist=dist, distortion_model=FISHEYE)
