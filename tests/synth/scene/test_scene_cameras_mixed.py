"""Scenes of cameras with different kinds of port (synth scene --port mixed --ports K0,K1,…,
synth.scene.mixed): every camera's port read back from the file as the options built it (a
window two cameras share written once), Mitsuba's own intersection of every camera's rays with
the file's glass (through its own port, then into the water past every other glass; a camera in
air straight to the targets), small eval runs that render every camera and measure it, a
calibration file of such a rig rendered as it is, and bad lists refused in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from measure import FlatPort
from measure.geometry.dome import DomePort
from synth.__main__ import main as synth_main
from synth.scene import load_scene, write_scene
from tests.conftest import assert_mitsuba_follows

SMALL = (320, 268)
INDICES = (1.0, 1.54, 1.33)
GRID = ["--layout", "grid", "--spacing", "150", "--half-width", "600", "--target-radius", "10",
        "--size", *map(str, SMALL)]
#: Two cameras behind one shared window, a dome, a window of its own.
SHARED_DOME_OWN = "paper,paper,dome,per-camera"
#: A dome, a window of its own, a (one-camera) flat port of the shared kind, a camera in air.
DOME_OWN_PAPER_AIR = "dome,per-camera,paper,none"


def _scene(tmp_path_factory, ports: str, name: str):
    path = tmp_path_factory.mktemp("mixed") / f"{name}.xml"
    assert synth_main(["scene", "--cameras", "4", "--port", "mixed", "--ports", ports,
                       "--port-distance", "40", *GRID, "--out", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def shared_dome_own(tmp_path_factory):
    return _scene(tmp_path_factory, SHARED_DOME_OWN, "shared_dome_own")


@pytest.fixture(scope="module")
def dome_own_paper_air(tmp_path_factory):
    return _scene(tmp_path_factory, DOME_OWN_PAPER_AIR, "dome_own_paper_air")


def test_every_camera_gets_its_own_kind_of_port_back(shared_dome_own, dome_own_paper_air):
    """paper: the flat port of --port-distance 40 along the first camera's axis, shared;
    per-camera: 40 mm along the camera's own axis (its own window); dome: centred on the
    camera; none: in air. The window cam0 and cam1 share is one glass in the file."""
    for path, kinds in ((shared_dome_own, SHARED_DOME_OWN), (dome_own_paper_air,
                                                            DOME_OWN_PAPER_AIR)):
        spec = load_scene(path)
        rig = spec.multirig
        assert rig.names == ("cam0", "cam1", "cam2", "cam3") and spec.has_port
        for kind, camera, port in zip(kinds.split(","), rig.cameras, rig.ports):
            if kind == "none":
                assert port is None
            elif kind == "dome":
                assert isinstance(port, DomePort) and port.indices == INDICES
                np.testing.assert_allclose(port.center, camera.center, atol=1e-9)
            else:
                assert isinstance(port, FlatPort) and port.indices == pytest.approx(INDICES)
                axis = (0.0, 0.0, 1.0) if kind == "paper" else camera.R[:, 2]
                np.testing.assert_allclose(port.normal, axis, atol=1e-12)
                # per-camera: 40 mm from its own centre; paper: 40 mm from the reference's
                from_centre = 40.0 if kind == "per-camera" else 40.0 - port.normal @ camera.center
                assert port.distance - port.normal @ camera.center == pytest.approx(from_centre,
                                                                                    abs=1e-9)
                assert port.thicknesses == pytest.approx((5.0,), abs=1e-9)
        assert spec.camera_ports == spec.ports
    shared = load_scene(shared_dome_own).multirig
    assert shared.ports[0] == shared.ports[1] != shared.ports[3]
    text = shared_dome_own.read_text()
    assert text.count('id="cam0_cam1_interface_') == 2 and 'id="cam0_interface_' not in text
    assert text.count('id="cam3_interface_') == 2 and text.count('id="dome_cam2_') == 2
    assert all(p.n_water == 1.34 for p in load_scene(shared_dome_own, {"n_water": 1.34})
               .multirig.ports)


def _border_and_grid():
    w, h = SMALL
    edge_u, edge_v = np.linspace(-0.5, w - 0.5, 81), np.linspace(-0.5, h - 0.5, 67)
    u, v = np.meshgrid(np.linspace(0, w - 1, 9), np.linspace(0, h - 1, 7))
    return np.concatenate(
        [np.column_stack([edge_u, np.full_like(edge_u, y)]) for y in (-0.5, h - 0.5)]
        + [np.column_stack([np.full_like(edge_v, x), edge_v]) for x in (-0.5, w - 0.5)]
        + [np.column_stack([u.ravel(), v.ravel()])])


@pytest.mark.parametrize("which", ["shared_dome_own", "dome_own_paper_air"])
def test_mitsuba_sees_each_camera_through_its_own_port(request, which):
    """Rays of each camera's image border and a grid, followed by Mitsuba's ``ray_intersect``
    and the dielectric's transmission: they cross the camera's own port (shared window, own
    window or dome) where the rig's trace says (float32 precision), and the water ray's next
    hit is a target (z near 1 m) or nothing — never another camera's glass; a camera in air
    meets no glass at all."""
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba()
    path = request.getfixturevalue(which)
    rig = load_scene(path).multirig
    scene = mi.load_file(str(path))
    uv = _border_and_grid()
    for view, camera in enumerate(rig.cameras):
        d = camera.rays(uv)
        if rig.ports[view] is None:
            ray = mi.Ray3f(mi.Point3f(*(float(c) for c in camera.center)),
                           mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
            si = scene.ray_intersect(ray)
            valid = np.array(si.is_valid()).ravel()
            assert valid.any()
            assert np.all(np.array(si.p).reshape(3, -1).T[valid, 2] > 990.0), view
            continue
        want = rig.trace(view, d, keep_interface_points=True)
        assert_mitsuba_follows(mi, scene, camera, d, want, 3e-4, view)


@pytest.mark.slow
@pytest.mark.parametrize("which", ["shared_dome_own", "dome_own_paper_air"])
def test_eval_run_renders_and_measures_every_camera(request, which, tmp_path):
    """64 spp at 320 px, as the all-dome and all-window runs of N cameras: every target two
    views see matched, none wrongly; every camera's detections where the Fermat forward model
    through its own port puts them (well under 0.05 px RMS); the depth error a fraction of a
    millimetre at 1 m."""
    from eval.cli import main as eval_main

    out = tmp_path / "run"
    assert eval_main(["run", str(request.getfixturevalue(which)), "--out", str(out), "--spp",
                      "64", "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    m, c = report["matching"], report["crosscheck"]
    assert report["cameras"] == ["cam0", "cam1", "cam2", "cam3"]
    assert m["wrong"] == 0 and m["visible_in_two_or_more"] > 60
    assert m["visible_in_two_or_more_matched"] == m["visible_in_two_or_more"]
    for name in report["cameras"]:
        assert c[name]["associated"] > 40 and c[name]["rms_px"] < 0.05, (name, c[name])
    assert report["methods"]["optical_path"]["rms_dp_mm"] < 1.0


def test_a_calibration_file_of_mixed_ports_is_rendered_as_it_is(dome_own_paper_air, tmp_path):
    """``synth scene --rig calib.yaml`` of a rig whose cameras have different kinds of port:
    the scene's rig is the file's, port by port (the camera in air in air)."""
    from synth.products.rig_file import write_rig_file

    rig = load_scene(dome_own_paper_air).multirig
    write_rig_file(tmp_path / "calib.yaml", rig)
    out = tmp_path / "again.xml"
    assert synth_main(["scene", "--rig", str(tmp_path / "calib.yaml"), *GRID[:-3],
                       "--out", str(out)]) == 0
    again = load_scene(out).multirig
    assert again.names == rig.names and again.ports[3] is None
    for k in range(3):
        a, b = again.ports[k], rig.ports[k]
        assert type(a) is type(b)
        np.testing.assert_allclose(again.cameras[k].center, rig.cameras[k].center, atol=1e-9)
        if isinstance(a, DomePort):
            np.testing.assert_allclose(a.center, b.center, atol=1e-9)
            assert a.radii == pytest.approx(b.radii, abs=1e-9)
        else:
            np.testing.assert_allclose(a.normal, b.normal, atol=1e-12)
            assert a.distance == pytest.approx(b.distance, abs=1e-9)


def test_the_writer_takes_a_list_of_flat_ports_domes_and_none(shared_dome_own, tmp_path):
    spec = load_scene(shared_dome_own)
    ports = list(spec.camera_ports)
    ports[3] = None
    path = tmp_path / "again.xml"
    write_scene(path, spec.all_cameras, ports, spec.targets, spec.target_radius)
    assert load_scene(path).multirig.ports == tuple(ports)


@pytest.mark.parametrize("extra, fragment", [
    (["--ports", "dome,dome,window,none"], "--ports dome,dome,window,none: 'window' is not"),
    (["--ports", "dome,dome,none"], "--ports dome,dome,none: 3 kinds for 4 cameras"),
    ([], "--ports: not given"),
    (["--ports", "dome,dome,none,none", "--port-distance", "40"], "--port-distance does not"),
    (["--ports", "paper,paper,none,none", "--dome-radius", "40"], "--dome-radius does not"),
    (["--ports", "paper,paper,dome,dome"], "--ports paper,paper,dome,dome: the cam2 camera's "
                                           "field of view meets the window cam0, cam1 share"),
])
def test_bad_input_is_one_line(tmp_path, capsys, extra, fragment):
    out = tmp_path / "x.xml"
    assert synth_main(["scene", "--cameras", "4", "--port", "mixed", *extra,
                       "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not out.exists()


def test_ports_without_port_mixed_is_refused(tmp_path, capsys):
    assert synth_main(["scene", "--cameras", "4", "--port", "dome", "--ports", "dome,none",
                       "--out", str(tmp_path / "x.xml")]) == 2
    assert "--ports dome,none needs --port mixed" in capsys.readouterr().err


def test_the_board_scenes_shapes_are_the_files_glass(shared_dome_own):
    """``port_shapes`` (the board scenes' Mitsuba dictionary shapes) holds the glass the file
    holds: the same ids, and every camera's rays meet it where they meet the file's (within
    float32 of the dictionary's transforms)."""
    from synth.rendering.mitsuba_setup import import_mitsuba
    from synth.scene.write import port_shapes

    mi, _ = import_mitsuba()
    spec = load_scene(shared_dome_own)
    shapes = port_shapes(mi, spec.camera_ports, cameras=spec.all_cameras)
    text = shared_dome_own.read_text()
    assert all(f'id="{sid}"' in text for sid in shapes)
    assert len(shapes) == text.count("dielectric")
    built, read = mi.load_dict({"type": "scene", **shapes}), mi.load_file(str(shared_dome_own))
    uv = _border_and_grid()
    for camera in spec.all_cameras:
        d = camera.rays(uv)
        ray = mi.Ray3f(mi.Point3f(*(float(c) for c in camera.center)),
                       mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
        a, b = built.ray_intersect(ray), read.ray_intersect(ray)
        assert np.all(np.array(a.is_valid())) and np.all(np.array(b.is_valid()))
        # the dictionary's look_at is composed in float32 (the file's in double): the window's
        # normal, target − origin at ~600 mm, is off by ~600 · 6e-8 rad, ~2e-3 mm at its edge
        np.testing.assert_allclose(np.array(a.p), np.array(b.p), rtol=0, atol=5e-3)


def test_two_cameras_of_two_kinds_are_refused(tmp_path, capsys):
    """A pair of mixed ports (a dome and a window), or every camera in air: one error line,
    no file — the pair's commands take one port, a window each or a dome each."""
    for argv, fragment in ((["--ports", "dome,per-camera"], "a pair of two kinds of port"),
                           (["--cameras", "3", "--ports", "none,none,none"],
                            "that is --port none")):
        path = tmp_path / "pair.xml"
        assert synth_main(["scene", "--port", "mixed", *argv, *GRID, "--out", str(path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
        assert not path.exists()
    # the same pair from a calibration file (a window and a dome)
    from measure.stereo.rig import Rig
    from synth.products.rig_file import write_rig_file
    from synth.scene.rig import paper_cameras

    left, right = paper_cameras((320, 268), 150.0)
    axis = left.R[:, 2]
    write_rig_file(tmp_path / "mix2.yaml", Rig((left, right), [
        FlatPort(axis, float(axis @ left.center) + 40.0, (5.0,), INDICES),
        DomePort(right.center, 60.0, 9.0, INDICES)]))
    assert synth_main(["scene", "--rig", str(tmp_path / "mix2.yaml"), "--out",
                       str(tmp_path / "pair.xml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a pair whose cameras have different kinds of port" in err[0], err
    assert not (tmp_path / "pair.xml").exists()
