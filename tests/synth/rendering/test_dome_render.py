"""Rendered dome scenes (small): synth dataset / check and synth boards through two decentred
domes — the renderer's target centres and board corners against measure's forward projection
through each camera's own dome."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from measure.calibration.board import Board
from measure.geometry.projection import project
from synth.__main__ import main as synth_main
from synth.products.boards import read_boards, write_boards
from synth.products.dataset import read_calib, read_dataset
from synth.scene.layouts import grid_plane
from synth.scene.rig import paper_cameras
from synth.scene import load_scene, write_scene
from synth.scene.dome import dome_pair

#: Every test here renders with Mitsuba.
pytestmark = pytest.mark.slow

SIZE, FOCAL = (320, 268), 150.0
OFFSET = (2.0, -1.0, 1.5)


@pytest.fixture(scope="module")
def dome_scene(tmp_path_factory):
    """A 320x268 rig, each camera in a dome decentred by (2, -1, 1.5) mm, 9x9 targets of radius
    16 mm, 80 mm apart at Z = 1 m."""
    cameras = paper_cameras(SIZE, FOCAL)
    pair = dome_pair(cameras, 50.0, 8.0, OFFSET, (1.0, 1.54, 1.33))
    targets = grid_plane(1000.0, 320.0, 80.0) + np.array([3.0, -2.0, 0.0])
    path = tmp_path_factory.mktemp("dome") / "dome.xml"
    return str(write_scene(path, cameras, pair, targets, 16.0, spp=64))


def test_dataset_and_check_through_the_domes(dome_scene, tmp_path, capsys):
    out = tmp_path / "ds"
    assert synth_main(["dataset", dome_scene, "--out", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    assert synth_main(["check", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["passed"] and report["all_found"]
    assert report["left"]["found"] == report["left"]["in_image"] > 40
    assert report["rms_px"] < 0.03, report["rms_px"]
    data = read_dataset(out)
    spec = load_scene(dome_scene)
    assert data.rig.port.kind == "dome" and data.rig.port == spec.rig.port and data.has_port
    for view, camera in enumerate(data.rig.cameras):  # pixels.csv: through its own dome
        want = project(camera, spec.rig.view_port(view), data.targets)
        got = (data.pixels_left, data.pixels_right)[view]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    cameras = json.loads((out / "cameras.json").read_text())
    assert cameras["port"]["domes"]["right"]["radius"] == 50.0
    assert (out / "colmap" / "cameras.txt").read_text().count("DOMEPORT") >= 2
    assert data.manifest["colmap"].startswith("colmap/: cameras.txt (DOMEPORT")


def test_calib_yaml_round_trip_of_a_dome_rig(dome_scene, tmp_path):
    from synth.products.dataset import write_calib

    spec = load_scene(dome_scene)
    write_calib(tmp_path / "calib.yaml", spec.rig)
    calib = read_calib(str(tmp_path / "calib.yaml"))
    assert calib["has_port"] and calib["rig"].port.kind == "dome"
    for got, want in ((calib["port"].left, spec.rig.port.left),
                      (calib["port"].right, spec.rig.port.right)):
        np.testing.assert_allclose(got.center, want.center, rtol=0, atol=1e-12)
        assert (got.radius, got.thickness, got.indices) == (want.radius, want.thickness,
                                                            want.indices)


def test_boards_through_the_domes_match_the_forward_model(dome_scene, tmp_path):
    board = Board("chessboard", (7, 6), 60.0)
    spec = load_scene(dome_scene, {"width": 480, "height": 402})
    write_boards(spec, tmp_path / "b", board, n_poses=3, seed=5, distance_range=(450.0, 650.0),
                 progress=False)
    data = read_boards(tmp_path / "b")
    rig = data.calib["rig"]
    assert rig.port.kind == "dome" and not data.air
    assert set(os.listdir(tmp_path / "b")) >= {"calib.yaml", "corners.csv", "left_02.png"}
    errors = []
    for k, pair in enumerate(data.images):
        rows = data.corners[data.corners[:, 0] == k]
        world = data.poses[k].apply(board.corners())
        for view, image in enumerate(pair):
            np.testing.assert_allclose(rows[:, 5 + 2 * view:7 + 2 * view],
                                       project(rig.cameras[view], rig.view_port(view), world),
                                       atol=1e-9)
            ids, uv = board.detect(image)
            assert ids.size >= board.n_corners - 1
            errors.append(uv - rows[ids][:, 5 + 2 * view:7 + 2 * view])
    errors = np.concatenate(errors)
    assert np.sqrt(np.mean(np.sum(errors ** 2, axis=1))) < 0.05


def test_synth_boards_command_on_a_dome_scene(dome_scene, tmp_path, capsys):
    out = tmp_path / "b"
    assert synth_main(["boards", dome_scene, "--poses", "2", "--squares", "7x6", "--square-mm",
                       "60", "--distance", "450", "650", "--out", str(out),
                       "--no-progress"]) == 0
    assert "behind the domes" in capsys.readouterr().out
    assert read_calib(str(out / "calib.yaml"))["rig"].port.kind == "dome"
