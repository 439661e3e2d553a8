"""python -m eval run on small dome scenes: every method through each camera's own dome, the
pinhole baseline exact behind centred domes, the flat port's options refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from eval.cli import main
from eval.core.assumption import assumed_rig, describe_rig, parse_assumptions, rig_difference
from synth.scene.layouts import grid_plane
from synth.scene.rig import paper_cameras
from synth.scene import load_scene, write_scene
from synth.scene.dome import dome_pair

SIZE, FOCAL, SPP = (320, 268), 150.0, 16
METHODS = "optical_path,su,regular,reprojection"


def _scene(root, offset):
    cameras = paper_cameras(SIZE, FOCAL)
    pair = dome_pair(cameras, 50.0, 8.0, offset, (1.0, 1.54, 1.33))
    targets = grid_plane(1000.0, 320.0, 80.0) + np.array([3.0, -2.0, 0.0])
    return str(write_scene(root / f"dome_{offset[0]:g}.xml", cameras, pair, targets, 16.0,
                           spp=SPP))


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("domes")
    return {"centred": _scene(root, (0.0, 0.0, 0.0)), "decentred": _scene(root, (2.0, 0.0, 0.0))}


def _run(scene, out, *extra):
    assert main(["run", scene, "--out", str(out), "--methods", METHODS, "--no-progress",
                 *extra]) == 0
    return json.loads((out / "report.json").read_text())


@pytest.mark.slow
def test_every_method_through_decentred_domes(scenes, tmp_path):
    report = _run(scenes["decentred"], tmp_path / "run")
    matching, methods = report["matching"], report["methods"]
    assert matching["wrong"] == 0 and matching["visible_in_both_matched"] == \
        matching["visible_in_both"] > 40
    assert report["crosscheck"]["rms_px"] < 0.05
    assert report["rigs"]["truth"]["port"]["kind"] == "dome"
    assert report["rigs"]["difference"] == {}
    # At f = 150 px a 0.05 px centroid error is ~0.5 mm of depth at 1 m; the pinhole baseline
    # ignores the 2 mm decentring of both domes and is off by far more.
    for method in ("optical_path", "su", "reprojection"):
        assert methods[method]["rms_dp_mm"] < 3.0, method
    assert methods["regular"]["rms_dp_mm"] > 3 * methods["optical_path"]["rms_dp_mm"]


@pytest.mark.slow
def test_eccentricity_correction_through_domes(scenes, tmp_path):
    report = _run(scenes["decentred"], tmp_path / "run", "--eccentricity")
    corrected = report["methods"]["optical_path"]  # the default: corrected
    assert corrected["n"] == report["eccentricity"]["uncorrected"]["methods"]["optical_path"]["n"]
    assert corrected["rms_dp_mm"] < 3.0


@pytest.mark.slow
def test_centred_domes_make_the_pinhole_baseline_exact(scenes, tmp_path):
    methods = _run(scenes["centred"], tmp_path / "run")["methods"]
    # the camera centres are the domes' centres: no ray is bent, regular is optical_path
    assert methods["regular"]["rms_dp_mm"] == pytest.approx(methods["optical_path"]["rms_dp_mm"],
                                                            rel=1e-6, abs=1e-6)


@pytest.mark.parametrize("extra, fragment", [
    (["--self-calibrate", "n_water"], "--self-calibrate does not apply to the dome scene"),
    (["--assume", "port_distance=90"], "--assume port_distance does not apply to a dome rig"),
    (["--assume", "port_normal=0 0.1 1"], "--assume port_normal does not apply to a dome rig"),
])
def test_flat_port_options_refused_for_domes(scenes, tmp_path, capsys, extra, fragment):
    out = tmp_path / "out"
    assert main(["run", scenes["decentred"], "--out", str(out), "--no-progress", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not out.exists()


def test_assumed_dome_rig_and_its_difference(scenes):
    truth = load_scene(scenes["decentred"]).rig
    believed = assumed_rig(truth, True, parse_assumptions(["n_water=1.34", "focal=151"]))
    assert believed.port.kind == "dome"
    assert believed.port.left.indices == believed.port.right.indices == (1.0, 1.54, 1.34)
    np.testing.assert_array_equal(believed.port.right.center, truth.port.right.center)
    diff = rig_difference(truth, believed)
    assert diff["left_dome_index_2"] == pytest.approx(0.01)
    assert diff["right_dome_index_2"] == pytest.approx(0.01)
    assert {"left_K", "right_K"} <= set(diff) and "left_dome_center_mm" not in diff
    centred = load_scene(scenes["centred"]).rig
    moved = rig_difference(truth, centred)
    assert moved["left_dome_center_mm"] == pytest.approx([-2.0, 0.0, 0.0])
    assert describe_rig(truth)["port"]["right"]["radius_mm"] == 50.0


def test_a_flat_port_calibration_is_refused_for_a_dome_scene(scenes, tmp_path, capsys):
    from synth.products.dataset import write_calib
    from synth.scene.rig import paper_rig

    calib = tmp_path / "flat.yaml"
    write_calib(calib, paper_rig(size=SIZE, focal_px=FOCAL))
    for option in ("--calib", "--compare-calib"):
        assert main(["run", scenes["decentred"], "--out", str(tmp_path / "out"), option,
                     str(calib), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "a flat-port calibration, but the scene has domes" in err[0]


@pytest.mark.slow
def test_points_through_domes_carry_the_domes_covariance(scenes, tmp_path):
    """A dome calibration whose covariance names each dome's centre (reference frame): the
    points measured through the domes carry its rig part (larger σ than the scene's exact rig)."""
    from measure.stereo.rig_covariance import RigCovariance
    from synth.products.dataset import read_calib, write_calib, write_dataset

    data = tmp_path / "data"
    write_dataset(load_scene(scenes["decentred"]), data, spp=SPP, progress=False)
    rig = read_calib(data / "calib.yaml")["rig"]
    names = ("left.dome_center[2]", "right.dome_center[0]", "right.dome_center[2]")
    calib = tmp_path / "dome_cov.yaml"
    write_calib(calib, rig, covariance=RigCovariance(names, np.diag([0.5, 0.5, 0.5]) ** 2))
    reports = {}
    for name, extra in (("exact", []), ("cov", ["--calib", str(calib)])):
        out = tmp_path / name
        assert main(["run", scenes["decentred"], "--from", str(data), "--out", str(out),
                     "--methods", "optical_path", "--no-progress", *extra]) == 0
        reports[name] = json.loads((out / "report.json").read_text())
    assert "rig covariance" in reports["cov"]["uncertainty"]["rig"]
    sz = {k: r["uncertainty"]["summaries"]["optical_path"]["sigma"]["median_sigma_mm"]["z"]
          for k, r in reports.items()}
    assert sz["cov"] > 1.5 * sz["exact"], sz
