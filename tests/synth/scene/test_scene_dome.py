"""Dome scenes: each camera inside two concentric Mitsuba spheres — written, read back into a
StereoRig with a DomePair, traced by Mitsuba itself like measure's backward trace, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from measure import StereoRig
from measure.geometry.dome import DomePair, trace_through_dome
from synth.scene.layouts import paper_plane
from synth.scene.rig import paper_cameras
from synth.scene import SceneError, load_scene, write_scene
from synth.scene.dome import check_field_of_view, dome_pair, pair_from_spheres
from tests.conftest import REPO

SMALL = (320, 268)
FOCAL = 1100.0 * SMALL[0] / 2448
INDICES = (1.0, 1.54, 1.33)


def _small_dome_scene(tmp_path, offset=(2.0, 0.0, 0.0), radius=50.0, thickness=8.0):
    left, right = paper_cameras(SMALL, FOCAL)
    pair = dome_pair((left, right), radius, thickness, offset, INDICES)
    path = write_scene(tmp_path / "dome.xml", (left, right), pair, paper_plane(1000.0)[:60], 2.5)
    return path, (left, right), pair


def test_dome_pair_puts_each_dome_at_the_offset_in_its_camera_frame():
    left, right = paper_cameras(SMALL, FOCAL)
    pair = dome_pair((left, right), 50.0, 8.0, (2.0, -1.0, 3.0), INDICES)
    for camera, dome in ((left, pair.left), (right, pair.right)):
        np.testing.assert_allclose(camera.R.T @ (dome.center - camera.center), [2.0, -1.0, 3.0],
                                   atol=1e-12)
        assert dome.radius == 50.0 and dome.thickness == 8.0 and dome.indices == INDICES


def test_round_trip_gives_a_rig_with_the_same_domes(tmp_path):
    path, (left, right), pair = _small_dome_scene(tmp_path, offset=(2.0, -0.5, 1.25))
    spec = load_scene(path)
    assert spec.rig.port.kind == "dome" and spec.has_port and spec.port is spec.rig.port
    for got, want in ((spec.rig.port.left, pair.left), (spec.rig.port.right, pair.right)):
        np.testing.assert_allclose(got.center, want.center, rtol=0, atol=1e-12)
        assert got.radius == want.radius and got.thickness == pytest.approx(want.thickness, abs=1e-12)
        assert got.indices == want.indices
    np.testing.assert_allclose(spec.rig.right.t, right.t, atol=1e-12)
    assert load_scene(path, {"n_water": 1.34}).rig.port.right.indices == (1.0, 1.54, 1.34)
    assert spec.targets.shape == (60, 3)


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (2.0, 0.0, 0.0), (0.0, 1.5, -3.0)])
def test_mitsuba_traces_the_domes_like_measure(tmp_path, offset):
    """Rays from each camera centre, followed by Mitsuba's ``ray_intersect`` and the dielectric
    BSDF's transmission: air inside, glass between the spheres, water outside — the same water
    rays as measure.geometry.dome.trace_through_dome (float32 precision)."""
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba()
    path, cameras, pair = _small_dome_scene(tmp_path, offset=offset)
    scene = mi.load_file(str(path))
    u, v = np.meshgrid(np.linspace(-0.5, SMALL[0] - 0.5, 9), np.linspace(-0.5, SMALL[1] - 0.5, 7))
    uv = np.column_stack([u.ravel(), v.ravel()])
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.DeltaTransmission
    for view, camera in enumerate(cameras):
        want = trace_through_dome(camera.center, camera.rays(uv), pair[view])
        d = camera.rays(uv)
        ray = mi.Ray3f(mi.Point3f(*(float(c) for c in camera.center)), mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
        name = ("left", "right")[view]
        for k, sphere in enumerate(("inner", "outer")):
            si = scene.ray_intersect(ray)
            hit = np.array(si.p).reshape(3, -1).T
            np.testing.assert_allclose(hit, want.interface_points[k], rtol=0, atol=2e-4)
            radius = np.linalg.norm(hit - pair[view].center, axis=1)
            np.testing.assert_allclose(radius, pair[view].radii[k], atol=2e-4,
                                       err_msg=f"{name} {sphere}")
            sample, weight = si.bsdf().sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
            assert np.all(np.array(weight).reshape(3, -1) > 0)
            out = si.to_world(sample.wo)
            ray = mi.Ray3f(si.p + out * 1e-3, out)
        got = np.array(ray.d).reshape(3, -1).T
        np.testing.assert_allclose(got, want.directions, rtol=0, atol=2e-6)
        # the third hit of a water ray, if any, is a target: never the other dome
        si = scene.ray_intersect(ray)
        hit = np.array(si.p).reshape(3, -1).T
        valid = np.array(si.is_valid()).ravel()
        other = pair[1 - view]
        assert np.all(np.linalg.norm(hit[valid] - other.center, axis=1) > other.radii[1] + 1)


def test_field_of_view_check():
    left, right = paper_cameras()
    check_field_of_view(StereoRig(left, right, dome_pair((left, right), 50, 8, (2, 0, 0), INDICES)))
    with pytest.raises(ValueError, match="overlap"):
        check_field_of_view(StereoRig(left, right, dome_pair((left, right), 95, 8, (0, 0, 0),
                                                             INDICES)))
    with pytest.raises(ValueError, match="right camera's field of view reaches the left dome"):
        check_field_of_view(StereoRig(left, right, dome_pair((left, right), 50, 8, (0, 0, 45),
                                                             INDICES)))


def test_pair_from_spheres_refuses_what_is_not_a_dome():
    c = np.zeros(3)
    good = {"dome_left_inner": (c, 50.0, 1.54, 1.0), "dome_left_outer": (c, 58.0, 1.33, 1.54),
            "dome_right_inner": (c + 200, 50.0, 1.54, 1.0),
            "dome_right_outer": (c + 200, 58.0, 1.33, 1.54)}
    assert isinstance(pair_from_spheres(good), DomePair)
    for key, value, message in (
            ("dome_left_outer", (c + 1, 58.0, 1.33, 1.54), "not concentric"),
            ("dome_left_outer", (c, 49.0, 1.33, 1.54), "must be larger"),
            ("dome_left_outer", (c, 58.0, 1.33, 1.5), "two indices"),
            ("dome_right_outer", (c + 200, 58.0, 1.34, 1.54), "different water")):
        with pytest.raises(ValueError, match=message):
            pair_from_spheres({**good, key: value})
    with pytest.raises(ValueError, match="'ball' is not a dome sphere"):
        pair_from_spheres({**good, "ball": (c, 5.0, 1.33, 1.5)})
    with pytest.raises(ValueError, match="missing"):
        pair_from_spheres({k: v for k, v in good.items() if k != "dome_right_inner"})


def test_bad_dome_scene_files_raise_scene_error(tmp_path):
    path, _, _ = _small_dome_scene(tmp_path)
    text = open(path).read()
    cases = {
        "flip": (text.replace('<float name="radius" value="58"/>',
                              '<float name="radius" value="58"/><boolean name="flip_normals" '
                              'value="true"/>', 1), "flip its normals"),
        "missing": (text.replace('id="dome_right_outer"', 'id="dome_right_other"'), "missing"),
        "camera outside": (text.replace('value="2, 0, 0"', 'value="60, 0, 0"'),
                           "outside its dome"),
    }
    for case, (edited, message) in cases.items():
        bad = tmp_path / f"{case.replace(' ', '_')}.xml"
        bad.write_text(edited)
        with pytest.raises(SceneError, match=message):
            load_scene(bad)


SCENE_BAD = {
    "camera outside the dome": (["--dome-offset", "60", "0", "0"], "outside its dome"),
    "radius zero": (["--dome-radius", "0"], "--dome-radius"),
    "thickness negative": (["--dome-thickness", "-1"], "--dome-thickness"),
    "targets inside the dome": (["--layout", "grid", "--z", "30"], "inside the dome"),
    "targets in the glass": (["--layout", "grid", "--z", "55"], "in the glass"),
    "field of view": (["--dome-offset", "0", "0", "45"], "field of view"),
    "domes overlap": (["--dome-radius", "95"], "overlap"),
    # degenerate domes (issue 37: accepted), refused with the minimum
    "radius tiny": (["--dome-radius", "0.001"],
                    "--dome-radius 0.001 --dome-thickness 8: dome radius 0.001 mm is below the "
                    "minimum of 1 mm"),
    "thickness tiny": (["--dome-thickness", "1e-9"],
                       "--dome-thickness 1e-9: dome thickness 1e-9 mm is below the minimum of "
                       "0.1 mm"),
    "flat option": (["--port-distance", "90"], "--port-distance"),
    "water": (["--water", "coastal"], "--water"),
}


@pytest.mark.parametrize("case", sorted(SCENE_BAD))
def test_cli_scene_dome_bad_input_exit_2_one_line(tmp_path, capsys, case):
    from synth.__main__ import main

    extra, message = SCENE_BAD[case]
    out = tmp_path / "s.xml"
    assert main(["scene", "--port", "dome", "--size", *map(str, SMALL), *extra,
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error:") and message in err, err
    assert not out.exists()


def test_cli_dome_options_refused_without_a_dome(tmp_path, capsys):
    from synth.__main__ import main

    assert main(["scene", "--dome-radius", "40", "--out", str(tmp_path / "s.xml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--dome-radius" in err


@pytest.mark.parametrize("name, offset", [("dome_centred.xml", (0.0, 0.0, 0.0)),
                                          ("dome_decentred.xml", (2.0, 0.0, 0.0))])
def test_committed_dome_scenes(name, offset):
    spec = load_scene(REPO / "scenes" / name)
    left, right = paper_cameras()
    want = dome_pair((left, right), 50.0, 8.0, offset, INDICES)
    assert spec.rig.port.kind == "dome" and spec.size == (2448, 2048)
    for got, dome in ((spec.rig.port.left, want.left), (spec.rig.port.right, want.right)):
        np.testing.assert_allclose(got.center, dome.center, atol=1e-12)
        assert (got.radius, got.thickness, got.indices) == (50.0, 8.0, INDICES)
    np.testing.assert_array_equal(spec.targets, paper_plane(1000.0))


def test_a_degenerate_dome_is_refused_in_a_calibration_and_a_scene(tmp_path):
    """The minimum holds wherever a dome is read: a calib.yaml's dome map and a scene's
    spheres, not only synth scene's options."""
    from measure import StereoRig
    from synth.products.dataset import DatasetError, read_calib, write_calib
    from synth.scene.dome import MIN_DOME_THICKNESS_MM, pair_from_spheres

    left, right = paper_cameras(SMALL, 150.0)
    pair = dome_pair((left, right), 50.0, 8.0, (0.0, 0.0, 0.0), INDICES)
    path = tmp_path / "calib.yaml"
    write_calib(path, StereoRig(left, right, pair))
    assert read_calib(path)["has_port"]
    path.write_text(path.read_text().replace("thickness: 8.", "thickness: 1.0000000000000001e-09"))
    with pytest.raises(DatasetError, match="calib.yaml: left dome: dome thickness 1e-9 mm is "
                                           "below the minimum"):
        read_calib(path)
    spheres = {}
    for name, dome in (("left", pair.left), ("right", pair.right)):
        n_air, n_glass, n_water = dome.indices
        spheres[f"dome_{name}_inner"] = (dome.center, 50.0, n_glass, n_air)
        spheres[f"dome_{name}_outer"] = (dome.center, 50.0 + MIN_DOME_THICKNESS_MM / 2, n_water,
                                         n_glass)
    with pytest.raises(ValueError, match="below the minimum of 0.1 mm"):
        pair_from_spheres(spheres)
