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


def _three_cameras(tmp_path):
    """A row of three cameras: the pair's two behind the paper's one flat port and one more,
    200 mm beyond the right one, inside its own dome (1 mm off its centre), written as a rig
    file of N cameras; and a photo."""
    from measure import Camera
    from measure.geometry.dome import DomePort
    from measure.stereo.multirig import MultiRig
    from synth.products.rig_file import write_rig_file

    pair = paper_rig(size=SIZE, focal_px=75.0)
    third = Camera(pair.right.K, SIZE, R=pair.right.R, t=pair.right.t + np.array([200.0, 0, 0]))
    dome = DomePort(third.center + np.array([1.0, 0, 0]), 50.0, 8.0, pair.port.indices)
    rig = MultiRig([pair.left, pair.right, third], [pair.port, pair.port, dome])
    calib = tmp_path / "rig.yaml"
    write_rig_file(calib, rig)
    image = tmp_path / "photo.png"
    cv2.imwrite(str(image), np.tile(np.arange(SIZE[0], dtype=np.uint8), (SIZE[1], 1)))
    return rig, str(calib), str(image)


def test_any_pair_of_a_rig_of_n_cameras(tmp_path, capsys):
    """--cameras A,B rectifies two cameras of a rig of N: cam0,cam1 (the port they share) the
    same maps as the pair's own calibration of those two cameras; cam1,cam2 (the shared flat
    port and a dome, its left camera away from the reference origin) exact on the plane at
    --distance (the warp's error there below 1e-6 px, growing off it); a rig of three without
    --cameras, or a camera it does not hold: one line, exit 2."""
    rig, calib, photo = _three_cameras(tmp_path)
    pair_calib = tmp_path / "pair.yaml"
    write_calib(pair_calib, rig.pair(0, 1), has_port=True)
    outs = {}
    for name, extra in (("rig", ["--calib", calib, "--cameras", "cam0,cam1"]),
                        ("pair", ["--calib", str(pair_calib)]),
                        ("right", ["--calib", calib, "--cameras", "cam1,cam2"])):
        outs[name] = tmp_path / name
        assert main(["rectify", photo, photo, *extra, "--distance", "1000", "--error-distances",
                     "1000,1500", "--out", str(outs[name]), "--no-progress"]) == 0, name
    capsys.readouterr()
    rig_maps, pair_maps = np.load(outs["rig"] / "maps.npz"), np.load(outs["pair"] / "maps.npz")
    for key in pair_maps.files:
        np.testing.assert_array_equal(rig_maps[key], pair_maps[key])
    report = json.loads((outs["right"] / "errors.json").read_text())
    assert report["cameras"] == ["cam1", "cam2"]
    exact, off = report["errors"]["1000"], report["errors"]["1500"]
    assert exact["left_px"]["max"] < 1e-6 and exact["right_px"]["max"] < 1e-6
    assert off["left_px"]["median"] > 1e-3  # the flat port: no central camera
    for extra, fragment in ((["--calib", calib], "--cameras cam0,cam1"),
                            (["--calib", calib, "--cameras", "cam0,cam7"], "no camera 'cam7'"),
                            (["--calib", calib, "--cameras", "cam1,cam1"], "two different")):
        out = tmp_path / "refused"
        assert main(["rectify", photo, photo, *extra, "--distance", "1000", "--out", str(out),
                     "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
        assert not out.exists()
