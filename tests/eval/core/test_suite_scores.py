"""python -m eval score SUITE --submission DIR: the project's own baseline (eval run's clouds)
scored per dataset equals eval run key by key; a missing dataset is a listed failure; a
submission in metres or in another frame is detected and said so. A suite of two 320 x 268
datasets at 4 spp."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pyarrow.parquet as pq
import pytest

from eval.cli import main
from eval.core.suite_scores import aggregate, find_submission
from synth.commands import main as synth_main
from tests.conftest import REPO

SPEC = f"""
name = "score-me"
seed = 1
scenes = ["{REPO / 'scenes' / 'small_grid.xml'}"]
render = "targets"
render_width = 320

[fixed]
spp = 4

[grid]
"D.target_z" = [1000, 1200]
"""


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    root = tmp_path_factory.mktemp("suite_scores")
    (root / "spec.toml").write_text(SPEC)
    suite, sub = root / "suite", root / "sub"
    assert synth_main(["suite", str(root / "spec.toml"), "--out", str(suite), "--workers", "1",
                       "--no-progress"]) == 0
    index = pq.read_table(suite / "index.parquet").to_pylist()
    reports = {}
    for row in index:  # the project scores itself: eval run's output folder is the submission
        run = sub / row["folder"]
        assert main(["run", str(REPO / "scenes" / "small_grid.xml"), "--from",
                     str(suite / row["folder"]), "--out", str(run), "--no-progress"]) == 0
        reports[row["folder"]] = json.loads((run / "report.json").read_text())
    return suite, sub, index, reports


@pytest.mark.slow
def test_the_baseline_scores_equal_eval_run_key_by_key(baseline, tmp_path):
    suite, sub, index, reports = baseline
    out = tmp_path / "scores"
    assert main(["score", str(suite), "--submission", str(sub), "--out", str(out),
                 "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert [r["folder"] for r in summary["datasets"]] == [r["folder"] for r in index]
    for row in summary["datasets"]:
        assert row["status"] == "ok" and row["submission"].endswith("points_optical_path_all.ply")
        ours = dict(reports[row["folder"]]["methods"]["optical_path"])
        ours.pop("coverage_95")  # a point's covariance needs its pixels: not in a PLY file
        assert set(row["scores"]) == set(ours)
        for key, value in ours.items():
            assert row["scores"][key] == value, (row["folder"], key)
    table = pq.read_table(out / "summary.parquet").to_pylist()
    assert [r["row"] for r in table].count("dataset") == 2
    assert any(r["row"] == "aggregate" and r["group"] == "D.target_z" for r in table)
    assert (out / "summary.csv").is_file() and "## Aggregated" in (out / "summary.md").read_text()
    assert (out / "figures" / "error_vs_D.target_z.png").stat().st_size > 1000


@pytest.mark.slow
def test_scores_inside_the_suite_are_refused_and_the_suite_resumes(baseline, tmp_path, capsys):
    """``--out SUITE/scores`` made the suite refuse to resume (a folder it did not write): the
    scores go beside the suite, and synth suite still finds its own folder."""
    suite, sub, _, _ = baseline
    assert main(["score", str(suite), "--submission", str(sub), "--out",
                 str(suite / "scores"), "--no-progress"]) == 2
    assert "inside the suite" in capsys.readouterr().err
    assert not (suite / "scores").exists()
    assert synth_main(["suite", str(suite.parent / "spec.toml"), "--out", str(suite),
                       "--workers", "1", "--no-progress"]) == 0


@pytest.mark.slow
def test_missing_metres_and_offset_submissions_are_failures_and_warnings(baseline, tmp_path,
                                                                         capsys):
    from synth.formats.cloudfile import read_cloud_points

    suite, sub, index, _ = baseline
    mine = tmp_path / "mine"
    first, second = index[0]["folder"], index[1]["folder"]
    (mine / first).mkdir(parents=True)
    import open3d as o3d

    points = read_cloud_points(str(sub / first / "points_optical_path.ply"))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points / 1000.0))  # metres
    o3d.io.write_point_cloud(str(mine / first / "points.ply"), cloud)
    out = tmp_path / "scores"
    capsys.readouterr()
    assert main(["score", str(suite), "--submission", str(mine), "--out", str(out),
                 "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert f"failure: {second} (missing)" in err
    assert f"warning: {first}: looks like metres" in err
    md = (out / "summary.md").read_text()
    assert "1 missing or failed" in md and second in md and "looks like metres" in md
    # another frame: shifted by 200 mm
    shutil.rmtree(mine / first)
    (mine / first).mkdir()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points + [200.0, 0.0, 0.0]))
    o3d.io.write_point_cloud(str(mine / first / "points.ply"), cloud)
    assert main(["score", str(suite), "--submission", str(mine), "--out", str(out),
                 "--no-progress"]) == 1
    assert "rigid shift" in capsys.readouterr().err


def test_find_submission_prefers_points_then_the_methods_cloud_then_pairs(tmp_path):
    assert find_submission(str(tmp_path), "surface", "su") is None
    assert find_submission(str(tmp_path), "targets", "su") is None
    (tmp_path / "pairs.csv").write_text("u_left,v_left,u_right,v_right\n")
    assert find_submission(str(tmp_path), "targets", "su")[0] == "pairs"
    (tmp_path / "points_su.ply").write_text("")
    assert find_submission(str(tmp_path), "targets", "su")[1].endswith("points_su.ply")
    (tmp_path / "points_su_all.ply").write_text("")
    assert find_submission(str(tmp_path), "targets", "su")[1].endswith("points_su_all.ply")
    (tmp_path / "points.ply").write_text("")
    assert find_submission(str(tmp_path), "targets", "su")[1].endswith("points.ply")
    assert find_submission(str(tmp_path), "surface", "su") == ("points",
                                                               str(tmp_path / "points.ply"))
    (tmp_path / "depth.npy").write_text("")
    assert find_submission(str(tmp_path), "surface", "su")[1].endswith("depth.npy")


def test_aggregate_counts_failures_and_takes_the_worst():
    rows = [{"status": "ok", "p": 1, "rms_dp_mm": 0.1, "fscore_1mm": 0.9, "mean_dz_mm": -0.5},
            {"status": "ok", "p": 2, "rms_dp_mm": 0.3, "fscore_1mm": 0.7, "mean_dz_mm": 0.2},
            {"status": "missing", "p": 2}]
    out = {(a["group"], a["value"]): a for a in aggregate(rows, ["p"])}
    everything = out[("all", None)]
    assert everything["scored"] == 2 and everything["failed"] == 1
    assert everything["rms_dp_mm.worst"] == 0.3 and everything["fscore_1mm.worst"] == 0.7
    assert everything["mean_dz_mm.worst"] == -0.5
    assert np.isclose(everything["rms_dp_mm.mean"], 0.2)
    assert out[("p", "2")]["failed"] == 1 and out[("p", "2")]["rms_dp_mm.median"] == 0.3


@pytest.fixture(scope="module")
def surface_suite(tmp_path_factory):
    root = tmp_path_factory.mktemp("surface_suite")
    spec = root / "surfaces.toml"
    spec.write_text(f'scenes = ["{REPO / "scenes" / "speckle_tilted.xml"}"]\n'
                    f'render = "surface"\nrender_width = 96\n[fixed]\nspp = 2\n')
    suite = root / "suite"
    assert synth_main(["suite", str(spec), "--out", str(suite), "--workers", "1",
                       "--no-progress"]) == 0
    return suite, pq.read_table(suite / "index.parquet").to_pylist()[0]["folder"]


@pytest.mark.slow
def test_a_surface_suite_scored_with_its_own_truth_depth_is_exact(surface_suite, tmp_path):
    from synth.formats.exchange import read_pfm, write_pfm

    suite, folder = surface_suite
    sub = tmp_path / "sub"
    (sub / folder).mkdir(parents=True)
    write_pfm(str(sub / folder / "depth.pfm"),
              read_pfm(str(suite / folder / "left_truth_zdepth.pfm")))
    out = tmp_path / "scores"
    assert main(["score", str(suite), "--submission", str(sub), "--out", str(out),
                 "--no-progress"]) == 0
    row = json.loads((out / "summary.json").read_text())["datasets"][0]
    assert row["status"] == "ok" and row["measured_fraction"] == 1.0
    assert row["p2m_max_mm"] < 1e-3  # float32 depths of ~1 m: ~3e-5 mm steps


def _truth_cloud(suite, folder):
    from synth.products.truth_maps import read_truth_maps

    size = json.loads((suite / folder / "manifest.json").read_text())["image_size"]
    truth = read_truth_maps(str(suite / folder), "left", tuple(size))
    points = truth.points[truth.overlap]
    return points[np.isfinite(points).all(axis=1)]


@pytest.mark.slow
def test_a_surface_cloud_is_scored_and_one_in_metres_or_shifted_is_said(surface_suite, tmp_path,
                                                                        capsys):
    import open3d as o3d

    suite, folder = surface_suite
    points = _truth_cloud(suite, folder)
    out = tmp_path / "scores"
    runs = {"exact": points, "metres": points / 1000.0,
            "shifted": points + np.array([0.0, 0.0, 120.0])}
    rows = {}
    for name, cloud_points in runs.items():
        sub = tmp_path / name
        (sub / folder).mkdir(parents=True)
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud_points))
        o3d.io.write_point_cloud(str(sub / folder / "points.ply"), cloud)
        assert main(["score", str(suite), "--submission", str(sub), "--out",
                     str(out / name), "--no-progress"]) == 0
        rows[name] = json.loads((out / name / "summary.json").read_text())["datasets"][0]
        assert rows[name]["submission"] == f"{folder}/points.ply"
    exact = rows["exact"]
    assert exact["status"] == "ok" and not exact["warnings"]
    assert exact["scores"]["cloud_points"] == len(points)
    assert exact["p2m_max_mm"] < 1e-3 and exact["depth_rms_mm"] < 1e-9
    assert exact["measured_fraction"] == 1.0 and exact["fscore_1mm"] == 1.0
    assert "looks like metres" in rows["metres"]["warnings"]
    assert rows["metres"]["p2m_rms_mm"] > 500  # scored as given
    assert "rigid shift of (+0.0, +0.0, -120.0) mm" in rows["shifted"]["warnings"]
    assert "looks like metres" in capsys.readouterr().err


def test_swept_values_are_in_numeric_order():
    from eval.core.suite_scores import distinct_values

    rows = [{"z": 2000}, {"z": 600}, {"z": 1000}, {"z": 600.0}, {"z": None}]
    assert distinct_values(rows, "z") == [600, 1000, 2000, None]
    groups = [a["value"] for a in aggregate([{"status": "ok", **r} for r in rows[:3]], ["z"])]
    assert groups == [None, "600", "1000", "2000"]


def _data(size=(96, 80)):
    """What :func:`depth_points` reads of a dataset: its rig."""
    from types import SimpleNamespace

    from measure import StereoRig
    from synth.scene.rig import paper_cameras, paper_port

    return SimpleNamespace(rig=StereoRig(*paper_cameras(size, 45.0), paper_port()))


def _bad_depth_files(tmp_path):
    """``{name: (path, fragment of the reason)}``: depth submissions that are no depth maps."""
    from synth.formats.exchange import write_pfm

    files = {}
    for name, array, fragment in (
            ("zero_d", np.array(1000.0), "a 0-d array of shape ()"),
            ("one_d", np.full(96 * 80, 1000.0), "a 1-d array of shape (7680,)"),
            ("string", np.array(["1000"] * 7680).reshape(80, 96), "not depths"),
            ("string_0d", np.array("abc"), "not depths")):
        path = tmp_path / name / "depth.npy"
        path.parent.mkdir()
        np.save(path, array)
        files[name] = (path, fragment)
    path = tmp_path / "all_nan" / "depth.pfm"
    path.parent.mkdir()
    write_pfm(str(path), np.full((80, 96), np.nan, np.float32))
    files["all_nan"] = (path, "no pixel has a finite positive depth")
    path = tmp_path / "big_endian_header" / "depth.pfm"  # the scale says big-endian
    path.parent.mkdir()
    write_pfm(str(path), np.full((80, 96), 1000.0, np.float32))
    path.write_bytes(path.read_bytes().replace(b"\n-1.0\n", b"\n1.0\n", 1))
    files["big_endian_header"] = (path, "says big-endian data, but the data read as big-endian "
                                        "are not depths")
    return files


def test_depth_files_that_are_no_depth_maps_are_named(tmp_path):
    """A 0-d, 1-D or string ``depth.npy``, an all-NaN ``depth.pfm``, a PFM whose scale says the
    wrong byte order: one ValueError naming the file and why (they were internal errors that
    aborted the whole suite's scoring, or an all-NaN map "scored")."""
    from eval.core.suite_scores import depth_points
    from synth.formats.exchange import write_pfm

    data = _data()
    for name, (path, fragment) in _bad_depth_files(tmp_path).items():
        with pytest.raises(ValueError, match=re.escape(fragment)) as caught:
            depth_points(str(path), data)
        assert str(path) in str(caught.value), name
    good = tmp_path / "good.pfm"
    write_pfm(str(good), np.full((80, 96), 1000.0, np.float32))
    assert np.isfinite(depth_points(str(good), data)).all()


def test_a_mesh_given_as_points_is_refused(tmp_path):
    """A mesh PLY (its faces declared) is no point cloud: its vertices were scored as points."""
    import open3d as o3d

    from eval.cli import CLIError
    from eval.core.scoring import read_points

    mesh = o3d.geometry.TriangleMesh.create_box(100.0, 100.0, 100.0)
    path = tmp_path / "points.ply"
    o3d.io.write_triangle_mesh(str(path), mesh)
    with pytest.raises(CLIError, match=r"points.ply: a mesh \(12 faces\), not a point cloud"):
        read_points(str(path))
    cloud = o3d.geometry.PointCloud(mesh.vertices)
    o3d.io.write_point_cloud(str(path), cloud)
    assert len(read_points(str(path))) == 8


def test_a_bug_in_one_datasets_scoring_fails_that_dataset_only(tmp_path, monkeypatch):
    """An unexpected exception while scoring one dataset: that dataset fails with the reason
    ``internal error: …`` (it aborted the whole suite's scoring)."""
    import eval.core.suite_scores as suite_scores
    import synth.products.dataset as dataset

    (tmp_path / "sub" / "ds1").mkdir(parents=True)
    np.save(tmp_path / "sub" / "ds1" / "depth.npy", np.ones((80, 96)))
    monkeypatch.setattr(dataset, "read_dataset", lambda path: _data())

    def bug(*args):
        raise KeyError("oops")

    monkeypatch.setattr(suite_scores, "_score_surface", bug)
    row = {"status": "ok", "render": "surface", "folder": "ds1"}
    result = suite_scores.score_entry(str(tmp_path / "suite"), str(tmp_path / "sub"), row,
                                      "optical_path", None)
    assert result["status"] == "failed"
    assert result["error"] == "internal error: KeyError: 'oops'"


@pytest.mark.slow
def test_bad_depth_files_and_a_mesh_are_failures_of_their_dataset(surface_suite, tmp_path,
                                                                  capsys):
    """``eval score --submission`` on each: exit 1, the dataset failed with the reason, the
    summary written."""
    import open3d as o3d

    suite, folder = surface_suite
    (tmp_path / "files").mkdir()
    submissions = _bad_depth_files(tmp_path / "files")
    mesh = tmp_path / "files" / "mesh.ply"
    o3d.io.write_triangle_mesh(str(mesh), o3d.geometry.TriangleMesh.create_box(100.0, 100.0, 1.0))
    submissions["mesh"] = (mesh, "a mesh (12 faces), not a point cloud")
    for name, (path, fragment) in submissions.items():
        sub = tmp_path / "sub" / name
        (sub / folder).mkdir(parents=True)
        target = "points.ply" if name == "mesh" else path.name
        shutil.copy(path, sub / folder / target)
        out = tmp_path / "scores" / name
        code = main(["score", str(suite), "--submission", str(sub), "--out", str(out),
                     "--no-progress"])
        err = capsys.readouterr().err
        assert code == 1, (name, err)
        row = json.loads((out / "summary.json").read_text())["datasets"][0]
        assert row["status"] == "failed" and fragment in row["error"], (name, row["error"])
        # the error names the submission's file, not an option the user never gave
        assert f"{folder}/{target}" in row["error"] and "--points" not in row["error"]
        assert "internal error" not in err
