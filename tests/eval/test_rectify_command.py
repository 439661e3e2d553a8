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


def test_the_rectified_calibration_is_read_by_the_commands(tmp_path):
    """calib_rectified.yaml (no port; the real port's plane kept, behind the virtual cameras)
    is read as the pinhole pair it is (issue 53: eval measure refused it, "left camera centre
    lies on the water side"): a point projected with OpenCV's pinhole model through its two
    cameras is triangulated back to itself."""
    from measure import triangulate
    from synth.products.dataset import read_calib

    calib, (left, right) = _inputs(tmp_path)
    out = tmp_path / "out"
    assert main(["rectify", "--calib", calib, "--distance", "1000", left, right, "--out", str(out),
                 "--no-progress"]) == 0
    read = read_calib(str(out / "calib_rectified.yaml"))
    assert not read["has_port"]
    point = np.array([[30.0, -20.0, 1000.0]])
    uv = []
    for K, D, R, T in ((read["K1"], read["D1"], np.eye(3), np.zeros(3)),
                       (read["K2"], read["D2"], read["R"], read["T"].ravel())):
        pixels, _ = cv2.projectPoints(point, cv2.Rodrigues(R)[0], T, K, D)
        uv.append(pixels.reshape(1, 2))
    result = triangulate(read["rig"], uv[0], uv[1], "optical_path")
    np.testing.assert_allclose(result.points, point, atol=1e-6)


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
