"""Circle grids (measure.calibration.circles, Board kinds ``circles`` / ``acircles``) and a
symmetric board's turn settled by a pair (measure.calibration.symmetry)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from measure import Camera
from measure.calibration.air import Detections, calibrate_in_air
from measure.calibration.board import Board, BoardError


def _dot_grid(cols, rows, pitch_px=40, radius_px=12, supersample=8):
    """A symmetric dot grid seen through a strong perspective (area-sampled, 640 × 480) and
    the true centroid of each dot's image (its outline mapped and its area centroid taken: the
    image of a dot's centre lies beside it, the eccentricity)."""
    ss, p = supersample, pitch_px
    width, height = (cols + 1) * p, (rows + 1) * p
    fine = np.full((height * ss, width * ss), 255, np.float32)
    centres = np.array([((j + 1) * p - 0.5, (i + 1) * p - 0.5)
                        for i in range(rows) for j in range(cols)])
    for c in centres:
        cv2.circle(fine, tuple(int(round(((v + 0.5) * ss - 0.5) * 16)) for v in c),
                   radius_px * ss * 16, 0, -1, cv2.LINE_AA, 4)
    H = cv2.getPerspectiveTransform(np.float32([[0, 0], [width, 0], [width, height], [0, height]]),
                                    np.float32([[60, 50], [560, 80], [540, 400], [70, 430]]))
    S = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1.0]])
    image = cv2.resize(cv2.warpPerspective(fine, S @ H @ np.linalg.inv(S), (640 * ss, 480 * ss),
                                           flags=cv2.INTER_LINEAR, borderValue=255),
                       (640, 480), interpolation=cv2.INTER_AREA)
    angle = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    truth = []
    for c in centres:
        o = cv2.perspectiveTransform((c + radius_px * np.column_stack(
            [np.cos(angle), np.sin(angle)])).reshape(-1, 1, 2), H).reshape(-1, 2)
        x, y, x1, y1 = o[:, 0], o[:, 1], np.roll(o[:, 0], -1), np.roll(o[:, 1], -1)
        a = x * y1 - x1 * y
        truth.append([np.sum((x + x1) * a), np.sum((y + y1) * a)] / (3 * np.sum(a)))
    return image, np.array(truth)


def test_circle_grid_geometry_and_symmetries():
    board = Board("acircles", (4, 11), 20.0, circle_mm=15.0)
    corners = board.corners()
    assert board.n_corners == 44 and corners.shape == (44, 3)
    np.testing.assert_allclose(corners[4], [20.0, 20.0, 0.0])     # row 1 starts at s
    np.testing.assert_allclose(corners[1], [40.0, 0.0, 0.0])      # 2s apart in a row
    assert not board.symmetric                                      # OpenCV's sample: 11 rows
    assert Board("acircles", (4, 10), 20.0).symmetric
    assert len(Board("circles", (26, 26), 1.0).symmetries()) == 4   # a square grid: 4 turns
    assert len(Board("circles", (7, 5), 1.0).symmetries()) == 2
    with pytest.raises(BoardError, match="do not fit"):
        Board("circles", (7, 5), 10.0, circle_mm=12.0)
    assert Board.from_dict(board.to_dict()) == board


def test_dots_are_measured_where_a_lamp_cannot_pull_them():
    """A 7 × 5 dot grid under a light that falls off across the image: the dots' centres lie
    within 0.03 px RMS of their images' true centroids with and without the lamp; OpenCV's
    blob centres move with the light (their error grows)."""
    board = Board("circles", (7, 5), 40.0)
    image, truth = _dot_grid(7, 5)
    u = np.arange(640, dtype=np.float32)[None, :]
    errors = []
    for gradient in (0.0, 1.4 / 640):
        lit = ((0.05 * 255 + 0.95 * image) * np.clip(1 - gradient * (u - 320), 0.05, None)
               / 255).astype(np.float32)
        ids, uv = board.detect(lit)
        assert ids.size == board.n_corners
        errors.append(np.sqrt(np.mean(np.sum((uv - truth[ids]) ** 2, axis=1))))
        from measure.calibration.board import detector_view
        blobs = cv2.findCirclesGrid(detector_view(lit), (7, 5),
                                    flags=cv2.CALIB_CB_SYMMETRIC_GRID)[1].reshape(-1, 2)
        errors.append(np.sqrt(np.mean(np.sum((blobs - truth) ** 2, axis=1))))
    ours_even, blobs_even, ours_lamp, blobs_lamp = errors
    assert ours_even < 0.03 and ours_lamp < 0.03
    assert blobs_lamp > 1.5 * blobs_even and blobs_lamp > ours_lamp


def _projected_pair(board, n_poses=8, seed=3):
    """Two pinhole cameras 120 mm apart, turned 10° towards each other, and a board at random
    poses in front of both: the exact corners of each view (no noise)."""
    rng = np.random.default_rng(seed)
    K = np.array([[800.0, 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
    c, s = np.cos(np.radians(-10)), np.sin(np.radians(-10))
    left = Camera(K, (640, 480))
    right = Camera(K, (640, 480), R=[[c, 0, -s], [0, 1, 0], [s, 0, c]], t=(120, 0, 0))
    corners = board.corners()
    centre = corners.mean(axis=0)
    ids, pixels = [], []
    for _ in range(n_poses):
        from scipy.spatial.transform import Rotation

        R = Rotation.from_rotvec(rng.uniform(-0.4, 0.4, 3)).as_matrix()
        t = np.array([60, 0, 900.0]) + rng.uniform(-60, 60, 3) - R @ centre
        world = corners @ R.T + t
        views = []
        for camera in (left, right):
            local = (world - camera.t) @ camera.R
            views.append(cv2.projectPoints(local, np.zeros(3), np.zeros(3), K, None)[0]
                         .reshape(-1, 2))
        ids.append([np.arange(len(corners))] * 2)
        pixels.append(views)
    return Detections(ids, pixels), right


def test_a_pair_settles_a_symmetric_board_turned_in_one_view():
    """ROS's 9 × 7 board: the right view of three poses numbered from the other end (the
    board turned by 180°, what a detector does when the two cameras see it differently): the
    in-air calibration settles each pose's turn by the rig and finds the same stereo pose as
    with every pose numbered alike, to 1e-6 mm."""
    board = Board("chessboard", (9, 7), 30.0)
    detections, right = _projected_pair(board)
    (flip, _, _) = board.symmetries()[1]
    turned = Detections([list(v) for v in detections.ids], [list(v) for v in detections.pixels])
    for k in (1, 4, 6):
        turned.pixels[k][1] = detections.pixels[k][1][np.argsort(flip)]
    straight = calibrate_in_air(board, detections, (640, 480))
    settled = calibrate_in_air(board, turned, (640, 480))
    assert not settled.stereo_left_out
    np.testing.assert_allclose(settled.rig.right.t, straight.rig.right.t, atol=1e-6)
    np.testing.assert_allclose(settled.rig.right.t, right.t, atol=1e-3)


def test_the_dots_eccentricity_is_taken_out_of_a_calibration():
    """A camera's calibration from a grid of large dots whose image centroids (exact: each
    outline projected, its area centroid) lie up to tenths of a pixel beside their centres'
    images (up to 0.47 px here): fitted as centres, the fit absorbs most of it into the camera
    (RMS 0.001 px, fx 0.73 px short); with the eccentricity taken out (the dots' diameter
    given) fx is recovered to 0.01 px and the RMS falls to 1e-4 px."""
    from scipy.spatial.transform import Rotation

    from eval.calibrate.dots import views_of_camera
    from measure.calibration.air import calibrate_camera
    from measure.calibration.circles import corrected_for_eccentricity
    from measure.images.eccentricity import outline_centroid_offsets

    board = Board("circles", (8, 6), 30.0, circle_mm=24.0)
    K = np.array([[800.0, 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
    camera = Camera(K, (640, 480))
    rng = np.random.default_rng(5)
    corners, centre = board.corners(), board.corners().mean(axis=0)
    ids, pixels = [], []
    for _ in range(8):
        R = Rotation.from_rotvec(rng.uniform(-0.6, 0.6, 3)).as_matrix()
        t = np.array([0, 0, 450.0]) + rng.uniform(-40, 40, 3) - R @ centre
        world = corners @ R.T + t
        image = cv2.projectPoints(world, np.zeros(3), np.zeros(3), K, None)[0].reshape(-1, 2)
        image += outline_centroid_offsets(camera, None, world, np.repeat(R[:, 2][None], 48, 0),
                                          12.0, shading=False)
        ids.append([np.arange(48), np.empty(0, int)])
        pixels.append([image, np.empty((0, 2))])
    detections = Detections(ids, pixels)

    def fit(d):
        poses = d.found(0)
        obj = [corners[d.ids[k][0]].astype(np.float32) for k in poses]
        img = [d.pixels[k][0].astype(np.float32) for k in poses]
        out, model, _, _ = calibrate_camera(obj, img, (640, 480), "standard")
        return {"out": out, "model": model, "poses": poses}

    plain = fit(detections)
    corrected, _ = corrected_for_eccentricity(fit, detections, board, views_of_camera((640, 480)))
    assert abs(plain["out"][1][0, 0] - 800) > 0.5
    assert corrected["out"][0] < 1e-4 and abs(corrected["out"][1][0, 0] - 800) < 0.01


def test_underwater_the_in_air_rig_settles_the_turn():
    """Underwater the stereo pose is the in-air calibration's: the left view's board pose
    predicts the right view's corners, and the turn that predicts them is each pose's (the
    prediction ignores the port, whose error is pixels, a turn's the board's size)."""
    from measure import StereoRig
    from measure.calibration.symmetry import relabelled, settle_by_rig
    from measure.geometry.port import index_matched_port

    board = Board("chessboard", (9, 7), 30.0)
    detections, right = _projected_pair(board)
    left = Camera(right.K, (640, 480))
    rig = StereoRig(left, right, index_matched_port((0, 0, 1), np.stack([left.t, right.t])))
    (flip, _, _) = board.symmetries()[1]
    turned = Detections([list(v) for v in detections.ids], [list(v) for v in detections.pixels])
    for k in (0, 5):
        turned.pixels[k][1] = detections.pixels[k][1][np.argsort(flip)]
    turns = settle_by_rig(rig, board, turned)
    assert {k for k, s in turns.items() if s} == {0, 5}
    settled = relabelled(turned, 1, turns, board)
    for k in range(detections.n_poses):
        order = np.argsort(settled.ids[k][1])
        np.testing.assert_allclose(settled.pixels[k][1][order], detections.pixels[k][1])
