"""The optical path of N views (measure.stereo.multiview) against the Fermat forward model:
points projected into 2–13 cameras, each behind a shared flat port, its own flat port, its own
decentred dome or no port, come back to within 1e-9 mm."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure.geometry.camera import BROWN_CONRADY, FISHEYE, Camera
from measure.geometry.dome import DomePort
from measure.geometry.port import FlatPort, index_matched_port
from measure.geometry.projection import project
from measure.reasons import Reason
from measure.stereo.multiview import View, triangulate_views
from measure.stereo.triangulate import StereoRig, triangulate

SIZE, FOCAL = (2448, 2048), 1100.0
K = np.array([[FOCAL, 0, 1223.5], [0, FOCAL, 1023.5], [0, 0, 1.0]])
GLASS = (1.0, 1.54, 1.33)


def _ring(count, rng, model=BROWN_CONRADY):
    """``count`` cameras on an arc of radius 700 mm (0.3 rad apart, at most 1.2 rad in all),
    each turned towards a point 1.5 m ahead, with a little lens distortion of ``model``."""
    cameras = []
    for k in range(count):
        angle = (k - (count - 1) / 2) * min(0.3, 1.2 / max(count - 1, 1))
        centre = np.array([700 * np.sin(angle), 30 * np.cos(2 * angle), 700 * (1 - np.cos(angle))])
        forward = np.array([0, 0, 1500.0]) - centre
        z = forward / np.linalg.norm(forward)
        x = np.cross([0, 1, 0], z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z])
        dist = rng.normal(0, [0.05, 0.02, 0.0005, 0.0005] if model == BROWN_CONRADY
                          else [0.05, 0.02, 0.005, 0.002])
        cameras.append(Camera(K, SIZE, dist=dist, R=R, t=centre, distortion_model=model))
    return cameras


def _ports(cameras, mix, rng):
    """One port per camera: ``shared`` one flat port for all, ``own`` a flat port each (its
    distance and tilt differing), ``dome`` a decentred dome each, ``air`` none, or ``mixed``
    (shared flat, own flat, dome and air in turn)."""
    shared = FlatPort([0.0, 0.0, 1.0], 520.0, (8.0,), GLASS)
    out = []
    for k, camera in enumerate(cameras):
        kind = mix if mix != "mixed" else ("shared", "own", "dome", "air")[k % 4]
        axis = camera.R[:, 2]
        if kind == "shared":
            out.append(shared)
        elif kind == "own":
            tilt = Rotation.from_rotvec(np.radians(rng.uniform(-2, 2, 3))).as_matrix() @ axis
            out.append(FlatPort(tilt, float(tilt @ camera.center + rng.uniform(60, 120)),
                                (float(rng.uniform(5, 12)),), GLASS))
        elif kind == "dome":
            out.append(DomePort(camera.center + rng.normal(0, 1.5, 3), 60.0, 9.0, GLASS))
        else:
            out.append(index_matched_port(axis, camera.center[None]))
    return out


def _targets(rng, n=300):
    return np.column_stack([rng.uniform(-350, 350, n), rng.uniform(-300, 300, n),
                            rng.uniform(1100, 2000, n)])


@pytest.mark.parametrize("count,mix,model", [(2, "shared", BROWN_CONRADY),
                                             (3, "own", BROWN_CONRADY), (4, "dome", BROWN_CONRADY),
                                             (5, "air", BROWN_CONRADY), (7, "mixed", BROWN_CONRADY),
                                             (13, "mixed", BROWN_CONRADY), (4, "mixed", FISHEYE)])
def test_ideal_pixels_come_back_exactly(count, mix, model):
    rng = np.random.default_rng(count)
    cameras = _ring(count, rng, model)
    ports = _ports(cameras, mix, rng)
    points = _targets(rng)
    pixels = np.stack([project(c, p, points) for c, p in zip(cameras, ports)], axis=1)
    inside = (pixels[..., 0] >= -0.5) & (pixels[..., 0] <= SIZE[0] - 0.5) & (
        pixels[..., 1] >= -0.5) & (pixels[..., 1] <= SIZE[1] - 0.5)
    pixels[~inside] = np.nan
    result = triangulate_views([View(c, p) for c, p in zip(cameras, ports)], pixels)
    seen = inside.sum(axis=1)
    assert np.array_equal(result.valid, seen >= 2)
    assert (seen >= 2).mean() > 0.9
    np.testing.assert_array_equal(result.views[result.valid], seen[result.valid])
    error = np.linalg.norm(result.points[result.valid] - points[result.valid], axis=1)
    assert error.max() <= 1e-9
    assert np.nanmax(result.gap) <= 1e-9


def test_two_views_are_the_papers_optical_path():
    """With two views the least-squares point is the common perpendicular's midpoint: the same
    as the stereo triangulator's optical path, and the gap half its length."""
    rng = np.random.default_rng(2)
    left, right = _ring(2, rng)
    port = FlatPort([0.0, 0.0, 1.0], 520.0, (8.0,), GLASS)
    # pixels off the exact projections: rays that do not meet
    points = _targets(rng)
    uv = [project(c, port, points) + rng.normal(0, 0.3, (len(points), 2)) for c in (left, right)]
    # the stereo triangulator wants the left camera at the origin: move the frame
    to_left = lambda X: (X - left.center) @ left.R  # noqa: E731
    rig = StereoRig(Camera(K, SIZE, dist=left.dist),
                    Camera(K, SIZE, dist=right.dist, R=left.R.T @ right.R,
                           t=to_left(right.center[None])[0]),
                    FlatPort(left.R.T @ port.normal, port.distance - port.normal @ left.center,
                             port.thicknesses, port.indices))
    stereo = triangulate(rig, uv[0], uv[1])
    multi = triangulate_views([View(left, port), View(right, port)], np.stack(uv, axis=1))
    np.testing.assert_allclose(to_left(multi.points), stereo.points, atol=1e-8)
    np.testing.assert_allclose(multi.gap, stereo.gap / 2, rtol=1e-9, atol=1e-12)


def test_one_view_is_reported_never_triangulated():
    rng = np.random.default_rng(4)
    cameras = _ring(3, rng)
    ports = _ports(cameras, "own", rng)
    points = _targets(rng, 5)
    pixels = np.stack([project(c, p, points) for c, p in zip(cameras, ports)], axis=1)
    pixels[0, 1:] = np.nan  # only camera 0 saw target 0
    pixels[1, 0] = np.nan  # two views left for target 1
    pixels[2, :, :] = np.nan
    result = triangulate_views([View(c, p) for c, p in zip(cameras, ports)], pixels)
    assert result.reason[0] == Reason.TOO_FEW_VIEWS and np.all(np.isnan(result.points[0]))
    assert result.reason[2] == Reason.TOO_FEW_VIEWS
    assert result.valid[1] and result.views[1] == 2
    assert np.linalg.norm(result.points[1] - points[1]) < 1e-9
    with pytest.raises(ValueError, match=r"shape \(N, 3, 2\)"):
        triangulate_views([View(c, p) for c, p in zip(cameras, ports)], pixels[:, :2])
