"""Scenes of N cameras (synth scene --cameras N): every sensor read back at the pose written,
all behind the one port; a 4-camera render puts each target where the Fermat forward model says
in every view."""

from __future__ import annotations

import numpy as np
import pytest

from measure.geometry.projection import project
from synth.scene import load_scene


def test_cameras_option_writes_a_row_behind_one_port(tmp_path, capsys):
    from synth.__main__ import main

    out = tmp_path / "four.xml"
    assert main(["scene", "--cameras", "4", "--baseline", "150", "--toe-in", "4",
                 "--size", "320", "268", "--out", str(out)]) == 0
    spec = load_scene(out)
    assert spec.camera_names == ("cam0", "cam1", "cam2", "cam3")
    rig = spec.multirig
    for k, camera in enumerate(spec.all_cameras):
        np.testing.assert_allclose(camera.t, [150.0 * k, 0, 0], atol=1e-9)
        axis = camera.R[:, 2]  # turned 4k degrees about y towards the first camera
        np.testing.assert_allclose(axis, [-np.sin(np.radians(4 * k)), 0, np.cos(np.radians(4 * k))],
                                   atol=1e-7)
        assert rig.view_port(k) == spec.rig.port
    assert main(["scene", "--cameras", "3", "--port", "dome", "--dome-radius", "120",
                 "--out", str(tmp_path / "x.xml")]) == 2  # domes that overlap
    assert main(["scene", "--cameras", "1", "--out", str(tmp_path / "x.xml")]) == 2
    assert capsys.readouterr().err.count("error:") == 2


def test_a_ring_round_a_centre_camera(tmp_path, capsys):
    """``--arrangement ring``: cam0 at the origin looking along +z, the others evenly on the
    circle of radius --baseline round its axis, each turned --toe-in degrees towards that axis
    (about the circle's tangent); read back from the scene file."""
    from synth.__main__ import main

    out = tmp_path / "ring.xml"
    assert main(["scene", "--cameras", "5", "--arrangement", "ring", "--baseline", "150",
                 "--toe-in", "6", "--size", "320", "268", "--out", str(out)]) == 0
    spec = load_scene(out)
    cameras = spec.all_cameras
    np.testing.assert_allclose(cameras[0].R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(cameras[0].t, 0, atol=1e-12)
    for k, camera in enumerate(cameras[1:]):
        angle = 2 * np.pi * k / 4
        np.testing.assert_allclose(camera.t, [150 * np.cos(angle), 150 * np.sin(angle), 0],
                                   atol=1e-9)
        inward = -camera.t / np.linalg.norm(camera.t)
        axis = camera.R[:, 2]
        assert np.degrees(np.arccos(axis[2])) == pytest.approx(6.0, abs=1e-7)
        horizontal = axis[:2] / np.linalg.norm(axis[:2])
        np.testing.assert_allclose(horizontal, inward[:2], atol=1e-9)  # towards the axis
        assert np.linalg.det(camera.R) == pytest.approx(1.0)
    assert spec.multirig.view_port(3) == spec.rig.port
    assert main(["scene", "--cameras", "2", "--arrangement", "ring",
                 "--out", str(tmp_path / "x.xml")]) == 2
    assert "--arrangement ring needs --cameras 3" in capsys.readouterr().err


@pytest.mark.slow
def test_every_camera_is_rendered(tmp_path):
    """Tiny render of 3 cameras: the brightest blob of each view is where the forward model
    projects the target nearest that camera's axis (within half a pixel at 320 px)."""
    from synth.__main__ import main
    from synth.rendering.render import render_views

    out = tmp_path / "three.xml"
    assert main(["scene", "--cameras", "3", "--layout", "grid", "--spacing", "300",
                 "--half-width", "300", "--target-radius", "12", "--size", "320", "268",
                 "--out", str(out)]) == 0
    spec = load_scene(out)
    images, info = render_views(spec, spp=16, progress=False)
    assert len(images) == 3 and set(info["render"]) >= {"cam0", "cam1", "cam2"}
    for camera, image in zip(spec.all_cameras, images):
        uv = project(camera, spec.rig.port, spec.targets)
        k = int(np.nanargmin(np.linalg.norm(uv - np.array(camera.size) / 2, axis=1)))
        u, v = np.round(uv[k]).astype(int)
        patch = image[v - 6:v + 7, u - 6:u + 7].astype(float)
        ys, xs = np.mgrid[v - 6:v + 7, u - 6:u + 7]
        centroid = np.array([(patch * xs).sum(), (patch * ys).sum()]) / patch.sum()
        assert np.linalg.norm(centroid - uv[k]) < 0.5
