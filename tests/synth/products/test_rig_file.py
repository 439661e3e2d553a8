"""calib.yaml of N cameras (synth.products.rig_file): written and read back exactly; a rig of
two is today's two-camera file, byte for byte; bad files are one line naming the camera."""

from __future__ import annotations

import numpy as np
import pytest

from measure.geometry.camera import Camera
from measure.geometry.dome import DomePort
from measure.stereo.multirig import MultiRig
from synth.products.dataset import DatasetError, write_calib
from synth.products.rig_file import read_rig_file, write_rig_file
from synth.scene.rig import paper_intrinsics, paper_port, paper_rig, rotation_y


def _cameras(n):
    K = paper_intrinsics()
    return [Camera(K, (2448, 2048), dist=(0.01 * k, 0, 0, 0, 0),
                   R=rotation_y(-np.deg2rad(5.0 * k)), t=(200.0 * k, 0.0, 0.0)) for k in range(n)]


def _same(a: MultiRig, b: MultiRig):
    assert a.names == b.names
    for x, y in zip(a.cameras, b.cameras):
        np.testing.assert_array_equal(x.K, y.K)
        np.testing.assert_array_equal(x.R, y.R)
        np.testing.assert_array_equal(x.t, y.t)
        assert (x.dist is None) == (y.dist is None)
    assert a.ports == b.ports


def test_round_trip_of_shared_own_dome_and_no_port(tmp_path):
    cameras = _cameras(4)
    dome = DomePort(cameras[2].center + (0.5, 0, 0), 60.0, 8.0, (1.0, 1.5, 1.33))
    own = paper_port().replace(distance=90.0)
    dome3 = DomePort(cameras[3].center, 60.0, 8.0, (1.0, 1.5, 1.33))
    for ports in ([paper_port()] * 4, [paper_port(), paper_port(), dome, None],
                  [own, paper_port(), paper_port(), dome3]):
        rig = MultiRig(cameras, ports)
        write_rig_file(tmp_path / "calib.yaml", rig)
        _same(read_rig_file(tmp_path / "calib.yaml"), rig)


def test_two_cameras_write_todays_file(tmp_path):
    stereo = paper_rig()
    write_rig_file(tmp_path / "new.yaml", MultiRig.from_stereo(stereo))
    write_calib(tmp_path / "old.yaml", stereo)
    assert (tmp_path / "new.yaml").read_bytes() == (tmp_path / "old.yaml").read_bytes()
    back = read_rig_file(tmp_path / "old.yaml")
    assert back.names == ("left", "right") and back.ports == (paper_port(), paper_port())
    np.testing.assert_allclose(back.cameras[1].t, stereo.right.t, atol=1e-12)


def test_bad_files_name_the_camera(tmp_path):
    path = tmp_path / "calib.yaml"
    write_rig_file(path, MultiRig(_cameras(3), [paper_port()] * 3))
    text = path.read_text()
    overlap = text.replace("data: [ 400., 0., 0. ]", "data: [ 200., 0., 0. ]")
    path.write_text(overlap)
    with pytest.raises(DatasetError, match=r"calib.yaml: cameras cam1 and cam2 overlap"):
        read_rig_file(path)
    path.write_text(text + "ports:\n   kind: flat\n")
    with pytest.raises(DatasetError, match=r"ports: one value where 3 are needed"):
        read_rig_file(path)
    path.write_text(text.replace("data: [ 400., 0., 0. ]", "data: [ 400., 0., 103. ]"))
    with pytest.raises(DatasetError, match=r"cam2 centre lies on the water side"):
        read_rig_file(path)


def test_another_kind_of_calibration_is_named_not_misread(tmp_path):
    """A calibration of the wrong kind is named for what it is (issue 53): one camera's
    camera.yaml where a pair or a rig is expected (it said "units: 'px …': only mm is read"),
    a file of N cameras where a pair is expected ("no matrix K1"), and the folder of a
    calibration rather than its file ("no such file")."""
    from eval.calibrate.single import write_camera_files
    from synth.products.dataset import read_calib

    one = tmp_path / "one"
    one.mkdir()
    write_camera_files(one, _cameras(1)[0], "standard", 0.1, {}, other_formats=False)
    for read in (read_calib, read_rig_file):
        with pytest.raises(DatasetError, match=r"camera.yaml: a calibration of one camera "
                                               r"\(camera_matrix"):
            read(str(one / "camera.yaml"))
    four = tmp_path / "four.yaml"
    write_rig_file(four, MultiRig(_cameras(4), [paper_port()] * 4))
    with pytest.raises(DatasetError, match=r"four.yaml: a calibration of 4 cameras, not of a "
                                           r"stereo pair"):
        read_calib(str(four))
    pair = tmp_path / "pair"
    pair.mkdir()
    write_calib(pair / "calib.yaml", paper_rig())
    for read in (read_calib, read_rig_file):
        with pytest.raises(DatasetError, match=r"pair: a folder, not a calibration file \(give "
                                               r".*pair/calib.yaml\)"):
            read(str(pair))
