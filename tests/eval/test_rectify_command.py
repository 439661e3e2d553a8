"""``eval rectify``: the files it writes, and its refusals."""

from __future__ import annotations

import json

import cv2
import numpy as np

from eval.cli import main
from synth.products.dataset import write_calib
from synth.scene.rig import paper_rig

SIZE = (160, 134)


def _inputs(tmp_path, in_air=False):
    calib = tmp_path / "calib.yaml"
    write_calib(calib, paper_rig(in_air=in_air, size=SIZE, focal_px=75.0), has_port=not in_air)
    image = np.tile(np.arange(SIZE[0], dtype=np.uint8), (SIZE[1], 1))
    paths = []
    for name in ("left", "right"):
        paths.append(str(tmp_path / f"{name}.png"))
        cv2.imwrite(paths[-1], image)
    return str(calib), paths


def test_writes_the_rectified_pair_maps_calibration_and_error_map(tmp_path, capsys):
    calib, (left, right) = _inputs(tmp_path)
    out = tmp_path / "out"
    assert main(["rectify", "--calib", calib, "--distance", "1000", left, right, "--out", str(out),
                 "--error-distances", "700,1500", "--no-progress"]) == 0
    for name in ("left_rectified.png", "right_rectified.png", "maps.npz", "calib_rectified.yaml",
                 "errors.json", "error_map.png"):
        assert (out / name).is_file(), name
    report = json.loads((out / "errors.json").read_text())
    assert set(report["errors"]) == {"700", "1500"}
    assert report["errors"]["700"]["left_px"]["median"] > 0
    maps = np.load(out / "maps.npz")
    assert maps["left_map_x"].shape == (SIZE[1], SIZE[0]) and maps["left_map_x"].dtype == np.float32
    assert cv2.imread(str(out / "left_rectified.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint8


def test_refusals_are_one_line_and_write_nothing(tmp_path, capsys):
    calib, (left, right) = _inputs(tmp_path)
    air_dir = tmp_path / "air"
    air_dir.mkdir()
    air_calib, _ = _inputs(air_dir, in_air=True)
    for extra, fragment in ((["--calib", calib, "--distance", "50"], "beyond the glass"),
                            (["--calib", air_calib, "--distance", "1000"], "without a port"),
                            (["--calib", calib, "--distance", "1000", "--error-distances", "x"],
                             "--error-distances")):
        out = tmp_path / "out"
        assert main(["rectify", left, right, "--out", str(out), "--no-progress", *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
        assert not out.exists()
