"""synth.formats.calib_formats: calibmar's stereo YAML pair and the COLMAP fork's cameras.txt, written
from and read back into read_calib's dictionary exactly; bad files are one DatasetError."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measure import Camera, FlatPort, StereoRig
from measure.geometry.dome import DomePair, DomePort
from measure.geometry.flat_pair import FlatPair
from measure.geometry.flatport_format import to_domeport, to_flatport
from synth.formats.calib_formats import (CALIBMAR_NAME, COLMAP_CAMERAS_NAME, COLMAP_RIG_NAME,
                                 CalibFormatError, calib_format, colmap_camera, write_calibmar,
                                 write_calibration_formats, write_colmap)
from synth.products.dataset import DatasetError, read_calib, write_calib
from synth.scene.rig import air_port, paper_rig

KEYS = ("size", "K1", "D1", "K2", "D2", "R", "T", "port", "has_port", "rig", "covariance",
        "models")


def _rig(dist_left=(0.1, -0.02, 0.001, -0.002, 0.0), dist_right=(-0.1, 0.02, 0.0, 0.001, 0.0),
         layers=(5.3,), indices=(1.0, 1.49, 1.3412)) -> StereoRig:
    K1 = np.array([[1100.3, 0, 1223.7], [0, 1101.9, 1023.2], [0, 0, 1]])
    K2 = np.array([[1098.25, 0, 1224.125], [0, 1099.5, 1022.875], [0, 0, 1]])
    R = Rotation.from_rotvec([0.01, -0.08, 0.02]).as_matrix()
    return StereoRig(Camera(K1, (2448, 2048), dist=dist_left),
                     Camera(K2, (2448, 2048), dist=dist_right, R=R, t=(201.3, -1.2, 3.4)),
                     FlatPort((0.02, -0.01, 1), 101.7, layers, indices))


def _project(tmp_path, rig, has_port=True) -> dict:
    path = tmp_path / "calib.yaml"
    write_calib(path, rig, has_port)
    return read_calib(path)


def _assert_same(got: dict, want: dict):
    assert set(got) == set(KEYS) and got["size"] == want["size"]
    assert got["has_port"] == want["has_port"]
    for key in ("K1", "D1", "K2", "D2", "R", "T"):
        assert got[key].shape == want[key].shape, key
        np.testing.assert_allclose(got[key], want[key], rtol=1e-12, atol=1e-14, err_msg=key)
    a, b = got["port"], want["port"]
    np.testing.assert_allclose(a.normal, b.normal, rtol=0, atol=1e-15)
    assert a.distance == pytest.approx(b.distance, rel=1e-12)
    np.testing.assert_allclose(a.thicknesses, b.thicknesses, rtol=1e-12)
    assert a.indices == b.indices
    np.testing.assert_allclose(got["rig"].right.t, want["rig"].right.t, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("fmt", ["calibmar", "colmap"])
def test_round_trip_through_each_format(tmp_path, fmt):
    """project → calibmar / colmap → project, to 1e-12 relative (the port exactly here)."""
    want = _project(tmp_path, _rig())
    if fmt == "calibmar":
        first, second = write_calibmar(tmp_path / "cal.yaml", want["rig"])
        assert os.path.basename(second) == "cal_stereo.yaml"
        paths = [first, second]  # either file names the pair
    else:
        paths = [write_colmap(tmp_path / "cameras.txt", want["rig"])[0]]
    for path in paths:
        assert calib_format(path) == fmt
        got = read_calib(path)
        _assert_same(got, want)
        # here the half-pixel shift and the metres undo exactly: bit for bit
        assert got["port"] == want["port"]
        for key in ("K1", "D1", "K2", "D2"):
            np.testing.assert_array_equal(got[key], want[key])


def test_fisheye_cameras_round_trip_as_opencv_fisheye(tmp_path):
    """OpenCV's fisheye model: calib.yaml (D1_model), calibmar and COLMAP as OPENCV_FISHEYE
    with COLMAP's parameter order fx, fy, cx, cy, k1, k2, k3, k4 (its documentation)."""
    plain = _rig()
    dist = (0.05, 0.01, -0.003, 0.0007)
    rig = StereoRig(*(Camera(c.K, c.size, dist, c.R, c.t, "fisheye") for c in plain.cameras),
                    plain.port)
    want = _project(tmp_path, rig)
    assert want["models"] == ("fisheye", "fisheye") and want["rig"].left.fisheye
    paths = [write_calibmar(tmp_path / "cal.yaml", rig)[0],
             write_colmap(tmp_path / "cameras.txt", rig)[0]]
    line = next(x for x in open(paths[1]).read().splitlines() if x and x[0] != "#").split()
    assert line[1] == "OPENCV_FISHEYE"
    K = rig.left.K
    np.testing.assert_array_equal([float(v) for v in line[4:12]],
                                  [K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5, *dist])
    assert "model: OPENCV_FISHEYE" in open(paths[0]).read()
    for path in paths:
        got = read_calib(path)
        _assert_same(got, want)
        assert got["models"] == ("fisheye", "fisheye")
        for camera in got["rig"].cameras:
            assert camera.fisheye and np.array_equal(camera.dist, dist)


def test_half_pixel_shift_is_in_the_files(tmp_path):
    """COLMAP's principal point is OpenCV's + 0.5 px, in both formats (1223.7 → 1224.2)."""
    rig = _project(tmp_path, _rig())["rig"]
    write_calibration_formats(tmp_path, rig)
    line = [row for row in (tmp_path / COLMAP_CAMERAS_NAME).read_text().splitlines()
            if row.startswith("1 ")][0]
    assert line.split()[:8] == ["1", "OPENCV", "2448", "2048", "1100.3", "1101.9", "1224.2",
                                "1023.7"]
    assert "parameters: [1100.3, 1101.9, 1224.2, 1023.7," in (tmp_path / CALIBMAR_NAME).read_text()
    assert colmap_camera(rig.right)[1][2:4] == [1224.625, 1023.375]


def test_files_as_the_tools_read_them(tmp_path):
    """cameras.txt: single spaces (the fork splits on ' '), the header says the convention and
    the pycolmap warning; rig_config.json: the fork's keys; calibmar: its line prefixes."""
    rig = _project(tmp_path, _rig())["rig"]
    written = write_calibration_formats(tmp_path, rig)
    assert sorted(os.path.basename(p) for p in written) == sorted(
        [CALIBMAR_NAME, "calibmar_stereo.yaml", COLMAP_CAMERAS_NAME, COLMAP_RIG_NAME])
    text = (tmp_path / COLMAP_CAMERAS_NAME).read_text()
    data = [row for row in text.splitlines() if not row.startswith("#")]
    assert len(data) == 2 and all("  " not in row and row == row.strip() for row in data)
    assert all(row.split()[12] == "FLATPORT" and len(row.split()) == 21 for row in data)
    assert "(0.5, 0.5)" in text and "silently DROP" in text and "pycolmap" in text
    config = json.loads((tmp_path / COLMAP_RIG_NAME).read_text())
    assert config[0]["ref_camera_id"] == 1
    assert [c["image_prefix"] for c in config[0]["cameras"]] == ["left/", "right/"]
    stereo = (tmp_path / "calibmar_stereo.yaml").read_text().splitlines()
    for prefix in ("model: OPENCV", "parameters: [", "non_svp_model: FLATPORT",
                   "non_svp_parameters: [", "width: 2448", "height: 2048",
                   "cam_to_world_rotation_rowmajor: [", "cam_to_world_translation: ["):
        assert any(row.startswith(prefix) for row in stereo), prefix
    translation = [row for row in stereo if row.startswith("cam_to_world_translation")][0]
    assert "0.2013" in translation  # metres


def test_k3_needs_full_opencv(tmp_path):
    """k3 ≠ 0 (or the rational k4–k6) is written as FULL_OPENCV, exactly; OPENCV refuses it."""
    want = _project(tmp_path, _rig(dist_left=(0.1, -0.02, 0.001, -0.002, 0.03)))
    write_colmap(tmp_path / "cameras.txt", want["rig"])
    assert " FULL_OPENCV " in (tmp_path / "cameras.txt").read_text()
    _assert_same(read_calib(tmp_path / "cameras.txt"), want)
    with pytest.raises(CalibFormatError, match="k3"):
        write_colmap(tmp_path / "other.txt", want["rig"], model="OPENCV")
    rational = _rig(dist_left=(0.1, -0.02, 0.001, -0.002, 0.03, 0.01, -0.002, 0.0005))
    write_calibmar(tmp_path / "rational.yaml", rational)
    got = read_calib(tmp_path / "rational.yaml")
    np.testing.assert_array_equal(got["D1"].ravel(), rational.left.dist)


@pytest.mark.parametrize("layers, indices, word", [((5.0, 3.0), (1.0, 1.49, 1.54, 1.33), "one glass"),
                                                   ((), (1.0, 1.33), "one glass")])
def test_ports_flatport_cannot_hold(tmp_path, layers, indices, word):
    rig = _rig(layers=layers, indices=indices)
    for write in (write_calibmar, write_colmap):
        with pytest.raises(CalibFormatError, match=word):
            write(tmp_path / "x.yaml", rig)


def test_skew_cannot_be_written(tmp_path):
    K = np.array([[1100.0, 0.5, 1223.5], [0, 1100.0, 1023.5], [0, 0, 1]])
    rig = paper_rig()
    skewed = StereoRig(Camera(K, rig.left.size), rig.right, rig.port)
    with pytest.raises(CalibFormatError, match="skew"):
        write_colmap(tmp_path / "cameras.txt", skewed)


def test_in_air_calibration(tmp_path):
    """has_port False: calibmar's non_svp_model NONE, no FLATPORT in cameras.txt; read back as an
    in-air calibration with the index-matched air port."""
    want = _project(tmp_path, StereoRig(paper_rig().left, paper_rig().right, air_port()), False)
    write_calibration_formats(tmp_path, want["rig"], has_port=False)
    assert "non_svp_model: NONE" in (tmp_path / CALIBMAR_NAME).read_text()
    assert "FLATPORT 0" not in (tmp_path / COLMAP_CAMERAS_NAME).read_text()
    for name in (CALIBMAR_NAME, COLMAP_CAMERAS_NAME):
        got = read_calib(tmp_path / name)
        _assert_same(got, want)
        assert got["port"] == air_port() and not got["has_port"]


def test_calibmars_documented_example(tmp_path):
    """calibmar's own example (doc/source/calibration_report_format.md, 10 significant digits)
    as the first camera, with a second camera written beside it: read, the port in the left
    frame is the documented one."""
    first = ("model: OPENCV\n# fx, fy, cx, cy, k1, k2, p1, p2\nparameters: [705.391983, "
             "705.210233, 963.440447, 604.968632, -0.105541, 0.066014, 0.001093, -8.6e-05]\n"
             "non_svp_model: FLATPORT\n# Nx, Ny, Nz, int_dist, int_thick, na, ng, nw (Note that "
             "[Nx, Ny, Nz] must be unit vector)\nnon_svp_parameters: [0.01311427226, "
             "-0.004460945556, 0.9999040533, 0.02531637365, 0.01, 1, 1.49, 1.333]\nwidth: 1920\n"
             "height: 1200\n# overall_rms: 0.8004862862\n# target: chessboard, 7, 8, 0.040000\n"
             "\n\n# stereo pose (camera to world, …)\ncam_to_world_rotation_rowmajor: [1, 0, 0, 0, "
             "1, 0, 0, 0, 1]\ncam_to_world_translation: [0, 0, 0]\n")
    (tmp_path / "calibration.yaml").write_text(first)
    port = FlatPort((0.01311427226, -0.004460945556, 0.9999040533), 25.31637365, (10.0,),
                    (1.0, 1.49, 1.333))
    K = np.array([[705.0, 0, 960.0], [0, 705.0, 600.0], [0, 0, 1]])
    right = Camera(K, (1920, 1200), R=Rotation.from_rotvec([0, -0.05, 0]).as_matrix(),
                   t=(120.0, 0.5, -1.0))
    params = to_flatport(port, right)
    R = [float(v) for v in right.R.ravel()]
    second = (f"model: PINHOLE\nparameters: [705.0, 705.0, 960.5, 600.5]\nnon_svp_model: FLATPORT\n"
              f"non_svp_parameters: [{', '.join(map(repr, params))}]\nwidth: 1920\nheight: 1200\n"
              f"cam_to_world_rotation_rowmajor: [{', '.join(map(repr, R))}]\n"
              f"cam_to_world_translation: [0.12, 0.0005, -0.001]\n")
    (tmp_path / "calibration_stereo.yaml").write_text(second)
    got = read_calib(tmp_path / "calibration.yaml")
    assert got["size"] == (1920, 1200) and got["has_port"]
    np.testing.assert_allclose(got["K1"][:2, 2], [962.940447, 604.468632], rtol=1e-15)
    np.testing.assert_allclose(got["D1"].ravel(), [-0.105541, 0.066014, 0.001093, -8.6e-05, 0])
    np.testing.assert_allclose(got["K2"], K)
    assert got["port"].distance == pytest.approx(25.31637365, rel=1e-12)
    np.testing.assert_allclose(got["rig"].right.t, right.t, rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# bad files: one DatasetError naming the file
# ---------------------------------------------------------------------------------------------
def _written(tmp_path):
    rig = _project(tmp_path, _rig())["rig"]
    write_calibration_formats(tmp_path, rig)
    return tmp_path


def _edit(path, old, new):
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize("name, old, new, word", [
    ("calibmar_stereo.yaml", "non_svp_model: FLATPORT", "non_svp_model: DOMEPORT",
     "non_svp_model DOMEPORT"),
    ("calibmar_stereo.yaml", "non_svp_model: FLATPORT", "non_svp_model: NONE",
     "non_svp_model NONE"),
    ("calibmar.yaml", "non_svp_parameters: [0.019995001874219095",
     "non_svp_parameters: [0.2", "unit vector"),
    ("calibmar.yaml", "0.1017, 0.0053", "-0.1017, 0.0053", "int_dist must be > 0"),
    ("calibmar.yaml", "0.0053, 1.0, 1.49", "0.0053, 0.9, 1.49", "indices"),
    ("calibmar.yaml", "model: OPENCV", "model: THIN_PRISM_FISHEYE", "unsupported camera model"),
    ("calibmar.yaml", "parameters: [1100.3, ", "parameters: [", "needs 8 finite parameters"),
    # the right count with a number that is not finite: which one is named
    ("calibmar.yaml", "parameters: [1100.3, ", "parameters: [nan, ", r"got fx = nan$"),
    ("calibmar.yaml", "width: 2448", "width: 2000", "image size"),
    ("calibmar.yaml", "model: OPENCV\n", "", "no model"),
    ("calibmar_stereo.yaml", "cam_to_world_translation: [", "cam_to_world_translation: [1.0, ",
     "3 numbers"),
])
def test_bad_calibmar_files(tmp_path, name, old, new, word):
    folder = _written(tmp_path)
    _edit(folder / name, old, new)
    with pytest.raises(DatasetError, match=word) as info:
        read_calib(folder / CALIBMAR_NAME)
    assert "calibmar" in str(info.value) and "\n" not in str(info.value)


def test_calibmar_partner_missing(tmp_path):
    folder = _written(tmp_path)
    os.remove(folder / "calibmar_stereo.yaml")
    with pytest.raises(DatasetError, match="calibmar_stereo.yaml: no such file"):
        read_calib(folder / CALIBMAR_NAME)


@pytest.mark.parametrize("old, new, word", [
    ("1 OPENCV 2448 2048 1100.3", "1 FISHEYE_X 2448 2048 1100.3", "unsupported camera model"),
    ("1 OPENCV 2448 2048 1100.3 ", "1 OPENCV 2448 2048 ", "FLATPORT and 8 numbers may follow"),
    # a DOMEPORT whose centre (here the flat port's unit normal, 1 m) is not inside its radius
    (" FLATPORT 0.0199", " DOMEPORT 0.0199", "camera centre lies outside its dome"),
    (" FLATPORT 0.0199", " SPHEREPORT 0.0199", "found 'SPHEREPORT'"),
    (" 1.0 1.49 1.3412\n2", " 1.0 1.49\n2", "FLATPORT needs 8"),
    ("1 OPENCV 2448 2048 1100.3", "1 OPENCV 2448 2048 1e400", r"got fx = inf$"),
    (" 1.0 1.49 1.3412\n2", " 1.0 1.49 inf\n2", r"got nw = inf$"),
    ("2 OPENCV 2448 2048", "3 OPENCV 2448 2048", "names cameras"),
    ("2 OPENCV 2448 2048", "2 OPENCV 2448 2000", "different image sizes"),
])
def test_bad_cameras_txt(tmp_path, old, new, word):
    folder = _written(tmp_path)
    _edit(folder / COLMAP_CAMERAS_NAME, old, new)
    with pytest.raises(DatasetError, match=word) as info:
        read_calib(folder / COLMAP_CAMERAS_NAME)
    assert COLMAP_CAMERAS_NAME in str(info.value) or COLMAP_RIG_NAME in str(info.value)


def test_cameras_txt_needs_its_rig_config(tmp_path):
    folder = _written(tmp_path)
    os.remove(folder / COLMAP_RIG_NAME)
    with pytest.raises(DatasetError, match="rig_config.json: no such file"):
        read_calib(folder / COLMAP_CAMERAS_NAME)
    write_colmap(folder / COLMAP_CAMERAS_NAME, _rig())
    config = json.loads((folder / COLMAP_RIG_NAME).read_text())
    del config[0]["cameras"][1]["cam_from_rig_rotation"]
    (folder / COLMAP_RIG_NAME).write_text(json.dumps(config))
    with pytest.raises(DatasetError, match="relative pose"):
        read_calib(folder / COLMAP_CAMERAS_NAME)


def test_a_nan_in_the_rig_configs_quaternion_is_refused(tmp_path):
    """JSON reads NaN; a NaN quaternion's norm compared with 1 was not 'more than 1e-6 off'."""
    folder = _written(tmp_path)
    text = (folder / COLMAP_RIG_NAME).read_text()
    config = json.loads(text)
    config[0]["cameras"][1]["cam_from_rig_rotation"][2] = float("nan")
    (folder / COLMAP_RIG_NAME).write_text(json.dumps(config))
    assert "NaN" in (folder / COLMAP_RIG_NAME).read_text()
    with pytest.raises(DatasetError, match="camera 2: the rotation must be a unit quaternion"):
        read_calib(folder / COLMAP_CAMERAS_NAME)


def test_three_cameras_are_not_a_stereo_rig(tmp_path):
    folder = _written(tmp_path)
    text = (folder / COLMAP_CAMERAS_NAME).read_text()
    last = text.strip().splitlines()[-1]
    (folder / COLMAP_CAMERAS_NAME).write_text(text + "3" + last[1:] + "\n")
    with pytest.raises(DatasetError, match=r"a rig of 3 camera\(s\), not a stereo pair"):
        read_calib(folder / COLMAP_CAMERAS_NAME)


def test_project_files_still_read_and_unknown_content_is_opencvs_error(tmp_path):
    want = _project(tmp_path, paper_rig())
    assert calib_format(tmp_path / "calib.yaml") == "opencv" and want["has_port"]
    (tmp_path / "junk.yaml").write_text("just some words\n")
    with pytest.raises(DatasetError, match="junk.yaml"):
        read_calib(tmp_path / "junk.yaml")


# ---------------------------------------------------------------------------------------------
# DOMEPORT: one dome per camera
# ---------------------------------------------------------------------------------------------
def _dome_rig() -> StereoRig:
    rig = _rig()
    return StereoRig(rig.left, rig.right, DomePair(
        DomePort(rig.left.center + (1.25, -0.75, 2.5), 50.8, 7.9, (1.0, 1.473, 1.3412)),
        DomePort(rig.right.center + (-0.5, 1.0, -3.25), 60.3, 8.1, (1.0, 1.52, 1.3412))))


def _assert_same_domes(got: DomePair, want: DomePair):
    for a, b in ((got.left, want.left), (got.right, want.right)):
        np.testing.assert_allclose(a.center, b.center, rtol=0, atol=1e-12)
        assert a.radius == pytest.approx(b.radius, rel=1e-14)
        assert a.thickness == pytest.approx(b.thickness, rel=1e-14)
        assert a.indices == b.indices


@pytest.mark.parametrize("fmt", ["calibmar", "colmap"])
def test_dome_rigs_round_trip_through_each_format(tmp_path, fmt):
    """A DomePair rig → calibmar / cameras.txt (DOMEPORT: the dome centre in each camera's
    frame, metres) → read_calib: every dome to 1e-12 mm, the cameras as for FLATPORT."""
    rig = _dome_rig()
    if fmt == "calibmar":
        path = write_calibmar(tmp_path / "cal.yaml", rig)[1]
    else:
        path = write_colmap(tmp_path / "cameras.txt", rig)[0]
    got = read_calib(path)
    assert got["has_port"] and got["rig"].port.kind == "dome"
    _assert_same_domes(got["port"], rig.port)
    np.testing.assert_allclose(got["rig"].right.t, rig.right.t, rtol=1e-12)
    np.testing.assert_allclose(got["rig"].right.R, rig.right.R, rtol=0, atol=1e-15)
    np.testing.assert_allclose(got["K2"], rig.right.K, rtol=1e-15)


def test_domeport_lines_as_the_tools_read_them(tmp_path):
    """cameras.txt: ``DOMEPORT`` and 8 numbers after the camera parameters; calibmar:
    ``non_svp_model: DOMEPORT`` and the fork's parameter names as the comment."""
    rig = _dome_rig()
    write_calibration_formats(tmp_path, rig)
    data = [row for row in (tmp_path / COLMAP_CAMERAS_NAME).read_text().splitlines()
            if not row.startswith("#")]
    assert all(row.split()[12] == "DOMEPORT" and len(row.split()) == 21 for row in data)
    params = [float(v) for v in data[1].split()[13:]]
    assert params == to_domeport(rig.port.right, rig.right)
    # the right dome's centre in the right camera's frame, in metres
    np.testing.assert_allclose(params[:3], rig.right.R.T @ (-0.5, 1.0, -3.25) * 1e-3,
                               rtol=1e-12)
    assert params[3:5] == pytest.approx([0.0603, 0.0081], rel=1e-15)
    stereo = (tmp_path / "calibmar_stereo.yaml").read_text()
    assert "non_svp_model: DOMEPORT\n# Cx, Cy, Cz, int_radius, int_thick, na, ng, nw\n" in stereo


@pytest.mark.parametrize("name, old, new, word", [
    ("calibmar_stereo.yaml", "non_svp_model: DOMEPORT", "non_svp_model: FLATPORT",
     "non_svp_model FLATPORT"),
    ("calibmar.yaml", "0.0508, 0.0079,", "0.0508, -0.0079,", "int_thick must be > 0"),
    ("calibmar.yaml", "0.0508, 0.0079,", "0.0, 0.0079,", "int_radius must be > 0"),
    ("calibmar.yaml", "0.0508, 0.0079,", "0.001, 0.0079,", "outside its dome"),
    ("calibmar.yaml", "0.0079, 1.0, 1.473", "0.0079, 0.9, 1.473", "indices"),
    ("cameras.txt", " 1.0 1.52 1.3412", " 1.0 1.52", "DOMEPORT needs 8"),
    ("cameras.txt", "DOMEPORT 0.00125", "FLATPORT 0.00125", "unit vector"),
])
def test_bad_domeport_files(tmp_path, name, old, new, word):
    write_calibration_formats(tmp_path, _dome_rig())
    _edit(tmp_path / name, old, new)
    with pytest.raises(DatasetError, match=word) as info:
        read_calib(tmp_path / name)
    assert "\n" not in str(info.value)


def test_cameras_with_two_housings_are_refused(tmp_path):
    """One camera FLATPORT, the other DOMEPORT: one error naming the file."""
    write_colmap(tmp_path / COLMAP_CAMERAS_NAME, _dome_rig())
    text = (tmp_path / COLMAP_CAMERAS_NAME).read_text().splitlines()
    flat = " ".join(["FLATPORT"] + [repr(v) for v in to_flatport(_rig().port, _rig().left)])
    text = [row.split(" DOMEPORT ")[0] + " " + flat if row.startswith("1 ") else row
            for row in text]
    (tmp_path / COLMAP_CAMERAS_NAME).write_text("\n".join(text) + "\n")
    with pytest.raises(DatasetError, match="both cameras need the same housing"):
        read_calib(tmp_path / COLMAP_CAMERAS_NAME)


# ---------------------------------------------------------------------------------------------
# two housings: a FLATPORT per camera (measure.geometry.flat_pair.FlatPair)
# ---------------------------------------------------------------------------------------------
#: The right camera of the hand-written files: turned 5° about y towards the left one, 200 mm
#: to its right (camera-to-left: X_left = R·X_right + t).
RIGHT_R = Rotation.from_rotvec([0.0, -np.radians(5.0), 0.0]).as_matrix()
RIGHT_T_M = (0.2, 0.0, 0.0)
#: Each camera's FLATPORT as the tools document it (normal in that camera's frame, metres).
LEFT_FLATPORT = [0.0, 0.0, 1.0, 0.06, 0.005, 1.0, 1.54, 1.33]
RIGHT_FLATPORT = [float(np.sin(np.radians(2.0))), 0.0, float(np.cos(np.radians(2.0))), 0.08,
                  0.008, 1.0, 1.49, 1.33]
K_TEXT = "1100.0, 1100.0, 1224.0, 1024.0, 0.0, 0.0, 0.0, 0.0"


def _expected_pair() -> FlatPair:
    """The two ports in the left camera's frame (mm), from the FLATPORT definition: the normal
    rotated into the left frame, the distance from the left origin = int_dist + n·(camera
    centre)."""
    t = np.array(RIGHT_T_M) * 1000.0
    right_normal = RIGHT_R @ RIGHT_FLATPORT[:3]
    return FlatPair(FlatPort((0, 0, 1), 60.0, (5.0,), (1.0, 1.54, 1.33)),
                    FlatPort(right_normal, 80.0 + right_normal @ t, (8.0,), (1.0, 1.49, 1.33)))


def _assert_same_pair(got, want):
    assert isinstance(got, FlatPair), type(got)
    for a, b in ((got.left, want.left), (got.right, want.right)):
        np.testing.assert_allclose(a.normal, b.normal, rtol=0, atol=1e-15)
        assert a.distance == pytest.approx(b.distance, rel=1e-13)
        np.testing.assert_allclose(a.thicknesses, b.thicknesses, rtol=1e-13)
        np.testing.assert_allclose(a.indices, b.indices, rtol=1e-15)


def _numbers(values) -> str:
    return ", ".join(repr(float(v)) for v in values)


def test_calibmar_with_a_flatport_per_camera(tmp_path):
    """calibmar's two files written by hand (its documented keys), each camera with its own
    FLATPORT: read as two housings; written back, each file holds its camera's FLATPORT."""
    pose = (f"cam_to_world_rotation_rowmajor: [{_numbers(RIGHT_R.ravel())}]\n"
            f"cam_to_world_translation: [{_numbers(RIGHT_T_M)}]\n")
    for name, params, tail in (("calibration.yaml", LEFT_FLATPORT, ""),
                               ("calibration_stereo.yaml", RIGHT_FLATPORT, pose)):
        (tmp_path / name).write_text(
            f"model: OPENCV\nparameters: [{K_TEXT}]\nnon_svp_model: FLATPORT\n"
            f"non_svp_parameters: [{_numbers(params)}]\nwidth: 2448\nheight: 2048\n{tail}")
    got = read_calib(tmp_path / "calibration.yaml")
    assert got["has_port"] and got["rig"].port.kind == "flat pair"
    _assert_same_pair(got["port"], _expected_pair())
    np.testing.assert_allclose(got["rig"].right.t, (200.0, 0.0, 0.0), rtol=0, atol=1e-12)
    first, second = write_calibmar(tmp_path / "out.yaml", got["rig"])
    for path, want in ((first, LEFT_FLATPORT), (second, RIGHT_FLATPORT)):
        line = next(row for row in open(path).read().splitlines()
                    if row.startswith("non_svp_parameters:"))
        written = [float(v) for v in line.split("[")[1].rstrip("]").split(",")]
        np.testing.assert_allclose(written, want, rtol=1e-13, atol=1e-16)


def test_colmap_cameras_with_a_flatport_per_camera(tmp_path):
    """cameras.txt and rig_config.json written by hand (the fork's documented line and rig
    configuration: cam_from_rig as w, x, y, z and metres): read as two housings and written
    back with each camera's own FLATPORT."""
    cam_from_rig = Rotation.from_matrix(RIGHT_R.T)
    x, y, z, w = cam_from_rig.as_quat()
    translation = -(RIGHT_R.T @ RIGHT_T_M)
    (tmp_path / COLMAP_CAMERAS_NAME).write_text(
        "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"1 PINHOLE 2448 2048 1100 1100 1224 1024 FLATPORT {' '.join(map(repr, LEFT_FLATPORT))}\n"
        f"2 PINHOLE 2448 2048 1100 1100 1224 1024 FLATPORT {' '.join(map(repr, RIGHT_FLATPORT))}\n")
    (tmp_path / COLMAP_RIG_NAME).write_text(json.dumps([{"ref_camera_id": 1, "cameras": [
        {"camera_id": 1, "image_prefix": "left/", "cam_from_rig_rotation": [1, 0, 0, 0],
         "cam_from_rig_translation": [0, 0, 0]},
        {"camera_id": 2, "image_prefix": "right/", "cam_from_rig_rotation": [w, x, y, z],
         "cam_from_rig_translation": translation.tolist()}]}]))
    got = read_calib(tmp_path / COLMAP_CAMERAS_NAME)
    _assert_same_pair(got["port"], _expected_pair())
    out = tmp_path / "out"
    out.mkdir()
    write_colmap(out / COLMAP_CAMERAS_NAME, got["rig"])
    rows = [row.split() for row in (out / COLMAP_CAMERAS_NAME).read_text().splitlines()
            if not row.startswith("#")]
    for row, want in zip(rows, (LEFT_FLATPORT, RIGHT_FLATPORT)):
        assert row[12] == "FLATPORT"
        np.testing.assert_allclose([float(v) for v in row[13:]], want, rtol=1e-13, atol=1e-16)


def test_calib_yaml_of_two_housings(tmp_path):
    """calib.yaml holds a ``ports`` map (left, right) and reads back the same pair; a ``ports``
    map with one camera's port only is one DatasetError naming the missing one."""
    pair = _expected_pair()
    rig = StereoRig(Camera(np.diag([1100.0, 1100.0, 1.0]), (2448, 2048)),
                    Camera(np.diag([1100.0, 1100.0, 1.0]), (2448, 2048), R=RIGHT_R,
                           t=np.array(RIGHT_T_M) * 1000.0), pair)
    got = _project(tmp_path, rig)
    _assert_same_pair(got["rig"].port, pair)  # the normal is normalized again on reading: 1 ulp
    text = (tmp_path / "calib.yaml").read_text()
    assert "\nports:\n   left:\n" in text and "\nport:" not in text
    (tmp_path / "calib.yaml").write_text(text[:text.index("   right:")])
    with pytest.raises(DatasetError, match=r"calib.yaml: ports: no right map .*needs both"):
        read_calib(tmp_path / "calib.yaml")


def test_a_rig_of_four_cameras_in_the_colmap_forks_files(tmp_path):
    """N cameras, each with its own housing line (a shared flat port, a dome, none): each
    FLATPORT line is the port seen from that camera (normal R_kᵀ N, distance D − N·t_k, metres,
    written by hand here from the documented format), rig_config.json holds cam_from_rig of
    every camera, and reading both gives the rig back."""
    from measure.geometry.dome import DomePort
    from measure.stereo.multirig import MultiRig
    from synth.formats.calib_formats import read_colmap_rig, write_colmap_rig
    from synth.scene.rig import paper_port, row_cameras

    cameras = row_cameras(4)
    port = paper_port()
    dome = DomePort(cameras[3].center + [0.0, 0.0, 2.0], 50.0, 8.0, (1.0, 1.5, 1.33))
    rig = MultiRig(cameras, [port, port, port, dome])
    path = tmp_path / "cameras.txt"
    write_colmap_rig(path, rig)
    lines = [line.split() for line in path.read_text().splitlines() if not line.startswith("#")]
    assert [int(line[0]) for line in lines] == [1, 2, 3, 4]
    for k in (1, 2):
        flat = [float(v) for v in lines[k][lines[k].index("FLATPORT") + 1:]]
        normal = cameras[k].R.T @ port.normal
        np.testing.assert_allclose(flat[:3], normal, atol=1e-12)
        assert flat[3] == pytest.approx((port.distance - port.normal @ cameras[k].t) / 1000.0)
        assert flat[4] == pytest.approx(0.005) and flat[5:] == [1.0, 1.54, 1.33]
    assert "DOMEPORT" in lines[3]
    config = json.loads((tmp_path / "rig_config.json").read_text())[0]
    assert config["ref_camera_id"] == 1 and len(config["cameras"]) == 4
    np.testing.assert_allclose(config["cameras"][2]["cam_from_rig_translation"],
                               -cameras[2].R.T @ cameras[2].t / 1000.0, atol=1e-12)
    back = read_colmap_rig(path)
    for a, b in zip(back.cameras, rig.cameras):
        np.testing.assert_allclose(a.R, b.R, atol=1e-12)
        np.testing.assert_allclose(a.t, b.t, atol=1e-9)
    for a, b in zip(back.ports[:3], rig.ports[:3]):
        np.testing.assert_allclose(a.normal, b.normal, atol=1e-12)
        assert a.distance == pytest.approx(b.distance, abs=1e-9)
    np.testing.assert_allclose(back.ports[3].center, dome.center, atol=1e-9)


def test_a_colmap_rig_of_three_cameras_becomes_a_scene(tmp_path, capsys):
    """``synth scene --rig cameras.txt`` of three cameras (the COLMAP fork's files): the scene
    holds the three cameras where the files put them (it said "a stereo rig has two", issue
    53); a pair's reader says the file is a rig of three, not a pair."""
    from measure.stereo.multirig import MultiRig
    from synth.__main__ import main as synth_main
    from synth.formats.calib_formats import write_colmap_rig
    from synth.products.dataset import DatasetError, read_calib
    from synth.scene import load_scene
    from synth.scene.rig import paper_port, row_cameras

    cameras = row_cameras(3)
    write_colmap_rig(tmp_path / "cameras.txt", MultiRig(cameras, [paper_port()] * 3))
    scene = tmp_path / "three.xml"
    assert synth_main(["scene", "--rig", str(tmp_path / "cameras.txt"), "--out", str(scene)]) == 0
    rig = load_scene(str(scene)).multirig
    assert len(rig.cameras) == 3
    for got, want in zip(rig.cameras, cameras):
        np.testing.assert_allclose(got.t, want.t, atol=1e-3)
    with pytest.raises(DatasetError, match=r"cameras.txt: a rig of 3 camera\(s\), not a stereo "
                                           r"pair"):
        read_calib(str(tmp_path / "cameras.txt"))
