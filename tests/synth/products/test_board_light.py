"""A printed board lit by a lamp (``synth boards --light``): the rendered white squares against
the closed-form radiance of a diffuse surface under a spot, the truth unchanged, the options
refused where they cannot apply."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure import FlatPort
from measure.calibration.board import Board
from synth.__main__ import main as synth_main
from synth.products.board_light import (BoardLight, board_radiance, spot_falloff,
                                        stored_white_ratios, white_square_centres,
                                        white_square_levels)
from synth.products.boards import BoardPose, read_boards, write_boards
from synth.scene import load_scene, write_scene
from synth.scene.rig import paper_cameras

SIZE, FOCAL = (480, 402), 225.0
BOARD = Board("chessboard", (7, 6), 60.0)
DISTANCE = (450.0, 650.0)


def test_spot_falloff_is_full_in_the_beam_linear_to_the_cutoff_and_zero_beyond():
    angles = np.radians([0.0, 30.0, 37.5, 45.0, 50.0])
    np.testing.assert_allclose(spot_falloff(np.cos(angles), 40.0, 30.0),
                               [1.0, 1.0, 0.25, 0.0, 0.0], atol=1e-12)


def test_stored_white_ratios_expose_the_median_view_at_the_level_and_clip():
    """Three views' white squares (linear): the median view's median square lands at 200 DN,
    the brightest view clips at 255 and its ratio shrinks, a square outside the image (NaN) is
    left out."""
    views = [np.array([1.0, 1.0, 2.0]), np.array([2.0, 3.0, 4.0]), np.array([3.0, 9.0, np.nan])]
    ratio, clipped = stored_white_ratios(views, 200.0)
    # medians 1, 3, 6 -> the middle one (3) at 200 DN: scale 200 / 3
    np.testing.assert_allclose(ratio, [133.0 / 67.0, 255.0 / 133.0, 255.0 / 200.0])
    np.testing.assert_array_equal(clipped, [False, True, True])


def test_closed_form_radiance_of_white_paper_facing_the_lamp():
    """``ρ/π · I / r²`` on the spot's axis, falling with cos θ and 1/r² beside it."""
    light = BoardLight("spot", (0.0, 0.0, 0.0), (0.0, 0.0, 1000.0), intensity=1e6,
                       cutoff_deg=60.0)
    camera = paper_cameras(SIZE, FOCAL)[0]  # at the origin: the camera frame is the reference
    points = np.array([[0.0, 0.0, 1000.0], [0.0, 0.0, 2000.0], [500.0, 0.0, 1000.0]])
    L = board_radiance(light, camera, points, np.array([0.0, 0.0, -1.0]), 0.8)
    cos = 1000.0 / np.hypot(500.0, 1000.0)
    np.testing.assert_allclose(L, 0.8 / np.pi * 1e6 * np.array(
        [1e-6, 0.25e-6, cos / (500.0 ** 2 + 1000.0 ** 2)]), rtol=1e-12)


def test_placed_fills_the_medium_default_and_the_aim_only():
    air = BoardLight().placed(True, 575.0)
    water = BoardLight().placed(False, 1050.0)
    assert air.position_mm == (-200.0, -150.0, -600.0) and air.aim_mm == (0.0, 0.0, 575.0)
    assert water.position_mm == (-300.0, -200.0, 150.0)
    mine = BoardLight("point", (1.0, 2.0, 3.0), (0.0, 0.0, 9.0)).placed(True, 575.0)
    assert mine.position_mm == (1.0, 2.0, 3.0) and mine.aim_mm == (0.0, 0.0, 9.0)
    with pytest.raises(ValueError, match="0 <= black < white <= 1"):
        BoardLight(black=0.9, white=0.5)
    with pytest.raises(ValueError, match="spot angle"):
        BoardLight(cutoff_deg=95.0)


def test_white_squares_of_a_chessboard_are_those_of_its_pattern():
    centres = white_square_centres(BOARD)
    texels = 10
    pattern = BOARD.pattern(texels)
    ij = (centres[:, :2] / BOARD.square_mm * texels).astype(int) + texels  # + the white margin
    assert len(centres) == 21 and np.all(pattern[ij[:, 1], ij[:, 0]] == 255)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("lit")
    port = FlatPort(np.array([0.0, 0.0, 1.0]), 100.0, (5.0,), (1.0, 1.54, 1.33))
    return str(write_scene(root / "rig.xml", paper_cameras(SIZE, FOCAL), port,
                           np.array([[0.0, 0.0, 1000.0]]), 10.0))


@pytest.mark.slow
def test_lit_board_in_air_has_the_closed_form_radiance_and_the_same_truth(scene, tmp_path):
    """In air, the mean of each white square's middle equals ``ρ/π · I · falloff · cos θ / r²``
    at its centre within 1.5 % (the closed form is of the centre; the patch averages a square
    whose light varies by a few percent across it, nearly linearly), the squares differ
    across a board (a lamp, not a glow), and the folder's truth is the luminous board's byte
    for byte."""
    spec = load_scene(scene)
    light = BoardLight("spot", cutoff_deg=35.0)
    lit = write_boards(spec, tmp_path / "lit", BOARD, n_poses=3, spp=64, seed=5, air=True,
                       distance_range=DISTANCE, progress=False, light=light)
    write_boards(spec, tmp_path / "glow", BOARD, n_poses=3, spp=4, seed=5, air=True,
                 distance_range=DISTANCE, progress=False)
    for name in ("corners.csv", "poses.csv", "calib.yaml"):
        assert (tmp_path / "lit" / name).read_bytes() == (tmp_path / "glow" / name).read_bytes()
    placed = light.placed(True, 550.0)
    assert lit["light"]["position_mm"] == [-200.0, -150.0, -600.0]
    assert lit["light"]["aim_mm"] == [0.0, 0.0, 550.0]
    data = read_boards(tmp_path / "lit")
    rig = data.calib["rig"]
    ratios = []
    for pair, pose in zip(data.images, data.poses):
        for view, camera in enumerate(rig.cameras):
            levels = white_square_levels(pair[view], camera, rig.port, BOARD, pose)
            expected = board_radiance(placed, rig.left, pose.apply(white_square_centres(BOARD)),
                                      pose.R @ [0.0, 0.0, -1.0], placed.white)
            lit_squares = expected > 0.05 * expected.max()  # off the cut-off's edge
            np.testing.assert_allclose(levels[lit_squares], expected[lit_squares], rtol=0.015)
            ratios.append(levels.max() / levels.min())
    assert max(ratios) > 1.2


@pytest.mark.slow
def test_lit_board_behind_the_port_is_detected_at_the_forward_model(scene, tmp_path):
    """Behind the port the lamp is in the water; the board is found in every view and its
    corners lie where the forward model puts them (RMS < 0.05 px, as the luminous board's)."""
    spec = load_scene(scene)
    write_boards(spec, tmp_path / "wet", BOARD, n_poses=2, spp=16, seed=2, air=False,
                 distance_range=DISTANCE, progress=False, light=BoardLight("spot"))
    data = read_boards(tmp_path / "wet")
    errors = []
    for k, pair in enumerate(data.images):
        rows = data.corners[data.corners[:, 0] == k]
        for view, image in enumerate(pair):
            ids, uv = BOARD.detect(image)
            assert ids.size == BOARD.n_corners
            errors.append(uv - rows[ids][:, 5 + 2 * view:7 + 2 * view])
    errors = np.concatenate(errors)
    assert np.sqrt(np.mean(np.sum(errors ** 2, axis=1))) < 0.05
    manifest = json.loads((tmp_path / "wet" / "manifest.json").read_text())
    assert manifest["light"]["position_mm"] == [-300.0, -200.0, 150.0]


def test_white_square_levels_sample_the_middle_of_each_square():
    """On an image that is 1 on the middle 0.6 × 0.6 of each white square (drawn from the
    pinhole projection of its corners) and 0 elsewhere, every level is 1; on its complement 0."""
    import cv2

    from measure.geometry.port import index_matched_port

    camera = paper_cameras(SIZE, FOCAL)[0]
    port = index_matched_port(camera.R[:, 2], camera.t[None])
    pose = BoardPose(Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix(),
                     np.array([-200.0, -150.0, 600.0]))
    half = 0.3 * BOARD.square_mm
    square = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]])
    image = np.zeros(SIZE[::-1], np.float32)
    for centre in white_square_centres(BOARD):
        uv = camera.project(pose.apply(centre + square))
        cv2.fillConvexPoly(image, np.rint(uv * 16).astype(np.int32), 1.0, cv2.LINE_8, 4)
    np.testing.assert_allclose(white_square_levels(image, camera, port, BOARD, pose), 1.0)
    np.testing.assert_allclose(white_square_levels(1 - image, camera, port, BOARD, pose), 0.0)


def test_light_options_are_refused_where_they_cannot_apply(scene, tmp_path, capsys):
    def fails(extra, text):
        argv = ["boards", scene, "--out", str(tmp_path / "b"), "--squares", "7x6",
                "--square-mm", "60", "--poses", "1", "--distance", "450", "650", "--quiet"]
        assert synth_main(argv + extra) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and text in err and err.count("\n") == 1, err
        assert not (tmp_path / "b").exists()

    fails(["--light-angle", "20"], "--light-angle does not apply without --light")
    fails(["--light", "point", "--light-angle", "20"], "does not apply to a point light")
    fails(["--light", "spot", "--light-position", "0,0,50"], "is not in the water")
    fails(["--light", "spot", "--print-reflectance", "0.9,0.2"], "black < white")
    fails(["--light", "spot", "--light-position", "1,2"], "X,Y,Z")
