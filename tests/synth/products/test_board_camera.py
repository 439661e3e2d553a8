"""Cameras as they are on rendered boards (``synth boards --vignetting --lens-falloff
--aperture-radius --readout-ms --exposure-ms --board-velocity``): a rolling shutter's shear
against motion × readout time, its truth round trip, vignetting as the closed-form factor, a
thin lens's blur, motion blur as the still board smeared along its motion, and the options
refused where they cannot apply."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure import FlatPort
from measure.calibration.board import Board
from measure.geometry.port import index_matched_port
from measure.geometry.projection import project
from synth.__main__ import main as synth_main
from synth.products.board_camera import (BAND_MOTION_PX, CameraEffects, rolling_pixels,
                                         row_bands)
from synth.products.boards import (BoardPose, build_board_scene, read_boards, render_pose,
                                   write_boards)
from synth.rendering.camera_effects import vignetting_map
from synth.scene import load_scene, write_scene
from synth.scene.rig import paper_cameras

SIZE, FOCAL = (480, 402), 225.0
BOARD = Board("chessboard", (7, 6), 60.0)
DISTANCE = (450.0, 650.0)
PORT = FlatPort(np.array([0.0, 0.0, 1.0]), 100.0, (5.0,), (1.0, 1.54, 1.33))
ROLLING = CameraEffects(readout_s=0.03, velocity_mm_s=(1500.0, 300.0, -200.0))
POSE = BoardPose(Rotation.from_rotvec([0.2, -0.3, 0.1]).as_matrix(),
                 np.array([-150.0, -120.0, 550.0]))


@pytest.mark.parametrize("port", [None, PORT], ids=["air", "port"])
def test_rolling_truth_is_the_pixel_of_its_own_rows_instant(port):
    """Each truth pixel, projected again with the board moved to the instant of its own row,
    returns to itself within 0.01 px (the issue's round trip); it is not the still pixel."""
    camera = paper_cameras(SIZE, FOCAL)[0]
    port = port or index_matched_port(camera.R[:, 2], camera.t[None])
    corners = BOARD.corners()
    uv, t = rolling_pixels(camera, port, corners, POSE, ROLLING)
    row_instant = 0.03 * (uv[:, 1] / (SIZE[1] - 1) - 0.5)
    np.testing.assert_allclose(t, row_instant, atol=1e-15)
    again = project(camera, port, POSE.apply(corners) + np.outer(row_instant,
                                                                 ROLLING.velocity_mm_s))
    assert np.max(np.abs(again - uv)) < 0.01
    assert np.max(np.abs(project(camera, port, POSE.apply(corners)) - uv)) > 1.0


def test_bands_keep_the_board_within_their_motion_bound():
    camera = paper_cameras(SIZE, FOCAL)[0]
    port = index_matched_port(camera.R[:, 2], camera.t[None])
    points = np.concatenate([BOARD.outline(), BOARD.corners()])
    slow = CameraEffects(readout_s=0.03, velocity_mm_s=(300.0, 60.0, -40.0))  # ~7 px in all
    bands = row_bands(camera, port, points, POSE, slow)
    assert bands[0][0] == 0 and bands[-1][1] == SIZE[1] and 50 < len(bands) < SIZE[1]
    assert all(a[1] == b[0] for a, b in zip(bands[:-1], bands[1:]))
    rows = max(end - first for first, end in bands)
    step = slow.readout_s * (rows - 1) / (SIZE[1] - 1)  # the first row's instant to the last's
    still = POSE.apply(points)
    moved = [project(camera, port, still + slow.board_shift(s)) for s in (0.0, step)]
    assert np.max(np.linalg.norm(moved[1] - moved[0], axis=1)) <= BAND_MOTION_PX
    fast = row_bands(camera, port, points, POSE, ROLLING)  # 0.09 px a row: a band per row
    assert fast == [(r, r + 1) for r in range(SIZE[1])]
    assert row_bands(camera, port, points, POSE, CameraEffects()) == [(0, SIZE[1])]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("camera")
    return str(write_scene(root / "rig.xml", paper_cameras(SIZE, FOCAL), PORT,
                           np.array([[0.0, 0.0, 1000.0]]), 10.0))


@pytest.mark.slow
def test_rolling_shutter_shears_the_board_by_motion_times_readout(scene, tmp_path):
    """A board moving sideways at 1.5 m/s, 30 ms readout: the detected corners' horizontal
    offset from the still board grows along the rows at the rate motion × readout time
    predicts (image velocity from the forward model at t = ±1 ms times each row's instant),
    within 5 % where the shear across the board exceeds 5 px, within 0.3 px across it always;
    the corners lie on the rolling truth as near as the still board's lie on the still truth
    (same pose, seed and samples; 0.01-0.05 px on these 20-px squares), not on the still
    truth."""
    effects = CameraEffects(readout_s=0.03, velocity_mm_s=(1500.0, 0.0, 0.0))
    write_boards(load_scene(scene), tmp_path / "roll", BOARD, n_poses=2, spp=16, seed=4,
                 air=True, distance_range=DISTANCE, progress=False, effects=effects)
    data = read_boards(tmp_path / "roll")
    rig = data.calib["rig"]
    assert data.manifest["render"]["views"][0]["left"]["mode"] == "rolling shutter"
    sheared = 0
    spec = load_scene(scene)
    mscene, mi, _ = build_board_scene(spec, BOARD, True)
    still_images = [render_pose(mscene, mi, spec, BOARD, pose, k, 16, 4)[0]
                    for k, pose in enumerate(data.poses)]
    for k, (pair, pose) in enumerate(zip(data.images, data.poses)):
        truth = data.corners[data.corners[:, 0] == k]
        for view, (image, camera) in enumerate(zip(pair, rig.cameras)):
            ids, uv = BOARD.detect(image)
            assert ids.size >= BOARD.n_corners - 2
            still = project(camera, rig.port, pose.apply(BOARD.corners()))[ids]
            ends = [project(camera, rig.port, pose.apply(BOARD.corners()[ids])
                            + effects.board_shift(s)) for s in (-1e-3, 1e-3)]
            predicted = (ends[1] - ends[0])[:, 0] / 2e-3 * effects.row_time(still[:, 1],
                                                                             SIZE[1])
            design = np.column_stack([np.ones(ids.size), still[:, 1]])
            measured = np.linalg.lstsq(design, uv[:, 0] - still[:, 0], rcond=None)[0][1]
            expected = np.linalg.lstsq(design, predicted, rcond=None)[0][1]
            span = np.ptp(still[:, 1])  # rows the corners cover
            assert abs(measured - expected) * span < 0.3  # px across the board
            if expected * span > 5.0:  # a shear that stands out of the corners' noise
                assert measured == pytest.approx(expected, rel=0.05)
                sheared += 1
            rolling = truth[ids][:, 5 + 2 * view:7 + 2 * view]
            rms = np.sqrt(np.mean(np.sum((uv - rolling) ** 2, axis=1)))
            assert np.sqrt(np.mean(np.sum((uv - still) ** 2, axis=1))) > 0.5
            # as near as the still board's corners come to its still truth, at that pose
            ids, uv = BOARD.detect(still_images[k][view])
            still = project(camera, rig.port, pose.apply(BOARD.corners()))[ids]
            still_rms = np.sqrt(np.mean(np.sum((uv - still) ** 2, axis=1)))
            assert rms < still_rms + 0.01 and rms < 0.06
    assert sheared >= 2


@pytest.mark.slow
def test_vignetting_multiplies_the_render_by_its_closed_form(scene, tmp_path):
    """The same request with and without vignetting renders the same samples: the ratio of the
    two images is the cos⁴ × falloff map wherever the board is (16-bit quantization aside)."""
    spec = load_scene(scene)
    effects = CameraEffects(cos4=True, lens_falloff=0.3)
    for name, given in (("plain", None), ("vignetted", effects)):
        write_boards(spec, tmp_path / name, BOARD, n_poses=1, spp=4, seed=6, air=True,
                     distance_range=DISTANCE, progress=False, effects=given)
    plain, vignetted = (read_boards(tmp_path / name) for name in ("plain", "vignetted"))
    assert (tmp_path / "plain" / "corners.csv").read_bytes() == \
        (tmp_path / "vignetted" / "corners.csv").read_bytes()
    for view, camera in enumerate(plain.calib["rig"].cameras):
        a, b = plain.images[0][view], vignetted.images[0][view]
        bright = a > 0.2 * a.max()
        factor = vignetting_map(camera, True, 0.3)
        np.testing.assert_allclose(b[bright] / a[bright], factor[bright], rtol=2e-3)
        assert factor[bright].min() < 0.8


@pytest.mark.slow
def test_thin_lens_blurs_the_board_but_keeps_its_corners(scene, tmp_path):
    """An 8 mm aperture radius focused 300 mm beyond the boards blurs their edges (the steepest
    gradient falls by more than a third) and the corners stay within 0.1 px RMS of the
    pinhole's forward model (the blur is symmetric about the chief ray)."""
    spec = load_scene(scene)
    sharp_dir, blur_dir = tmp_path / "sharp", tmp_path / "blur"
    write_boards(spec, sharp_dir, BOARD, n_poses=1, spp=16, seed=8, distance_range=DISTANCE,
                 progress=False)
    manifest = write_boards(spec, blur_dir, BOARD, n_poses=1, spp=64, seed=8,
                            distance_range=DISTANCE, progress=False,
                            effects=CameraEffects(aperture_radius_mm=8.0,
                                                  focus_distance_mm=900.0))
    assert manifest["camera_effects"]["focus_distance_mm"] == 900.0
    sharp, blur = read_boards(sharp_dir), read_boards(blur_dir)
    for view in range(2):
        a, b = sharp.images[0][view], blur.images[0][view]
        steepest = [np.percentile(np.abs(np.diff(img, axis=1)) / img.max(), 99.9) for img in (a, b)]
        assert steepest[1] < 0.67 * steepest[0]
        ids, uv = BOARD.detect(b)
        truth = blur.corners[ids][:, 5 + 2 * view:7 + 2 * view]
        assert np.sqrt(np.mean(np.sum((uv - truth) ** 2, axis=1))) < 0.1


def test_camera_options_are_refused_where_they_cannot_apply(scene, tmp_path, capsys):
    distorted = write_scene(tmp_path / "dist.xml",
                            paper_cameras(SIZE, FOCAL, dist=(-0.1, 0.0, 0.0, 0.0, 0.0)), PORT,
                            np.array([[0.0, 0.0, 1000.0]]), 10.0)

    def fails(extra, text, where=scene):
        argv = ["boards", str(where), "--out", str(tmp_path / "b"), "--squares", "7x6",
                "--square-mm", "60", "--poses", "1", "--distance", "450", "650", "--quiet"]
        assert synth_main(argv + extra) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and text in err and err.count("\n") == 1, err
        assert not (tmp_path / "b").exists()

    fails(["--focus-distance", "800"], "--focus-distance does not apply without --aperture")
    fails(["--readout-ms", "30"], "go together")
    fails(["--exposure-ms", "10"], "go together")
    fails(["--exposure-ms", "10", "--readout-ms", "30", "--board-velocity", "1,0,0"],
          "not rendered together")
    fails(["--exposure-ms", "10", "--board-velocity", "1000,0,0"], "motion blur", distorted)
    fails(["--board-velocity", "1,0,0"], "go together")
    fails(["--lens-falloff", "1"], "lens falloff")
    fails(["--readout-ms", "30", "--board-velocity", "1000,0,0"], "rolling shutter",
          distorted)
    fails(["--aperture-radius", "2"], "thin lens", distorted)


def _box(width: float, shift: float) -> np.ndarray:
    """A motion's box kernel on whole pixels: each offset j weighted by the overlap of its
    pixel [j - 1/2, j + 1/2] with [shift - width/2, shift + width/2]."""
    reach = int(np.ceil(abs(shift) + width / 2)) + 1
    j = np.arange(-reach, reach + 1, dtype=float)
    weights = np.clip(np.minimum(j + 0.5, shift + width / 2)
                      - np.maximum(j - 0.5, shift - width / 2), 0.0, None)
    return weights / weights.sum()


@pytest.mark.slow
def test_motion_blur_is_the_still_board_smeared_along_its_motion(scene, tmp_path):
    """A board moving sideways at 1.5 m/s during a 10 ms exposure (about 6 px on these 20-px
    squares): over the board's middle, the render is the still board's (same pose at
    mid-exposure, same samples) convolved along u with a box as wide as the forward model's
    motion of the board's centre — what is left is under a quarter of the blur's own change —
    and that box is centred on the still board (mid-exposure: half a pixel either way fits
    worse); rows along the motion keep their sharp edges (the steepest gradient along v stays
    above 0.7 of the still board's)."""
    effects = CameraEffects(exposure_s=0.01, velocity_mm_s=(1500.0, 0.0, 0.0))
    spec = load_scene(scene)
    manifest = write_boards(spec, tmp_path / "blur", BOARD, n_poses=1, spp=64, seed=4, air=True,
                            distance_range=DISTANCE, progress=False, effects=effects)
    assert manifest["render"]["views"][0]["left"]["mode"] == "motion blur"
    assert manifest["camera_effects"]["exposure_s"] == 0.01
    data = read_boards(tmp_path / "blur")
    rig, pose = data.calib["rig"], data.poses[0]
    mscene, mi, _ = build_board_scene(spec, BOARD, True)
    still = render_pose(mscene, mi, spec, BOARD, pose, 0, 64, 4)[0]
    centre = pose.apply(BOARD.corners()).mean(axis=0, keepdims=True)
    for view, camera in enumerate(rig.cameras):
        blurred, sharp = data.images[0][view], still[view]
        ends = [project(camera, rig.port, centre + effects.board_shift(t))
                for t in (-0.005, 0.005)]
        width = float(abs(ends[1] - ends[0])[0, 0])
        assert 4.0 < width < 9.0
        uv = project(camera, rig.port, pose.apply(BOARD.corners()))
        rows = slice(int(np.percentile(uv[:, 1], 30)), int(np.percentile(uv[:, 1], 70)))
        cols = slice(int(uv[:, 0].min()), int(uv[:, 0].max()))
        scale = float(sharp.max())

        def misfit(shift):
            smeared = np.array([np.convolve(row, _box(width, shift), mode="same")
                                for row in sharp[rows]])
            return np.sqrt(np.mean(((blurred[rows] - smeared)[:, cols] / scale) ** 2))

        change = np.sqrt(np.mean(((blurred - sharp)[rows, cols] / scale) ** 2))
        assert misfit(0.0) < 0.25 * change
        assert misfit(0.0) < min(misfit(-0.5), misfit(0.5))
        along = [np.percentile(np.abs(np.diff(img, axis=0)) / img.max(), 99.9)
                 for img in (sharp, blurred)]
        assert along[1] > 0.7 * along[0]
