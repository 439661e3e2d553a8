"""One printed board rendered alone (:mod:`synth.products.printed_board`): a bent board's corners
found by plain OpenCV where the bent truth says, not where the flat one does; a laminate's
highlight; the sag's shape."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from measure import Camera
from measure.calibration.board import Board
from synth.products.board_light import BoardLight
from synth.products.printed_board import bent_points, render_board, sag_z

BOARD = Board("chessboard", (9, 7), 30.0)
K = np.array([[600.0, 0, 320.0], [0, 600.0, 240.0], [0, 0, 1]])
DIST = np.array([-0.1, 0.05, 0.0, 0.0, 0.0])
POSE = (cv2.Rodrigues(np.array([0.3, -0.2, 0.05]))[0], np.array([-120.0, -90.0, 450.0]))


def _extent():
    o = BOARD.outline()
    return o[:, 0].min(), o[:, 0].max(), o[:, 1].min(), o[:, 1].max()


def _lamp(position):
    return {"type": "point", "position": list(position),
            "intensity": {"type": "rgb", "value": 1e6}}


def _opencv_corners(image):
    gray = np.clip(image / np.percentile(image, 99.5) * 255, 0, 255).astype(np.uint8)
    ok, c = cv2.findChessboardCorners(gray, (8, 6))
    assert ok
    return cv2.cornerSubPix(gray, c, (5, 5), (-1, -1), (3, 40, 1e-3)).reshape(-1, 2)


def _truth(points):
    return cv2.projectPoints(points, cv2.Rodrigues(POSE[0])[0], POSE[1], K, DIST)[0].reshape(-1, 2)


def test_sag_is_the_middle_nearer_by_sag_and_the_side_edges_unmoved():
    extent = (-30.0, 300.0, -30.0, 240.0)
    np.testing.assert_allclose(sag_z([-30.0, 135.0, 300.0, 52.5], extent, 2.0),
                               [0.0, -2.0, 0.0, -1.5], atol=1e-12)
    p = bent_points(np.array([[135.0, 10.0, 0.0]]), extent, 2.0)
    np.testing.assert_allclose(p, [[135.0, 10.0, -2.0]], atol=1e-12)


@pytest.mark.slow
def test_a_bent_board_is_seen_where_its_bent_truth_says():
    """Plain OpenCV's corners on the render of a board bent by 3 mm (the camera distorted)
    against OpenCV's projection of the bent corners, and of the flat ones."""
    camera = Camera(K, (640, 480), dist=DIST)
    texture = BoardLight().reflectance(BOARD.pattern(32))
    image = render_board(camera, POSE, texture, _extent(), _lamp((0.0, 0.0, -1000.0)), 8, 0,
                         sag_mm=3.0)
    found = _opencv_corners(image)

    def error(points):
        truth = _truth(points)
        return np.linalg.norm(found[:, None] - truth[None], axis=2).min(axis=1)

    bent = error(bent_points(BOARD.corners(), _extent(), 3.0))
    flat = error(BOARD.corners())
    assert np.sqrt(np.mean(bent ** 2)) < 0.15
    assert np.sqrt(np.mean(flat ** 2)) > 0.6


@pytest.mark.slow
def test_a_laminate_mirrors_the_lamp_where_a_matte_print_does_not():
    """The lamp beside the camera, the board facing it: the laminate's brightest pixel is many
    times the matte print's (a highlight), the matte print's is near its whites' level."""
    camera = Camera(K, (640, 480))
    pose = (np.eye(3), np.array([-135.0, -105.0, 500.0]))
    texture = BoardLight().reflectance(BOARD.pattern(16))
    lamp = _lamp((-20.0, 0.0, 0.0))
    matte = render_board(camera, pose, texture, _extent(), lamp, 4, 0)
    glossy = render_board(camera, pose, texture, _extent(), lamp, 4, 0, laminate_alpha=0.05)
    white = 0.8 / np.pi * 1e6 / 500.0 ** 2          # white paper facing the lamp, ρ/π · I / r²
    assert 0.95 * white < matte.max() < 1.05 * white
    assert glossy.max() > 3 * matte.max()
