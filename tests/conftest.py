"""Shared fixtures and hypothesis strategies for the geometry tests."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from synth.rig import paper_rig

settings.register_profile("ci", deadline=None, max_examples=60,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci")


SMALL_SCENE_SIZE = (320, 268)
SMALL_SCENE_SPP = 36


@pytest.fixture(scope="session")
def small_scene(tmp_path_factory):
    """A small scene file: the paper's port, a 320x268 rig (f = 150 px), 9x9 targets of radius
    16 mm, 80 mm apart on the plane Z = 1 m."""
    from synth.layouts import grid_plane
    from synth.rig import paper_cameras, paper_port
    from synth.scene import write_scene

    left, right = paper_cameras(SMALL_SCENE_SIZE, 150.0)
    targets = grid_plane(1000.0, 320.0, 80.0) + np.array([3.0, -2.0, 0.0])
    path = tmp_path_factory.mktemp("scene") / "small.xml"
    return str(write_scene(path, (left, right), paper_port(), targets, 16.0, spp=SMALL_SCENE_SPP))


@pytest.fixture(scope="session")
def rig():
    """The paper's rig behind the paper's port (full-size images)."""
    return paper_rig()


@pytest.fixture(scope="session")
def air_rig():
    """The same cameras with an index-matched (all-air) port."""
    return paper_rig(in_air=True)


def rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation matrix from small angles about x, y, z (radians), R = Rz Ry Rx."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", [rz, ry, rx]).as_matrix()
