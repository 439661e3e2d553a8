"""``eval calibrate --detections``: a user's own detections files instead of photos, circle
grids and their dots' eccentricity, and the options that do not apply."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.__main__ import main as eval_main
from measure import Camera
from measure.calibration.board import Board
from measure.images.eccentricity import outline_centroid_offsets

K = np.array([[800.0, 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
BOARD = Board("circles", (8, 6), 30.0, circle_mm=24.0)
GRID = ["--board", "circles", "--circles", "8x6", "--pitch-mm", "30"]


def _run(argv) -> int:
    return eval_main(argv + ["--no-progress"])


def _write_one_camera(folder, n_poses=8, seed=5):
    """One camera's detections of a grid of large dots: each dot's image centroid (its
    outline projected, the area centroid), written as 'id u v' in a shuffled order."""
    rng = np.random.default_rng(seed)
    camera = Camera(K, (640, 480))
    corners, centre = BOARD.corners(), BOARD.corners().mean(axis=0)
    folder.mkdir(parents=True)
    k = 0
    while k < n_poses:
        R = Rotation.from_rotvec(rng.uniform(-0.6, 0.6, 3)).as_matrix()
        t = np.array([0, 0, 450.0]) + rng.uniform(-40, 40, 3) - R @ centre
        world = corners @ R.T + t
        uv = cv2.projectPoints(world, np.zeros(3), np.zeros(3), K, None)[0].reshape(-1, 2)
        if np.any(uv < 20) or np.any(uv > [620, 460]):  # the whole grid inside the image
            continue
        uv += outline_centroid_offsets(camera, None, world, np.repeat(R[:, 2][None], len(uv), 0),
                                       BOARD.circle_mm / 2, shading=False)
        order = rng.permutation(len(uv))
        lines = ["# id u v"] + [f"{i} {uv[i, 0]:.6f} {uv[i, 1]:.6f}" for i in order]
        (folder / f"view{k:02d}.txt").write_text("\n".join(lines) + "\n")
        k += 1


def test_one_camera_from_its_detections_with_the_dots_eccentricity(tmp_path):
    """fx of the camera that made the detections: 0.73 px short fitted as the dots' centres,
    within 0.01 px with their diameter given (the eccentricity taken out)."""
    _write_one_camera(tmp_path / "dets")
    common = ["calibrate", str(tmp_path / "dets"), "--detections", "--image-size", "640x480",
              "--air", "--lens", "standard", *GRID]
    assert _run(common + ["--out", str(tmp_path / "plain")]) == 0
    assert _run(common + ["--circle-mm", "24", "--out", str(tmp_path / "dots")]) == 0
    plain = json.loads((tmp_path / "plain" / "report.json").read_text())["camera"]["fx"]
    dots = json.loads((tmp_path / "dots" / "report.json").read_text())["camera"]["fx"]
    assert abs(plain["estimate"] - 800) > 0.5 and abs(dots["estimate"] - 800) < 0.01


@pytest.mark.parametrize("extra, message", [
    (["--image-size", "640x480"], "--image-size does not apply without --detections"),
    (["--detections"], "give --image-size"),
    (["--detections", "--image-size", "640by480"], "--image-size must be WxH"),
    (["--detections", "--image-size", "640x480", "--encoding", "srgb"],
     "--encoding does not apply to --detections"),
    (["--detections", "--image-size", "640x480", "--stereo-intrinsics", "refined"],
     "--stereo-intrinsics does not apply without --model absorbed"),
    (["--detections", "--image-size", "100x100"], "lies outside the 100x100 image"),
])
def test_options_that_do_not_apply_are_one_line(tmp_path, capsys, extra, message):
    _write_one_camera(tmp_path / "dets", n_poses=4)
    assert _run(["calibrate", str(tmp_path / "dets"), "--air", *GRID, *extra,
                 "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


def test_circle_options_with_a_chessboard_are_refused(tmp_path, capsys):
    _write_one_camera(tmp_path / "dets", n_poses=4)
    assert _run(["calibrate", str(tmp_path / "dets"), "--air", "--detections", "--image-size",
                 "640x480", "--squares", "10x7", "--square-mm", "30", "--pitch-mm", "30",
                 "--out", str(tmp_path / "out")]) == 2
    assert "--pitch-mm does not apply to a chessboard" in capsys.readouterr().err


def test_frames_of_a_video_are_thinned_by_pose():
    """Ten board poses, each seen in four nearly equal frames (a video): thinned to ten, one
    of each pose is kept; fewer poses than the limit are all kept."""
    from eval.calibrate.sources import thin_by_pose
    from measure.calibration.air import Detections

    rng = np.random.default_rng(2)
    corners = BOARD.corners()
    ids, pixels, pose_of = [], [], []
    for pose in range(10):
        R = Rotation.from_rotvec(rng.uniform(-0.5, 0.5, 3)).as_matrix()
        t = np.array([0, 0, 500.0]) + rng.uniform(-60, 60, 3) - R @ corners.mean(axis=0)
        uv = cv2.projectPoints(corners @ R.T + t, np.zeros(3), np.zeros(3), K,
                               None)[0].reshape(-1, 2)
        for _ in range(4):  # the frames of one moment: a tenth of a pixel apart
            ids.append([np.arange(len(uv)), np.empty(0, int)])
            pixels.append([uv + rng.normal(0, 0.1, uv.shape), np.empty((0, 2))])
            pose_of.append(pose)
    detections = Detections(ids, pixels)
    thinned, kept = thin_by_pose(detections, BOARD, (640, 480), 10)
    assert sorted(pose_of[k] for k in kept) == list(range(10))
    assert len(thinned.found(0)) == 10
    same, all_kept = thin_by_pose(detections, BOARD, (640, 480), 40)
    assert all_kept == list(range(40))
