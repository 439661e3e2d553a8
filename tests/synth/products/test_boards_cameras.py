"""``synth boards`` of a scene of three cameras behind one port (small images): one image per
camera and pose, the truth of every camera's corners, and corners detected on the renders where
the forward model through the port puts them."""

from __future__ import annotations

import os

import numpy as np
import pytest

from measure.calibration.board import Board
from measure.geometry.projection import project
from synth.__main__ import main as synth_main
from synth.products.boards import read_boards
from synth.products.rig_file import read_rig_file

pytestmark = pytest.mark.slow

BOARD = Board("chessboard", (7, 6), 60.0)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("three_boards")
    scene = root / "three.xml"
    assert synth_main(["scene", "--cameras", "3", "--baseline", "150", "--size", "480", "402",
                       "--focal", "225", "--out", str(scene)]) == 0
    out = {}
    for name, extra in (("air", ["--air"]), ("water", [])):
        out[name] = root / name
        assert synth_main(["boards", str(scene), "--poses", "3", "--squares", "7x6",
                           "--square-mm", "60", "--distance", "450", "700", "--spp", "16",
                           "--seed", "4", *extra, "--out", str(out[name]), "--no-progress"]) == 0
    return out


def test_one_image_per_camera_and_the_truth_of_each(folders):
    for name, folder in folders.items():
        data = read_boards(folder)
        files = set(os.listdir(folder))
        assert {f"cam{v}_{k:02d}.png" for v in range(3) for k in range(3)} <= files
        assert not any(f.startswith(("left", "right")) for f in files)
        rig = read_rig_file(folder / "calib.yaml")
        assert rig.names == ("cam0", "cam1", "cam2") and rig.refracts == (name == "water")
        assert len(data.images) == 3 and all(len(views) == 3 for views in data.images)
        corners = BOARD.corners()
        for k, pose in enumerate(data.poses):
            rows = data.corners[data.corners[:, 0] == k]
            world = pose.apply(corners)
            whole = []
            for v, camera in enumerate(rig.cameras):  # corners.csv: the forward model
                uv = project(camera, rig.view_port(v), world)
                np.testing.assert_allclose(rows[:, 5 + 2 * v:7 + 2 * v], uv, atol=1e-9)
                whole.append(camera.in_image(uv, 10).all())
            assert whole[k % 3] and sum(whole) >= 2, (name, k, whole)


def test_detected_corners_match_the_forward_model(folders):
    """Where the whole board is in a view, OpenCV finds its corners within 0.05 px RMS of the
    forward model's pixels (through the port in water)."""
    for folder in folders.values():
        data = read_boards(folder)
        errors, found = [], 0
        for k, views in enumerate(data.images):
            rows = data.corners[data.corners[:, 0] == k]
            for v, image in enumerate(views):
                ids, uv = BOARD.detect(image)
                if ids.size:
                    found += 1
                    errors.append(uv - rows[ids][:, 5 + 2 * v:7 + 2 * v])
        assert found >= 6
        errors = np.concatenate(errors)
        assert np.sqrt(np.mean(np.sum(errors ** 2, axis=1))) < 0.05
