"""Scene files: write -> read round trips, -D overrides, Mitsuba's own loader, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from measure import Camera, FlatPort
from synth.scene.layouts import paper_plane, random_volume
from synth.scene.rig import paper_cameras, paper_port, paper_rig
from synth.scene import SceneError, load_scene, parse_defines, write_scene
from tests.conftest import REPO


SCENES = ["paper_plane.xml", "paper_plane_2m.xml", "air_plane.xml"]
SMALL = (320, 268)


def _assert_camera_equal(a: Camera, b: Camera):
    np.testing.assert_allclose(a.K, b.K, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.R, b.R, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.t, b.t, rtol=0, atol=1e-12)
    assert a.size == b.size
    if b.dist is None:
        assert a.dist is None
    else:
        np.testing.assert_allclose(a.dist, b.dist, rtol=0, atol=1e-15)


def _assert_port_equal(a: FlatPort, b: FlatPort):
    np.testing.assert_allclose(a.normal, b.normal, atol=1e-12)
    assert a.distance == pytest.approx(b.distance, abs=1e-9)
    np.testing.assert_allclose(a.thicknesses, b.thicknesses, atol=1e-9)
    assert a.indices == b.indices


def test_round_trip_paper_rig_with_distortion_and_principal_point(tmp_path):
    left, right = paper_cameras(SMALL, 150.0, dist=(-0.12, 0.03, 0.001, -0.0007, 0.002))
    K = left.K.copy()
    K[0, 2] += 7.25
    K[1, 2] -= 3.5
    left = Camera(K, SMALL, dist=left.dist)
    port = paper_port()
    targets = paper_plane(1000.0)[:40]
    path = write_scene(tmp_path / "s.xml", (left, right), port, targets, 3.5)
    spec = load_scene(path)
    _assert_camera_equal(spec.rig.left, left)
    _assert_camera_equal(spec.rig.right, right)
    _assert_port_equal(spec.rig.port, port)
    assert spec.has_port and spec.port is spec.rig.port
    np.testing.assert_array_equal(spec.targets, targets)
    np.testing.assert_array_equal(spec.target_ids, np.arange(40))
    assert spec.target_radius == pytest.approx(3.5, abs=1e-12)
    assert spec.params["target_z"] == "1000" and spec.params["n_water"] == "1.33"


@pytest.mark.parametrize("port", [
    FlatPort((0, 0, 1), 80.0, (), (1.0, 1.34)),
    FlatPort((0.05, -0.02, 1), 90.0, (4.0, 6.5), (1.0, 1.49, 1.52, 1.335)),
])
def test_round_trip_other_ports_and_random_layout(tmp_path, port):
    left, right = paper_cameras(SMALL, 150.0)
    targets = random_volume(25, 3, z_range=(700.0, 1500.0))
    spec = load_scene(write_scene(tmp_path / "s.xml", (left, right), port, targets, 4.0))
    _assert_port_equal(spec.rig.port, port)
    np.testing.assert_allclose(spec.targets, targets, rtol=0, atol=1e-12)
    assert "target_z" not in spec.params


def test_air_scene_has_index_matched_stand_in_port(tmp_path):
    left, right = paper_cameras(SMALL, 150.0)
    spec = load_scene(write_scene(tmp_path / "a.xml", (left, right), None, paper_plane(), 2.5))
    assert not spec.has_port and spec.port is None
    assert spec.rig.port.indices == (1.0, 1.0)
    assert spec.params["port"] == "none"


def test_defines_override_defaults(tmp_path):
    spec = load_scene(REPO / "scenes" / "paper_plane.xml",
                      parse_defines(["n_water=1.34", "width=320", "height=268", "target_z=1500",
                                     "spp=4", "target_radius=5", "left_dist=-0.1 0.01 0 0 0"]))
    small = paper_rig(size=SMALL)
    np.testing.assert_allclose(spec.rig.left.K, small.left.K, atol=1e-9)
    assert spec.rig.port.n_water == 1.34
    assert np.all(spec.targets[:, 2] == 1500.0)
    assert spec.spp == 4 and spec.target_radius == 5.0
    np.testing.assert_allclose(spec.rig.left.dist, [-0.1, 0.01, 0, 0, 0])
    assert spec.rig.right.dist is None
    with pytest.raises(SceneError, match="unknown parameter -D water"):
        load_scene(REPO / "scenes" / "paper_plane.xml", {"water": "1.3"})
    with pytest.raises(SceneError, match="malformed -D"):
        parse_defines(["n_water"])


@pytest.mark.parametrize("name", SCENES)
def test_committed_scenes_match_the_paper_rig(name):
    spec = load_scene(REPO / "scenes" / name)
    rig = paper_rig(in_air=(name == "air_plane.xml"))
    _assert_camera_equal(spec.rig.left, rig.left)
    _assert_camera_equal(spec.rig.right, rig.right)
    if spec.has_port:
        _assert_port_equal(spec.rig.port, rig.port)
    z = 2000.0 if "2m" in name else 1000.0
    np.testing.assert_array_equal(spec.targets, paper_plane(z))
    assert spec.targets.shape == (496, 3)


@pytest.mark.parametrize("name", SCENES)
def test_mitsuba_loads_committed_scenes_and_agrees(name):
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba()
    path = REPO / "scenes" / name
    scene = mi.load_file(str(path))  # Mitsuba's own loader, its own defaults, no plugin of ours
    spec = load_scene(path)
    assert len(scene.sensors()) == 2
    ids = {shape.id() for shape in scene.shapes()}
    assert {f"target_{k}" for k in range(496)} <= ids
    assert len(ids) == 496 + (2 if spec.has_port else 0)
    for sensor, cam in zip(scene.sensors(), spec.cameras):
        params = mi.traverse(sensor)
        w = cam.size[0]
        assert float(params["x_fov"][0]) == pytest.approx(
            math.degrees(2 * math.atan(w / (2 * cam.K[0, 0]))), rel=1e-6)
        M = np.array(sensor.world_transform().matrix, dtype=float).reshape(4, 4)
        np.testing.assert_allclose(M[:3, :3] @ np.diag([-1.0, -1.0, 1.0]), cam.R, atol=1e-6)
        np.testing.assert_allclose(M[:3, 3], cam.t, atol=1e-4)


# --- bad input --------------------------------------------------------------------------------
def _xml(tmp_path, text, name="bad.xml"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _edit(tmp_path, old, new, name="edited.xml"):
    small = (REPO / "scenes" / "paper_plane.xml").read_text()
    assert old in small
    return _xml(tmp_path, small.replace(old, new, 1), name)


def _one_sensor(tmp_path):
    text = (REPO / "scenes" / "paper_plane.xml").read_text()
    start = text.index('    <sensor type="perspective" id="right">')
    end = text.index("</sensor>", start) + len("</sensor>")
    return _xml(tmp_path, text[:start] + text[end:], "one.xml")


def _no_port(tmp_path):
    text = (REPO / "scenes" / "paper_plane.xml").read_text()
    while '<shape type="rectangle"' in text:
        start = text.index('    <shape type="rectangle"')
        end = text.index("</shape>", start) + len("</shape>")
        text = text[:start] + text[end:]
    return _xml(tmp_path, text, "noport.xml")


BAD = {
    "missing": (lambda tmp: str(tmp / "nope.xml"), "cannot read"),
    "malformed": (lambda tmp: _xml(tmp, "<scene version='3.0.0'><sensor></scene>"), "malformed XML"),
    "not a scene": (lambda tmp: _xml(tmp, "<foo/>"), "expected <scene>"),
    "one sensor": (_one_sensor, "two sensors"),
    "no port": (_no_port, "no port"),
    "diffuse interface": (lambda tmp: _edit(tmp, '<bsdf type="dielectric">',
                                            '<bsdf type="roughdielectric">'), "expected 'dielectric'"),
    "inconsistent ior": (lambda tmp: _edit(tmp, '<float name="ext_ior" value="1.54"/>',
                                           '<float name="ext_ior" value="1.5"/>'), "ext_ior"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_scenes_raise_scene_error(tmp_path, case):
    make, message = BAD[case]
    with pytest.raises(SceneError, match=message):
        load_scene(make(tmp_path))


@pytest.mark.parametrize("case", sorted(BAD) + ["unknown -D", "bad -D", "bad option"])
def test_cli_bad_input_exit_code_2_and_one_line(tmp_path, capsys, case):
    from synth.__main__ import main

    scene = str(REPO / "scenes" / "paper_plane.xml")
    if case == "unknown -D":
        argv = ["render", scene, "--out", str(tmp_path / "o"), "-D", "n_glass=1.5"]
    elif case == "bad -D":
        argv = ["dataset", scene, "--out", str(tmp_path / "o"), "-D", "spp"]
    elif case == "bad option":
        argv = ["render", scene, "--out", str(tmp_path / "o"), "--spp", "many"]
    else:
        argv = ["dataset", BAD[case][0](tmp_path), "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".o")]


def test_cli_scene_writes_a_loadable_scene(tmp_path, capsys):
    from synth.__main__ import main

    out = tmp_path / "g.xml"
    assert main(["scene", "--layout", "grid", "--z", "1200", "--spacing", "100",
                 "--size", "320", "268", "--n-water", "1.34", "--target-radius", "8",
                 "--out", str(out)]) == 0
    spec = load_scene(out)
    assert spec.rig.port.n_water == 1.34 and spec.size == SMALL
    assert spec.target_radius == 8.0 and np.all(spec.targets[:, 2] == 1200.0)
