"""Vignetting maps against their closed forms: cos⁴ of the pixel's ray angle (with and
without lens distortion) and the lens falloff's quadratic."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from measure import Camera
from synth.rendering.camera_effects import (cos4_map, lens_falloff_map, pixel_grid,
                                            vignetting_map)

K = np.array([[300.0, 0.0, 170.2], [0.0, 300.0, 118.7], [0.0, 0.0, 1.0]])
SIZE = (320, 240)


def test_cos4_of_a_pinhole_is_that_of_atan_r_over_f():
    uv = pixel_grid(SIZE)
    r = np.hypot(uv[:, 0] - K[0, 2], uv[:, 1] - K[1, 2])
    expected = np.cos(np.arctan(r / 300.0)) ** 4
    np.testing.assert_allclose(cos4_map(Camera(K, SIZE)).ravel(), expected, atol=1e-12)


def test_cos4_follows_the_distorted_ray_not_the_pixel_radius():
    """With barrel distortion the corner's ray is farther off axis than its pixel radius says:
    cos⁴ of the angle of OpenCV's undistorted normalized point."""
    dist = np.array([-0.2, 0.05, 0.0, 0.0, 0.0])
    camera = Camera(K, SIZE, dist=dist)
    uv = pixel_grid(SIZE)
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, dist, None, None, None,
                                 (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))
    expected = (1.0 / (1.0 + np.sum(xy.reshape(-1, 2) ** 2, axis=1))) ** 2  # cos² θ squared
    np.testing.assert_allclose(cos4_map(camera).ravel(), expected, atol=1e-9)
    assert cos4_map(camera)[0, 0] < cos4_map(Camera(K, SIZE))[0, 0] - 0.01


def test_lens_falloff_keeps_one_minus_f_at_the_farthest_corner():
    falloff = lens_falloff_map(Camera(K, SIZE), 0.4)
    assert falloff.min() == pytest.approx(0.6, abs=1e-12)
    assert np.unravel_index(np.argmin(falloff), falloff.shape) == (239, 0)  # farthest corner
    assert falloff[119, 170] == pytest.approx(1 - 0.4 * (0.2 ** 2 + 0.3 ** 2)
                                              / (170.2 ** 2 + (239 - 118.7) ** 2), abs=1e-12)
    with pytest.raises(ValueError, match="lens falloff"):
        lens_falloff_map(Camera(K, SIZE), 1.0)


def test_vignetting_is_the_product_or_nothing():
    camera = Camera(K, SIZE)
    assert vignetting_map(camera) is None
    np.testing.assert_allclose(vignetting_map(camera, True, 0.3),
                               cos4_map(camera) * lens_falloff_map(camera, 0.3), rtol=1e-6)
