"""``python -m eval calibrate`` of photos behind two housings (``--port-distance LEFT,RIGHT``):
the options that give one shared port's distance are refused with one line before any photo
is read."""

from __future__ import annotations

import pytest

from eval.__main__ import main as eval_main

PHOTOS = ["--intrinsics", "calib.yaml", "--squares", "7x6", "--square-mm", "60"]


@pytest.mark.parametrize("extra, fragment", [
    (["--port-distance", "60,80", "--start-distance", "90"],
     "--start-distance does not apply to two housings: give each port's distance with "
     "--port-distance LEFT,RIGHT"),
    (["--port-distance", "60,80", "--design-port", "thickness=6,distance=90"],
     "--design-port distance= does not apply to two housings"),
    (["--port-distance", "60,80,90"], "3 values for 2 cameras"),
])
def test_one_ports_distance_is_refused_for_two_housings(tmp_path, monkeypatch, capsys, extra,
                                                         fragment):
    for side in ("left", "right"):
        (tmp_path / "photos" / side).mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    try:
        code = eval_main(["calibrate", "photos", *PHOTOS, *extra, "--out", "out",
                          "--no-progress"])
    except SystemExit as exc:  # argparse's own refusal of a bad value
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not (tmp_path / "out").exists()


def test_photos_behind_two_housings_fitted_as_one_port_exit_1(tmp_path, capsys):
    """Drawn photos of a pair behind two housings (ports 60 and 80 mm from their cameras, the
    right one tilted 2°): calibrated as one shared port the housing cannot fit them — exit 1,
    saying so and suggesting --port-distance; with --port-distance 70,70 they calibrate."""
    import cv2
    import numpy as np

    from measure import StereoRig
    from measure.geometry.port import index_matched_port
    from synth.products.boards import sample_poses
    from synth.products.dataset import write_calib
    from synth.scene.rig import paper_cameras
    from synth.scene.windows import flat_pair
    from tests.eval.calibrate.test_single_housing import BOARD, BOARD_ARGS, FOCAL, SIZE, _draw

    left, right = paper_cameras(SIZE, FOCAL)
    rig = StereoRig(left, right, flat_pair((left, right), (60.0, 80.0), ((0, 0), (0, 2.0)),
                                           (5.0, 5.0), (1.0, 1.54, 1.33)))
    write_calib(tmp_path / "calib.yaml", StereoRig(left, right, index_matched_port(
        (0, 0, 1), np.stack([left.t, right.t]))), has_port=False)
    rng = np.random.default_rng(7)
    for side in ("left", "right"):
        (tmp_path / "photos" / side).mkdir(parents=True)
    for k, pose in enumerate(sample_poses(rig, BOARD, 8, 7, True, (500.0, 800.0))):
        for view, side in enumerate(("left", "right")):
            cv2.imwrite(str(tmp_path / "photos" / side / f"{k:02d}.png"),
                        _draw(rig.cameras[view], None, pose, rng, rig, view))
    common = ["calibrate", str(tmp_path / "photos"), "--intrinsics", str(tmp_path / "calib.yaml"),
              *BOARD_ARGS, "--no-progress"]
    assert eval_main(common + ["--out", str(tmp_path / "shared")]) == 1
    err = capsys.readouterr().err
    assert "the port model does not describe these photos" in err
    assert "two housings? give --port-distance LEFT,RIGHT" in err
    assert eval_main(common + ["--port-distance", "70,70", "--out", str(tmp_path / "two")]) == 0
