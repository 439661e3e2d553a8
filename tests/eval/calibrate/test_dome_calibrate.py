"""python -m eval calibrate on boards rendered behind two decentred domes (small images): each
camera's decentring beside the truth with its σ; the flat port's design options refused."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from eval.__main__ import main as eval_main
from measure.calibration.board import Board
from synth.products.boards import write_boards
from synth.products.dataset import read_calib
from synth.scene.rig import paper_cameras
from synth.scene import load_scene, write_scene
from synth.scene.dome import dome_pair

#: Every test here renders with Mitsuba.
pytestmark = pytest.mark.slow

SIZE, FOCAL = (480, 402), 225.0
BOARD = Board("chessboard", (7, 6), 60.0)
OFFSET = (2.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def boards(tmp_path_factory):
    """A 480x402 rig, each camera in a dome decentred 2 mm along its x, and its boards
    underwater (8 poses)."""
    root = tmp_path_factory.mktemp("dome_boards")
    cameras = paper_cameras(SIZE, FOCAL)
    pair = dome_pair(cameras, 50.0, 8.0, OFFSET, (1.0, 1.54, 1.33))
    scene = str(write_scene(root / "dome.xml", cameras, pair, np.array([[0.0, 0.0, 1000.0]]),
                            10.0))
    write_boards(load_scene(scene), root / "water", BOARD, n_poses=8, seed=3,
                 distance_range=(450.0, 650.0), progress=False)
    return {"scene": scene, "water": str(root / "water"), "root": root}


@pytest.fixture(scope="module")
def air_boards(boards):
    """The same cameras' in-air boards (8 poses)."""
    write_boards(load_scene(boards["scene"]), boards["root"] / "air", BOARD, n_poses=8, seed=5,
                 air=True, distance_range=(350.0, 600.0), progress=False)
    return str(boards["root"] / "air")


def test_decentring_from_boards_behind_domes(boards, tmp_path, capsys):
    truth_calib = os.path.join(boards["water"], "calib.yaml")  # the exact intrinsics
    out = tmp_path / "cal"
    assert eval_main(["calibrate", boards["water"], "--intrinsics", truth_calib, "--out",
                      str(out), "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    housing = report["housing"]
    assert report["dome"] and housing["free"] == ["dome_center"] and housing["rms_px"] < 0.1
    params = housing["parameters"]
    assert set(params) == {f"{v}_dome_{a}" for v in ("left", "right") for a in "xyz"}
    for name, p in params.items():
        assert p["truth"] == pytest.approx(OFFSET["xyz".index(name[-1])], abs=1e-9)
        # small images (~30 px squares): loose bounds; the full-size numbers are in the docs
        assert abs(p["error"]) < 0.5 and abs(p["error_in_sigma"]) < 4, (name, p)
    calib = read_calib(str(out / "calib.yaml"))
    assert calib["rig"].port.kind == "dome"
    np.testing.assert_allclose(calib["port"].left.center, OFFSET, atol=0.5)
    assert "DOMEPORT" in (out / "cameras.txt").read_text()
    assert read_calib(str(out / "calib_in_air_only.yaml"))["port"].left.center.tolist() == \
        [0.0, 0.0, 0.0]
    assert "left dome x" in (out / "report.md").read_text()
    assert "housing left_dome_x" in capsys.readouterr().out


@pytest.mark.parametrize("extra, fragment", [
    (["--start-distance", "90"], "--start-distance does not apply to boards behind domes"),
    (["--free", "distance"], "unknown parameter of a dome rig distance"),
])
def test_flat_options_refused_for_domes(boards, tmp_path, capsys, extra, fragment):
    truth_calib = os.path.join(boards["water"], "calib.yaml")
    assert eval_main(["calibrate", boards["water"], "--intrinsics", truth_calib, "--out",
                      str(tmp_path / "cal"), "--no-progress", *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and fragment in err and err.count("\n") == 1, err
    assert not (tmp_path / "cal").exists()


@pytest.mark.parametrize("mode", ["prior", "propagate"])
def test_the_chain_behind_domes_carries_the_in_air_covariance(boards, air_boards, tmp_path,
                                                              mode):
    """In-air boards → their covariance → the domes: σ includes the in-air calibration's (above
    the conditional σ), the report says how, and calib.yaml's covariance names each dome's
    centre beside the in-air parameters — read back by eval run's reader."""
    out = tmp_path / "cal"
    assert eval_main(["calibrate", boards["water"], "--intrinsics", air_boards,
                      "--air-uncertainty", mode, "--out", str(out), "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    housing = report["housing"]
    assert housing["uncertainty"] == mode
    for name, p in housing["parameters"].items():
        assert p["sigma"] > p["sigma_conditional"] > 0, (name, p)
        assert abs(p["error"]) < 0.5 and abs(p["error_in_sigma"]) < 4, (name, p)
    covariance = read_calib(str(out / "calib.yaml"))["covariance"]
    dome_names = [f"{v}.dome_center[{k}]" for v in ("left", "right") for k in range(3)]
    assert list(covariance.names[-6:]) == dome_names and "left.fx" in covariance.names
    # the left camera is the reference frame: its dome centre's σ is its decentring's
    assert covariance.sigmas["left.dome_center[0]"] == pytest.approx(
        housing["parameters"]["left_dome_x"]["sigma"], rel=1e-9)
    text = (out / "report.md").read_text()
    assert "σ includes the in-air calibration's uncertainty" in text
    if mode == "prior":
        assert "left.fx" in housing["in_air_refined"]
