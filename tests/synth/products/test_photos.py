"""Tests of ``python -m synth photos``: rendered pairs written as 8-bit sRGB photos, no truth."""

import json
import os
import subprocess
import sys

import cv2
import numpy as np

from synth.products.photos import to_photo
from tests.conftest import REPO


def _fake(root, command, names):
    root.mkdir()
    (root / "manifest.json").write_text(json.dumps({"command": command}))
    (root / "calib.yaml").write_text("truth\n")
    ramp = (np.arange(64, dtype=np.uint16) * 1040).reshape(8, 8)
    for name in names:
        cv2.imwrite(str(root / name), ramp)
    return ramp


def _photos(*args):
    return subprocess.run([sys.executable, "-m", "synth", "photos", *map(str, args)], cwd=REPO,
                          capture_output=True, text=True)


def test_boards_become_jpeg_pairs_and_nothing_else(tmp_path):
    _fake(tmp_path / "b", "synth boards", ["left_00.png", "right_00.png", "left_01.png",
                                           "right_01.png"])
    out = tmp_path / "p"
    run = _photos(tmp_path / "b", "--out", out)
    assert run.returncode == 0, run.stderr
    assert "2 pair(s)" in run.stdout
    visible = sorted(os.path.relpath(os.path.join(d, f), out) for d, _, fs in os.walk(out)
                     for f in fs if not f.startswith("."))
    assert visible == ["left/00.jpg", "left/01.jpg", "right/00.jpg", "right/01.jpg"]


def test_boards_of_three_cameras_become_a_folder_per_camera(tmp_path):
    """``synth boards`` of a scene of N cameras (``cam0_PP.png``, …) becomes ``cam0/PP.jpg``, …
    — what ``eval calibrate`` reads as photos of N cameras (it said "no rendered image
    left_PP.png", issue 53); a camera's missing pose is named."""
    names = [f"cam{k}_{p:02d}.png" for k in range(3) for p in range(2)]
    _fake(tmp_path / "b", "synth boards", names)
    out = tmp_path / "p"
    run = _photos(tmp_path / "b", "--out", out)
    assert run.returncode == 0, run.stderr
    visible = sorted(os.path.relpath(os.path.join(d, f), out) for d, _, fs in os.walk(out)
                     for f in fs if not f.startswith("."))
    assert visible == [f"cam{k}/{p:02d}.jpg" for k in range(3) for p in range(2)]
    (tmp_path / "b" / "cam2_01.png").unlink()
    run = _photos(tmp_path / "b", "--out", tmp_path / "q")
    assert run.returncode == 2 and "cam2_01.png" in run.stderr, run.stderr
    assert not (tmp_path / "q").exists()


def test_dataset_png_is_the_srgb_of_the_linear_image(tmp_path):
    ramp = _fake(tmp_path / "d", "synth dataset", ["left.png", "right.png"])
    run = _photos(tmp_path / "d", "--out", tmp_path / "p", "--format", "png")
    assert run.returncode == 0, run.stderr
    stored = cv2.imread(str(tmp_path / "p" / "left" / "pair.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(stored, to_photo(ramp))
    assert stored.dtype == np.uint8 and stored[7, 7] == 255


def test_bad_inputs_exit_2_and_write_nothing(tmp_path):
    run = _photos(tmp_path / "none", "--out", tmp_path / "p")
    assert run.returncode == 2 and run.stderr.startswith("error:") and "no such folder" in run.stderr
    (tmp_path / "e").mkdir()
    run = _photos(tmp_path / "e", "--out", tmp_path / "p")
    assert run.returncode == 2 and "manifest.json" in run.stderr
    _fake(tmp_path / "d", "synth dataset", ["left.png", "right.png"])
    run = _photos(tmp_path / "d", "--out", tmp_path / "p", "--format", "png", "--quality", "80")
    assert run.returncode == 2 and "--quality does not apply" in run.stderr
    assert not (tmp_path / "p").exists()
