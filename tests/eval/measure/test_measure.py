"""``python -m eval measure`` end to end on small renders exported as 8-bit sRGB PNG photos
(``synth photos --format png``): the measured points against the dataset's truth, ``eval score``
on the written cloud, several pairs, dense matching; and the bad inputs (exit 2, one ``error:``
line, no output directory left).

The bounds come from measuring these very cases (numbers in the comments: 2026-12-02, 2 cores),
with margin for the renderer."""

from __future__ import annotations

import csv
import json
import os
import shutil

import cv2
import numpy as np
import open3d as o3d
import pytest

from eval.cli import main as eval_main
from synth.__main__ import main as synth_main
from synth.products.dataset import write_calib, write_dataset
from synth.scene.rig import paper_cameras, paper_port

SPP = 16
COLUMNS = ["pair", "method", "x_mm", "y_mm", "z_mm", "gap_mm", "u_left", "v_left", "u_right",
           "v_right"]


@pytest.fixture(scope="module")
def photos(small_scene, tmp_path_factory):
    """The small target scene rendered as a dataset and exported as 8-bit sRGB PNG photos."""
    root = tmp_path_factory.mktemp("measure")
    write_dataset(small_scene, root / "ds", spp=SPP, progress=False)
    assert synth_main(["photos", str(root / "ds"), "--out", str(root / "ph"), "--format",
                       "png"]) == 0
    return root


def _nearest(points, truth):
    from scipy.spatial import cKDTree

    return cKDTree(truth).query(points)[0]


@pytest.mark.slow
def test_one_pair_measures_the_targets_and_eval_score_reads_the_cloud(photos, capsys):
    root, out = photos, photos / "out"
    assert eval_main(["measure", "--calib", str(root / "ds" / "calib.yaml"),
                      str(root / "ph" / "left" / "pair.png"), str(root / "ph" / "right" / "pair.png"),
                      "--out", str(out), "--methods", "optical_path,regular", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "1 pair(s), 1 measured: 81 targets matched" in printed and f"wrote {out}" in printed
    report = json.loads((out / "report.json").read_text())
    pair = report["pairs"][0]
    # measured here: 81 of 81 detected and matched, none ambiguous; gap RMS 0.116 mm
    assert pair["detected"] == {"left": 81, "right": 81} and pair["matched"] == 81
    assert pair["ambiguous"] == 0 and pair["unmatched"] == {"left": 0, "right": 0}
    optical = pair["methods"]["optical_path"]
    assert optical["points"] == 81 and optical["gap"]["rms_mm"] < 0.3
    # the plane Z = 1000 mm, facing the cameras: plane RMS 0.54 mm here
    plane = optical["plane"]
    assert plane["normal"][2] < -0.999 and abs(plane["distance_mm"] - 1000) < 2
    assert plane["rms_mm"] < 2
    text = json.dumps(report)
    for word in ("truth", "correct", "wrong", "dP", "targets.ply"):
        assert word not in text
    # the honest end-to-end test: every point near its true target (RMS 0.78 mm, max 2.4 mm)
    truth = np.asarray(o3d.io.read_point_cloud(str(root / "ds" / "targets.ply")).points)
    cloud = np.asarray(o3d.io.read_point_cloud(str(out / "points.ply")).points)
    assert len(cloud) == 81
    distance = _nearest(cloud, truth)
    assert np.sqrt(np.mean(distance ** 2)) < 2.0 and distance.max() < 5.0
    # the regular method (port ignored) is ~300 mm off
    regular = np.asarray(o3d.io.read_point_cloud(str(out / "points_regular.ply")).points)
    assert np.median(_nearest(regular, truth)) > 50
    with open(out / "points.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == COLUMNS and len(rows) == 162
    first = [r for r in rows if r["method"] == "optical_path"]
    assert np.allclose([[float(r[c]) for c in ("x_mm", "y_mm", "z_mm")] for r in first], cloud,
                       atol=1e-5)
    assert (out / "views.png").stat().st_size > 1000 and (out / "report.md").stat().st_size > 500
    # eval score accepts the written cloud against the dataset
    assert eval_main(["score", str(root / "ds"), "--points", str(out / "points.ply"), "--out",
                      str(root / "score"), "--json"]) == 0
    scored = json.loads(capsys.readouterr().out)
    assert scored["methods"]["theirs"]["n"] == 81
    assert scored["methods"]["theirs"]["rms_dp_mm"] < 2.0


@pytest.mark.slow
def test_point_covariances_with_and_without_the_calibrations_covariance(photos, capsys):
    """A calibration without covariance is accepted (the points carry the pixel-noise part and
    the report says so); with one, σ grows; the files hold one row per point."""
    from measure.stereo.rig_covariance import RigCovariance
    from synth.products.dataset import read_calib

    root = photos
    rig = read_calib(root / "ds" / "calib.yaml")["rig"]
    with_cov = root / "with_cov.yaml"
    write_calib(with_cov, rig, covariance=RigCovariance(
        ("port.distance", "right.center[0]", "left.fx"), np.diag([1.0, 0.5, 0.5]) ** 2))
    reports = {}
    for name, calib in (("plain", root / "ds" / "calib.yaml"), ("with", with_cov)):
        out = root / f"unc_{name}"
        assert eval_main(["measure", "--calib", str(calib), str(root / "ph" / "left" / "pair.png"),
                          str(root / "ph" / "right" / "pair.png"), "--out", str(out), "--methods",
                          "optical_path,regular", "--quiet"]) == 0
        reports[name] = json.loads((out / "report.json").read_text())
        unc = reports[name]["uncertainty"]
        assert list(unc["methods"]) == ["optical_path"]  # regular ignores the port: none
        with open(out / unc["files"]["optical_path"]["csv"], newline="") as fh:
            assert len(list(csv.DictReader(fh))) == 81
        assert (out / "ellipses.png").stat().st_size > 1000
        assert "## Uncertainty" in (out / "report.md").read_text()
    plain, with_rig = (reports[k]["uncertainty"] for k in ("plain", "with"))
    assert "holds no covariance" in plain["rig"] and "pixel-noise part only" in plain["rig"]
    assert "rig covariance" in with_rig["rig"]
    assert plain["pixel_sigma"]["pair"]["median_px"] > 0
    sz = [u["methods"]["optical_path"]["sigma"]["median_sigma_mm"]["z"] for u in (plain, with_rig)]
    assert sz[1] > 2 * sz[0], sz
    assert reports["plain"]["pairs"][0]["methods"]["optical_path"]["sigma"]["n"] == 81


@pytest.mark.slow
def test_folders_pair_by_name_and_a_pair_with_nothing_matched_is_reported(photos, capsys):
    root = photos
    folders = root / "many"
    for view in ("left", "right"):
        (folders / view).mkdir(parents=True)
        for name in ("a", "b"):
            shutil.copy(root / "ph" / view / "pair.png", folders / view / f"{name}.png")
        cv2.imwrite(str(folders / view / "c.png"), np.zeros((268, 320), np.uint8))  # black
    out = root / "many_out"
    assert eval_main(["measure", "--calib", str(root / "ds" / "calib.yaml"),
                      str(folders / "left"), str(folders / "right"), "--out", str(out),
                      "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "3 pair(s), 2 measured: 162 targets matched" in captured.out
    assert "warning: c: no target was matched" in captured.err
    report = json.loads((out / "report.json").read_text())
    assert [p["name"] for p in report["pairs"]] == ["a", "b", "c"]
    assert report["pairs"][2]["problem"] and report["pairs"][2]["detected"] == {"left": 0,
                                                                                "right": 0}
    assert report["summary"]["problems"] == [report["pairs"][2]["problem"]]
    assert len(o3d.io.read_point_cloud(str(out / "points.ply")).points) == 162
    for name in ("a", "b", "c"):
        assert (out / f"views_{name}.png").is_file()
    with open(out / "points.csv", newline="") as fh:
        assert {r["pair"] for r in csv.DictReader(fh)} == {"a", "b"}


@pytest.mark.slow
def test_dense_measures_a_speckled_plane(tmp_path, capsys):
    scene = str(tmp_path / "plane.xml")
    assert synth_main(["scene", "--layout", "surface", "--surface", "plane", "--size", "320",
                       "268", "--speckle-size", "12", "--out", scene]) == 0
    write_dataset(scene, tmp_path / "ds", spp=SPP, progress=False)
    assert synth_main(["photos", str(tmp_path / "ds"), "--out", str(tmp_path / "ph"),
                       "--format", "png"]) == 0
    calib, out = str(tmp_path / "ds" / "calib.yaml"), tmp_path / "out"
    left, right = str(tmp_path / "ph" / "left"), str(tmp_path / "ph" / "right")
    # the target options are refused with --dense, never ignored
    assert eval_main(["measure", "--calib", calib, left, right, "--dense", "--depth-range",
                      "900,1100", "--threshold-fraction", "0.3", "--out", str(out)]) == 2
    assert "--threshold-fraction does not apply with --dense" in capsys.readouterr().err
    assert not out.exists()
    assert eval_main(["measure", "--calib", calib, left, right, "--dense", "--depth-range",
                      "900,1100", "--out", str(out), "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["mode"] == "dense"
    # measured here: 69894 pixels, 0.59 mm RMS from the true surface, plane RMS 0.53 mm
    matched = report["pairs"][0]["matched"]["optical_path"]
    assert matched > 50000
    with open(out / "points.csv", newline="") as fh:
        rows = np.array([[float(r[c]) for c in COLUMNS[2:]] for r in csv.DictReader(fh)])
    assert len(rows) == matched
    truth = np.load(tmp_path / "ds" / "left_truth_points.npy")
    true = truth[rows[:, 5].astype(int), rows[:, 4].astype(int)]
    error = np.linalg.norm(rows[:, :3] - true, axis=1)
    assert np.sqrt(np.nanmean(error ** 2)) < 1.0
    plane = report["pairs"][0]["methods"]["optical_path"]["plane"]
    assert abs(plane["distance_mm"] - 1000) < 2 and plane["rms_mm"] < 1.0
    assert len(o3d.io.read_point_cloud(str(out / "points.ply")).points) == matched


def test_the_dense_summary_prints_the_plane_fit_not_the_gap():
    """Dense matches lie on the epipolar curves by construction: their gap (~0) says nothing, so
    the printed line gives the plane fit's RMS (a range over several pairs); targets keep the
    gap."""
    from eval.measure.command import summary_line

    def pair(rms, problem=None):
        return {"problem": problem, "methods": {} if problem else
                {"optical_path": {"plane": {"rms_mm": rms}}}}

    report = {"mode": "dense", "timings_s": {"total": 3.0},
              "pairs": [pair(0.45), pair(None, "b: no pixel was matched"), pair(0.61)],
              "summary": {"pairs": 3, "measured_pairs": 2, "matched": 1000,
                          "methods": {"optical_path": {"rms_mm": 1e-9}}}}
    line = summary_line(report)
    assert "plane fit RMS optical_path 0.450–0.610 mm" in line and "gap" not in line
    report["pairs"] = report["pairs"][:1]
    assert "plane fit RMS optical_path 0.450 mm" in summary_line(report)
    report["mode"] = "targets"
    assert "gap RMS optical_path 0.0000 mm" in summary_line(report)


# --- bad inputs: no render needed --------------------------------------------------------------
def test_an_in_air_calibration_is_said(tmp_path, capsys):
    """Photos measured with an in-air calibration (no port) are measured as if taken in air: a
    warning on stderr, ``has_port`` false in report.json and a line in report.md (underwater
    photos would otherwise come out at the wrong depth with exit 0). The photos: 20 Gaussian
    targets on a plane at 1 m drawn where the in-air rig projects them (no render)."""
    from measure import StereoRig
    from measure.geometry.projection import project
    from synth.scene.rig import air_port

    size = (320, 268)
    rig = StereoRig(*paper_cameras(size, 150.0), air_port())
    write_calib(tmp_path / "air.yaml", rig, has_port=False)
    xs, ys = np.meshgrid(np.linspace(-90, 210, 5), np.linspace(-120, 120, 4))
    points = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 1000.0)])
    vv, uu = np.mgrid[0:size[1], 0:size[0]]
    for view, camera in (("left", rig.left), ("right", rig.right)):
        image = sum(np.exp(-((uu - u) ** 2 + (vv - v) ** 2) / (2 * 1.5 ** 2))
                    for u, v in project(camera, rig.port, points))
        cv2.imwrite(str(tmp_path / f"{view}.png"), np.clip(np.rint(image * 200), 0, 255)
                    .astype(np.uint8))
    out = tmp_path / "out"
    assert eval_main(["measure", "--calib", str(tmp_path / "air.yaml"), str(tmp_path / "left.png"),
                      str(tmp_path / "right.png"), "--depth-range", "900,1100", "--out", str(out),
                      "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "20 targets matched" in captured.out
    assert captured.err.startswith("warning: --calib ") and "in-air calibration" in captured.err
    report = json.loads((out / "report.json").read_text())
    assert report["has_port"] is False and "in-air calibration" in (out / "report.md").read_text()
    # the same rig written as an absorbed calibration (eval calibrate --model absorbed) is said
    # to be one: the port absorbed, not modelled
    write_calib(tmp_path / "absorbed.yaml", rig, has_port=False, extra={"model": "absorbed"})
    out = tmp_path / "out_absorbed"
    assert eval_main(["measure", "--calib", str(tmp_path / "absorbed.yaml"),
                      str(tmp_path / "left.png"), str(tmp_path / "right.png"), "--depth-range",
                      "900,1100", "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "absorbed calibration" in err and "in-air calibration" not in err
    assert json.loads((out / "report.json").read_text())["model"] == "absorbed"


@pytest.fixture
def user(tmp_path, monkeypatch):
    """A working folder with the small rig's calibration, a calibration of the full-size rig,
    black photos of the small size (nothing to detect) and a file that is no image."""
    monkeypatch.chdir(tmp_path)
    from measure import StereoRig

    from measure.stereo.rig_covariance import RigCovariance

    for name, size, focal in (("calib.yaml", (320, 268), 150.0),
                              ("big.yaml", (2448, 2048), 1100.0)):
        write_calib(tmp_path / name, StereoRig(*paper_cameras(size, focal), paper_port()))
    singular = object.__new__(RigCovariance)  # what RigCovariance itself refuses to hold
    for field_name, value in (("names", ("port.distance", "port.index[2]")),
                              ("matrix", np.ones((2, 2))), ("normal_axes", None)):
        object.__setattr__(singular, field_name, value)
    write_calib(tmp_path / "singular.yaml", StereoRig(*paper_cameras((320, 268), 150.0),
                                                      paper_port()), covariance=singular)
    for view in ("left", "right"):
        (tmp_path / view).mkdir()
        cv2.imwrite(str(tmp_path / view / "p1.png"), np.zeros((268, 320), np.uint8))
    (tmp_path / "garbage.png").write_text("not an image")
    (tmp_path / "alone").mkdir()
    cv2.imwrite(str(tmp_path / "alone" / "p2.png"), np.zeros((268, 320), np.uint8))
    return tmp_path


BAD = [
    (["--calib", "big.yaml", "left/p1.png", "right/p1.png"], "2448x2048"),
    (["--calib", "calib.yaml", "left", "alone"], "no photo of the same name"),
    (["--calib", "calib.yaml", "garbage.png", "right/p1.png"], "garbage.png"),
    (["--calib", "calib.yaml", "left/p1.png", "missing.png"], "missing.png"),
    (["--calib", "calib.yaml", "left/p1.png", "right"], "not a photo and a folder"),
    (["--calib", "missing.yaml", "left/p1.png", "right/p1.png"], "missing.yaml"),
    (["--calib", "garbage.png", "left/p1.png", "right/p1.png"], "garbage.png"),
    (["--calib", ".", "left/p1.png", "right/p1.png"], "a folder; give the calibration file, e.g. "
                                                        "--calib ./calib.yaml"),
    (["--calib", "calib.yaml", "left/p1.png", "right/p1.png"],
     "left/p1.png, right/p1.png: no target was matched"),
    (["--calib", "calib.yaml", "left", "right"], "no target was matched"),
    (["--calib", "calib.yaml", "left", "right", "--dense"], "--dense needs --depth-range"),
    (["--calib", "calib.yaml", "left", "right", "--dense", "--depth-range", "900,1100",
      "--gate-mm", "1"], "--gate-mm does not apply with --dense"),
    (["--calib", "calib.yaml", "left", "right", "--methods", "optical_path,nope"], "nope"),
    (["--calib", "calib.yaml", "left", "right", "--dense", "--depth-range", "900,1100",
      "--methods", "su"], "su"),
    (["--calib", "calib.yaml", "left", "right", "--floor-fraction", "1"], "--floor-fraction"),
    (["--calib", "calib.yaml", "left", "right", "--dense", "--depth-range", "900,1100",
      "--pixel-sigma", "0.1"], "--pixel-sigma does not apply with --dense"),
    (["--calib", "calib.yaml", "left", "right", "--pixel-sigma", "-1"], "--pixel-sigma"),
    (["--calib", "singular.yaml", "left/p1.png", "right/p1.png"], "singular.yaml"),
]


@pytest.mark.parametrize("argv, fragment", BAD, ids=[a[-1] if i < 7 else f"{i}"
                                                     for i, (a, _) in enumerate(BAD)])
def test_bad_inputs_exit_2_with_one_line_and_write_nothing(user, capsys, argv, fragment):
    before = sorted(os.listdir(user))
    assert eval_main(["measure", *argv, "--out", "out", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and fragment in err[0], err
    assert sorted(os.listdir(user)) == before  # no output directory, no staging left


def test_a_dome_calibration_is_one_error_line_where_it_cannot_apply(tmp_path):
    """A DOMEPORT calibration reads (synth.formats.calib_formats) and eval measure takes it (targets
    and --dense); eval run on a flat-port scene refuses it: one CLIError naming the file, no
    traceback."""
    from types import SimpleNamespace

    from eval.cli import CLIError
    from eval.measure.inputs import read_calibration
    from eval.run.inputs import budget_rigs, measurement_calibration
    from measure import StereoRig
    from measure.geometry.dome import DomePair, DomePort
    from synth.formats.calib_formats import write_calibmar

    left, right = paper_cameras()
    pair = DomePair(DomePort(left.center, 50.0, 8.0, (1.0, 1.49, 1.33)),
                    DomePort(right.center, 50.0, 8.0, (1.0, 1.49, 1.33)))
    path = write_calibmar(tmp_path / "dome.yaml", StereoRig(left, right, pair))[0]
    assert read_calibration(path)[0].port.kind == "dome"
    flat = SimpleNamespace(rig=StereoRig(left, right, None))  # eval run: a flat-port scene
    with pytest.raises(CLIError, match=r"--calib .*dome\.yaml: a dome-port calibration"):
        measurement_calibration(SimpleNamespace(calib=path, assumptions={}), flat)
    with pytest.raises(CLIError, match=r"--compare-calib .*dome\.yaml: a dome-port"):
        budget_rigs(SimpleNamespace(compare_calib=(path,)), flat.rig, None)


def test_dense_measures_a_plane_through_decentred_domes(tmp_path):
    """eval measure --dense with a DOMEPORT calibration (calibmar's YAML): a speckle plane 1 m
    away rendered analytically through two decentred domes (synth.products.dense_pairs, as
    tests/measure/stereo/test_dome_stereo.py), written as 16-bit PNG photos. Measured (2026-12-02):
    74,340 of the 85,760 pixels matched, the plane fit 999.996 mm away, RMS 0.291 mm (a pixel
    spans 3.5 mm there); the pinhole baseline, searching where it sees the surface (592–1094
    mm, eval.run.dense.pinhole_depth_range), matched 20,785 pixels with a plane fit RMS of
    10.3 mm (behind centred domes it matches as many as the optical path, RMS 0.30 mm: the
    pinhole model is exact there)."""
    from measure import StereoRig
    from measure.geometry.dome import DomePair, DomePort
    from synth.formats.calib_formats import write_calibmar
    from synth.products.dense_pairs import PlaneSurface, SpeckleTexture, render_pair
    from synth.scene.rig import paper_rig

    base = paper_rig(size=(320, 268))
    indices = (1.0, 1.49, 1.33)
    rig = StereoRig(base.left, base.right,
                    DomePair(DomePort(base.left.center + (1.5, -1.0, 2.0), 50.0, 8.0, indices),
                             DomePort(base.right.center + (-2.0, 0.5, -1.0), 50.0, 8.0,
                                      indices)))
    images = render_pair(rig, PlaneSurface.create((0.0, 0.0, 1000.0), (0.0, 0.0, 1.0)),
                         SpeckleTexture.random((-1300, 1500, -1100, 1100), 17.0, seed=1))
    for name, image in zip(("left", "right"), images):
        cv2.imwrite(str(tmp_path / f"{name}.png"),
                    np.round(np.clip(image, 0, 1) * 65535).astype(np.uint16))
    calib = write_calibmar(tmp_path / "dome.yaml", rig)[0]
    out = tmp_path / "out"
    assert eval_main(["measure", "--calib", str(calib), str(tmp_path / "left.png"),
                      str(tmp_path / "right.png"), "--dense", "--depth-range", "900,1100",
                      "--methods", "optical_path,regular", "--out", str(out), "--quiet"]) == 0
    pair = json.loads((out / "report.json").read_text())["pairs"][0]
    assert pair["matched"]["optical_path"] > 0.8 * 320 * 268
    plane = pair["methods"]["optical_path"]["plane"]
    assert abs(plane["distance_mm"] - 1000.0) < 0.05 and plane["rms_mm"] < 0.4
    with open(out / "points.csv", newline="") as fh:
        z = np.array([float(row["z_mm"]) for row in csv.DictReader(fh)
                      if row["method"] == "optical_path"])
    assert len(z) == pair["matched"]["optical_path"] and np.sqrt(np.mean((z - 1000) ** 2)) < 0.4
    # ignoring the decentred domes costs: fewer pixels, each far off
    assert pair["matched"]["regular"] < 0.5 * pair["matched"]["optical_path"]
    assert pair["methods"]["regular"]["plane"]["rms_mm"] > 5.0


@pytest.mark.slow
def test_photos_through_domes_are_measured_and_scored(tmp_path):
    """The closed loop behind the decentred domes: a small render written as JPEG photos,
    measured with the dataset's dome calibration (no truth), scored against the dataset."""
    data, photos = tmp_path / "ds", tmp_path / "photos"
    assert synth_main(["dataset", "scenes/dome_decentred.xml", "-D", "width=816", "-D",
                       "height=683", "--spp", "16", "--out", str(data), "--quiet"]) == 0
    assert synth_main(["photos", str(data), "--out", str(photos)]) == 0
    assert eval_main(["measure", "--calib", str(data / "calib.yaml"), str(photos / "left"),
                      str(photos / "right"), "--out", str(tmp_path / "m"), "--quiet"]) == 0
    report = json.loads((tmp_path / "m" / "report.json").read_text())
    assert report["uncertainty"]["methods"]["optical_path"]["sigma"]["n"] > 300
    assert eval_main(["score", str(data), "--points", str(tmp_path / "m" / "points.ply"),
                      "--out", str(tmp_path / "s"), "--quiet"]) in (0, 1)
    scores = json.loads((tmp_path / "s" / "report.json").read_text())
    # every measured point is one of the targets (3.8 mm gate), none an extra; at a third of
    # the full size (816 px, 16 spp, JPEG) the error measured 0.895 mm RMS on 2026-12-02
    assert scores["association"]["unassociated"] == 0
    assert scores["association"]["associated"] == report["uncertainty"]["methods"][
        "optical_path"]["sigma"]["n"]
    assert scores["methods"]["theirs"]["rms_dp_mm"] < 1.2


@pytest.mark.slow
@pytest.mark.parametrize("order, fragment", [
    (("right", "left"), "left and right look swapped (81 match with the photos the other way "
                        "round)"),
    (("left", "left"), "the photos do not look like the pair the calibration describes")])
def test_photos_that_are_not_the_calibrations_pair_exit_1_with_the_report(photos, capsys, order,
                                                                          fragment):
    """Left and right swapped, or one photo twice: a few targets match by accident (19 of 81)
    and triangulate far from the plane. Exit 1, one ``failed:`` line naming the problem, the
    report written (its summary says the same)."""
    root = photos
    out = root / f"not_a_pair_{order[0]}_{order[1]}"
    code = eval_main(["measure", "--calib", str(root / "ds" / "calib.yaml"),
                      str(root / "ph" / order[0] / "pair.png"),
                      str(root / "ph" / order[1] / "pair.png"), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.splitlines()
    failed = [line for line in err if line.startswith("failed:")]
    assert code == 1, err
    assert len(failed) == 1 and fragment in failed[0] and "less than half of the 81" in failed[0]
    assert not [line for line in err if line.startswith("error:")]
    report = json.loads((out / "report.json").read_text())
    assert report["pairs"][0]["matched"] < 81 / 2
    assert report["summary"]["failures"] == [report["pairs"][0]["failure"]]
    assert "Verdict: failed" in (out / "report.md").read_text()


def test_the_right_pair_is_not_a_mismatch_and_a_swapped_one_is_named():
    """:func:`pair_mismatch` on the simulator's exact pixels of the small rig: none for the
    pair, "swapped" for the views exchanged (no rendering)."""
    from eval.measure.pipeline import TargetOptions, pair_mismatch
    from measure.stereo.matching import match_targets
    from synth.scene.layouts import grid_plane
    from synth.scene.rig import paper_cameras, paper_port
    from measure import StereoRig
    from measure.geometry.projection import project

    left, right = paper_cameras((320, 268), 150.0)
    rig = StereoRig(left, right, paper_port())
    targets = grid_plane(1000.0, 320.0, 80.0) + np.array([3.0, -2.0, 0.0])
    centers = {"left": project(left, rig.port, targets), "right": project(right, rig.port, targets)}
    options = TargetOptions()
    matched = len(match_targets(rig, centers["left"], centers["right"], gate_mm=0.5).left)
    assert matched == len(targets)
    assert pair_mismatch(rig, "p", centers, matched, options) is None
    swapped = {"left": centers["right"], "right": centers["left"]}
    n = len(match_targets(rig, swapped["left"], swapped["right"], gate_mm=0.5).left)
    assert n < len(targets) / 2
    problem = pair_mismatch(rig, "p", swapped, n, options)
    assert problem is not None and "left and right look swapped" in problem
    assert f"{len(targets)} match with the photos the other way round" in problem


def test_a_pair_lost_to_ambiguity_names_the_depth_range_not_the_photos():
    """A row-aligned pair in air (a rectified one) on a grid of targets: each left target
    meets its row's right targets at several depths, so most are dropped as ambiguous. The
    failure says so and names --depth-range (it said only "the photos do not look like the
    pair"); with a depth window the pair matches and is no mismatch."""
    from eval.measure.pipeline import TargetOptions, pair_mismatch
    from measure import Camera, StereoRig
    from measure.geometry.port import index_matched_port
    from measure.geometry.projection import project
    from measure.stereo.matching import match_targets
    from synth.scene.layouts import grid_plane

    K = np.array([[220.0, 0, 159.5], [0, 220.0, 133.5], [0, 0, 1]])
    left, right = Camera(K, (320, 268)), Camera(K, (320, 268), t=(200.0, 0, 0))
    rig = StereoRig(left, right, index_matched_port((0, 0, 1), np.stack([left.t, right.t])))
    targets = grid_plane(1000.0, 320.0, 80.0)
    centers = {v: project(c, rig.port, targets) for v, c in (("left", left), ("right", right))}
    loose = match_targets(rig, centers["left"], centers["right"], gate_mm=0.5)
    assert len(loose.left) < len(targets) / 2 <= len(loose.left) + loose.n_ambiguous
    problem = pair_mismatch(rig, "p", centers, len(loose.left), TargetOptions(),
                            loose.n_ambiguous)
    assert f"{loose.n_ambiguous} more were dropped as ambiguous" in problem
    assert "bound the depth with --depth-range" in problem and "models no port" in problem
    window = TargetOptions(depth_range=(800.0, 1250.0))
    bounded = match_targets(rig, centers["left"], centers["right"], gate_mm=0.5,
                            depth_range=(800.0, 1250.0))
    assert len(bounded.left) == len(targets)
    assert pair_mismatch(rig, "p", centers, len(bounded.left), window,
                         bounded.n_ambiguous) is None


def test_many_ambiguous_targets_without_a_depth_window_are_warned_about():
    """The small rig on its 9 × 9 grid with 0.05 px of noise and no depth window (seed 0): more
    than half of the targets are dropped as ambiguous and some of the pairs kept are a row's
    shifted partners (10 of 38), with exit 0 and no word before. Now a warning names the count
    and --depth-range; with a depth window, or few ambiguous, none."""
    from eval.measure.pipeline import PairResult, TargetOptions, ambiguity_warning
    from measure import StereoRig
    from measure.geometry.projection import project
    from measure.stereo.matching import match_targets
    from synth.scene.layouts import grid_plane
    from synth.scene.rig import paper_cameras, paper_port

    left, right = paper_cameras((320, 268), 143.79)
    rig = StereoRig(left, right, paper_port())
    targets = grid_plane(1000.0, 320.0, 80.0)
    rng = np.random.default_rng(0)
    uv = [project(c, rig.port, targets) + rng.normal(0, 0.05, (len(targets), 2))
          for c in (left, right)]
    matches = match_targets(rig, *uv, gate_mm=0.5)
    assert np.any(matches.left != matches.right)  # the case the warning is for

    def result(ambiguous, matched):
        return PairResult("p", None, None, {"detected": {"left": 81, "right": 81},
                                            "matched": matched, "ambiguous": ambiguous})

    warning = ambiguity_warning(result(matches.n_ambiguous, len(matches.left)), TargetOptions())
    assert warning is not None and f"{matches.n_ambiguous} of 81 targets dropped" in warning
    assert "--depth-range NEAR,FAR" in warning
    assert ambiguity_warning(result(matches.n_ambiguous, len(matches.left)),
                             TargetOptions(depth_range=(800.0, 1250.0))) is None
    assert ambiguity_warning(result(2, 79), TargetOptions()) is None


def test_when_every_pair_failed_only_the_error_is_printed(user, capsys):
    """Two pairs, nothing matched in either: one ``error:`` line, no ``warning: …; the other
    pairs are measured`` before it (there are none)."""
    for view in ("left", "right"):
        cv2.imwrite(str(user / view / "p3.png"), np.zeros((268, 320), np.uint8))
    assert eval_main(["measure", "--calib", "calib.yaml", "left", "right", "--out", "out",
                      "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: no pair was measured (2 pairs)"), err
    assert not (user / "out").exists()
