"""``python -m eval run`` on a surface scene: dense matching through the port, scored against
the mesh; and the bad inputs of surface scenes.

The small rig (320 x 268 px, f = 144 px) has 7.7x the full-size pixel footprint, so its depth
errors are several times the full-size ones; the bounds below come from measuring this very
case (numbers in the comments) with margin for the renderer's seed, not from the issue's
full-size targets (measured by the benchmarks, README)."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

from eval.__main__ import main as eval_main
from synth.__main__ import main as synth_main
from synth.products.dataset import write_dataset
from tests.conftest import REPO

SMALL = ("--size", "320", "268")
DOTS = ("--speckle-size", "12")  # 2.2-4.1 px at 1 m in the small image


@pytest.fixture(scope="module")
def plane_case(tmp_path_factory):
    root = tmp_path_factory.mktemp("dense")
    scene = str(root / "plane.xml")
    assert synth_main(["scene", "--layout", "surface", "--surface", "plane", *SMALL, *DOTS,
                       "--out", scene]) == 0
    write_dataset(scene, root / "ds", spp=16, progress=False)
    return root, scene, str(root / "ds")


def _snapshot(root):
    return sorted(os.path.relpath(os.path.join(d, f), root) for d, _, files in os.walk(root)
                  for f in files)


@pytest.mark.slow
def test_dense_run_measures_the_plane_and_shows_what_ignoring_refraction_costs(plane_case):
    root, scene, ds = plane_case
    out = str(root / "run")
    assert eval_main(["run", scene, "--from", ds, "--out", out, "--no-progress"]) == 0
    report = json.load(open(os.path.join(out, "report.json")))
    refractive, pinhole = report["methods"]["optical_path"], report["methods"]["regular"]
    # measured here: 91.0 % of the overlap, RMS 0.53 mm, F@1mm 0.88, flatness 0.53 mm
    assert refractive["measured_fraction"] >= 0.85
    assert refractive["p2m_rms_mm"] <= 0.8
    assert refractive["fscore_1mm"] >= 0.8
    assert refractive["measured_outside_overlap"] <= 0.001 * refractive["measured_pixels"]
    # ignoring the port puts the plane where it appears (~250 mm nearer) and bends it
    assert pinhole["p2m_median_mm"] > 100 and pinhole["fscore_5mm"] < 0.01
    for name in ("report.md", "views.png", "distances.png", "depth_error_optical_path.png",
                 "points_optical_path.ply", "points_regular.ply", "sigma_z_optical_path.png"):
        assert os.path.getsize(os.path.join(out, name)) > 0
    # every matched pixel of optical_path has a σ (regular, which ignores the port, none)
    assert set(report["uncertainty"]) == {"optical_path"}
    uncertainty = report["uncertainty"]["optical_path"]
    assert uncertainty["matching_sigma"]["source"].startswith("matching σ per pixel")
    assert uncertainty["sigma"]["n"] == refractive["measured_pixels"]
    sigma_z = np.load(os.path.join(out, "sigma_z_optical_path.npy"))
    assert sigma_z.shape == (268, 320) and np.isfinite(sigma_z).sum() == uncertainty["sigma"]["n"]
    assert uncertainty["coverage"]["n"] > 0.9 * uncertainty["sigma"]["n"]
    assert report["figures"] == ["views.png", "depth_error_optical_path.png",
                                 "sigma_z_optical_path.png", "depth_error_regular.png",
                                 "distances.png"]
    # --no-figures: the same numbers, clouds and σ map, no PNG file
    bare = str(root / "run_no_figures")
    assert eval_main(["run", scene, "--from", ds, "--out", bare, "--no-progress",
                      "--no-figures"]) == 0
    without = json.load(open(os.path.join(bare, "report.json")))
    assert without["figures"] == [] and without["methods"] == report["methods"]
    assert sorted(n for n in os.listdir(bare) if not n.startswith(".")) == [
        "points_optical_path.ply", "points_regular.ply", "report.json", "report.md",
        "sigma_z_optical_path.npy"]
    assert ".png" not in open(os.path.join(bare, "report.md")).read()


@pytest.mark.slow
@pytest.mark.parametrize("argv, fragment", [
    (["--eccentricity"], "applies to target scenes"),
    (["--pixel-sigma", "0"], "--pixel-sigma '0': expected auto or a positive number"),
    (["--methods", "su"], "surface scene is measured with"),
    (["--depth-range", "2000,2100"], "excludes the surface"),
    (["--depth-range", "50,2000"], "NEAR must lie beyond the port"),
])
def test_dense_run_bad_options(plane_case, capsys, argv, fragment):
    root, scene, ds = plane_case
    before = _snapshot(root)
    code = eval_main(["run", scene, "--from", ds, "--out", str(root / "bad"), "--no-progress",
                      *argv])
    err = capsys.readouterr().err
    assert code == 2 and fragment in err and "Traceback" not in err
    assert len([line for line in err.splitlines() if line.startswith("error:")]) == 1
    assert _snapshot(root) == before


@pytest.mark.slow
def test_dense_run_with_a_stated_pixel_sigma(plane_case):
    """``--pixel-sigma PX`` on a surface scene: the right pixel's σ along the epipolar curve,
    the same for every pixel; the points' σ scale with it (σ_z ∝ PX: first order)."""
    root, scene, ds = plane_case
    sigmas = {}
    for px in ("0.05", "0.1"):
        out = str(root / f"stated_{px}")
        assert eval_main(["run", scene, "--from", ds, "--out", out, "--no-progress",
                          "--methods", "optical_path", "--pixel-sigma", px]) == 0
        report = json.load(open(os.path.join(out, "report.json")))
        matching = report["uncertainty"]["optical_path"]["matching_sigma"]
        assert matching["stated_px"] == float(px) == matching["median_px"] == matching["max_px"]
        sigmas[px] = np.load(os.path.join(out, "sigma_z_optical_path.npy"))
    np.testing.assert_allclose(sigmas["0.1"], 2 * sigmas["0.05"], rtol=1e-5)


@pytest.mark.slow
def test_dense_run_with_a_rig_covariance(plane_case, tmp_path):
    """``--calib`` with a covariance: the points' σ add the rig's part (larger than the
    matching σ's alone), the coverage is counted in 3 dimensions (a rig error moves a point off
    its ray), and the report names the calibration. The scene's own rig is exact, so this one
    calibration is a draw of zero error: σ overstates, and the report says so."""
    from measure.stereo.rig_covariance import RigCovariance
    from synth.products.dataset import read_calib, write_calib

    root, scene, ds = plane_case
    calib = tmp_path / "with.yaml"
    write_calib(calib, read_calib(os.path.join(ds, "calib.yaml"))["rig"],
                covariance=RigCovariance(("port.distance", "port.index[2]", "right.center[0]"),
                                         np.diag([1.0, 1e-3, 0.5]) ** 2))
    reports = {}
    for name, extra in (("plain", []), ("with", ["--calib", str(calib)])):
        out = str(tmp_path / name)
        assert eval_main(["run", scene, "--from", ds, "--out", out, "--no-progress",
                          "--methods", "optical_path", *extra]) == 0
        reports[name] = json.load(open(os.path.join(out, "report.json")))
    plain, with_rig = (reports[k]["uncertainty"]["optical_path"] for k in ("plain", "with"))
    assert "exact" in plain["rig"] and "3 parameters" in with_rig["rig"]
    assert plain["coverage"]["dof"] == 1 and with_rig["coverage"]["dof"] == 3
    assert with_rig["sigma"]["median_sigma_mm"]["z"] > 2 * plain["sigma"]["median_sigma_mm"]["z"]
    assert "one draw of the rig error" in with_rig["coverage"]["verdict"]


@pytest.mark.slow
@pytest.mark.parametrize("argv, fragment", [
    (["--rms", "0.1"], "--rms does not apply"),
    (["--max", "0.5"], "--max does not apply"),
])
def test_check_of_a_surface_dataset_refuses_the_detection_bounds(plane_case, capsys, argv,
                                                                 fragment):
    """A surface dataset's truth maps are checked, not detections: the bounds of the
    detections cannot apply and are refused (issue 22: they were ignored)."""
    root, _, ds = plane_case
    before = _snapshot(root)
    code = synth_main(["check", ds, *argv])
    err = capsys.readouterr().err
    assert code == 2 and fragment in err and "Traceback" not in err, err
    assert len([line for line in err.splitlines() if line.startswith("error:")]) == 1
    assert _snapshot(root) == before


@pytest.mark.slow
def test_scene_whose_mesh_is_missing(plane_case, tmp_path, capsys):
    _, scene, _ = plane_case
    copy = tmp_path / "plane.xml"
    shutil.copy(scene, copy)  # the mesh and texture stay behind
    code = eval_main(["run", str(copy), "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "plane_surface.ply" in err and "does not exist" in err
    assert not (tmp_path / "out").exists()


def _write_obj(path, vertices, faces):
    lines = [f"v {x} {y} {z}" for x, y, z in vertices] + [f"f {a + 1} {b + 1} {c + 1}"
                                                          for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("setup, fragment", [
    ("missing", "no such file"),
    ("empty", "is empty"),
    ("behind", "out of the water"),
    ("aside", "not seen by both cameras"),
    ("txt", "expected a .ply or .obj"),
    ("wound", "wound the other way"),  # the cameras see the back: it would render black
])
def test_bad_user_meshes(tmp_path, capsys, setup, fragment):
    mesh = tmp_path / ("mesh.txt" if setup == "txt" else "mesh.obj")
    quad = np.array([[-100.0, -100, 0], [100, -100, 0], [100, 100, 0], [-100, 100, 0]])
    faces = [(0, 1, 2), (0, 2, 3)]
    if setup == "empty":
        mesh.write_text("")
    elif setup == "behind":  # a square straddling the port
        _write_obj(mesh, quad + [0, 0, 90], faces)
    elif setup == "aside":  # 5 m to the side: in the water, seen by neither camera
        _write_obj(mesh, quad + [5000, 0, 1000], faces)
    elif setup == "wound":
        _write_obj(mesh, quad * 5 + [0, 0, 1000], faces)  # normal +z: away from the cameras
    elif setup == "txt":
        mesh.write_text("v 0 0 1000\n")
    before = _snapshot(tmp_path)
    code = synth_main(["scene", "--layout", "surface", "--surface", "mesh", "--mesh", str(mesh),
                       *SMALL, *DOTS, "--out", str(tmp_path / "s.xml")])
    err = capsys.readouterr().err
    assert code == 2 and fragment in err and "Traceback" not in err, err
    assert _snapshot(tmp_path) == before


def test_user_mesh_and_fine_speckle_warning(tmp_path, capsys):
    """A user's OBJ becomes a scene (planar texture coordinates); dots below a pixel warn
    (12 mm dots on a sheet 5 m away: ~0.5 px in the small image)."""
    mesh = tmp_path / "mesh.obj"
    quad = np.array([[-1500.0, -1000, 5000], [1700, -1000, 5000], [1700, 1000, 5200],
                     [-1500, 1000, 5200]])
    _write_obj(mesh, quad, [(0, 2, 1), (0, 3, 2)])  # wound to face the cameras (-z)
    code = synth_main(["scene", "--layout", "surface", "--surface", "mesh", "--mesh", str(mesh),
                       *SMALL, *DOTS, "--out", str(tmp_path / "s.xml")])
    captured = capsys.readouterr()
    assert code == 0 and "warning: --speckle-size 12 mm" in captured.err, captured.err
    assert (tmp_path / "s_surface.ply").exists()


@pytest.mark.slow
def test_dense_run_through_a_sensor_and_a_median_filter(plane_case):
    """--sensor and --median-filter apply to the images the matcher sees and are reported
    (measured here: 91.0 % of the overlap matched through imx174 + a 3x3 median)."""
    root, scene, ds = plane_case
    out = str(root / "run_sensor")
    assert eval_main(["run", scene, "--from", ds, "--out", out, "--no-progress", "--methods",
                      "optical_path", "--sensor", "imx174", "--median-filter", "3"]) == 0
    report = json.load(open(os.path.join(out, "report.json")))
    assert report["sensor"]["model"]["name"] == "imx174" and report["median_filter"] == 3
    assert list(report["methods"]) == ["optical_path"]
    assert report["methods"]["optical_path"]["measured_fraction"] >= 0.85


@pytest.mark.slow
def test_mesh_without_surface_mesh_and_score_of_a_surface_dataset(plane_case, tmp_path, capsys):
    root, _, ds = plane_case
    mesh = tmp_path / "mesh.obj"
    _write_obj(mesh, [[0, 0, 1000], [10, 0, 1000], [0, 10, 1000]], [(0, 1, 2)])
    code = synth_main(["scene", "--layout", "surface", "--mesh", str(mesh), *SMALL,
                       "--out", str(tmp_path / "s.xml")])
    assert code == 2 and "--mesh needs --layout surface --surface mesh" in capsys.readouterr().err
    code = eval_main(["score", ds, "--points", str(mesh), "--out", str(tmp_path / "score")])
    err = capsys.readouterr().err
    # a surface dataset's points are scored against its true mesh; a mesh file is not a cloud
    assert code == 2 and err.count("error:") == 1 and str(mesh) in err and "no points" in err
    assert "Traceback" not in err and not (tmp_path / "score").exists()


@pytest.mark.slow
def test_damaged_truth_maps_are_refused(plane_case, tmp_path, capsys):
    """Truth points that are NaN where the valid mask says the surface is hit: refused — by
    their SHA-256 against the manifest's, and in a manifest without the hashes (before format
    3) by the maps' own consistency."""
    _, scene, ds = plane_case
    copy = tmp_path / "ds"
    shutil.copytree(ds, copy)
    points = np.load(copy / "left_truth_points.npy")
    np.save(copy / "left_truth_points.npy", np.full_like(points, np.nan))
    argv = ["run", scene, "--from", str(copy), "--out", str(tmp_path / "out"), "--no-progress"]
    code = eval_main(argv)
    err = capsys.readouterr().err
    assert code == 2 and "left_truth_points.npy: changed since" in err and "Traceback" not in err
    manifest = json.loads((copy / "manifest.json").read_text())
    del manifest["sha256"], manifest["manifest_sha256"]
    (copy / "manifest.json").write_text(json.dumps(manifest))
    code = eval_main(argv)
    err = capsys.readouterr().err
    assert code == 2 and "truth maps disagree" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_depth_range_needing_too_many_planes(plane_case, monkeypatch, capsys):
    """A search that needs more sweep planes than measure.dense.match.MAX_PLANES is refused before
    any image work (at full size 200-1e9 mm needs thousands; here the cap is lowered to 20)."""
    import measure.dense.match

    root, scene, ds = plane_case
    monkeypatch.setattr(measure.dense.match, "MAX_PLANES", 20)
    before = _snapshot(root)
    code = eval_main(["run", scene, "--from", ds, "--out", str(root / "bad"), "--no-progress",
                      "--depth-range", "200,1e9"])
    err = capsys.readouterr().err
    assert code == 2 and "sweep planes, more than 20: narrow it" in err and "--depth-range" in err
    assert _snapshot(root) == before


@pytest.mark.slow
def test_a_dense_run_that_measured_nothing_exits_1(tmp_path, capsys):
    """The committed speckle plane at 320 x 268 px and 4 spp: its dots are far below a pixel and
    nothing matches. The run writes its report and says that it failed (exit 1, one line)."""
    out = tmp_path / "run"
    code = eval_main(["run", str(REPO / "scenes" / "speckle_plane.xml"), "-D", "width=320",
                      "-D", "height=268", "--spp", "4", "--methods", "optical_path",
                      "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    failed = [line for line in err.splitlines() if line.startswith("failed:")]
    assert code == 1 and len(failed) == 1 and "0 % of the overlap" in failed[0], err
    report = json.loads((out / "report.json").read_text())
    assert report["methods"]["optical_path"]["measured_fraction"] == 0
    assert report["verdict"]["passed"] is False


def test_the_pinhole_search_range_brackets_where_the_pinhole_model_sees_the_surface():
    """The pinhole baseline's range (eval.run.dense.pinhole_depth_range): behind centred domes
    exactly the refractive one with the near end lowered 20 %; behind decentred domes it holds
    the depths at which the pinhole model triangulates the exact pixels of planes at both ends
    (the pair below, 2.5–4.6 mm off centre, shows a plane at 900 mm as near as 624 mm: the
    refractive range lowered 20 %, what the baseline searched before, starts at 720 mm); and
    its near end never
    falls inside the glass, where the matcher refuses depth planes (before: a valid
    --depth-range 70,1100 refused behind domes, 120,1100 behind the paper's port, for a near
    end the user never gave)."""
    from measure import StereoRig
    from measure.dense.match import glass_depth
    from measure.geometry.dome import DomePair, DomePort
    from measure.geometry.projection import project
    from measure.stereo.triangulate import triangulate
    from synth.scene.rig import paper_rig

    from eval.run.dense import PINHOLE_NEAR_MARGIN, pinhole_depth_range

    base = paper_rig(size=(320, 268))
    indices = (1.0, 1.49, 1.33)

    def domes(left_offset, right_offset):
        return StereoRig(base.left, base.right, DomePair(
            DomePort(base.left.center + left_offset, 50.0, 8.0, indices),
            DomePort(base.right.center + right_offset, 50.0, 8.0, indices)))

    centred = pinhole_depth_range(domes((0, 0, 0), (0, 0, 0)), (900.0, 1100.0))
    np.testing.assert_allclose(centred, (900.0 * (1 - PINHOLE_NEAR_MARGIN), 1100.0), rtol=1e-12)
    decentred = domes((3.0, -2.0, 4.0), (-4.0, 1.0, -2.0))
    near, far = pinhole_depth_range(decentred, (900.0, 1100.0))
    grid = np.stack(np.meshgrid(np.arange(0.0, 320.0, 8.0), np.arange(0.0, 268.0, 8.0)),
                    axis=-1).reshape(-1, 2)
    rays = decentred.trace(0, decentred.left.rays(grid))
    for depth in (900.0, 1000.0, 1100.0):
        points = rays.origins + ((depth - rays.origins[:, 2]) / rays.directions[:, 2])[:, None] \
            * rays.directions
        uv_right = project(decentred.right, decentred.port.right, points)
        seen = decentred.right.in_image(uv_right)
        pinhole = triangulate(decentred, grid[seen], uv_right[seen], "regular").points[:, 2]
        assert seen.sum() > 100 and near <= pinhole.min() and pinhole.max() <= far + 1e-6, (
            depth, pinhole.min(), pinhole.max(), near, far)
    # a near end close to the glass: clamped 1 mm beyond it, for domes and the flat port
    for rig, requested in ((decentred, 70.0), (base, 120.0)):
        assert pinhole_depth_range(rig, (requested, 1100.0))[0] == glass_depth(rig) + 1.0


def test_the_pinhole_search_range_behind_two_housings_is_traced(monkeypatch):
    """Two housings (each camera its own flat port; before, an AttributeError: the range asked
    for the shared port's closed form): two ports in the place of the paper's shared one give
    the range traced through them — the same, to 1e-9, as the same lattice traced through the
    shared port itself, and its near end no farther than the closed form's (off-axis points
    appear nearer than the paraxial depth)."""
    from measure import StereoRig
    from measure.geometry.flat_pair import FlatPair
    from measure.geometry.port import FlatPort
    from synth.scene.rig import paper_rig

    from eval.run.dense import pinhole_depth_range

    shared = paper_rig(size=(320, 268))
    housings = StereoRig(shared.left, shared.right, FlatPair(shared.port, shared.port))
    traced = pinhole_depth_range(housings, (900.0, 1100.0))
    closed_form = pinhole_depth_range(shared, (900.0, 1100.0))
    monkeypatch.setattr(FlatPort, "apparent_depths", lambda self, depths: None)
    np.testing.assert_allclose(traced, pinhole_depth_range(shared, (900.0, 1100.0)), rtol=1e-9)
    assert traced[0] <= closed_form[0]
