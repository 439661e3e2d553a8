"""Scenes of N cameras each inside its own dome (synth scene --cameras N --port dome, the pair's
dome code for N): every camera's dome read back from the file as written, Mitsuba's own
intersection of every camera's rays with the file's spheres (through its own dome, then into
the water past every other), a small eval run that renders every camera and measures it, and
bad input refused in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from measure.geometry.dome import DomePort, trace_through_dome
from synth.__main__ import main as synth_main
from synth.scene import SceneError, load_scene
from synth.scene.dome import camera_domes
from tests.conftest import assert_mitsuba_follows

SMALL = (320, 268)
OFFSET = (2.0, -1.0, 1.5)
INDICES = (1.0, 1.54, 1.33)
#: A ring of four: cam0 in the centre, three round it.
RING = ["--cameras", "4", "--arrangement", "ring", "--port", "dome", "--dome-offset",
        *map(str, OFFSET), "--layout", "grid", "--spacing", "150", "--half-width", "600",
        "--target-radius", "10", "--size", *map(str, SMALL)]


@pytest.fixture(scope="module")
def ring(tmp_path_factory):
    path = tmp_path_factory.mktemp("domes") / "ring.xml"
    assert synth_main(["scene", *RING, "--out", str(path)]) == 0
    return path


@pytest.mark.parametrize("arrangement", ["row", "ring"])
def test_every_camera_gets_its_dome_back_as_written(tmp_path, arrangement):
    path = tmp_path / f"{arrangement}.xml"
    assert synth_main(["scene", "--cameras", "3", "--arrangement", arrangement, "--port", "dome",
                       "--dome-radius", "45", "--dome-thickness", "6", "--dome-offset",
                       *map(str, OFFSET), "--size", *map(str, SMALL), "--out", str(path)]) == 0
    spec = load_scene(path)
    rig = spec.multirig
    assert rig.names == ("cam0", "cam1", "cam2") and spec.has_port
    want = camera_domes(spec.all_cameras, 45.0, 6.0, OFFSET, INDICES)
    for k, camera in enumerate(rig.cameras):
        dome = rig.view_port(k)
        assert isinstance(dome, DomePort)
        np.testing.assert_allclose(dome.center, want[k].center, rtol=0, atol=1e-9)
        np.testing.assert_allclose(camera.R.T @ (dome.center - camera.center), OFFSET, atol=1e-9)
        assert dome.radius == 45.0 and dome.thickness == pytest.approx(6.0, abs=1e-12)
        assert dome.indices == INDICES
    assert spec.camera_ports == list(rig.ports)
    assert all(p.n_water == 1.34 for p in load_scene(path, {"n_water": 1.34}).multirig.ports)


def test_mitsuba_sees_each_camera_through_its_own_dome(ring):
    """Rays of each camera's image, followed by Mitsuba's ``ray_intersect`` and the dielectric's
    transmission: they cross the camera's own two spheres where the dome's trace says (float32
    precision), and the water ray's next hit is a target (z near 1 m) or nothing — never
    another camera's dome."""
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba()
    rig = load_scene(ring).multirig
    scene = mi.load_file(str(ring))
    u, v = np.meshgrid(np.linspace(-0.5, SMALL[0] - 0.5, 17), np.linspace(-0.5, SMALL[1] - 0.5, 13))
    uv = np.column_stack([u.ravel(), v.ravel()])
    for view, camera in enumerate(rig.cameras):
        d = camera.rays(uv)
        want = trace_through_dome(camera.center, d, rig.view_port(view))
        assert_mitsuba_follows(mi, scene, camera, d, want, 3e-4, view)


@pytest.mark.slow
def test_eval_run_renders_and_measures_every_camera(ring, tmp_path):
    """64 spp at 320 px: every target two views see matched, none wrongly; every camera's
    detections where the Fermat forward model through its own dome puts them. (At 16 spp the
    centroids' noise, ~0.04 px, is ~0.3 mm at 1 m through an unmagnifying dome at f = 144 px,
    and 12–24 of the 81 tracks' rays miss the 0.5 mm gate: dropped as ambiguous, none wrong.)"""
    from eval.cli import main as eval_main

    out = tmp_path / "run"
    assert eval_main(["run", str(ring), "--out", str(out), "--spp", "64", "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    m, c = report["matching"], report["crosscheck"]
    assert report["cameras"] == ["cam0", "cam1", "cam2", "cam3"]
    assert m["wrong"] == 0 and m["visible_in_two_or_more"] > 40
    assert m["visible_in_two_or_more_matched"] == m["visible_in_two_or_more"]
    for name in report["cameras"]:
        assert c[name]["associated"] > 40 and c[name]["rms_px"] < 0.05, (name, c[name])
    # at 320 px a target's depth error through the domes is a fraction of a millimetre
    assert report["methods"]["optical_path"]["rms_dp_mm"] < 1.0


SCENE_BAD = {
    "camera outside its dome": (["--dome-offset", "0", "0", "60"],
                                "--dome-offset 0 0 60: cam0 centre lies outside its dome"),
    "domes overlap": (["--baseline", "100"], "the cam0 and cam1 domes overlap"),
    "field of view": (["--dome-offset", "0", "0", "45"],
                      "the cam1 camera's field of view reaches the cam0 dome"),
    "flat option": (["--port-distance", "90"], "--port-distance"),
    "targets inside a dome": (["--layout", "grid", "--z", "30"], "inside the cam0 dome"),
}


@pytest.mark.parametrize("case", sorted(SCENE_BAD))
def test_bad_input_is_one_error_line(tmp_path, capsys, case):
    extra, message = SCENE_BAD[case]
    out = tmp_path / "s.xml"
    assert synth_main(["scene", "--cameras", "3", "--arrangement", "ring", "--port", "dome",
                       "--size", *map(str, SMALL), *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error:") and message in err, err
    assert not out.exists()


def test_a_scene_file_missing_a_camera_dome_is_refused(ring, tmp_path):
    text = ring.read_text()
    bad = tmp_path / "bad.xml"
    bad.write_text(text.replace('id="dome_cam3_inner"', 'id="dome_cam3_other"'))
    with pytest.raises(SceneError, match="'dome_cam3_other' is not a dome sphere"):
        load_scene(bad)


def test_a_calibration_file_of_domes_is_rendered_as_it_is(ring, tmp_path):
    """``synth scene --rig calib.yaml`` of a MultiRig whose cameras are each inside their own
    dome: the scene's rig is the file's, dome by dome."""
    from synth.products.rig_file import write_rig_file

    rig = load_scene(ring).multirig
    calib = tmp_path / "calib.yaml"
    write_rig_file(calib, rig)
    out = tmp_path / "again.xml"
    assert synth_main(["scene", "--rig", str(calib), "--layout", "grid", "--spacing", "150",
                       "--half-width", "600", "--target-radius", "10", "--out", str(out)]) == 0
    again = load_scene(out).multirig
    assert again.names == rig.names
    for k in range(len(rig)):
        a, b = rig.view_port(k), again.view_port(k)
        np.testing.assert_allclose(b.center, a.center, rtol=0, atol=1e-9)
        assert (b.radius, b.indices) == (a.radius, a.indices)
        assert b.thickness == pytest.approx(a.thickness, abs=1e-12)


def test_rig_differences_name_the_camera_whose_dome_moved(ring):
    """What ``eval run --from`` compares a dataset's ``calib.yaml`` with: each camera's dome."""
    from eval.run.multiview import rig_differences
    from measure.stereo.multirig import MultiRig

    rig = load_scene(ring).multirig
    assert rig_differences(rig, rig) == []
    ports = list(rig.ports)
    ports[2] = ports[2].replace(center=ports[2].center + [0.5, 0.0, 0.0],
                                indices=(1.0, 1.54, 1.34))
    moved = MultiRig(rig.cameras, ports, rig.names)
    assert rig_differences(rig, moved) == ["cam2 dome_center_mm", "cam2 dome_index_2"]


@pytest.mark.slow
def test_a_dataset_of_domes_is_checked_and_measured_from_its_files(tmp_path):
    """``synth dataset`` of three cameras in domes: ``synth check`` finds every target in every
    view where the forward model puts it; ``eval run --from`` measures the files."""
    from eval.cli import main as eval_main
    from synth.products.crosscheck import check_dataset

    scene = tmp_path / "row.xml"
    assert synth_main(["scene", "--cameras", "3", "--port", "dome", "--dome-offset", "2", "0",
                       "0", "--layout", "grid", "--spacing", "150", "--half-width", "600",
                       "--target-radius", "10", "--size", *map(str, SMALL),
                       "--out", str(scene)]) == 0
    data = tmp_path / "ds"
    assert synth_main(["dataset", str(scene), "--out", str(data), "--spp", "64"]) == 0
    report = check_dataset(data, rms_px=0.05, max_px=0.15)
    assert report["views"] == ["cam0", "cam1", "cam2"] and report["passed"], report
    out = tmp_path / "run"
    assert eval_main(["run", str(scene), "--from", str(data), "--out", str(out)]) == 0
    run = json.loads((out / "report.json").read_text())
    assert run["matching"]["wrong"] == 0 and run["matching"]["visible_in_two_or_more_matched"] \
        == run["matching"]["visible_in_two_or_more"] == 81


@pytest.mark.slow
def test_boards_in_domes_render_and_their_housing_calibration_is_refused(ring, tmp_path, capsys):
    """``synth boards`` of N cameras in domes renders every camera through its own dome;
    ``eval calibrate`` of them is one ``error:`` line (the housing of N cameras is flat)."""
    from eval.cli import main as eval_main

    boards = tmp_path / "boards"
    assert synth_main(["boards", str(ring), "--out", str(boards), "--poses", "2", "--spp", "4",
                       "--no-progress"]) == 0
    assert sorted(p.name for p in boards.glob("cam*_00.png")) == [f"cam{k}_00.png"
                                                                  for k in range(4)]
    capsys.readouterr()
    assert eval_main(["calibrate", str(boards), "--out", str(tmp_path / "cal")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cam0's port is not flat" in err, err


@pytest.mark.parametrize("port", ["paper", "per-camera", "none"])
def test_dome_options_are_refused_without_domes(tmp_path, capsys, port):
    out = tmp_path / "s.xml"
    assert synth_main(["scene", "--cameras", "3", "--port", port, "--dome-radius", "40",
                       "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--dome-radius" in err and f"--port {port}" in err, err
    assert not out.exists()
