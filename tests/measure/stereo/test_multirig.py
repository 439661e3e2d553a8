"""A rig of N cameras (measure.stereo.multirig): what it refuses, the pair rigs it gives, and
its views, against the Fermat forward model."""

from __future__ import annotations

import numpy as np
import pytest

from measure.geometry.camera import Camera
from measure.geometry.dome import DomePort
from measure.geometry.port import FlatPort
from measure.geometry.projection import project
from measure.stereo.multirig import MultiRig, ViewPorts
from measure.stereo.multiview import triangulate_views
from measure.stereo.triangulate import triangulate

K = np.array([[1100.0, 0, 1223.5], [0, 1100.0, 1023.5], [0, 0, 1.0]])
SIZE = (2448, 2048)
PORT = FlatPort((0, 0, 1), 100.0, (5.0,), (1.0, 1.54, 1.33))


def _row(n, step=200.0, toe_deg=5.0):
    out = []
    for k in range(n):
        a = -np.radians(toe_deg * k)
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        out.append(Camera(K, SIZE, R=R, t=(step * k, 0.0, 0.0)))
    return out


def test_refuses_overlap_glass_and_one_port_for_many():
    cameras = _row(3)
    moved = cameras[:2] + [Camera(K, SIZE, t=cameras[0].t)]
    with pytest.raises(ValueError, match="cameras cam0 and cam2 overlap"):
        MultiRig(moved, [PORT] * 3)
    # cam1 behind its own port, cam2 sitting in cam1's 5 mm glass (z = 102 mm)
    own = FlatPort((0, 0, 1), 100.0, (5.0,), (1.0, 1.54, 1.33))
    inside = cameras[:2] + [Camera(K, SIZE, t=(400.0, 0.0, 102.0))]
    dome = DomePort((400.0, 0.0, 102.0), 50.0, 8.0, (1.0, 1.5, 1.33))
    with pytest.raises(ValueError, match="cam2 centre lies inside cam1's port glass"):
        MultiRig(inside, [None, own.replace(distance=99.0), dome])
    with pytest.raises(ValueError, match="ports: one value where 3 are needed"):
        MultiRig(cameras, PORT)
    with pytest.raises(ValueError, match="no port for cam2"):
        MultiRig(cameras, [PORT, PORT])
    with pytest.raises(ValueError, match="right centre lies on the water side"):
        MultiRig([cameras[0], Camera(K, SIZE, t=(0, 0, 150.0))], [PORT, PORT])


def test_pairs_and_views_reproduce_the_forward_model():
    """A shared port stays the rig's FlatPort in a pair; a dome and a camera in air make a
    pair of their own ports. Every pair triangulates the forward model's pixels back, and so
    do all views together."""
    cameras = _row(4)
    dome = DomePort(cameras[2].center + (1.0, -0.5, 0.8), 60.0, 8.0, (1.0, 1.5, 1.33))
    rig = MultiRig(cameras, [PORT, PORT, dome, None])
    assert rig.pair(0, 1).port == PORT
    assert isinstance(rig.pair(1, 2).port, ViewPorts)
    points = np.column_stack([np.linspace(-200, 500, 20), np.linspace(-300, 300, 20),
                              np.linspace(900, 1400, 20)])
    ports = [PORT, PORT, dome, None]
    pixels = np.stack([project(c, p, points) for c, p in zip(cameras, ports)], axis=1)
    for i, j in ((0, 1), (0, 2), (1, 3), (2, 3)):
        result = triangulate(rig.pair(i, j), pixels[:, i], pixels[:, j])
        assert np.max(np.linalg.norm(result.points - points, axis=1)) < 1e-8
    result = triangulate_views(rig.views(), pixels)
    assert np.max(np.linalg.norm(result.points - points, axis=1)) < 1e-9
