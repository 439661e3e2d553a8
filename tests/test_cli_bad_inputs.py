"""Bad input to either command line: exit 2, exactly one ``error:`` line, no traceback, and no
file created, changed or deleted (a refused command leaves no staging directory either).

Every case runs in a fresh directory holding a copy of the scene (and, where needed, a small
dataset); the whole tree is snapshotted before and after the call.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from eval.cli import main as eval_main
from synth.__main__ import main as synth_main
from tests.conftest import REPO

SMALL = ["-D", "width=320", "-D", "height=268", "--spp", "4", "--no-progress"]


def snapshot(root: Path) -> dict:
    """Every path below ``root`` with its size, mtime and content hash (directories too)."""
    out = {}
    for path in sorted(root.rglob("*")):
        rel = str(path.relative_to(root))
        if path.is_dir():
            out[rel] = "dir"
        else:
            stat = path.stat()
            out[rel] = (stat.st_size, stat.st_mtime_ns,
                        hashlib.sha256(path.read_bytes()).hexdigest())
    return out


@pytest.fixture(scope="session")
def dataset_template(tmp_path_factory, small_scene):
    """Valid outputs of the small scene (each rendered once, at 4 spp), and the scene beside
    them: the dataset ``ds``, the dataset ``dss`` stored through the imx174 sensor, and
    ``bair``, one pose of a board in air."""
    root = tmp_path_factory.mktemp("template")
    shutil.copy(small_scene, root / "small.xml")
    assert synth_main(["dataset", str(root / "small.xml"), "--out", str(root / "ds"),
                       "--spp", "4", "--quiet"]) == 0
    assert synth_main(["dataset", str(root / "small.xml"), "--out", str(root / "dss"),
                       "--spp", "4", "--sensor", "imx174", "--quiet"]) == 0
    assert synth_main(["boards", str(root / "small.xml"), "--out", str(root / "bair"),
                       "--spp", "4", "--poses", "1", "--air", "--squares", "7x6",
                       "--square-mm", "40", "--distance", "450", "650", "--quiet"]) == 0
    return root


@pytest.fixture
def workdir(tmp_path, monkeypatch, small_scene):
    """A fresh directory with ``paper_plane.xml`` and ``small.xml`` (add the dataset ``ds``
    with :func:`_add_dataset`)."""
    shutil.copy(REPO / "scenes" / "paper_plane.xml", tmp_path / "paper_plane.xml")
    shutil.copy(small_scene, tmp_path / "small.xml")
    monkeypatch.chdir(tmp_path)
    return tmp_path


#: Setups that damage the dataset ``ds``.
DATASET_SETUPS = ("garbage_calib", "no_left_png", "bad_manifest", "truncated_targets",
                  "truncated_pixels", "truncated_points", "edited_manifest",
                  "edited_manifest_no_hashes", "edited_calib", "edited_calib_no_hashes")
#: Cases that render before they are refused (nothing matched in the images).
RENDERING = ("max_depth=0", "3000,4000", "target_radius=0")


#: The rendered outputs of :func:`dataset_template` a case may name.
RENDERED = ("ds", "dss", "bair")


def _rendered_names(setup, argv) -> set:
    """The rendered outputs (:data:`RENDERED`) that a case uses."""
    names = {a.split("/")[0] for a in argv if a.split("/")[0] in RENDERED}
    return names | ({"ds"} if setup in DATASET_SETUPS else set())


def _needs_dataset(setup, argv) -> bool:
    return bool(_rendered_names(setup, argv))


def _add_dataset(workdir: Path, request, names=("ds",)) -> None:
    """Copy the rendered outputs ``names`` (default the dataset ``ds`` of ``small.xml``) into
    ``workdir``."""
    for name in names:
        shutil.copytree(request.getfixturevalue("dataset_template") / name, workdir / name)


def _cases(cases):
    """pytest params of ``(setup, argv, fragment)`` cases; those that need the rendered
    dataset or render themselves are marked ``slow``."""
    params = []
    for setup, argv, fragment in cases:
        slow = _needs_dataset(setup, argv) or any(r in argv_part for argv_part in argv
                                                  for r in RENDERING)
        params.append(pytest.param(setup, argv, fragment, marks=[pytest.mark.slow] if slow else [],
                                   id=" ".join(argv)[:70] + (f" [{setup}]" if setup else "")))
    return params


def _prepare(workdir: Path, setup: str | None):
    if setup == "user_dir":
        (workdir / "out").mkdir()
        (workdir / "out" / "mine.txt").write_text("my notes")
    elif setup == "out_file":
        (workdir / "out").write_text("a file where a directory should go")
    elif setup == "garbage_calib":
        (workdir / "ds" / "calib.yaml").write_text("%YAML:1.0\nK1: [garbage\n")
    elif setup == "no_left_png":
        (workdir / "ds" / "left.png").unlink()
    elif setup == "bad_manifest":
        (workdir / "ds" / "manifest.json").write_text("{not json")
    elif setup == "truncated_targets":  # theirs.ply: the whole truth, as a user's cloud
        shutil.copy(workdir / "ds" / "targets.ply", workdir / "theirs.ply")
        _truncate(workdir / "ds" / "targets.ply")
    elif setup == "truncated_pixels":
        _truncate(workdir / "ds" / "pixels.csv")
    elif setup == "truncated_points":
        shutil.copy(workdir / "ds" / "targets.ply", workdir / "half.ply")
        _truncate(workdir / "half.ply")
    elif setup == "truncated_corners":
        _truncate(workdir / "bair" / "corners.csv")
    elif setup == "edited_boards_calib":
        with open(workdir / "bair" / "calib.yaml", "a") as handle:
            handle.write("# edited by hand\n")
    elif setup in ("edited_manifest", "edited_manifest_no_hashes"):  # the truth edited by hand
        _edit_manifest(workdir / "ds", n_water="1.40", hashes=setup == "edited_manifest")
    elif setup in ("edited_calib", "edited_calib_no_hashes"):
        calib = workdir / "ds" / "calib.yaml"
        calib.write_text(calib.read_text().replace("1.3300000000000001", "1.3999999999999999"))
        if setup == "edited_calib_no_hashes":
            _edit_manifest(workdir / "ds", hashes=False)
    elif setup == "empty_scene":
        (workdir / "empty.xml").write_text("")
    elif setup == "not_xml":
        (workdir / "bad.xml").write_text("<scene version='3.0.0'><sensor")
    elif setup == "not_scene":
        (workdir / "foo.xml").write_text("<foo/>")
    elif setup == "scene_dir":
        (workdir / "adir").mkdir()
    elif setup == "foreign_file":
        (workdir / "notes.txt").write_text("a user's notes, not written by eval bench")
    elif setup == "user_mesh":  # the user's own file where synth scene puts the scene's mesh
        (workdir / "x_surface.ply").write_text("ply\nformat ascii 1.0\nmy scanned part\n")
    elif setup == "user_texture":  # a file named like the shared speckle texture
        (workdir / SURFACE_TEXTURE).write_bytes(b"my own picture")
    elif setup == "other_texture":  # a valid PNG of the texture's size but other pixels
        import cv2
        import numpy as np

        ok, data = cv2.imencode(".png", np.full((160, 200), 200, np.uint8))
        (workdir / SURFACE_TEXTURE).write_bytes(data.tobytes())


def _edit_manifest(ds: Path, n_water: str | None = None, hashes: bool = True) -> None:
    """Edit a dataset's manifest by hand: set its scene's ``n_water``; without ``hashes``, drop
    its file hashes and its own hash (as in a manifest written before they were recorded)."""
    import json

    manifest = json.loads((ds / "manifest.json").read_text())
    if n_water is not None:
        manifest["scene"]["params"]["n_water"] = n_water
    if not hashes:
        manifest.pop("manifest_sha256", None)
        manifest.pop("sha256", None)
    (ds / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")


def _truncate(path: Path) -> None:
    """Cut ``path`` to half its size (a copy interrupted half-way)."""
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


def _assert_refused(code, capsys, before, workdir, fragment=None):
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    if fragment:
        assert fragment.lower() in lines[0].lower(), lines[0]
    assert snapshot(workdir) == before
    assert not [p for p in workdir.rglob(".*staging*")]


RUN = ["run", "paper_plane.xml", "--out", "out", *SMALL]
RUN_SMALL = ["run", "small.xml", "--out", "out", "--spp", "4", "--no-progress"]
RUN_FROM = ["run", "small.xml", "--out", "out", "--from", "ds", "--no-progress"]
MEASURE = ["measure", "--calib", "ds/calib.yaml", "ds/left.png", "ds/right.png", "--out", "out",
           "--quiet"]
EVAL_CASES = [
    # data loss
    ("user_dir", RUN, "did not write"),
    (None, ["run", "paper_plane.xml", "--out", ".", *SMALL], "did not write"),
    ("out_file", RUN, "not a directory"),
    ("user_dir", ["paper", "--out", "out", "--trials", "2", "--no-progress"], "did not write"),
    (None, ["paper", "--out", ".", "--trials", "2", "--no-progress"], "did not write"),
    ("out_file", ["paper", "--out", "out", "--trials", "2", "--no-progress"], "not a directory"),
    # nothing matched
    (None, RUN + ["-D", "max_depth=0"], "match"),
    (None, RUN + ["--depth-range", "3000,4000"], "match"),
    (None, RUN + ["-D", "target_radius=0"], "target_radius"),
    # too large, distortion
    (None, RUN + ["-D", "width=100000", "-D", "height=100000"], "GiB"),
    (None, RUN + ["-D", "left_dist=-0.5 0 0 0 0"], "dist"),
    # a distortion that folds within the image: the camera and where it folds (issue 37)
    (None, RUN + ["-D", "left_dist=-5 0 0 0 0"],
     "left_dist: the lens distortion [-5.0, 0.0, 0.0, 0.0, 0.0] folds within the 320x268 image, "
     "about"),
    (None, RUN + ["-D", "left_dist=nan 0 0 0 0"], "dist"),
    (None, RUN + ["-D", "left_dist=1 2"], "dist"),
    # options
    (None, RUN + ["--gate-mm", "inf"], "--gate-mm"),
    (None, RUN + ["--gate-mm", "nan"], "--gate-mm"),
    (None, RUN + ["--gate-mm", "-1"], "--gate-mm"),
    (None, RUN + ["--gate-mm", "0"], "--gate-mm"),
    (None, RUN + ["--noise-px", "inf"], "--noise-px"),
    (None, RUN + ["--noise-px", "nan"], "--noise-px"),
    (None, RUN + ["--noise-px", "-1"], "--noise-px"),
    (None, RUN + ["--spp", "0"], "--spp"),
    (None, RUN + ["--spp", "abc"], "--spp"),
    (None, RUN + ["--seed", "-3"], "--seed"),
    (None, RUN + ["--seed", "3", "-D", "seed=4"], "seed"),
    # seeds beyond Mitsuba's 32-bit sampler seed (they wrapped: 2^32 rendered seed 0's bytes)
    (None, RUN + ["--seed", "4294967296"], "4294967294"),
    (None, RUN + ["-D", "seed=4294967295"], "4294967294"),
    (None, RUN + ["--depth-range", "5"], "--depth-range"),
    (None, RUN + ["--depth-range", "2,1"], "--depth-range"),
    (None, RUN + ["--depth-range", "nan,5"], "--depth-range"),
    # a leading minus is the value, not an option (issue 37: "expected one argument")
    # an empty --out is named as such (it was "--out exists and holds files this command did
    # not write": the empty path is the current directory) (issue 37)
    (None, ["run", "paper_plane.xml", "--out", "", *SMALL], "argument --out: the path is empty"),
    (None, ["sweep", "sweep.toml", "--out", " "], "argument --out: the path is empty"),
    (None, ["bench", "--out", ""], "argument --out: the path is empty"),
    (None, RUN + ["--depth-range", "-100,2000"],
     "--depth-range -100,2000: the near end must not be negative"),
    (None, RUN + ["--gate-mm", "-1e9"], "--gate-mm: expected a positive finite number, got '-1e9'"),
    (None, RUN + ["--max-elongation", "1"], "--max-elongation"),
    (None, RUN + ["--max-elongation", "inf"], "--max-elongation"),
    (None, RUN + ["--median-filter", "4"], "--median-filter"),
    (None, RUN + ["--methods", "bogus"], "bogus"),
    (None, RUN + ["--methods", ""], "method"),
    (None, RUN + ["--variant", "bogus_variant"], "bogus_variant"),
    # scene parameters
    (None, RUN + ["-D", "bogus=1"], "bogus"),
    (None, RUN + ["-D", "novalue"], "novalue"),
    (None, RUN + ["-D", "width=abc"], "width"),
    (None, RUN + ["-D", "width=0"], "width"),
    (None, RUN + ["-D", "width=-5"], "width"),
    (None, RUN + ["-D", "width=320.5"], "width"),
    (None, RUN + ["-D", "n_water=abc"], "n_water"),
    (None, RUN + ["-D", "n_water=nan"], "n_water"),
    (None, RUN + ["-D", "spp=0"], "spp"),
    (None, RUN + ["-D", "target_z=-5"], "target_z"),
    # scene files
    (None, ["run", "missing.xml", "--out", "out", "--no-progress"], "missing.xml"),
    ("not_xml", ["run", "bad.xml", "--out", "out", "--no-progress"], "bad.xml"),
    ("not_scene", ["run", "foo.xml", "--out", "out", "--no-progress"], "foo.xml"),
    ("empty_scene", ["run", "empty.xml", "--out", "out", "--no-progress"], "empty.xml"),
    ("scene_dir", ["run", "adir", "--out", "out", "--no-progress"], "adir"),
    # datasets
    ("garbage_calib", RUN_FROM, "calib.yaml"),
    ("no_left_png", RUN_FROM, "left.png"),
    ("bad_manifest", RUN_FROM, "manifest.json"),
    (None, RUN_FROM + ["-D", "width=640"], "640"),
    (None, RUN_FROM + ["-D", "n_water=1.36"], "n_water"),
    (None, RUN_SMALL[:-1] + ["--from", "missing_ds", "--no-progress"], "missing_ds"),
    (None, ["run", "paper_plane.xml", "--from", "ds", "--out", "out", "--no-progress"], "another scene"),
    # options that cannot apply are refused, never ignored (issue 22)
    (None, RUN_FROM + ["--spp", "8"], "--spp does not apply"),
    (None, RUN_FROM + ["--variant", "scalar_rgb"], "--variant does not apply"),
    (None, RUN_FROM + ["-D", "spp=8"], "spp=4"),  # compared with what was rendered
    (None, ["run", "small.xml", "--out", "out", "--from", "dss", "--sensor", "imx174",
            "--no-progress"], "--sensor does not apply"),
    (None, RUN + ["-D", "spp=8"], "--spp 4 conflicts with -D spp=8"),
    (None, ["run", str(REPO / "scenes" / "air_plane.xml"), "--out", "out", *SMALL,
            "--self-calibrate", "n_water"], "no port"),
    (None, ["score", "missing_ds", "--points", "theirs.ply", "--method", "su"],
     "--method does not apply"),
    (None, ["score", "missing_ds", "--pixels", "pairs.csv", "--units", "m"],
     "--units does not apply"),
    (None, ["calibrate", "bair", "--free", "n_water", "--out", "out", "--no-progress"],
     "--free does not apply"),
    (None, ["calibrate", "bair", "--n-water", "1.2", "--out", "out", "--no-progress"],
     "--n-water does not apply"),
    (None, ["calibrate", "bair", "--start-distance", "90", "--out", "out", "--no-progress"],
     "--start-distance does not apply"),
    (None, ["calibrate", "bair", "--squares", "9x6", "--out", "out", "--no-progress"],
     "the folder's board.json defines the board"),
    (None, ["calibrate", "missing_photos", "--air", "--out", "out", "--no-progress"],
     "missing_photos"),
    (None, ["sweep", str(REPO / "sweeps" / "smoke.toml"), "--out", "sw", "--connect-timeout",
            "3", "--no-progress"], "--connect-timeout does not apply"),
    # files are read whole or refused (issue 22)
    ("truncated_targets", ["score", "ds", "--points", "theirs.ply", "--out", "sc"],
     "targets.ply: truncated"),
    ("truncated_targets", RUN_FROM, "targets.ply: truncated"),
    ("truncated_points", ["score", "ds", "--points", "half.ply", "--out", "sc"],
     "half.ply: truncated"),
    ("truncated_pixels", ["score", "ds", "--pixels", "ds/pixels.csv", "--out", "sc"],
     "pixels.csv"),
    ("truncated_corners", ["calibrate", "bair", "--out", "out", "--no-progress"], "corners.csv"),
    # a dataset's manifest is not a place to edit the truth (issue 22)
    ("edited_manifest", RUN_FROM, "manifest.json was changed"),
    ("edited_manifest", ["score", "ds", "--points", "ds/targets.ply", "--out", "sc"],
     "manifest.json was changed"),
    ("edited_manifest_no_hashes", RUN_FROM, "disagree with its request key"),
    ("edited_calib", RUN_FROM, "calib.yaml: changed"),
    ("edited_calib", ["score", "ds", "--pixels", "ds/pixels.csv", "--out", "sc"],
     "calib.yaml: changed"),
    ("edited_calib_no_hashes", RUN_FROM, "calib.yaml disagrees"),
    ("edited_boards_calib", ["calibrate", "bair", "--out", "out", "--no-progress"],
     "calib.yaml: changed since synth boards wrote it"),
    # truth and assumption
    (None, RUN + ["--assume", "bogus=1"], "bogus"),
    (None, RUN + ["--assume", "n_water"], "n_water"),
    (None, RUN + ["--assume", "n_water=abc"], "n_water"),
    (None, RUN + ["--assume", "n_water=0.9"], "indices"),
    (None, RUN + ["--assume", "port_distance=-5"], "assume"),
    (None, RUN + ["--assume", "port_normal=0 0"], "port_normal"),
    (None, RUN + ["--assume", "focal=0"], "focal"),
    (None, RUN + ["--calib", "missing.yaml"], "missing.yaml"),
    ("garbage_calib", RUN + ["--calib", "ds/calib.yaml"], "calib.yaml"),
    (None, RUN + ["--calib", "ds/calib.yaml", "-D", "width=640"], "image size"),
    (None, RUN + ["--self-calibrate", "n_glass"], "n_glass"),
    # bench and paper options
    (None, ["bench", "--points", "0"], "--points"),
    (None, ["bench", "--points", "abc"], "--points"),
    (None, ["bench", "--out", "ds"], "directory"),
    (None, ["bench", "--out", "missing_dir/x.json"], "missing_dir"),
    ("foreign_file", ["bench", "--out", "notes.txt"], "not a file this command wrote"),
    (None, ["paper", "--trials", "0", "--out", "p"], "--trials"),
    (None, ["paper", "--seed", "-1", "--out", "p"], "--seed"),
    (None, ["no_such_command"], "no_such_command"),
    # measure: a user's photos (here the dataset's 16-bit renders) with a calibration
    ("user_dir", MEASURE, "did not write"),
    (None, MEASURE[:-3] + ["--out", ".", "--quiet"], "did not write"),
    ("out_file", MEASURE, "not a directory"),
    ("garbage_calib", MEASURE, "calib.yaml"),
    (None, MEASURE + ["--depth-range", "3000,4000"], "no target was matched"),
    (None, ["measure", "--calib", "ds/calib.yaml", "ds/left.png", "small.xml", "--out", "out"],
     "small.xml"),
]

SCENE = ["scene", "--out", "x.xml"]
#: A small surface scene (texture of 200 x 160 texels) and the name of its texture.
SURFACE = SCENE + ["--layout", "surface", "--size", "320", "268", "--speckle-size", "50"]
SURFACE_TEXTURE = "speckle_50mm_0.5_0_2000x1600mm.png"
DATASET = ["dataset", "small.xml", "--out", "out", "--spp", "4", "--quiet"]
RENDER = ["render", "small.xml", "--out", "out", "--spp", "4", "--quiet"]
BOARDS = ["boards", "small.xml", "--out", "out", "--poses", "1", "--quiet"]
SYNTH_CASES = [
    (None, SCENE + ["--layout", "grid", "--spacing", "0"], "--spacing"),
    (None, SCENE + ["--layout", "grid", "--spacing", "-5"], "--spacing"),
    (None, SCENE + ["--layout", "grid", "--spacing", "nan"], "--spacing"),
    (None, SCENE + ["--layout", "grid", "--spacing", "0.001"], "grid"),
    (None, SCENE + ["--z", "nan"], "--z"),
    (None, SCENE + ["--z", "-100"], "--z"),
    (None, SCENE + ["--size", "0", "10"], "--size"),
    (None, SCENE + ["--focal", "0"], "--focal"),
    (None, SCENE + ["--layout", "random", "--n", "0"], "--n"),
    (None, SCENE + ["--layout", "random", "--z-range", "5", "1"], "--z-range"),
    (None, SCENE + ["--target-radius", "-1"], "--target-radius"),
    (None, SCENE + ["--n-water", "nan"], "--n-water"),
    (None, SCENE + ["--n-water", "0.5"], "index >= 1"),
    (None, SCENE + ["--dist", "nan", "0", "0", "0", "0"], "--dist"),
    (None, SCENE + ["--dist", "0.1", "0"], "dist"),
    (None, ["scene", "--out", "missing_dir/x.xml"], "missing_dir"),
    (None, ["scene", "--out", "paper_plane_copy.xml"], None),  # placeholder replaced below
    (None, ["scene", "--out", "ds"], "directory"),
    ("user_dir", DATASET, "did not write"),
    (None, DATASET[:3] + ["."] + DATASET[4:], "did not write"),
    ("out_file", DATASET, "not a directory"),
    ("user_dir", RENDER, "did not write"),
    ("out_file", RENDER, "not a directory"),
    (None, DATASET + ["-D", "width=100000", "-D", "height=100000"], "GiB"),
    (None, DATASET + ["--seed", "1", "-D", "seed=2"], "seed"),
    (None, DATASET + ["--seed", "4294967296"], "4294967294"),
    (None, RENDER + ["-D", "seed=99999999999"], "4294967294"),
    (None, SCENE + ["--seed", "4294967295"], "4294967294"),
    # full film, two passes per view (3000 spp at 320 x 268): pass 1 of the right view is
    # S + 1 + 2^21
    (None, RENDER + ["--spp", "3000", "--seed", "4294967294", "--full-film"], "4292870142"),
    # adaptive: the pilot (pass 0), then up to two masked calls or full-film passes
    (None, RENDER + ["--spp", "3000", "--seed", "4294967294"], "4290772990"),
    # 15 board poses: pose k's views are seeded S + 2k and S + 2k + 1 (+ 2^21 for the pass
    # after an adaptive render's pilot)
    (None, ["boards", "small.xml", "--out", "out", "--seed", "4294967280", "--quiet",
            "--full-film"], "4294967266"),
    (None, ["boards", "small.xml", "--out", "out", "--seed", "4294967280", "--quiet"],
     "4292870114"),
    (None, RENDER + ["-D", "left_dist=-0.5 0 0 0 0"], "dist"),
    ("garbage_calib", ["check", "ds"], "calib.yaml"),
    ("no_left_png", ["check", "ds"], "left.png"),
    ("bad_manifest", ["check", "ds"], "manifest.json"),
    (None, ["check", "missing_ds"], "missing_ds"),
    (None, ["check", "small.xml"], "small.xml"),
    (None, ["check", "ds", "--rms", "nan"], "--rms"),
    (None, ["check", "ds", "--rms", "-1"], "--rms"),
    (None, SCENE + ["--layer", "1.49", "10", "--n-glass", "1.5"], "--layer"),
    (None, SCENE + ["--layer", "0.9", "10"], "--layer"),
    (None, SCENE + ["--layer", "1.5", "-1"], "--layer"),
    (None, SCENE + ["--port", "none", "--lighting", "lit"], "needs a port"),
    (None, SCENE + ["--focus-distance", "800"], "--aperture-radius"),
    (None, SCENE + ["--aperture-radius", "nan"], "--aperture-radius"),
    (None, SCENE + ["--z", "5000", "--target-radius", "4000"], "visible"),
    (None, SCENE + ["--layout", "cylinder", "--half-angle", "95"], "--half-angle"),
    (None, SCENE + ["--layout", "tilted", "--tilt", "0", "85"], "--tilt"),
    (None, SCENE + ["--layout", "tilted", "--tilt", "79.9", "79.9"], "--tilt"),
    (None, SCENE + ["--layout", "random", "--n", "100000000"], "--n"),
    (None, SCENE + ["--layout", "sphere", "--surface-radius", "1e12"], "--surface-radius"),
    (None, SCENE + ["--aperture-radius", "1", "--dist", "0.1", "0", "0", "0"], "--dist"),
    # options that cannot apply are refused, never ignored (issue 22)
    (None, SCENE + ["--layout", "paper", "--spacing", "30"], "--spacing does not apply"),
    (None, SCENE + ["--layout", "grid", "--tilt", "0", "10"], "--tilt does not apply"),
    (None, SCENE + ["--layout", "grid", "--n", "5"], "--n does not apply"),
    (None, SCENE + ["--layout", "random", "--z", "900"], "--z does not apply"),
    (None, SCENE + ["--layout", "paper", "--half-width", "300"], "--half-width does not apply"),
    (None, SCENE + ["--layout", "paper", "--surface", "wavy"], "--surface does not apply"),
    (None, SCENE + ["--layout", "paper", "--speckle-size", "3"], "--speckle-size does not apply"),
    (None, SCENE + ["--layout", "surface", "--wavelength", "100"], "--wavelength does not apply"),
    (None, SCENE + ["--layout", "surface", "--n", "10"], "--n does not apply"),
    (None, SCENE + ["--port", "none", "--n-water", "1.34"], "--n-water does not apply"),
    (None, SCENE + ["--port", "none", "--port-tilt", "1", "0"], "--port-tilt does not apply"),
    # two housings: a value per camera, windows that keep the fields of view apart
    (None, SCENE + ["--port", "per-camera", "--port-distance", "80"],
     "--port-distance 80: --port per-camera needs one value per camera"),
    (None, SCENE + ["--port", "per-camera", "--port-tilt", "0", "0,2"],
     "--port-tilt 0: --port per-camera needs one value per camera"),
    (None, SCENE + ["--port", "paper", "--glass-thickness", "5,6"],
     "--glass-thickness 5,6: 2 values are for --port per-camera"),
    (None, SCENE + ["--port", "per-camera", "--port-distance", "100,120"],
     "the left camera's field of view passes through the right window"),
    (None, DATASET + ["-D", "spp=8"], "--spp 4 conflicts with -D spp=8"),
    (None, RENDER + ["-D", "spp=8"], "--spp 4 conflicts with -D spp=8"),
    (None, BOARDS + ["--spp", "4", "-D", "spp=8"], "--spp 4 conflicts with -D spp=8"),
    (None, BOARDS + ["--seed", "1", "-D", "seed=2"], "--seed 1 conflicts with -D seed=2"),
    (None, BOARDS + ["--air", "-D", "n_water=1.4"], "n_water"),
    (None, BOARDS + ["-D", "target_radius=3"], "target_radius"),
    # files are read whole or refused (issue 22)
    ("truncated_targets", ["check", "ds"], "targets.ply: truncated"),
    ("truncated_pixels", ["check", "ds"], "pixels.csv"),
    ("edited_manifest", ["check", "ds"], "manifest.json was changed"),
    # the files beside the scene: neither the mesh nor the shared texture of someone else
    ("user_mesh", SURFACE, "x_surface.ply"),
    ("user_texture", SURFACE, SURFACE_TEXTURE),
    ("other_texture", SURFACE, SURFACE_TEXTURE),
]
# Overwriting a file that `synth scene` did not write (the scene file of someone else).
SYNTH_CASES[16] = (None, ["scene", "--out", "small_copy_foreign.xml"], "not a file this command wrote")


@pytest.mark.parametrize("setup, argv, fragment", _cases(EVAL_CASES))
def test_eval_bad_input(workdir, capsys, request, setup, argv, fragment):
    if _needs_dataset(setup, argv):
        _add_dataset(workdir, request, _rendered_names(setup, argv))
    _prepare(workdir, setup)
    before = snapshot(workdir)
    code = eval_main(list(argv))
    _assert_refused(code, capsys, before, workdir, fragment)


@pytest.mark.parametrize("setup, argv, fragment", _cases(SYNTH_CASES))
def test_synth_bad_input(workdir, capsys, request, setup, argv, fragment):
    if _needs_dataset(setup, argv):
        _add_dataset(workdir, request, _rendered_names(setup, argv))
    _prepare(workdir, setup)
    (workdir / "small_copy_foreign.xml").write_text("<scene version='3.0.0'/>\n")
    before = snapshot(workdir)
    code = synth_main(list(argv))
    _assert_refused(code, capsys, before, workdir, fragment)


@pytest.mark.slow
def test_earlier_output_is_replaced_and_stale_staging_removed(workdir, capsys, request):
    """Positive control: a second run over its own output succeeds; a staging directory of a
    dead process (PID 999999 does not exist here) is cleaned up by the next run."""
    _add_dataset(workdir, request)
    argv = ["run", "small.xml", "--out", "out", "--from", "ds", "--methods", "optical_path",
            "--no-progress"]
    assert eval_main(argv) == 0
    stale = workdir / ".out.staging-999999-abc"
    stale.mkdir()
    (stale / "partial.png").write_bytes(b"x")
    assert eval_main(argv) == 0
    assert not stale.exists() and (workdir / "out" / "report.json").is_file()
    names = sorted(p.name for p in workdir.iterdir())
    assert names == sorted(["ds", "out", "paper_plane.xml", "small.xml"])


@pytest.mark.slow
def test_a_manifest_without_hashes_that_agrees_with_itself_is_read(workdir, request):
    """Positive control of the edited-manifest cases: a manifest without its hashes (as
    written before format 3) whose request key still agrees with it is read."""
    _add_dataset(workdir, request)
    _edit_manifest(workdir / "ds", hashes=False)
    assert eval_main(["score", "ds", "--points", "ds/targets.ply", "--out", "sc"]) == 0


@pytest.mark.slow
def test_from_dataset_with_its_own_parameters_runs(workdir, request):
    """``-D spp=4`` on a dataset rendered with ``--spp 4`` is what was rendered (issue 22: the
    manifest recorded the scene's default, 36, and the run was refused)."""
    _add_dataset(workdir, request)
    assert eval_main(["run", "small.xml", "--from", "ds", "--out", "out", "-D", "width=320",
                      "-D", "spp=4", "--methods", "optical_path", "--no-progress"]) == 0


@pytest.mark.parametrize("module, argv", [
    ("eval", ["run", "paper_plane.xml", "--out", "out", "--gate-mm", "inf"]),
    ("eval", ["run", "missing.xml", "--out", "out"]),
    ("synth", ["scene", "--layout", "grid", "--spacing", "0", "--out", "x.xml"]),
    ("synth", ["check", "missing_ds"]),
])
def test_python_m_path(workdir, module, argv):
    before = snapshot(workdir)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.run([sys.executable, "-m", module, *argv], cwd=workdir, env=env,
                          capture_output=True, text=True, timeout=120)
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr
    assert snapshot(workdir) == before


@pytest.mark.parametrize("script", ["refstereo-eval", "refstereo-synth"])
def test_console_scripts(workdir, script):
    path = Path(sys.executable).parent / script
    if not path.exists():
        pytest.skip(f"{script} is not installed in this environment (pip install -e .)")
    proc = subprocess.run([str(path), "--no-such-option"], cwd=workdir, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.startswith("error:")


# --- random values ---------------------------------------------------------------------------
BAD_TEXT = st.sampled_from(["nan", "inf", "-inf", "0", "-1", "1e308", "abc", "", " ", "1,2",
                            "0x10", "1e-300", "-0"])
SIZES = st.one_of(st.integers(64, 400).map(str), BAD_TEXT)
NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), BAD_TEXT,
                    st.text(max_size=5))


@pytest.mark.slow
@settings(max_examples=25, deadline=None)
@given(defines=st.dictionaries(
    st.sampled_from(["width", "height", "n_water", "target_radius", "target_z", "max_depth",
                     "spp", "left_dist"]),
    st.one_of(SIZES, NUMBERS), max_size=3))
def test_random_scene_parameters(small_scene, tmp_path_factory, defines):
    root = tmp_path_factory.mktemp("random")
    shutil.copy(small_scene, root / "small.xml")
    before = snapshot(root)
    argv = ["run", str(root / "small.xml"), "--out", str(root / "out"), "--spp", "1",
            "--methods", "optical_path", "--no-progress"]
    for name, value in defines.items():
        argv += ["-D", f"{name}={value}"]
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = eval_main(argv)
    text = err.getvalue()
    assert code in (0, 1, 2), text
    assert "Traceback" not in text
    if code == 1:  # a run that knows its result is wrong (e.g. n_water = 64) says so and why
        assert [line for line in text.splitlines() if line.startswith("failed:")], text
        assert (root / "out" / "report.json").is_file()
    after = snapshot(root)
    if code == 2:
        assert len([line for line in text.splitlines() if line.startswith("error:")]) == 1
        assert after == before
    else:
        assert {k: v for k, v in after.items() if not k.startswith("out")} == before


@settings(max_examples=25, deadline=None)
@given(option=st.sampled_from(["--spacing", "--z", "--target-radius", "--n-water", "--focal",
                               "--half-width", "--port-distance", "--glass-thickness"]),
       value=NUMBERS)
def test_random_scene_options(tmp_path_factory, option, value):
    root = tmp_path_factory.mktemp("random_scene")
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = synth_main(["scene", "--layout", "grid", "--out", str(root / "s.xml"),
                           "--size", "320", "268", option, value])
    text = err.getvalue()
    assert code in (0, 2), text
    assert "Traceback" not in text
    if code == 2:
        assert len([line for line in text.splitlines() if line.startswith("error:")]) == 1
        assert list(root.iterdir()) == []
    else:
        assert [p.name for p in root.iterdir()] == ["s.xml"]


def test_a_broken_photo_is_one_error_line_and_nothing_before_it(workdir):
    """A JPEG cut short and a PNG that is no PNG: libjpeg's "Premature end of JPEG file",
    libpng's "libpng error" and OpenCV's "[ WARN:0…] imread_" used to precede the ``error:`` line
    (they write to the process's stderr, past Python): the one line naming the file is all a
    new process prints (issue 53)."""
    import cv2
    import numpy as np

    from synth.products.dataset import write_calib
    from synth.scene.rig import paper_rig

    image = (np.indices((240, 320)).sum(axis=0) % 255).astype(np.uint8)
    ok, data = cv2.imencode(".jpg", image)
    (workdir / "cut.jpg").write_bytes(data.tobytes()[:1500])
    (workdir / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)
    cv2.imwrite(str(workdir / "good.png"), image)
    write_calib(workdir / "calib.yaml", paper_rig())
    env = dict(os.environ, PYTHONPATH=str(REPO))
    for left, name in (("cut.jpg", "cut.jpg: a truncated JPEG"), ("bad.png", "bad.png")):
        proc = subprocess.run([sys.executable, "-m", "eval", "measure", "--calib", "calib.yaml",
                               left, "good.png", "--out", "out", "--no-progress"], cwd=workdir,
                              env=env, capture_output=True, text=True, timeout=120)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1, proc.stderr
        assert lines[0].startswith("error:") and name in lines[0], proc.stderr
    assert not (workdir / "out").exists()
