"""The edges of the measure API: zero rows, undistortion that cannot converge, value equality,
clear errors for malformed input, port=None meaning no port."""

from __future__ import annotations

import numpy as np
import pytest

from measure import Camera, FlatPort, Reason, StereoRig, triangulate
from measure.stereo.matching import match_targets
from measure.geometry.projection import project
from synth.scene.rig import paper_rig

METHODS = ("optical_path", "su", "regular", "reprojection")


def _distorted_rig(dist=(-0.02, 0.004, 0.0003, -0.0002, 0.0)):
    rig = paper_rig()
    left = Camera(rig.left.K, rig.left.size, dist=dist)
    right = Camera(rig.right.K, rig.right.size, dist=dist, R=rig.right.R, t=rig.right.t)
    return StereoRig(left, right, rig.port)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("distorted", [False, True])
def test_zero_rows_everywhere(method, distorted):
    rig = _distorted_rig() if distorted else paper_rig()
    result = triangulate(rig, np.zeros((0, 2)), np.zeros((0, 2)), method)
    assert result.points.shape == (0, 3) and result.gap.shape == (0,) and result.reason.shape == (0,)
    assert project(rig.left, rig.port, np.zeros((0, 3))).shape == (0, 2)
    assert rig.left.rays(np.zeros((0, 2))).shape == (0, 3)
    matches = match_targets(rig, np.zeros((0, 2)), np.full((3, 2), 1000.0))
    assert matches.left.shape == (0,)


def test_undistortion_round_trips_or_says_not_converged():
    """k1 = -0.1 on the paper rig folds before the image corner: the corner pixel has no
    undistorted position (it used to come back as a ray 199 px away with reason OK)."""
    rig = paper_rig()
    camera = Camera(rig.left.K, rig.left.size, dist=(-0.1, 0, 0, 0, 0))
    pixels = np.array([[2447.0, 2047.0], [1223.5, 1023.5], [900.0, 700.0], [np.nan, 5.0]])
    xy, reason = camera.normalized_with_reason(pixels)
    assert list(reason) == [Reason.NOT_CONVERGED, Reason.OK, Reason.OK, Reason.INVALID_INPUT]
    assert np.all(np.isnan(xy[[0, 3]]))
    ok = reason == Reason.OK
    back = camera.distort(xy[ok]) @ camera.K[:2, :2].T + camera.K[:2, 2]
    assert np.max(np.abs(back - pixels[ok])) < 1e-9
    # The reason reaches the triangulation.
    right = Camera(rig.right.K, rig.right.size, dist=(-0.1, 0, 0, 0, 0), R=rig.right.R, t=rig.right.t)
    result = triangulate(StereoRig(camera, right, rig.port), pixels[:2], pixels[:2])
    assert list(result.reason) == [Reason.NOT_CONVERGED, Reason.OK]
    assert camera.distortion_problem() is not None
    assert _distorted_rig().left.distortion_problem() is None


@pytest.mark.parametrize("dist, fragment", [((np.nan, 0, 0, 0, 0), "finite"),
                                            ((1, 2, 3), "4, 5 or 8")])
def test_bad_distortion_is_refused(dist, fragment):
    with pytest.raises(ValueError, match=fragment):
        Camera(paper_rig().left.K, (2448, 2048), dist=dist)


def test_sizes_must_be_whole_pixels():
    K = paper_rig().left.K
    with pytest.raises(ValueError, match="whole numbers"):
        Camera(K, (100.7, 80.2))
    assert Camera(K, (100.0, 80.0)).size == (100, 80)


@pytest.mark.parametrize("kwargs, fragment", [
    (dict(thicknesses=[[5, 1]]), "thicknesses"),
    (dict(thicknesses="abc"), "thicknesses"),
    (dict(indices=[[1, 1.5, 1.33]]), "indices"),
    (dict(normal=(0, 0)), "normal"),
    (dict(distance="far"), "distance"),
])
def test_flat_port_errors_name_the_argument(kwargs, fragment):
    args = dict(normal=(0, 0, 1), distance=100, thicknesses=(5,), indices=(1, 1.54, 1.33))
    args.update(kwargs)
    with pytest.raises(ValueError, match=fragment):
        FlatPort(**args)


def test_value_equality_and_hash():
    a, b = paper_rig(), paper_rig()
    assert a == b and hash(a) == hash(b) and a.port == b.port and a.left == b.left
    assert a.left != a.right and a != paper_rig(in_air=True)
    assert {a: 1}[b] == 1 and len({a.left, b.left, a.right}) == 2
    assert a.port != a.port.replace(indices=(1.0, 1.54, 1.34))


def test_no_port_means_all_air_and_single_points():
    rig = paper_rig()
    point = np.array([100.0, 50.0, 1000.0])
    assert np.allclose(project(rig.left, None, point), rig.left.project(point[None]), atol=1e-9)
    assert project(rig.left, rig.port, point).shape == (1, 2)
    air = StereoRig(rig.left, rig.right, None)
    assert air.port.indices == (1.0, 1.0)
    uv = [project(c, None, point)[0] for c in (rig.left, rig.right)]
    assert np.allclose(triangulate(air, uv[0], uv[1], "regular").points, point, atol=1e-9)


def test_detector_refuses_values_beyond_float32():
    from measure import detect_targets

    image = np.zeros((60, 60))
    image[20:30, 20:30] = 1e39  # finite in float64, infinite in float32
    with pytest.raises(ValueError, match="float32"):
        detect_targets(image)
    image[20:30, 20:30] = 1e30  # large but representable: found
    assert detect_targets(image).n_found == 1
