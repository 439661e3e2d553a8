"""Shared fixtures and hypothesis strategies for the geometry tests."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from synth.rig import paper_rig

settings.register_profile("ci", deadline=None, max_examples=60,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci")


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
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx
