"""python -m eval score: an external reconstruction scored against a rendered dataset."""

from __future__ import annotations

import csv
import json
import re

import numpy as np
import open3d as o3d
import pytest

from eval.cli import main
from eval.score import associate_points, default_gate_mm
from synth.products.dataset import write_dataset

SPP = 16


@pytest.fixture(scope="module")
def scored_run(small_scene, tmp_path_factory):
    root = tmp_path_factory.mktemp("score")
    data, run = root / "data", root / "run"
    write_dataset(small_scene, data, spp=SPP, progress=False)
    assert main(["run", small_scene, "--from", str(data), "--out", str(run),
                 "--no-progress"]) == 0
    return data, run, json.loads((run / "report.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("method, gate", [("optical_path", []), ("su", ["--gate-mm", "40"])])
def test_scoring_a_runs_own_points_reproduces_its_numbers(scored_run, tmp_path, method, gate):
    """Su's errors (up to ~5 mm here) exceed the default gate (half the 80 mm spacing is
    40 mm; the default is that, computed from the truth) only if told otherwise."""
    data, run, report = scored_run
    assert report["matching"]["wrong"] == 0
    out = tmp_path / "score"
    assert main(["score", str(data), "--points", str(run / f"points_{method}.ply"),
                 "--out", str(out)] + gate) == 0
    scored = json.loads((out / "report.json").read_text())
    theirs = scored["methods"]["theirs"]
    ours = report["methods"][method]
    assert set(ours) == set(theirs)
    for key, value in ours.items():
        if key != "coverage_95":  # a point's covariance needs its pixels: not in a PLY file
            assert theirs[key] == value, key
    assert theirs["coverage_95"] is None
    assert scored["association"]["unassociated"] == 0
    assert (scored["association"]["visible_in_both_scored"]
            == report["matching"]["visible_in_both_matched"])
    for name in ("report.md", "error_maps.png", "histograms.png", "points_scored.ply"):
        assert (out / name).stat().st_size > 200


@pytest.mark.slow
def test_matched_pixels_are_triangulated_with_the_datasets_calibration(scored_run, tmp_path,
                                                                        capsys):
    data, _, _ = scored_run
    rows = list(csv.DictReader(open(data / "pixels.csv")))
    pairs = tmp_path / "pairs.csv"
    with open(pairs, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["u_left", "v_left", "u_right", "v_right", "note"])
        for row in rows:  # the simulator's exact pixels of every target
            writer.writerow([row["u_left"], row["v_left"], row["u_right"], row["v_right"], "x"])
    out = tmp_path / "score"
    assert main(["score", str(data), "--pixels", str(pairs), "--out", str(out)]) == 0
    scored = json.loads((out / "report.json").read_text())
    st = scored["methods"]["optical_path"]
    assert st["n"] == len(rows) and scored["association"]["unassociated"] == 0
    # Exact pixels through the exact model: round-off only — and no ellipsoids of round-off
    # size whose "coverage" would say σ fails (it read 0.008 here before)
    assert st["rms_dp_mm"] < 1e-8
    assert st["coverage_95"] is None
    assert scored["uncertainty"]["note"].startswith("no coverage: the pixels carry no noise")
    # The same pixels with the port absorbed by a pinhole calibration of the dataset's boards
    # (docs/absorbed.md): its virtual frame puts the points tens of mm off (a wider gate keeps
    # each with its target), and the lengths between them err where the optical path's do not.
    out = tmp_path / "score_absorbed"
    # with a gate narrower than its offset none of them is associated: a fail that says what
    # to do, not a score of nothing with exit 0
    assert main(["score", str(data), "--pixels", str(pairs), "--method", "absorbed",
                 "--gate-mm", "10", "--out", str(tmp_path / "narrow")]) == 1
    assert "give a wider --gate-mm" in capsys.readouterr().err
    assert main(["score", str(data), "--pixels", str(pairs), "--method", "absorbed",
                 "--gate-mm", "200", "--out", str(out)]) == 0
    absorbed = json.loads((out / "report.json").read_text())["methods"]["absorbed"]
    assert absorbed["n"] == len(rows) and absorbed["rms_dp_mm"] > 1.0
    assert abs(absorbed["length_worst_pct"]) > 1e3 * abs(st["length_worst_pct"])


def _noisy_pairs(rows, path, sigma_px: float = 0.1, seed: int = 12):
    """``path``: the finite pixel pairs of a dataset's ``pixels.csv`` rows with Gaussian noise
    of ``sigma_px`` on each coordinate (seeded)."""
    rng = np.random.default_rng(seed)
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["u_left", "v_left", "u_right", "v_right"])
        for row in rows:
            exact = np.array([float(row[c]) for c in ("u_left", "v_left", "u_right", "v_right")])
            if np.all(np.isfinite(exact)):
                writer.writerow(exact + rng.normal(0, sigma_px, 4))
    return path


@pytest.mark.slow
def test_pixels_get_covariances_and_their_coverage(scored_run, tmp_path, capsys):
    """Noisy pixels (σ = 0.1 px, seeded) triangulated with the dataset's calib.yaml, which holds
    no covariance: the points carry the pixel-noise part only (the report says so), σ from the
    residuals, and about 95 % of them lie inside their 95 % ellipsoid."""
    data, _, _ = scored_run
    rows = list(csv.DictReader(open(data / "pixels.csv")))
    pairs = _noisy_pairs(rows, tmp_path / "pairs.csv")
    for extra in ([], ["--pixel-sigma", "0.1"]):
        out = tmp_path / f"score{len(extra)}"
        assert main(["score", str(data), "--pixels", str(pairs), "--out", str(out), *extra]) == 0
        scored = json.loads((out / "report.json").read_text())
        unc = scored["uncertainty"]
        assert "holds no covariance" in unc["rig"] and "pixel-noise part only" in unc["rig"]
        coverage = scored["methods"]["optical_path"]["coverage_95"]
        assert 0.85 <= coverage <= 1.0, coverage
        assert unc["summaries"]["optical_path"]["coverage"]["n"] == len(rows)
        assert (out / "uncertainty_optical_path.csv").exists() and (out / "ellipses.png").exists()
    assert unc["pixel_sigma"]["stated_px"] == 0.1
    assert "coverage of the 95 % ellipsoids" in capsys.readouterr().out
    # --pixel-sigma needs pixels
    assert main(["score", str(data), "--points", str(tmp_path / "x.ply"), "--pixel-sigma",
                 "0.1", "--out", str(tmp_path / "no")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--pixel-sigma" in err[0]


@pytest.mark.slow
def test_pixels_through_domes_get_covariances_too(tmp_path):
    """Behind the decentred domes (a small render) noisy pixels (σ = 0.1 px, seeded) get point
    covariances like a flat port's (they were left without: the port's kind was asked), and
    at least 85 % of the points lie inside their 95 % ellipsoid — the flat port's test band.
    Here the σ is conservative in depth: 0.993 of 423 points covered with this seed, 0.966 of
    412 with another, the depth errors' normalized std 0.72 (x 0.87, y 0.92)."""
    from synth.commands import main as synth_main

    data = tmp_path / "ds"
    assert synth_main(["dataset", "scenes/dome_decentred.xml", "-D", "width=612", "-D",
                       "height=512", "--spp", "16", "--out", str(data), "--quiet"]) == 0
    pairs = _noisy_pairs(list(csv.DictReader(open(data / "pixels.csv"))), tmp_path / "pairs.csv")
    out = tmp_path / "score"
    assert main(["score", str(data), "--pixels", str(pairs), "--out", str(out), "--quiet"]) in (0, 1)
    scored = json.loads((out / "report.json").read_text())
    summary = scored["uncertainty"]["summaries"]["optical_path"]
    assert summary["coverage"]["n"] > 300
    assert 0.85 <= scored["methods"]["optical_path"]["coverage_95"] <= 1.0


def test_association_is_one_to_one_and_gated():
    truth = np.array([[0.0, 0, 1000], [40, 0, 1000], [80, 0, 1000]])
    points = np.array([[0.3, 0, 1000], [0.1, 0, 1000], [41, 0, 1000], [60, 0, 1000]])
    assert associate_points(points, truth, 5.0).tolist() == [-1, 0, 1, -1]
    assert associate_points(np.zeros((0, 3)), truth, 5.0).tolist() == []
    assert default_gate_mm(truth) == 20.0


def test_duplicates_are_said_to_be_duplicates_not_far():
    """A point on a target a nearer point holds is a duplicate (the same match written twice),
    not a point farther than the gate from every target (issue 53: "not within 40 mm")."""
    from eval.core.scoring import score_points, unassociated_text

    truth = np.array([[0.0, 0, 1000], [40, 0, 1000], [80, 0, 1000]])
    points = np.array([[0.3, 0, 1000], [0.1, 0, 1000], [41, 0, 1000], [60, 0, 1000],
                       [41, 0, 1000]])
    association = score_points(points, truth, np.ones(3, bool), 5.0, 0)[2]
    assert association["unassociated"] == 3 and association["duplicates"] == 2
    assert unassociated_text(association) == ("3 not: 2 duplicate(s) of a target a nearer "
                                              "point holds, 1 farther than 5 mm from every "
                                              "target")


def _fails(capsys, args, fragment):
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err


@pytest.mark.slow
def test_bad_input_exits_2_and_writes_nothing(scored_run, tmp_path, capsys):
    data, _, _ = scored_run
    out = tmp_path / "out"
    empty = tmp_path / "empty.ply"
    empty.write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty double x\n"
                     "property double y\nproperty double z\nend_header\n")
    garbage = tmp_path / "garbage.ply"
    garbage.write_text("not a point cloud\n")
    nan = tmp_path / "nan.ply"
    o3d.io.write_point_cloud(str(nan), o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.array([[0.0, 0, 1000], [np.nan, 0, 1000]]))))
    short = tmp_path / "short.csv"
    short.write_text("u_left,v_left,u_right\n1,2,3\n")
    text = tmp_path / "text.csv"
    text.write_text("u_left,v_left,u_right,v_right\n1,2,three,4\n")
    _fails(capsys, ["score", str(data), "--points", str(empty), "--out", str(out)], "no points")
    _fails(capsys, ["score", str(data), "--points", str(garbage), "--out", str(out)],
           "not a PLY file")
    _fails(capsys, ["score", str(data), "--points", str(nan), "--out", str(out)], "NaN")
    _fails(capsys, ["score", str(data), "--points", str(tmp_path / "none.ply"), "--out",
                    str(out)], "no such file")
    _fails(capsys, ["score", str(data), "--pixels", str(short), "--out", str(out)],
           "missing column(s) v_right")
    _fails(capsys, ["score", str(data), "--pixels", str(text), "--out", str(out)], "line 2")
    _fails(capsys, ["score", str(tmp_path), "--points", str(nan), "--out", str(out)],
           "manifest.json")
    assert not out.exists()


def test_an_empty_cloud_is_still_written(tmp_path):
    """A method with no correctly matched target still gets its (empty, valid) PLY."""
    from eval.core.cloud_metrics import write_colored_ply

    write_colored_ply(tmp_path / "e.ply", np.zeros((0, 3)), np.zeros(0), 1.0)
    text = (tmp_path / "e.ply").read_text()
    assert text.startswith("ply\n") and "element vertex 0" in text and text.endswith("end_header\n")


def _submit(path, points):
    o3d.io.write_point_cloud(str(path), o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(points)), write_ascii=False)
    return str(path)


def _theirs(run):
    return np.asarray(o3d.io.read_point_cloud(str(run / "points_optical_path.ply")).points)


@pytest.mark.slow
@pytest.mark.parametrize("name, change, cause", [
    ("metres", lambda p: p / 1000, r"looks like metres \(pass --units m\)"),
    ("flip_y", lambda p: p * [1, -1, 1], "y negated"),
    ("offset", lambda p: p + [80, 0, 0], r"rigid shift of \(-80\.\d, [+-]0\.\d, [+-]0\.\d\) mm"),
    ("offset_small", lambda p: p + [0, 0, 25], r"rigid shift of \([+-]0\.\d, [+-]0\.\d, -2[45]\.\d\) mm"),
    ("duplicates", lambda p: np.concatenate([p, p[:10]]), "10 points repeat"),
])
def test_an_implausible_submission_gets_one_warning_naming_the_likely_cause(
        scored_run, tmp_path, capsys, name, change, cause):
    """Scored as given, with one warning line on stderr and in the report (issue 22: a cloud
    in metres scored '0 of 69 points within 40 mm' with no hint, a y-flipped one scored like
    the right one, an 80 mm offset one like a good one with 8 points fewer); exit 1 with a
    FAIL line exactly when none of the points lies within the gate of a target (issue 53:
    that was exit 0)."""
    data, run, _ = scored_run
    theirs = _submit(tmp_path / f"{name}.ply", change(_theirs(run)))
    out = tmp_path / "score"
    code = main(["score", str(data), "--points", theirs, "--out", str(out)])
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and re.search(cause, warnings[0]), warnings
    report = json.loads((out / "report.json").read_text())
    nothing = report["association"]["associated"] == 0
    assert code == (1 if nothing else 0) and ("FAIL: none of the" in err) == nothing
    assert nothing or name != "metres"
    assert len(report["warnings"]) == 1 and re.search(cause, report["warnings"][0])
    assert re.search(cause, (out / "report.md").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("method", ["optical_path", "su", "regular"])
def test_a_plausible_submission_gets_no_warning(scored_run, tmp_path, capsys, method):
    """The run's own clouds, of every method (su's errors of a few mm, regular's of tens of
    mm: a wrong model is not a wrong frame), are scored without a warning."""
    data, run, _ = scored_run
    out = tmp_path / "score"
    code = main(["score", str(data), "--points", str(run / f"points_{method}.ply"), "--out",
                 str(out)])
    assert "warning:" not in capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    assert report["warnings"] == []
    # regular triangulation, which ignores the port, misses every target by more than the
    # gate at this scene's distance: nothing scored is exit 1 (the report says it all)
    assert code == (1 if report["association"]["associated"] == 0 else 0)
    assert method != "optical_path" or code == 0


@pytest.mark.slow
def test_units_m_converts_a_cloud_in_metres(scored_run, tmp_path, capsys):
    data, run, _ = scored_run
    metres = _submit(tmp_path / "metres.ply", _theirs(run) / 1000)
    out = tmp_path / "score"
    assert main(["score", str(data), "--points", metres, "--units", "m", "--out", str(out)]) == 0
    assert "warning:" not in capsys.readouterr().err
    scored = json.loads((out / "report.json").read_text())
    assert scored["source"]["units"] == "m" and scored["association"]["unassociated"] == 0
    millimetres = json.loads((run / "report.json").read_text())["methods"]["optical_path"]
    np.testing.assert_allclose(scored["methods"]["theirs"]["rms_dp_mm"],
                               millimetres["rms_dp_mm"], rtol=1e-9)


def test_units_does_not_apply_to_pixels(tmp_path, capsys):
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("u_left,v_left,u_right,v_right\n1,2,3,4\n")
    assert main(["score", str(tmp_path / "missing_ds"), "--pixels", str(pairs), "--units", "m",
                 "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--units does not apply with --pixels" in err[0]
    assert not (tmp_path / "out").exists()


def _fake_suite(root):
    """A suite folder as far as eval score's option checks read it: suite.json and an index of
    two target datasets."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    suite = root / "suite"
    suite.mkdir()
    (suite / "suite.json").write_text("{}")
    rows = [{"folder": f"ds{i}", "render": "targets", "status": "ok", "scene": "s", "seed": i}
            for i in range(2)]
    pq.write_table(pa.Table.from_pylist(rows), suite / "index.parquet")
    return suite


def test_method_is_refused_when_every_submission_is_a_cloud(tmp_path, capsys):
    """``--method su`` with only points.ply submissions: nothing is triangulated, the option
    cannot apply (it was ignored). With a pairs.csv among them it applies."""
    suite = _fake_suite(tmp_path)
    sub = tmp_path / "sub"
    for i in range(2):
        (sub / f"ds{i}").mkdir(parents=True)
        (sub / f"ds{i}" / "points.ply").write_text("ply\n")
    out = tmp_path / "scores"
    assert main(["score", str(suite), "--submission", str(sub), "--method", "su", "--out",
                 str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --method su does not apply"), err
    assert not out.exists()
    from eval.score import refuse_method_without_pairs

    (sub / "ds1" / "points.ply").unlink()
    (sub / "ds1" / "pairs.csv").write_text("u_left,v_left,u_right,v_right\n")
    refuse_method_without_pairs(str(suite), str(sub), "su")  # applies: no error


def test_a_suggested_option_value_reads_as_typed():
    """``--gate-mm 1e9`` was suggested back as ``--gate-mm 1e+09``."""
    from eval.measure.pipeline import TargetOptions, nothing_matched

    text = nothing_matched("p", {"left": 3, "right": 4}, TargetOptions(gate_mm=1e9))
    assert "--gate-mm 1e9" in text and "e+" not in text


@pytest.mark.slow
def test_dense_points_of_eval_measure_are_scored_against_the_surface(tmp_path, capsys):
    """``eval measure --dense``'s points.ply scored by ``eval score`` outside a suite (issue
    53: "a surface dataset …; eval score scores target datasets"): the point-to-mesh RMS is the
    RMS distance of the points from the plane the dataset's mesh lies in (computed here from
    the mesh's vertices); the same points in metres are exit 1 with the hint."""
    import open3d as o3d

    from synth.__main__ import main as synth_main
    from synth.scene.surfaces import read_ply

    data = tmp_path / "plane"
    assert synth_main(["dataset", "scenes/speckle_plane.xml", "-D", "width=320", "-D",
                       "height=268", "--spp", "16", "--out", str(data), "--no-progress"]) == 0
    measured = tmp_path / "measured"
    assert main(["measure", "--calib", str(data / "calib.yaml"), str(data / "left.png"),
                 str(data / "right.png"), "--dense", "--depth-range", "900,1100", "--out",
                 str(measured), "--no-progress"]) == 0
    out = tmp_path / "score"
    assert main(["score", str(data), "--points", str(measured / "points.ply"), "--out",
                 str(out)]) == 0
    scores = json.loads((out / "report.json").read_text())["scores"]
    vertices, _ = read_ply(str(data / "surface.ply"))
    centre = vertices.mean(axis=0)
    normal = np.linalg.svd(vertices - centre)[2][-1]
    points = np.asarray(o3d.io.read_point_cloud(str(measured / "points.ply")).points)
    rms = float(np.sqrt(np.mean(((points - centre) @ normal) ** 2)))
    assert scores["p2m_rms_mm"] == pytest.approx(rms, rel=1e-4) and rms < 5.0
    np.savetxt(tmp_path / "metres.xyz", points / 1000.0)
    capsys.readouterr()
    assert main(["score", str(data), "--points", str(tmp_path / "metres.xyz"), "--out",
                 str(tmp_path / "m")]) == 1
    err = capsys.readouterr().err
    assert "looks like metres" in err and "FAIL: none of the" in err, err
