"""The shared flat port of four cameras (measure.calibration.multi_housing) from board corners
projected through the port by the analytic Fermat forward model: the true port from exact
pixels (started 3 mm and 0.5° off), and σ against the spread of the errors over noise draws."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure import FlatPort
from measure.calibration.air import Detections
from measure.calibration.board import Board
from measure.calibration.multi_housing import calibrate_rig_housing
from measure.geometry.projection import project
from measure.stereo.multirig import MultiRig
from measure.geometry.camera import Camera

SIZE = (1224, 1024)
K = np.array([[550.0, 0, 611.5], [0, 550.0, 511.5], [0, 0, 1]])
TRUE_PORT = FlatPort(Rotation.from_rotvec([np.radians(1.0), 0, 0]).apply([0, 0, 1.0]), 100.0,
                     (10.0,), (1.0, 1.49, 1.333))


def _cameras(n=4):
    out = []
    for k in range(n):
        R = Rotation.from_rotvec([0, -np.radians(3.0 * k), 0]).as_matrix()
        out.append(Camera(K, SIZE, np.array([-0.05, 0.02, 0, 0, 0]),
                          None if k == 0 else R, None if k == 0 else np.array([150.0 * k, 0, 0])))
    return out


def _detections(board, cameras, port, rng, noise, n_poses=12):
    corners = board.corners()
    ids, pixels = [], []
    while len(ids) < n_poses:
        R = Rotation.from_rotvec(np.radians(rng.uniform(-25, 25, 3))).as_matrix()
        centre = np.array([rng.uniform(0, 450), rng.uniform(-150, 150), rng.uniform(800, 1300)])
        world = corners @ R.T + centre - R @ np.array([200.0, 140.0, 0])
        row_ids, row_px = [], []
        for camera in cameras:
            uv = project(camera, port, world)
            if camera.in_image(uv, 5.0).all():
                row_ids.append(np.arange(len(corners)))
                row_px.append(uv + rng.normal(0, noise, uv.shape))
            else:
                row_ids.append(np.zeros(0, int))
                row_px.append(np.zeros((0, 2)))
        if sum(len(i) > 0 for i in row_ids) >= 2:
            ids.append(row_ids)
            pixels.append(row_px)
    return Detections(ids, pixels)


def _start(cameras):
    design = TRUE_PORT.replace(normal=np.array([0, 0, 1.0]), distance=103.0)
    return MultiRig(cameras, [design] * len(cameras))


def test_exact_pixels_give_the_true_port():
    board = Board("chessboard", (9, 6), 50.0)
    cameras = _cameras()
    detections = _detections(board, cameras, TRUE_PORT, np.random.default_rng(1), 0.0)
    result = calibrate_rig_housing(_start(cameras), board, detections)
    assert abs(result.estimates["distance"] - TRUE_PORT.distance) < 1e-6
    assert np.linalg.norm(np.cross(result.estimates["normal"], TRUE_PORT.normal)) < 1e-8
    assert result.rms_px < 1e-6 and set(result.rms_px_per) == {"cam0", "cam1", "cam2", "cam3"}


@pytest.mark.slow
def test_sigma_covers_the_errors_of_noisy_corners():
    """0.1 px noise, 8 draws: the errors of D and the two tilts in σ spread like a unit
    normal (|z| ≤ 3 every time, RMS z within 0.6–1.5: a σ off by a factor 1.5 leaves it)."""
    board = Board("chessboard", (9, 6), 50.0)
    cameras = _cameras()
    z = []
    a, b = None, None
    for seed in range(8):
        detections = _detections(board, cameras, TRUE_PORT, np.random.default_rng(10 + seed), 0.1)
        result = calibrate_rig_housing(_start(cameras), board, detections)
        n = np.asarray(result.estimates["normal"])
        a, b = (np.asarray(v) for v in result.normal_axes)
        tilt = [np.dot(n - TRUE_PORT.normal, a), np.dot(n - TRUE_PORT.normal, b)]
        z.append([(result.estimates["distance"] - TRUE_PORT.distance) / result.sigmas["distance"],
                  tilt[0] / result.sigmas["normal"][0], tilt[1] / result.sigmas["normal"][1]])
    z = np.asarray(z)
    assert np.abs(z).max() <= 3.0, z
    assert 0.6 <= np.sqrt(np.mean(z ** 2)) <= 1.5, z


def test_exact_pixels_give_each_cameras_own_port():
    """Three cameras each behind its own port (distances 100, 104 and 97 mm, tilted 1°, 0.5°
    and −0.5°), started all at 103 mm untilted: every port to 1e-6 mm and 1e-8."""
    board = Board("chessboard", (9, 6), 50.0)
    cameras = _cameras(3)
    true = [TRUE_PORT.replace(normal=Rotation.from_rotvec([np.radians(a), np.radians(b), 0])
                              .apply([0, 0, 1.0]), distance=d)
            for a, b, d in ((1.0, 0.0, 100.0), (0.5, 0.3, 104.0), (-0.5, 0.0, 97.0))]
    rig = MultiRig(cameras, true)
    corners = board.corners()
    rng = np.random.default_rng(3)
    ids, pixels = [], []
    while len(ids) < 12:
        R = Rotation.from_rotvec(np.radians(rng.uniform(-25, 25, 3))).as_matrix()
        centre = np.array([rng.uniform(0, 300), rng.uniform(-150, 150), rng.uniform(800, 1300)])
        world = corners @ R.T + centre - R @ np.array([200.0, 140.0, 0])
        row = [project(c, p, world) for c, p in zip(cameras, true)]
        inside = [c.in_image(uv, 5.0).all() for c, uv in zip(cameras, row)]
        if sum(inside) >= 2:
            ids.append([np.arange(len(corners)) if ok else np.zeros(0, int) for ok in inside])
            pixels.append([uv if ok else np.zeros((0, 2)) for uv, ok in zip(row, inside)])
    design = [p.replace(normal=np.array([0, 0, 1.0]), distance=103.0) for p in true]
    result = calibrate_rig_housing(MultiRig(cameras, design), board, Detections(ids, pixels),
                                   per_camera=True)
    assert not result.shared and len(result.estimates["distance"]) == 3
    for k, port in enumerate(true):
        assert abs(result.estimates["distance"][k] - port.distance) < 1e-6
        assert np.linalg.norm(np.cross(result.estimates["normal"][k], port.normal)) < 1e-8
        assert result.rig.ports[k].distance == result.estimates["distance"][k]
    assert result.labels[:3] == ("cam0.distance", "cam1.distance", "cam2.distance")
    assert rig.ports[1] != rig.ports[0]
