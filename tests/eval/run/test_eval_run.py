"""python -m eval run end to end on a small scene (a few targets, small images)."""

from __future__ import annotations

import json
import os

import numpy as np
import open3d as o3d
import pytest

from eval.cli import main
from tests.conftest import REPO
from synth.products.dataset import write_dataset

SPP = 16


@pytest.fixture(scope="module")
def run_dir(small_scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "out"
    assert main(["run", small_scene, "--out", str(out), "--spp", str(SPP), "--no-progress",
                 "--methods", "optical_path,su,regular,absorbed"]) == 0
    return out


@pytest.mark.slow
def test_report_fields_and_numbers(run_dir):
    report = json.loads((run_dir / "report.json").read_text())
    assert report["targets"] == 81 and report["spp"] == SPP
    for view in ("left", "right"):
        assert set(report["detection"][view]) >= {"found", "rejected"}
    matching = report["matching"]
    # Every target wholly inside both images is matched, and no match is wrong.
    assert matching["visible_in_both_matched"] == matching["visible_in_both"] > 0
    assert matching["wrong"] == 0 and matching["pairs"] == matching["correct"]
    assert report["crosscheck"]["rms_px"] < 0.1
    methods = report["methods"]
    assert set(methods) == {"optical_path", "su", "regular", "absorbed"}
    for stats in methods.values():
        assert set(stats) >= {"n", "rms_dp_mm", "max_dp_mm", "mean_dx_mm", "mean_dy_mm",
                              "mean_dz_mm", "chamfer_mm", "fscore_1mm", "rms_dp_aligned_mm",
                              "flatness_mm", "length_median_pct", "length_worst_pct"}
    # The absorbed baseline (a pinhole calibration of the boards seen through the port) is in a
    # virtual frame: its raw error is far above what a rigid alignment leaves, and its lengths
    # are worse than the optical path's, which models the port.
    absorbed, optical = methods["absorbed"], methods["optical_path"]
    assert absorbed["n"] == optical["n"] and absorbed["invalid"] == 0
    assert absorbed["rms_dp_mm"] > 3 * absorbed["rms_dp_aligned_mm"]
    assert abs(absorbed["length_worst_pct"]) > 3 * abs(optical["length_worst_pct"])
    assert report["absorbed"]["stereo_rms_px"] > 0 and report["absorbed"]["lens_model"]
    # At f = 150 px a 0.05 px centroid error is ~0.5 mm of depth at 1 m: the optical path is
    # accurate to a few mm, the regular method (which ignores the port) is off by ~300 mm.
    assert methods["optical_path"]["rms_dp_mm"] < 3.0
    assert methods["regular"]["rms_dp_mm"] > 50 * methods["optical_path"]["rms_dp_mm"]
    assert methods["su"]["max_dp_mm"] > methods["optical_path"]["max_dp_mm"]
    assert set(report["timings_s"]) >= {"render", "detect", "match", "triangulate", "evaluate", "total"}
    assert report["variant"] and report["versions"]["numpy"]
    # how each view was rendered: adaptively, with its lit fraction and samples
    render = report["inputs"]["render"]["render"]
    for view in ("left", "right"):
        assert render[view]["mode"] == "adaptive" and 0 < render[view]["lit_fraction"] < 0.5
        assert render[view]["samples_on_mask"] == SPP * render[view]["mask_pixels"]
    assert "## Render" in (run_dir / "report.md").read_text()


@pytest.mark.slow
def test_figures_and_coloured_point_clouds(run_dir):
    report = json.loads((run_dir / "report.json").read_text())
    for name in ("report.md", "views.png", "error_maps.png", "histograms.png"):
        assert (run_dir / name).stat().st_size > 1000
    for method, ply in report["ply"].items():
        cloud = o3d.io.read_point_cloud(str(run_dir / ply["file"]))
        assert len(cloud.points) == ply["points"] == report["methods"][method]["n"]
        assert cloud.has_colors() and ply["vmax_mm"] > 0


@pytest.mark.slow
def test_from_dataset_gives_the_same_measurement(small_scene, tmp_path, capsys):
    data = tmp_path / "data"
    write_dataset(small_scene, data, spp=SPP, progress=False)
    out = tmp_path / "run"
    assert main(["run", small_scene, "--from", str(data), "--out", str(out), "--json",
                 "--no-progress", "--methods", "optical_path"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["inputs"]["from"] == os.path.abspath(data)
    assert printed["timings_s"]["render"] == 0.0 and list(printed["methods"]) == ["optical_path"]
    assert printed["matching"]["wrong"] == 0


@pytest.mark.slow
def test_pixel_noise_option_is_seeded(small_scene, tmp_path):
    reports = []
    for name in ("a", "b"):
        out = tmp_path / name
        # a gate that fits 0.3 px of noise at f = 150 px (0.5 mm matches 10 of 81: exit 1)
        assert main(["run", small_scene, "--out", str(out), "--spp", "4", "--noise-px", "0.3",
                     "--seed", "5", "--methods", "optical_path", "--gate-mm", "5",
                     "--no-progress"]) == 0
        reports.append(json.loads((out / "report.json").read_text())["methods"]["optical_path"])
    assert reports[0]["rms_dp_mm"] == reports[1]["rms_dp_mm"]


@pytest.mark.parametrize("extra, fragment", [
    (["--methods", "magic"], "magic"),
    (["-D", "no_such_parameter=1"], "no_such_parameter"),
    (["--depth-range", "5"], "--depth-range"),
    (["--threshold-fraction", "1.5"], "--threshold-fraction"),
    (["--sensor", "nikon"], "unknown sensor"),
    (["--absorbed-calib", "x.yaml"], "absorbed method"),
])
def test_bad_arguments_exit_2_with_one_line(small_scene, tmp_path, capsys, extra, fragment):
    out = tmp_path / "out"
    assert main(["run", small_scene, "--out", str(out), "--no-progress", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0]
    assert not out.exists()


def test_missing_or_malformed_scene(tmp_path, capsys):
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'><sensor")
    for scene in (str(tmp_path / "missing.xml"), str(bad)):
        assert main(["run", scene, "--out", str(tmp_path / "out"), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:")
    assert not (tmp_path / "out").exists()


def test_unwritable_out(small_scene, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert main(["run", small_scene, "--out", str(blocker / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --out") and "not a directory" in err


def _without_timings(report: dict) -> dict:
    report = dict(report)
    report.pop("timings_s")
    return report


@pytest.mark.slow
def test_identical_runs_give_identical_reports(small_scene, tmp_path):
    """Same arguments, same numbers: five runs give byte-identical report.json apart from the
    timings (the plane fit is seeded and single-threaded, the noise is seeded)."""
    data = tmp_path / "data"
    write_dataset(small_scene, data, spp=4, progress=False)
    texts = []
    for k in range(5):
        out = tmp_path / f"run{k}"
        # a gate that fits 0.2 px of noise at f = 150 px (0.5 mm matches 10 of 81: exit 1)
        assert main(["run", small_scene, "--from", str(data), "--out", str(out), "--noise-px",
                     "0.2", "--seed", "3", "--gate-mm", "5", "--no-progress"]) == 0
        texts.append(json.dumps(_without_timings(json.loads((out / "report.json").read_text())),
                                sort_keys=True).replace(str(out), "OUT"))
    assert all(text == texts[0] for text in texts[1:])
    assert json.loads(texts[0])["methods"]["optical_path"]["flatness_mm"] > 0


@pytest.mark.slow
def test_no_figures_writes_the_same_report_and_clouds_and_no_png(small_scene, tmp_path):
    """``--no-figures``: no PNG file and no matplotlib, the report's numbers, the PLY and CSV
    files of a run with the figures; report.json and report.md say which figures exist."""
    data = tmp_path / "data"
    write_dataset(small_scene, data, spp=4, progress=False)
    outs = {}
    for name, extra in (("figures", []), ("none", ["--no-figures"])):
        outs[name] = tmp_path / name
        assert main(["run", small_scene, "--from", str(data), "--out", str(outs[name]),
                     "--no-progress", *extra]) == 0
    with_figures, without = (json.loads((outs[k] / "report.json").read_text())
                             for k in ("figures", "none"))
    assert with_figures["figures"] == ["views.png", "error_maps.png", "histograms.png",
                                       "ellipses.png"] and without["figures"] == []
    for name in with_figures["figures"]:
        assert (outs["figures"] / name).stat().st_size > 1000
    assert not list(outs["none"].glob("*.png")) and ".png" not in (outs["none"] / "report.md"
                                                                   ).read_text()
    for report in (with_figures, without):
        for key in ("timings_s", "figures"):
            report.pop(key)
    assert json.dumps(with_figures, sort_keys=True).replace(str(outs["figures"]), "OUT") == \
        json.dumps(without, sort_keys=True).replace(str(outs["none"]), "OUT")
    def files(out):
        return sorted(p.name for p in out.iterdir() if p.suffix != ".png")

    assert files(outs["figures"]) == files(outs["none"])
    others = [name for name in files(outs["none"]) if name.endswith((".ply", ".csv"))]
    assert len(others) == 8  # points (correct, all) of 3 methods, covariances of optical_path
    for name in others:
        assert (outs["figures"] / name).read_bytes() == (outs["none"] / name).read_bytes(), name


@pytest.mark.slow
def test_seed_option_and_scene_parameter_mean_the_same(small_scene, tmp_path):
    """--seed 7 and -D seed=7 render the same images (one seed, one meaning)."""
    from synth.__main__ import main as synth_main

    for name, extra in (("a", ["--seed", "7"]), ("b", ["-D", "seed=7"]), ("c", [])):
        assert synth_main(["render", small_scene, "--out", str(tmp_path / name), "--spp", "4",
                           "--quiet", *extra]) == 0
    a, b, c = ((tmp_path / n / "left.png").read_bytes() for n in "abc")
    assert a == b and a != c


@pytest.mark.slow
def test_conflicting_define_with_from_dataset(small_scene, tmp_path, capsys):
    data = tmp_path / "data"
    write_dataset(small_scene, data, spp=4, progress=False, defines={"n_water": "1.34"})
    out = tmp_path / "out"
    assert main(["run", small_scene, "--from", str(data), "--out", str(out), "--no-progress",
                 "-D", "n_water=1.36"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "n_water=1.36" in err[0] and "n_water=1.34" in err[0]
    assert not out.exists()
    # The dataset's own parameters are the truth: without -D, or with the same value, it runs.
    assert main(["run", small_scene, "--from", str(data), "--out", str(out), "--no-progress",
                 "-D", "n_water=1.34", "--methods", "optical_path"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["matching"]["wrong"] == 0 and report["matching"]["pairs"] > 0


def test_scene_with_no_visible_target(tmp_path, capsys):
    from synth.scene.rig import paper_cameras, paper_port
    from synth.scene import write_scene

    left, right = paper_cameras((320, 268), 150.0)
    # Far off to the side: in the water, but in neither field of view.
    scene = write_scene(tmp_path / "empty.xml", (left, right), paper_port(),
                        np.array([[5000.0, 0.0, 1000.0]]), 10.0)
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out), "--no-progress"]) == 2
    assert "no target is visible" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.slow
def test_eccentricity_is_corrected_by_default_and_reported_before_and_after(small_scene,
                                                                            tmp_path):
    """By default the headline numbers are on the centres corrected for the disks'
    eccentricity, the raw centroids' beside them; --no-eccentricity measures the raw centroids
    only, and gives back the default run's uncorrected numbers."""
    data = tmp_path / "data"
    write_dataset(small_scene, data, spp=16, progress=False)
    out = tmp_path / "out"
    assert main(["run", small_scene, "--from", str(data), "--out", str(out),
                 "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    ecc = report["eccentricity"]
    raw = ecc["uncorrected"]["methods"]
    assert set(raw) == set(report["methods"]) and ecc["iterations"] == 2
    # 16 mm disks at f = 150 px: offsets of a few hundredths of a pixel, predicted in both views
    for view in ("left", "right"):
        assert 0.001 < ecc["offset_px"][view]["max_px"] < 0.5
    assert raw["optical_path"]["n"] == report["methods"]["optical_path"]["n"]
    assert raw["optical_path"]["rms_dp_mm"] != report["methods"]["optical_path"]["rms_dp_mm"]
    assert report["crosscheck"]["rms_px_outline"] > 0
    assert "optical_path (raw centroids)" in (out / "report.md").read_text()
    plain = tmp_path / "plain"
    assert main(["run", small_scene, "--from", str(data), "--out", str(plain),
                 "--no-eccentricity", "--no-progress"]) == 0
    plain_report = json.loads((plain / "report.json").read_text())
    assert plain_report["eccentricity"] is None
    assert plain_report["methods"]["optical_path"] == raw["optical_path"]


@pytest.mark.slow
def test_truth_and_assumption(small_scene, tmp_path):
    """Rendered with n_water = 1.34, measured assuming 1.33: the report records both rigs and
    the difference, the cross-check still uses the truth, and the points move (mostly in Z)."""
    data = tmp_path / "data"
    write_dataset(small_scene, data, spp=16, progress=False, defines={"n_water": "1.34"})
    reports = {}
    for name, extra in (("exact", []), ("assumed", ["--assume", "n_water=1.33"]),
                        ("calib", ["--calib", str(data / "calib.yaml")])):
        out = tmp_path / name
        # the wrong index moves every point by millimetres, far outside its σ: the run knows
        # (coverage 0.000) and exits 1, its report written
        assert main(["run", small_scene, "--from", str(data), "--out", str(out),
                     "--methods", "optical_path", "--no-progress", *extra]) == (
            1 if name == "assumed" else 0)
        reports[name] = json.loads((out / "report.json").read_text())
    assert any("σ does not describe its errors" in f
               for f in reports["assumed"]["verdict"]["failures"])
    exact, assumed, calib = (reports[k] for k in ("exact", "assumed", "calib"))
    assert assumed["rigs"]["difference"] == {"index_2": pytest.approx(-0.01)}
    assert assumed["rigs"]["truth"]["port"]["indices"][-1] == 1.34
    assert exact["rigs"]["difference"] == {} and calib["rigs"]["difference"] == {}
    for key in ("rms_dp_mm", "mean_dz_mm", "max_dp_mm"):  # the pose went through R, T and back
        assert calib["methods"]["optical_path"][key] == pytest.approx(
            exact["methods"]["optical_path"][key], abs=1e-9)
    assert assumed["crosscheck"] == exact["crosscheck"]  # the simulator predicts the truth
    shift = assumed["methods"]["optical_path"]["mean_dz_mm"] - exact["methods"]["optical_path"]["mean_dz_mm"]
    assert abs(shift) > 5 * abs(exact["methods"]["optical_path"]["mean_dz_mm"]) and abs(shift) > 1.0


@pytest.mark.slow
def test_self_calibration_of_the_water_index(small_scene, tmp_path):
    """Rendered with n_water = 1.34, measured assuming 1.33, the index estimated in situ: the
    estimate lies within 4 σ of the truth and removes the depth bias of the wrong index."""
    data = tmp_path / "data"
    write_dataset(small_scene, data, spp=36, progress=False, defines={"n_water": "1.34"})
    out = tmp_path / "out"
    assert main(["run", small_scene, "--from", str(data), "--out", str(out), "--methods",
                 "optical_path", "--assume", "n_water=1.33", "--self-calibrate", "n_water",
                 "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    cal = report["self_calibration"]
    assert cal["converged"] and cal["identifiable"] and cal["truth"]["n_water"] == 1.34
    assert abs(cal["error_in_sigma"]["n_water"]) < 4 and cal["sigmas"]["n_water"] < 0.002
    before = report["methods"]["optical_path"]["mean_dz_mm"]
    after = cal["methods"]["optical_path"]["mean_dz_mm"]
    assert abs(after) < 0.25 * abs(before)


@pytest.mark.slow
def test_self_calibration_sigma_includes_the_calibrations_covariance(small_scene, tmp_path):
    """--calib with a covariance (left cx and the port distance, 0.1 px and 0.2 mm): the index's
    σ includes it — larger than the conditional σ, which is the σ without a covariance — and
    the report names what entered."""
    from measure.stereo.rig_covariance import RigCovariance
    from synth.products.dataset import read_calib, write_calib

    data = tmp_path / "data"
    write_dataset(small_scene, data, spp=16, progress=False, defines={"n_water": "1.34"})
    rig = read_calib(data / "calib.yaml")["rig"]
    calib = tmp_path / "calib.yaml"
    write_calib(calib, rig, covariance=RigCovariance(["left.cx", "port.distance"],
                                                     np.diag([0.1 ** 2, 0.2 ** 2])))
    runs = {}
    for name, extra in (("with", ["--calib", str(calib)]), ("without", [])):
        assert main(["run", small_scene, "--from", str(data), "--out", str(tmp_path / name),
                     "--methods", "optical_path", "--assume", "n_water=1.33",
                     "--self-calibrate", "n_water", "--no-progress", *extra]) == 0
        runs[name] = json.loads((tmp_path / name / "report.json").read_text())["self_calibration"]
    with_cov, without = runs["with"], runs["without"]
    assert with_cov["sigma_includes"] == ["left.cx", "port.distance"]
    assert without["sigma_includes"] == [] and without["sigmas"] == without["sigmas_conditional"]
    assert with_cov["sigmas_conditional"]["n_water"] == pytest.approx(
        without["sigmas"]["n_water"], rel=1e-6)
    assert with_cov["sigmas"]["n_water"] > 1.2 * with_cov["sigmas_conditional"]["n_water"]


@pytest.mark.slow
def test_a_run_with_wrong_matches_exits_1_and_still_writes_its_report(small_scene, tmp_path,
                                                                      capsys):
    """A depth window that holds only the neighbouring column's depth makes every match wrong:
    the run says so in one line, exits 1, and writes the report (whose verdict says why)."""
    out = tmp_path / "out"
    code = main(["run", small_scene, "--out", str(out), "--spp", "4", "--methods",
                 "optical_path", "--depth-range", "700,900", "--no-progress"])
    err = capsys.readouterr().err
    failed = [line for line in err.splitlines() if line.startswith("failed:")]
    assert code == 1, err
    assert len(failed) == 1 and "wrong" in failed[0] and "no pair was matched correctly" in failed[0]
    assert not [line for line in err.splitlines() if line.startswith("error:")]
    report = json.loads((out / "report.json").read_text())
    assert report["matching"]["wrong"] > 0 and report["matching"]["correct"] == 0
    assert report["verdict"]["passed"] is False and len(report["verdict"]["failures"]) == 2
    assert "Verdict" in (out / "report.md").read_text()


def test_a_cross_check_from_one_view_is_a_failure():
    """The headline cross-check would come from one view alone: the run fails."""
    from eval.run.pipeline import run_failures

    report = {"matching": {"wrong": 0, "correct": 10, "pairs": 10},
              "crosscheck": {"left": {"associated": 12}, "right": {"associated": 0}}}
    failures = run_failures(report)
    assert len(failures) == 1 and "right" in failures[0] and "one view" in failures[0]
    report["crosscheck"]["right"]["associated"] = 12
    assert run_failures(report) == []


def test_a_sigma_that_covers_fewer_than_half_of_the_points_is_a_failure():
    """A run whose points' σ covered 0.000 of them (RMS dP in millimetres) exited 0: a σ
    that covers fewer than half fails the run; an optimistic one (0.84) is said, not failed."""
    from eval.run.pipeline import run_failures

    report = {"matching": {"wrong": 0, "correct": 300, "pairs": 300},
              "crosscheck": {"left": {"associated": 300}, "right": {"associated": 300}},
              "uncertainty": {"summaries": {"optical_path": {"coverage": {
                  "coverage_95": 0.0, "n": 300}}}}}
    failures = run_failures(report)
    assert len(failures) == 1 and "optical_path's σ does not describe its errors" in failures[0]
    report["uncertainty"]["summaries"]["optical_path"]["coverage"]["coverage_95"] = 0.839
    assert run_failures(report) == []
    report["uncertainty"]["summaries"]["optical_path"]["coverage"].update(coverage_95=0.1, n=10)
    assert run_failures(report) == []  # too few points to judge


@pytest.mark.slow
def test_point_covariances_with_and_without_a_rig_covariance(small_scene, tmp_path, capsys):
    """The points of optical_path carry covariances: from the pixel noise alone with the
    scene's rig or a calibration without covariance (the report says so), larger with a
    calibration's covariance; their files, coverage and summaries; a singular covariance is
    refused with one line naming the file."""
    from measure.stereo.rig_covariance import RigCovariance
    from synth.products.dataset import read_calib, write_calib

    data = tmp_path / "data"
    write_dataset(small_scene, data, spp=16, progress=False)
    rig = read_calib(data / "calib.yaml")["rig"]
    names = ("port.distance", "port.index[2]", "right.center[0]")
    with_cov = tmp_path / "with.yaml"
    write_calib(with_cov, rig, covariance=RigCovariance(names, np.diag([1.0, 1e-3, 0.5]) ** 2))
    reports = {}
    for name, extra in (("scene", []), ("plain", ["--calib", str(data / "calib.yaml")]),
                        ("with", ["--calib", str(with_cov)]), ("stated", ["--pixel-sigma", "0.2"])):
        out = tmp_path / name
        assert main(["run", small_scene, "--from", str(data), "--out", str(out), "--methods",
                     "optical_path,su", "--no-progress", *extra]) == 0
        reports[name] = json.loads((out / "report.json").read_text())
    scene, plain, with_rig = reports["scene"], reports["plain"], reports["with"]
    assert "exact" in scene["uncertainty"]["rig"]
    assert "holds no covariance" in plain["uncertainty"]["rig"]
    assert "pixel-noise part only" in plain["uncertainty"]["rig"]
    assert "rig covariance" in with_rig["uncertainty"]["rig"]
    assert scene["methods"]["su"]["coverage_95"] is None  # no covariance for Su's method
    summary = scene["uncertainty"]["summaries"]["optical_path"]
    assert summary["coverage"]["n"] == scene["methods"]["optical_path"]["n"]
    assert scene["methods"]["optical_path"]["coverage_95"] == summary["coverage"]["coverage_95"]
    assert 0 <= summary["coverage"]["coverage_95"] <= 1
    assert scene["uncertainty"]["pixel_sigma"]["residual_sigma0_px"] > 0
    sz = {k: r["uncertainty"]["summaries"]["optical_path"]["sigma"]["median_sigma_mm"]["z"]
          for k, r in reports.items()}
    assert sz["with"] > 2 * sz["plain"] and sz["plain"] == pytest.approx(sz["scene"], rel=1e-6)
    assert reports["stated"]["uncertainty"]["pixel_sigma"]["stated_px"] == 0.2
    files = scene["uncertainty"]["files"]["optical_path"]
    rows = (tmp_path / "scene" / files["csv"]).read_text().splitlines()
    assert len(rows) == 1 + scene["methods"]["optical_path"]["n"]
    assert (tmp_path / "scene" / "ellipses.png").stat().st_size > 1000
    assert "## Uncertainty" in (tmp_path / "scene" / "report.md").read_text()
    # a singular covariance: refused, one line naming the file, nothing written
    singular = object.__new__(RigCovariance)
    for field_name, value in (("names", names[:2]), ("matrix", np.ones((2, 2))),
                              ("normal_axes", None)):
        object.__setattr__(singular, field_name, value)
    bad = tmp_path / "singular.yaml"
    write_calib(bad, rig, covariance=singular)
    capsys.readouterr()
    assert main(["run", small_scene, "--from", str(data), "--out", str(tmp_path / "bad"),
                 "--calib", str(bad), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "singular.yaml" in err[0]
    assert not (tmp_path / "bad").exists()


def test_a_run_that_matched_fewer_than_half_of_the_visible_targets_fails():
    """1 correct match of 290 targets visible in both views (a lens distortion that magnifies
    one view three times): the run fails and says so; half or more passes."""
    from eval.run.pipeline import run_failures

    crosscheck = {"left": {"associated": 239}, "right": {"associated": 15}}
    report = {"matching": {"wrong": 0, "correct": 1, "pairs": 1, "visible_in_both": 290},
              "crosscheck": crosscheck}
    failures = run_failures(report)
    assert len(failures) == 1 and "only 1 of the 290 targets" in failures[0]
    assert "less than half" in failures[0]
    report["matching"].update(correct=145, pairs=145)
    assert run_failures(report) == []


@pytest.mark.slow
def test_a_magnifying_distortion_that_matches_almost_nothing_exits_1(tmp_path, capsys):
    """``-D left_dist=5 0 0 0 0`` is invertible (no fold) but magnifies the left view ~3×:
    1 of 290 visible targets matched. Exit 1, one ``failed:`` line, the report written."""
    out = tmp_path / "out"
    code = main(["run", str(REPO / "scenes" / "paper_plane.xml"), "-D", "left_dist=5 0 0 0 0",
                 "-D", "width=320", "-D", "height=268", "--spp", "4", "--no-progress", "--out", str(out)])
    err = capsys.readouterr().err
    failed = [line for line in err.splitlines() if line.startswith("failed:")]
    assert code == 1, err
    assert len(failed) == 1 and "less than half" in failed[0]
    report = json.loads((out / "report.json").read_text())
    assert report["verdict"]["passed"] is False
    assert report["matching"]["correct"] < report["matching"]["visible_in_both"] / 2


@pytest.mark.slow
def test_spp_that_the_sampler_rounds_up_is_said_and_json_stays_json(small_scene, tmp_path,
                                                                    capsys):
    """``--spp 5``: the scenes' multijitter sampler renders 6. The report records both and the
    summary says 6; Mitsuba's warning goes to stderr, so ``--json`` prints valid JSON."""
    out = tmp_path / "out"
    assert main(["run", small_scene, "--out", str(out), "--spp", "5", "--no-progress",
                 "--json"]) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out)  # Mitsuba's log line made this invalid
    assert report["spp"] == 5 and report["spp_rendered"] == 6
    assert "6 spp (5 requested" in captured.err
