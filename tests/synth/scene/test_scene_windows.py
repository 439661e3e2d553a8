"""Scenes of two housings (synth scene --port per-camera, synth.scene.windows): the ports read
back as each camera's own, and Mitsuba's own intersection of each camera's rays with the file's
windows: through its own window's interfaces, then into the water past the other window."""

from __future__ import annotations

import numpy as np
import pytest

from synth.__main__ import main as synth_main
from synth.scene import load_scene
from tests.conftest import assert_mitsuba_follows

SMALL = (320, 268)


@pytest.fixture(scope="module")
def pair_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("pair") / "pair.xml"
    assert synth_main(["scene", "--port", "per-camera", "--port-distance", "60,80", "--port-tilt",
                       "0,0", "0,2", "--glass-thickness", "5,8", "--size", *map(str, SMALL),
                       "--out", str(path)]) == 0
    return path


def test_each_port_is_given_from_its_own_camera(pair_scene):
    """FLATPORT's convention: each port's distance from its own camera's centre along its
    normal, its normal tilted from its own camera's optical axis."""
    spec = load_scene(pair_scene)
    assert spec.rig.port.kind == "flat pair"
    for view, (distance, tilt, thickness) in enumerate(((60.0, 0.0, 5.0), (80.0, 2.0, 8.0))):
        camera, port = spec.rig.cameras[view], spec.rig.view_port(view)
        assert port.distance - port.normal @ camera.center == pytest.approx(distance, abs=1e-9)
        axis = camera.R[:, 2]
        assert np.degrees(np.arccos(port.normal @ axis)) == pytest.approx(tilt, abs=1e-9)
        assert np.cross(axis, port.normal) @ camera.R[:, 1] >= 0  # tilted about the camera's y
        assert port.thicknesses == pytest.approx((thickness,), abs=1e-9)
    assert load_scene(pair_scene, {"n_water": 1.34}).rig.port.right.indices[-1] == 1.34


def test_mitsuba_sees_each_camera_through_its_own_window(pair_scene):
    """Rays of each camera's image border and a grid, followed by Mitsuba's ``ray_intersect``
    and the dielectric's transmission: they cross the camera's own port where
    ``trace_through_port`` says (float32 precision), and the water ray's next hit is a target
    (z near 1 m) or nothing — never the other window."""
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba()
    spec = load_scene(pair_scene)
    scene = mi.load_file(str(pair_scene))
    w, h = SMALL
    edge_u, edge_v = np.linspace(-0.5, w - 0.5, 81), np.linspace(-0.5, h - 0.5, 67)
    u, v = np.meshgrid(np.linspace(0, w - 1, 9), np.linspace(0, h - 1, 7))
    uv = np.concatenate([np.column_stack([edge_u, np.full_like(edge_u, y)]) for y in (-0.5, h - 0.5)]
                        + [np.column_stack([np.full_like(edge_v, x), edge_v]) for x in (-0.5, w - 0.5)]
                        + [np.column_stack([u.ravel(), v.ravel()])])
    for view, camera in enumerate(spec.rig.cameras):
        d = camera.rays(uv)
        want = spec.rig.view_port(view).trace(camera.center, d)
        assert_mitsuba_follows(mi, scene, camera, d, want, 2e-4)
