"""Rendered calibration boards and ``python -m eval calibrate`` on them (small images)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.__main__ import main as eval_main
from measure import FlatPort
from measure.calibration.board import Board
from measure.geometry.projection import project
from synth.__main__ import main as synth_main
from synth.products.boards import read_boards, write_boards
from synth.products.dataset import read_calib
from synth.scene.rig import paper_cameras
from synth.scene import load_scene, write_scene

#: Every test here renders with Mitsuba.
pytestmark = pytest.mark.slow

SIZE, FOCAL = (480, 402), 225.0
BOARD = Board("chessboard", (7, 6), 60.0)
DISTANCE = (450.0, 650.0)


@pytest.fixture(scope="module")
def boards(tmp_path_factory):
    """A 480x402 rig behind a port tilted by 1°, and its boards in air (4 poses) and
    underwater (5 poses)."""
    root = tmp_path_factory.mktemp("boards")
    normal = Rotation.from_rotvec([0, np.radians(1.0), 0]).apply([0, 0, 1.0])
    port = FlatPort(normal, 100.0, (5.0,), (1.0, 1.54, 1.33))
    scene = str(write_scene(root / "tilt.xml", paper_cameras(SIZE, FOCAL), port,
                            np.array([[0.0, 0.0, 1000.0]]), 10.0))
    spec = load_scene(scene)
    out = {"scene": scene, "root": root}
    for name, air, n in (("air", True, 4), ("water", False, 5)):
        write_boards(spec, root / name, BOARD, n_poses=n, seed=3, air=air,
                     distance_range=DISTANCE, progress=False)
        out[name] = str(root / name)
    return out


def test_folder_holds_images_truth_and_manifest(boards):
    data = read_boards(boards["water"])
    files = set(os.listdir(boards["water"]))
    assert {"calib.yaml", "board.json", "poses.csv", "corners.csv", "manifest.json",
            "left_00.png", "right_04.png"} <= files
    assert data.board == BOARD and not data.air and len(data.images) == 5
    rig = read_calib(os.path.join(boards["water"], "calib.yaml"))["rig"]
    assert abs(np.degrees(np.arccos(rig.port.normal[2])) - 1.0) < 1e-9
    corners = BOARD.corners()
    for k, pose in enumerate(data.poses):  # corners.csv is the forward model of poses.csv
        rows = data.corners[data.corners[:, 0] == k]
        world = pose.apply(corners)
        np.testing.assert_allclose(rows[:, 2:5], world, atol=1e-9)
        np.testing.assert_allclose(rows[:, 5:7], project(rig.left, rig.port, world), atol=1e-9)
        for camera in rig.cameras:  # the whole board inside both images
            assert camera.in_image(project(camera, rig.port, world), 10).all()
    assert read_boards(boards["air"]).air
    render = data.manifest["render"]  # how it was rendered: adaptively, per pose and view
    assert render["settings"]["mode"] == "adaptive" and len(render["views"]) == 5
    for pair in render["views"]:
        for stats in pair.values():
            assert stats["mode"] in ("adaptive", "full film") and stats["samples_on_mask"] > 0


def test_detected_corners_match_the_forward_model(boards):
    """Corner detection on the rendered images against the forward model's pixels of the true
    corners: every corner found, RMS below 0.05 px even on these small (~20 px) squares."""
    for folder in (boards["air"], boards["water"]):
        data = read_boards(folder)
        errors = []
        for k, pair in enumerate(data.images):
            rows = data.corners[data.corners[:, 0] == k]
            for view, image in enumerate(pair):
                ids, uv = BOARD.detect(image)
                assert ids.size >= BOARD.n_corners - 1
                errors.append(uv - rows[ids][:, 5 + 2 * view:7 + 2 * view])
        errors = np.concatenate(errors)
        assert np.sqrt(np.mean(np.sum(errors ** 2, axis=1))) < 0.05


def test_rerun_is_a_no_op_and_foreign_folders_are_refused(boards, tmp_path):
    spec = load_scene(boards["scene"])
    again = write_boards(spec, boards["air"], BOARD, n_poses=4, seed=3, air=True,
                         distance_range=DISTANCE, progress=False)
    assert again["skipped"]
    (tmp_path / "mine.txt").write_text("keep")
    with pytest.raises(ValueError, match="did not write"):
        write_boards(spec, tmp_path, BOARD, n_poses=1, air=True, progress=False)
    assert (tmp_path / "mine.txt").read_text() == "keep"


def test_calibrate_chain_from_images(boards, tmp_path, capsys):
    """In air, then the housing with the in-air intrinsics: files, and estimates near the truth
    (loose bounds: 5 small poses; the full-size numbers are in the README)."""
    assert eval_main(["calibrate", boards["air"], "--out", str(tmp_path / "air"),
                      "--no-progress"]) == 0
    report = json.loads((tmp_path / "air" / "report.json").read_text())
    assert report["detection"]["both"]["rms_px"] < 0.05
    assert abs(report["in_air"]["baseline_mm"]["error"]) < 1.0
    # the in-air calib.yaml carries the full covariance of the intrinsics and the stereo pose
    from measure.calibration.covariance import AIR_NAMES
    air_cov = read_calib(tmp_path / "air" / "calib.yaml")["covariance"]
    assert air_cov.names == AIR_NAMES
    assert report["in_air"]["baseline_sigma_mm"] > 0
    assert eval_main(["calibrate", boards["water"], "--intrinsics", boards["air"],
                      "--start-distance", "90", "--out", str(tmp_path / "water"),
                      "--no-progress"]) == 0
    out = tmp_path / "water"
    assert {"calib.yaml", "calib_in_air_only.yaml", "flatport.txt", "report.json", "report.md",
            "detections.png", "residuals.png", "poses.png"} <= set(os.listdir(out))
    report = json.loads((out / "report.json").read_text())
    housing = report["housing"]
    assert housing["rms_px"] < 0.1
    assert abs(housing["parameters"]["distance"]["error"]) < 2.0
    calib = read_calib(out / "calib.yaml")
    assert calib["has_port"] and abs(calib["port"].distance - 100.0) < 2.0
    # the housing's σ includes the in-air covariance, and the rig's joint covariance is written
    cov = calib["covariance"]
    assert cov.names == AIR_NAMES + ("port.distance", "port.tilt[0]", "port.tilt[1]")
    distance = housing["parameters"]["distance"]
    assert housing["uncertainty"] == "prior"
    assert distance["sigma"] > distance["sigma_conditional"] > 0
    assert cov.sigmas["port.distance"] == pytest.approx(distance["sigma"], rel=1e-9)
    design = read_calib(out / "calib_in_air_only.yaml")
    assert design["port"].distance == 90.0 and design["port"].normal[2] == 1.0
    assert "FLATPORT" in (out / "flatport.txt").read_text()
    assert "housing distance" in capsys.readouterr().out


def test_bad_inputs_are_one_line_and_exit_2(boards, tmp_path, capsys):
    def fails(argv, main, text):
        assert main(argv + (["--no-progress"] if main is eval_main else [])) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and text in err and err.count("\n") == 1, err

    fails(["boards", boards["scene"], "--out", str(tmp_path / "b"), "--squares", "7by5"],
          synth_main, "--squares")
    fails(["boards", boards["scene"], "--out", str(tmp_path / "b"), "--squares", "7x5"],
          synth_main, "looks the same turned by 180°")
    fails(["boards", boards["scene"], "--out", str(tmp_path / "b"), "--square-mm", "400",
           "--poses", "2"], synth_main, "board poses")
    fails(["calibrate", boards["water"], "--out", str(tmp_path / "c")], eval_main,
          "need --intrinsics")
    fails(["calibrate", boards["water"], "--intrinsics", boards["water"], "--out",
           str(tmp_path / "c")], eval_main, "rendered underwater")
    fails(["calibrate", boards["water"], "--intrinsics", boards["air"], "--free", "focal",
           "--out", str(tmp_path / "c")], eval_main, "unknown parameter focal")
    fails(["calibrate", str(tmp_path), "--out", str(tmp_path / "c")], eval_main,
          "not a boards folder")
    # intrinsics of another image size
    other = tmp_path / "other.yaml"
    from synth.products.dataset import write_calib
    from synth.scene.rig import paper_rig
    write_calib(other, paper_rig(size=(640, 480)))
    fails(["calibrate", boards["water"], "--intrinsics", str(other), "--out",
           str(tmp_path / "c")], eval_main, "image size")
    # a calibration whose covariance is singular: refused, naming the file
    from types import SimpleNamespace
    singular = tmp_path / "singular.yaml"
    write_calib(singular, paper_rig(size=read_calib(Path(boards["water"]) / "calib.yaml")["size"]),
                covariance=SimpleNamespace(names=["left.cx", "left.cy"],
                                           matrix=np.ones((2, 2)), normal_axes=None))
    fails(["calibrate", boards["water"], "--intrinsics", str(singular), "--out",
           str(tmp_path / "c")], eval_main, f"{singular}: covariance")
    # a board definition that does not match the images: it disagrees with the manifest (and
    # with corners.csv), refused before any detection
    wrong = tmp_path / "wrong"
    shutil.copytree(boards["air"], wrong)
    (wrong / "board.json").write_text(json.dumps(Board("chessboard", (9, 6), 60.0).to_dict()))
    fails(["calibrate", str(wrong), "--out", str(tmp_path / "c")], eval_main,
          "board.json: a chessboard 9x6, 60.0 mm board")
    assert not (tmp_path / "c").exists()


def test_define_spp_and_seed_mean_what_they_mean_everywhere(small_scene, tmp_path):
    """``-D spp=4`` renders 4 spp (it rendered the boards' default, 16, issue 22) and
    ``-D seed=2`` is ``--seed 2``: the same images."""
    common = ["boards", small_scene, "--poses", "1", "--air", "--squares", "7x6", "--square-mm",
              "40", "--distance", "450", "650", "--quiet"]
    for name, extra in (("defines", ["-D", "spp=4", "-D", "seed=2"]),
                        ("options", ["--spp", "4", "--seed", "2"])):
        assert synth_main(common + ["--out", str(tmp_path / name), *extra]) == 0
    manifests = [json.loads((tmp_path / name / "manifest.json").read_text())
                 for name in ("defines", "options")]
    assert [(m["spp"], m["seed"]) for m in manifests] == [(4, 2), (4, 2)]
    assert ((tmp_path / "defines" / "left_00.png").read_bytes()
            == (tmp_path / "options" / "left_00.png").read_bytes())


def test_a_rerun_renders_again_unless_every_image_is_whole(boards, tmp_path, capsys):
    """A boards folder is up to date only when every file it wrote is whole (issue 22: with one
    image cut the rerun said 'up to date')."""
    out = tmp_path / "air"
    argv = ["boards", boards["scene"], "--out", str(out), "--poses", "2", "--seed", "3",
            "--air", "--squares", "7x6", "--square-mm", "60", "--distance", "450", "650",
            "--spp", "4", "--quiet"]
    assert synth_main(argv) == 0
    image = out / "left_01.png"
    whole = image.read_bytes()
    image.write_bytes(whole[:100])
    capsys.readouterr()
    assert synth_main(argv) == 0
    printed = capsys.readouterr().out
    assert "nothing to do" not in printed and "rendering it again" in printed, printed
    assert image.read_bytes() == whole
    assert synth_main(argv) == 0 and "nothing to do" in capsys.readouterr().out


def test_truth_tables_with_a_byte_order_mark_are_read(tmp_path):
    """poses.csv / corners.csv re-saved with a byte-order mark read as before."""
    from synth.products.boards import POSES_HEADER, read_truth_table

    text = ",".join(POSES_HEADER) + "\n0,0.1,0.2,0.3,1,2,3\n"
    with_bom = tmp_path / "poses.csv"
    with_bom.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    np.testing.assert_array_equal(read_truth_table(str(with_bom), POSES_HEADER, 1),
                                  [[0, 0.1, 0.2, 0.3, 1, 2, 3]])
