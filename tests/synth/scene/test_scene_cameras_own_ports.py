"""Scenes of N cameras each behind its own flat port (synth scene --cameras N --port per-camera,
synth.scene.windows for N): each port read back from the file as its own camera's, Mitsuba's
own intersection of every camera's rays with the file's windows (through its own window, then
into the water past every other window), a tiny render whose targets the detector finds where
the Fermat forward model puts them through each camera's own port, a calibration file of such
a rig rendered as it is, and bad input refused in one line."""

from __future__ import annotations

import numpy as np
import pytest

from synth.__main__ import main as synth_main
from synth.scene import load_scene
from tests.conftest import assert_mitsuba_follows

SMALL = (320, 268)
#: Four cameras, each its own port: distance from its centre (mm), tilt about x and about y
#: from its own optical axis (degrees), glass thickness (mm).
DISTANCES, TILT_X, TILT_Y, GLASS = (40, 50, 60, 70), (0, 0, 1, 0), (0, 2, 0, 0), (5, 6, 5, 8)


def _csv(values) -> str:
    return ",".join(str(v) for v in values)


@pytest.fixture(scope="module")
def four_ports(tmp_path_factory):
    path = tmp_path_factory.mktemp("own") / "four.xml"
    assert synth_main(["scene", "--cameras", "4", "--port", "per-camera",
                       "--port-distance", _csv(DISTANCES), "--port-tilt", _csv(TILT_X),
                       _csv(TILT_Y), "--glass-thickness", _csv(GLASS), "--layout", "grid",
                       "--spacing", "150", "--half-width", "600", "--target-radius", "10",
                       "--size", *map(str, SMALL), "--out", str(path)]) == 0
    return path


def test_each_camera_has_its_own_port_as_given(four_ports):
    """FLATPORT's convention per camera: its port's distance from its own centre along its
    normal, its normal tilted from its own optical axis by the angles given."""
    spec = load_scene(four_ports)
    rig = spec.multirig
    assert rig.names == ("cam0", "cam1", "cam2", "cam3") and len(set(rig.ports)) == 4
    for k, camera in enumerate(rig.cameras):
        port = rig.view_port(k)
        assert port.distance - port.normal @ camera.center == pytest.approx(DISTANCES[k],
                                                                            abs=1e-9)
        axis = camera.R[:, 2]
        tilt = max(TILT_X[k], TILT_Y[k])  # one of the two is zero per camera
        assert np.degrees(np.arccos(port.normal @ axis)) == pytest.approx(tilt, abs=1e-9)
        if tilt:  # turned about the camera's own y (or x) axis
            about = camera.R[:, 1] if TILT_Y[k] else camera.R[:, 0]
            turn = np.cross(axis, port.normal)
            assert abs(turn @ about) == pytest.approx(np.linalg.norm(turn), rel=1e-9), k
        assert port.thicknesses == pytest.approx((GLASS[k],), abs=1e-9)
    assert all(p.n_water == 1.34 for p in load_scene(four_ports, {"n_water": 1.34}).multirig.ports)


def test_mitsuba_sees_each_camera_through_its_own_window(four_ports):
    """Rays of each camera's image border and a grid, followed by Mitsuba's ``ray_intersect``
    and the dielectric's transmission: they cross the camera's own port where the port's
    ``trace`` says (float32 precision), and the water ray's next hit is a target (z near 1 m)
    or nothing — never another camera's window."""
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba()
    rig = load_scene(four_ports).multirig
    scene = mi.load_file(str(four_ports))
    w, h = SMALL
    edge_u, edge_v = np.linspace(-0.5, w - 0.5, 81), np.linspace(-0.5, h - 0.5, 67)
    u, v = np.meshgrid(np.linspace(0, w - 1, 9), np.linspace(0, h - 1, 7))
    uv = np.concatenate([np.column_stack([edge_u, np.full_like(edge_u, y)]) for y in (-0.5, h - 0.5)]
                        + [np.column_stack([np.full_like(edge_v, x), edge_v]) for x in (-0.5, w - 0.5)]
                        + [np.column_stack([u.ravel(), v.ravel()])])
    for view, camera in enumerate(rig.cameras):
        d = camera.rays(uv)
        want = rig.view_port(view).trace(camera.center, d, keep_interface_points=True)
        assert_mitsuba_follows(mi, scene, camera, d, want, 3e-4, view)


@pytest.mark.slow
def test_a_render_puts_every_target_where_its_own_port_says(four_ports, tmp_path, capsys):
    """A 16 spp render of the four cameras: ``synth check`` finds every target in every view
    within 0.2 px RMS of the Fermat forward model through that camera's own port."""
    from synth.products.crosscheck import check_dataset
    from synth.products.rig_file import read_rig_file
    from synth.products.dataset import write_dataset

    out = tmp_path / "ds"
    write_dataset(load_scene(four_ports), out, spp=16, progress=False)
    assert read_rig_file(out / "calib.yaml") == load_scene(four_ports).multirig
    report = check_dataset(out, rms_px=0.2, max_px=0.5)
    assert report["views"] == ["cam0", "cam1", "cam2", "cam3"]
    for view in report["views"]:
        r = report[view]
        assert r["in_image"] > 20 and r["found"] == r["in_image"] and not r["missed"], view
        assert r["rms_px"] < 0.2, (view, r["rms_px"])
    assert report["passed"]


def test_a_calibration_file_of_own_ports_is_rendered_as_it_is(four_ports, tmp_path):
    """``synth scene --rig calib.yaml`` of a MultiRig whose cameras each have their own flat
    port: the scene's rig is the file's, port by port."""
    from synth.products.rig_file import write_rig_file

    rig = load_scene(four_ports).multirig
    write_rig_file(tmp_path / "calib.yaml", rig)
    out = tmp_path / "again.xml"
    assert synth_main(["scene", "--rig", str(tmp_path / "calib.yaml"), "--layout", "grid",
                       "--spacing", "150", "--half-width", "600", "--target-radius", "10",
                       "--out", str(out)]) == 0
    again = load_scene(out).multirig
    for k in range(4):
        a, b = again.view_port(k), rig.view_port(k)
        np.testing.assert_allclose(a.normal, b.normal, atol=1e-12)
        assert a.distance == pytest.approx(b.distance, abs=1e-9)
        assert a.thicknesses == pytest.approx(b.thicknesses, abs=1e-12)
        np.testing.assert_allclose(again.cameras[k].center, rig.cameras[k].center, atol=1e-9)


@pytest.mark.parametrize("extra, fragment", [
    (["--port-distance", "40,50"], "needs one value per camera, 4 values"),
    (["--port-distance", "40"], "needs one value per camera, 4 values"),
    (["--glass-thickness", "5,5,5"], "--glass-thickness 5,5,5"),
    (["--port-tilt", "0,0,0,0", "0,0"], "--port-tilt 0,0"),
    (["--port-distance", "150,150,150,150"], "window"),
])
def test_bad_input_is_one_line(tmp_path, capsys, extra, fragment):
    out = tmp_path / "x.xml"
    assert synth_main(["scene", "--cameras", "4", "--port", "per-camera", *extra,
                       "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not out.exists()
