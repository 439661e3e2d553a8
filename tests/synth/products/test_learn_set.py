"""``python -m synth learn``: the split by seed, refused options, and a small set end to end
(every file its manifest lists, the lists and the KITTI tree, resuming)."""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np
import pytest

from synth.commands import main as synth_main
from synth.products.learn_set import SPLITS, split_of


def test_a_scenes_split_depends_on_its_seed_alone():
    splits = [split_of(s) for s in range(20000)]
    shares = [splits.count(name) / len(splits) for name in SPLITS]
    assert shares == pytest.approx([0.8, 0.1, 0.1], abs=0.01)
    assert [split_of(s) for s in range(100)] == splits[:100]
    assert {split_of(s, (0, 0, 1)) for s in range(50)} == {"test"}


@pytest.mark.parametrize("argv, fragment", [
    (["--ports", "flat,glass"], "--ports"),
    (["--size", "10x10"], "--size"),
    (["--distance", "2000,1000"], "--distance"),
    (["--pitch", "10,90"], "--pitch"),
    (["--split", "0,0,0"], "--split"),
    (["--scenes", "0"], "--scenes"),
    (["--connect-timeout", "3"], "--connect-timeout"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers"),
    (["--object", "no_such_rock.ply"], "--object no_such_rock.ply: no such file"),
])
def test_bad_options_are_one_error_line(tmp_path, capsys, argv, fragment):
    out = tmp_path / "set"
    code = synth_main(["learn", "--out", str(out), "--no-progress", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error:") and fragment in err[0]
    assert not out.exists()


def test_a_folder_of_someone_else_is_refused(tmp_path, capsys):
    (tmp_path / "mine.txt").write_text("keep me\n")
    code = synth_main(["learn", "--out", str(tmp_path), "--scenes", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "did not write" in err
    assert sorted(os.listdir(tmp_path)) == ["mine.txt"]


def test_a_first_run_killed_before_its_end_is_resumed(tmp_path, capsys, monkeypatch):
    """learn.json is written before the first scene: a first run killed while rendering (its
    finished scene folders kept) is taken up by a rerun, not refused as someone else's."""
    from synth.infra.cli import CLIError
    from synth.products import learn_run

    out = tmp_path / "set"
    argv = ["learn", "--out", str(out), "--scenes", "2", "--size", "64x64", "--spp", "1",
            "--no-progress"]

    def killed(*args):
        (out / "scene_000000").mkdir()  # what a worker had finished
        raise CLIError("interrupted")

    monkeypatch.setattr(learn_run, "_render", killed)
    assert synth_main(argv) == 2
    assert json.loads((out / "learn.json").read_text())["runs"] == []
    capsys.readouterr()
    monkeypatch.setattr(learn_run, "_render", lambda *args: ({}, "nowhere", 0.0))
    assert synth_main(argv) == 0
    assert "did not write" not in capsys.readouterr().err
    spp = argv.index("--spp") + 1  # other options are still refused
    assert synth_main(argv[:spp] + ["2"] + argv[spp + 1:]) == 2


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow
def test_a_small_set_end_to_end(tmp_path, capsys):
    out = tmp_path / "set"
    argv = ["learn", "--out", str(out), "--scenes", "2", "--seed", "7", "--size", "128x96",
            "--spp", "2", "--workers", "1", "--no-progress", "--split", "0.5,0,0.5"]
    assert synth_main(argv) == 0
    printed = capsys.readouterr().out
    assert "2 rendered now" in printed and "0 failed" in printed
    assert "sampled pixels where the warp is exact" in printed
    for seed in (7, 8):
        folder = out / f"scene_{seed:06d}"
        manifest = json.loads((folder / "manifest.json").read_text())
        assert manifest["checks"]["passed"] and manifest["seed"] == seed
        cpu = manifest["cpu_seconds"]  # each part's CPU seconds beside its wall clock
        assert set(cpu) == set(manifest["seconds"]) and cpu["total"] >= cpu["render"] > 0
        for rel, entry in manifest["files"].items():
            assert _sha(folder / rel) == entry["sha256"], rel
        for rel in ("left.png", "truth/flow_left_to_right.flo", "rectified/disparity.pfm",
                    "rectified/disparity_occ.png", "colmap/cameras.txt",
                    "colmap/depth_maps/left.png.geometric.bin", "colmap_pinhole/cameras.txt",
                    "scene/scene.xml", "scene/seabed.ply", "scene/seabed_texture.png"):
            assert rel in manifest["files"], rel
        _exchange_files_hold_the_rig(folder)
        split = split_of(seed, (0.5, 0, 0.5))
        line = f"scene_{seed:06d}/rectified/left.png"
        assert line in (out / "lists" / f"{split}_sceneflow.txt").read_text()
        kitti = out / "kitti" / split / "disp_occ_0" / f"{seed:06d}_10.png"
        assert kitti.read_bytes() == (folder / "rectified" / "disparity_occ.png").read_bytes()
    rows = (out / "index.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[0].startswith("seed,split,folder,port")
    assert rows[0].endswith(",render_cpu_seconds,total_cpu_seconds")
    # a rerun renders nothing; one more scene renders one; other options are refused
    assert synth_main(argv) == 0 and "0 rendered now" in capsys.readouterr().out
    assert synth_main(argv[:4] + ["3"] + argv[5:]) == 0
    assert "1 rendered now" in capsys.readouterr().out
    spp = argv.index("--spp") + 1
    assert synth_main(argv[:spp] + ["4"] + argv[spp + 1:]) == 2
    assert "other options" in capsys.readouterr().err
    learn = json.loads((out / "learn.json").read_text())
    assert sorted(learn["scenes"]) == ["7", "8", "9"]
    assert np.all([s["status"] == "ok" for s in learn["scenes"].values()])
    for seed, entry in learn["scenes"].items():
        assert entry["manifest_sha256"] == _sha(out / f"scene_{int(seed):06d}" / "manifest.json")


def test_the_committed_learning_suite_is_synth_learns_defaults(tmp_path):
    """``suites/learn_sea.toml`` asks for what ``synth learn --scenes 200`` does by default."""
    from synth.commands import build_parser
    from synth.infra.grid import read_toml
    from synth.products.learn_run import read_learn_spec
    from synth.scene.sea_draw import SeaRanges
    from tests.conftest import REPO

    data, _, label = read_toml(REPO / "suites" / "learn_sea.toml")
    request = read_learn_spec(data, label, "out")
    args = build_parser().parse_args(["learn", "--out", "out", "--scenes", "200"])
    assert request.seeds == tuple(range(args.seed, args.seed + args.scenes))
    assert request.ranges == SeaRanges(size=args.size, ports=args.ports, waters=args.water,
                                       lights=args.light, distance_mm=args.distance,
                                       pitch_deg=args.pitch)
    assert request.spp == args.spp and request.fractions == args.split


@pytest.mark.parametrize("text, fragment", [
    ('render = "learn"\nscenes = 0\n', "scenes"),
    ('render = "learn"\nports = ["glass"]\n', "ports"),
    ('render = "learn"\ndistance_mm = [900, 100]\n', "distance_mm"),
    ('render = "learn"\ngrid = 1\n', "unknown key"),
])
def test_a_bad_learning_suite_is_one_error_line(tmp_path, capsys, text, fragment):
    spec = tmp_path / "spec.toml"
    spec.write_text(text)
    code = synth_main(["suite", str(spec), "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and fragment in err[0]
    assert not (tmp_path / "out").exists()


def _exchange_files_hold_the_rig(folder):
    """``calib.yaml`` and the COLMAP fork's ``cameras.txt`` read back as rigs that project the
    truth points onto their pixels (float32 points: within 1e-3 px), and the COLMAP depth map is
    the truth's z in metres."""
    import cv2

    from measure.geometry.projection import project
    from synth.formats.exchange import read_pfm
    from synth.formats.learn_formats import read_colmap_depth
    from synth.products.dataset import read_calib
    from synth.formats.calib_formats import read_colmap

    points = np.load(folder / "truth" / "left_points.npy").astype(np.float64)
    valid = cv2.imread(str(folder / "truth" / "left_valid.png"), cv2.IMREAD_UNCHANGED) > 0
    rows, cols = np.nonzero(valid)
    pick = np.linspace(0, rows.size - 1, 50).astype(int)
    uv = np.column_stack([cols[pick], rows[pick]]).astype(float)
    for rig in (read_calib(str(folder / "calib.yaml"))["rig"],
                read_colmap(str(folder / "colmap" / "cameras.txt"))["rig"]):
        found = project(rig.left, rig.view_port(0), points[rows[pick], cols[pick]])
        assert np.max(np.abs(found - uv)) < 1e-3
    z = read_pfm(str(folder / "truth" / "left_depth_z.pfm"))
    colmap = read_colmap_depth(str(folder / "colmap" / "depth_maps" / "left.png.geometric.bin"))
    np.testing.assert_allclose(colmap[valid], z[valid] / 1000.0, rtol=1e-6)
