"""python -m eval run on a scene of three cameras (small images, few large targets): every
target two views see is matched, none wrongly, and each is reported with the views that saw
it (the forward model's count); bad input is one error line naming the camera."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from eval.cli import main as eval_main
from eval.core.analytic import visible_targets
from synth.scene import load_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from synth.__main__ import main

    path = tmp_path_factory.mktemp("three") / "three.xml"
    assert main(["scene", "--cameras", "3", "--layout", "grid", "--spacing", "150",
                 "--half-width", "600", "--target-radius", "10", "--size", "320", "268",
                 "--out", str(path)]) == 0
    return str(path)


@pytest.mark.slow
def test_three_cameras_match_and_report_views(scene, tmp_path):
    out = tmp_path / "run"
    assert eval_main(["run", scene, "--out", str(out), "--spp", "16", "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    spec = load_scene(scene)
    rig = spec.multirig
    seen = sum(visible_targets(c, rig.view_port(k), spec.targets, spec.target_radius)[1]
               for k, c in enumerate(rig.cameras))
    m = report["matching"]
    assert m["wrong"] == 0 and m["visible_in_two_or_more"] == int((seen >= 2).sum())
    assert m["visible_in_two_or_more_matched"] == m["visible_in_two_or_more"]
    assert m["seen_once"] == int((seen == 1).sum()) > 0
    with open(out / "targets.csv") as fh:
        rows = list(csv.DictReader(fh))
    visible = np.array([float(r["views_visible"]) for r in rows])
    used = np.array([float(r["views_triangulated"]) for r in rows])
    np.testing.assert_array_equal(visible, seen)
    assert np.all(used[seen == 1] == 0)  # seen once: reported, never triangulated
    assert set(report["methods"]["optical_path"]["by_views"]) == {"2", "3"}
    # at 320 px a target's depth error through the port is a fraction of a millimetre
    assert report["methods"]["optical_path"]["rms_dp_mm"] < 1.0


def test_bad_input_names_the_camera(scene, tmp_path, capsys):
    calib = tmp_path / "calib.yaml"
    from synth.products.rig_file import write_rig_file

    spec = load_scene(scene)
    write_rig_file(calib, spec.multirig)
    text = calib.read_text()
    calib.write_text(text.replace("data: [ 400., 0., 0. ]", "data: [ 200., 0., 0. ]"))
    for extra, fragment in ((["--calib", str(calib)], "cameras cam1 and cam2 overlap"),
                            (["--assume", "n_water=1.34"], "--assume does not apply"),
                            (["--no-figures"], "--no-figures does not apply")):
        assert eval_main(["run", scene, "--out", str(tmp_path / "out"), "--no-progress",
                          *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not (tmp_path / "out").exists()


def test_commands_of_a_stereo_pair_refuse_more_cameras(scene, tmp_path, capsys):
    """A command that handles two views refuses a scene of three rather than use its first two
    cameras alone: one error line naming the scene and the command."""
    from synth.__main__ import main as synth_main

    for main, argv, command in (
            (synth_main, ["sequence", scene, "--approach", "2000,1000", "--frames", "2"],
             "synth sequence"),
            (eval_main, ["render-bench", scene, "--parts", "throughput"], "eval render-bench")):
        out = tmp_path / command.replace(" ", "_")
        assert main([*argv, "--out", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:"), err
        assert "3 cameras" in err[0] and command in err[0], err
        assert not out.exists()


def test_a_surface_scene_of_three_cameras_is_refused_by_dense_matching(
        surface_scene_of_three_cameras, tmp_path, capsys):
    """``eval run`` on a speckled surface seen by three sensors (the committed plane with a
    third camera added by hand): dense matching is a two-view method — one error line, nothing
    measured (it measured cam0 and cam1 as a pair before)."""
    scene = surface_scene_of_three_cameras
    out = tmp_path / "run"
    assert eval_main(["run", str(scene), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "3 cameras" in err[0] and "two views" in err[0], err
    assert not out.exists()


@pytest.mark.slow
def test_from_a_dataset_of_three_cameras_measures_its_images(scene, tmp_path, capsys):
    """``eval run --from DIR`` on a dataset of three cameras: the dataset's images, matched
    without truth and scored here against the scene's true targets; a changed file, or an
    option of a render, is one error line."""
    from synth.__main__ import main as synth_main
    from synth.scene import load_scene

    data = tmp_path / "ds"
    assert synth_main(["dataset", scene, "--out", str(data), "--spp", "16",
                       "--no-progress"]) == 0
    out = tmp_path / "run"
    assert eval_main(["run", scene, "--from", str(data), "--out", str(out),
                      "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["render"]["from"].endswith("ds") and report["spp"] == 16
    spec = load_scene(scene)
    rig = spec.multirig
    seen = sum(visible_targets(c, rig.view_port(k), spec.targets, spec.target_radius)[1]
               for k, c in enumerate(rig.cameras))
    m = report["matching"]
    assert m["wrong"] == 0 and m["visible_in_two_or_more"] == int((seen >= 2).sum())
    assert m["visible_in_two_or_more_matched"] == m["visible_in_two_or_more"]
    with open(out / "targets.csv") as fh:
        rows = list(csv.DictReader(fh))
    points = np.array([[float(r[a]) for a in "xyz"] for r in rows])
    used = np.array([float(r["views_triangulated"]) for r in rows]) >= 2
    errors = np.linalg.norm(points[used] - spec.targets[used], axis=1)  # the true targets
    assert used.sum() == m["visible_in_two_or_more"] and errors.max() < 3.0
    assert np.sqrt(np.mean(errors ** 2)) < 1.0
    assert set(report["methods"]["optical_path"]["by_views"]) == {"2", "3"}

    four = tmp_path / "four.xml"  # another scene, of four cameras (it said "unknown
    assert synth_main(["scene", "--cameras", "4", "--size", "320", "268",  # parameter -D …")
                       "--out", str(four)]) == 0
    capsys.readouterr()
    assert eval_main(["run", str(four), "--from", str(data), "--out", str(tmp_path / "bad"),
                      "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rendered from another scene" in err[0] and "3 cameras" in err[0], err
    assert not (tmp_path / "bad").exists()
    (data / "cam2" / "preview.png").write_bytes(b"not the preview")
    for argv, fragment in ((["--from", str(data)], "cam2/preview.png"),
                           (["--from", str(data), "--spp", "4"], "--spp does not apply")):
        assert eval_main(["run", scene, *argv, "--out", str(tmp_path / "bad"),
                          "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not (tmp_path / "bad").exists()



@pytest.mark.slow
def test_points_of_three_cameras_carry_covariances_that_cover_their_errors(scene, tmp_path):
    """Each track's point gets the covariance of its pixels' noise (the σ the residuals show
    beyond the detector's — here the added 0.1 px — or a stated one with the added noise in
    quadrature): the normalized errors against the truth have a spread of 1 within 25 % per
    axis (a variance off by a factor 2 is 41 %) and at least 85 % lie inside their 95 %
    ellipsoid; the files hold every correct point with its σ. ``--gate-mm 5``: at 320 px the
    default 0.5 mm gate keeps only the tracks whose rays the noise left close (44 of 64 at
    0.1 px), and their residuals understate the noise (0.04 px; the report then says σ
    understates the errors)."""
    for name, extra, sigma_px in (("auto", [], 0.1),
                                  ("stated", ["--pixel-sigma", "0.01"], np.hypot(0.01, 0.1))):
        out = tmp_path / name
        assert eval_main(["run", scene, "--out", str(out), "--spp", "16", "--no-progress",
                          "--noise-px", "0.1", "--gate-mm", "5", *extra]) == 0
        report = json.loads((out / "report.json").read_text())
        entry = report["uncertainty"]
        assert entry["methods"] == ["optical_path"] and "exact" in entry["rig"]
        assert abs(entry["pixel_sigma"]["median_px"] - sigma_px) <= 0.1 * sigma_px, entry
        coverage = entry["summaries"]["optical_path"]["coverage"]
        assert coverage["n"] == report["methods"]["optical_path"]["n"] >= 30
        spread = [coverage["normalized"][a]["std"] for a in "xyz"]
        assert all(0.75 <= s <= 1.25 for s in spread), coverage
        assert coverage["coverage_95"] >= 0.85, coverage
        with open(out / "uncertainty_optical_path.csv") as fh:
            rows = list(csv.DictReader(fh))
        assert len(rows) == coverage["n"]
        assert all(float(r["sigma_z"]) > 0 for r in rows)
    # at the default gate the matcher keeps the tracks the noise left close: σ understated, and
    # the report says what the pixels' covariance cannot hold
    out = tmp_path / "gate"
    assert eval_main(["run", scene, "--out", str(out), "--spp", "16", "--no-progress",
                      "--noise-px", "0.1"]) == 0
    coverage = json.loads((out / "report.json").read_text())["uncertainty"]["summaries"][
        "optical_path"]["coverage"]
    assert coverage["coverage_95"] < 0.9 and "--gate-mm" in coverage["verdict"], coverage


@pytest.mark.slow
def test_a_calibration_off_the_truth_is_named_in_the_verdict(scene, tmp_path):
    """--calib with cam2 1 mm farther along the baseline than rendered: its points share the
    rig's error, σ understates it, and the verdict puts it down to the calibration's rig (what
    differs, named as the pair's verdict names it), not to the pixels."""
    from synth.products.rig_file import write_rig_file

    calib = tmp_path / "calib.yaml"
    write_rig_file(calib, load_scene(scene).multirig)
    text = calib.read_text()
    assert text.count("data: [ 400., 0., 0. ]") == 1
    calib.write_text(text.replace("data: [ 400., 0., 0. ]", "data: [ 401., 0., 0. ]"))
    out = tmp_path / "off"
    assert eval_main(["run", scene, "--out", str(out), "--spp", "16", "--no-progress",
                      "--calib", str(calib)]) == 0
    coverage = json.loads((out / "report.json").read_text())["uncertainty"]["summaries"][
        "optical_path"]["coverage"]
    assert coverage["n"] >= 30 and coverage["coverage_95"] < 0.9, coverage
    assert "differs from the truth (cam2 pose: --assume or --calib)" in coverage["verdict"]


def test_a_report_from_before_one_schema_is_read_where_its_scores_were():
    """The N views' scores moved from ``scores`` to ``methods.optical_path`` (the pair's
    schema): a report of either place gives the same scores and the same report.md."""
    from eval.run.multiview import report_markdown, view_scores

    by_views = {"2": {"tracks": 3, "scored": 3, "rms_dp_mm": 0.5, "stats": {}},
                "3": {"tracks": 7, "scored": 6, "rms_dp_mm": 0.25, "stats": {}}}
    common = {"scene": "three.xml", "cameras": ["cam0", "cam1", "cam2"],
              "method": "optical_path", "verdict": {"passed": True, "failures": []},
              "matching": {"tracks": 10, "correct": 9, "wrong": 1, "conflicts_dropped": 0,
                           "visible_in_two_or_more": 10, "visible_in_two_or_more_matched": 9,
                           "seen_once": 2}}
    old = {**common, "scores": {"n": 9, "rms_dp_mm": 0.3, "stats": {}, "by_views": by_views}}
    new = {**common, "methods": {"optical_path": {"n": 9, "rms_dp_mm": 0.3,
                                                  "coverage_95": None, "by_views": by_views}}}
    assert view_scores(old) == view_scores(new) == {"n": 9, "rms_dp_mm": 0.3,
                                                    "by_views": by_views}
    text = report_markdown(new)
    assert text == report_markdown(old) and "| all | 9 | 0.3000 |" in text


@pytest.mark.slow
def test_three_cameras_with_the_reprojection_method_of_n_views(scene, tmp_path, capsys):
    """--methods optical_path,reprojection: both in ``methods`` in the pair's schema, the same
    tracks scored, the optical path's numbers those of a run of it alone, the reprojection's
    point (triangulate_rig) as close to the truth, each with its covariance files; a pair
    method is refused."""
    runs = {}
    for name, methods in (("both", "optical_path,reprojection"), ("alone", "optical_path")):
        out = tmp_path / name
        assert eval_main(["run", scene, "--out", str(out), "--spp", "16", "--no-progress",
                          "--noise-px", "0.1", "--gate-mm", "5", "--methods", methods]) == 0
        runs[name] = json.loads((out / "report.json").read_text())
    both = runs["both"]
    assert both["method"] == "optical_path" and list(both["methods"]) == ["optical_path",
                                                                          "reprojection"]
    assert both["methods"]["optical_path"] == runs["alone"]["methods"]["optical_path"]
    optical, reprojection = both["methods"]["optical_path"], both["methods"]["reprojection"]
    assert reprojection["n"] == optical["n"] >= 30 and reprojection["invalid"] == 0
    assert set(reprojection["by_views"]) == {"2", "3"}
    assert reprojection["rms_dp_mm"] < 1.2 * optical["rms_dp_mm"]
    assert reprojection["rms_dp_mm"] != optical["rms_dp_mm"]
    assert both["uncertainty"]["methods"] == ["optical_path", "reprojection"]
    assert reprojection["coverage_95"] >= 0.85
    assert (tmp_path / "both" / "uncertainty_reprojection.csv").exists()
    assert "reprojection: RMS dP" in (tmp_path / "both" / "report.md").read_text()
    capsys.readouterr()
    assert eval_main(["run", scene, "--out", str(tmp_path / "su"), "--no-progress",
                      "--methods", "optical_path,su"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "optical_path or reprojection" in err[0] and "not su" in err[0]
