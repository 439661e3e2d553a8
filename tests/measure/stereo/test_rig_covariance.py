"""measure.stereo.rig_covariance: the named covariance of a rig, and its node in calib.yaml."""

from __future__ import annotations

import numpy as np
import pytest

from measure.stereo.rig_covariance import CovarianceError, RigCovariance
from synth.products.dataset import DatasetError, read_calib, write_calib
from synth.scene.rig import paper_rig

NAMES = ("left.fx", "left.cx", "right.center[0]", "port.distance", "port.tilt[0]", "port.tilt[1]")


def _matrix(seed=0):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(len(NAMES), len(NAMES)))
    return a @ a.T + np.eye(len(NAMES)) * 1e-3


def test_calib_yaml_round_trips_the_covariance(tmp_path):
    axes = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    cov = RigCovariance(NAMES, _matrix(), axes)
    write_calib(tmp_path / "calib.yaml", paper_rig(), covariance=cov)
    back = read_calib(str(tmp_path / "calib.yaml"))["covariance"]
    assert back.names == NAMES
    np.testing.assert_array_equal(back.matrix, cov.matrix)
    np.testing.assert_array_equal(back.normal_axes, axes)


def test_a_calibration_without_covariance_reads_none(tmp_path):
    write_calib(tmp_path / "calib.yaml", paper_rig())
    assert read_calib(str(tmp_path / "calib.yaml"))["covariance"] is None


@pytest.mark.parametrize("matrix, words", [
    (np.zeros((6, 6)), "not positive"),
    (np.ones((6, 6)), "singular"),
    (np.triu(np.ones((6, 6))) + np.eye(6), "not symmetric"),
    (np.diag([1.0, 1e30, 1.0, 1.0, 1.0, 1.0]), "is 1e\\+15: no calibration is that uncertain"),
])
def test_a_bad_covariance_is_refused_naming_the_file(tmp_path, matrix, words):
    with pytest.raises(CovarianceError, match=words):
        RigCovariance(NAMES, matrix, np.eye(3)[:2])
    # the same matrix in a file: one DatasetError naming it
    path = tmp_path / "calib.yaml"
    write_calib(path, paper_rig())
    text = path.read_text().replace("port:", "covariance:\n   names: [ port.distance, left.fx ]\n"
                                    "   matrix: !!opencv-matrix\n      rows: 2\n      cols: 2\n"
                                    "      dt: d\n      data: [ 1., 2., 2., 1. ]\nport:", 1)
    path.write_text(text)
    with pytest.raises(DatasetError, match=f"{path}: covariance: .*singular"):
        read_calib(str(path))


def test_unknown_names_and_tilts_without_axes_are_refused():
    with pytest.raises(CovarianceError, match="unknown rig parameter"):
        RigCovariance(["left.focal"], [[1.0]])
    with pytest.raises(CovarianceError, match="without normal_axes"):
        RigCovariance(["port.tilt[0]"], [[1.0]])
    with pytest.raises(CovarianceError, match="repeat"):
        RigCovariance(["port.distance", "port.distance"], np.eye(2))


def test_dome_names_round_trip_through_a_dome_calib_yaml(tmp_path):
    """Each dome's centre (reference frame, mm) and the domes' water index are names of the
    grammar; a dome rig's calib.yaml keeps them."""
    from measure import StereoRig
    from synth.scene.rig import paper_cameras
    from synth.scene.dome import dome_pair

    names = ("left.fx", "right.rotation[1]", "left.dome_center[0]", "left.dome_center[2]",
             "right.dome_center[1]", "port.index[2]")
    cameras = paper_cameras()
    rig = StereoRig(*cameras, dome_pair(cameras, 50.0, 8.0, (2.0, 0.0, 0.0), (1.0, 1.54, 1.33)))
    rng = np.random.default_rng(1)
    a = rng.normal(size=(len(names), len(names)))
    cov = RigCovariance(names, a @ a.T + 1e-3 * np.eye(len(names)))
    write_calib(tmp_path / "calib.yaml", rig, covariance=cov)
    back = read_calib(str(tmp_path / "calib.yaml"))
    assert back["rig"].port.kind == "dome" and back["covariance"].names == names
    np.testing.assert_array_equal(back["covariance"].matrix, cov.matrix)
    for bad in ("left.dome_center[3]", "dome_center[0]", "port.dome_center[0]"):
        with pytest.raises(CovarianceError, match="unknown rig parameter"):
            RigCovariance([bad], [[1.0]])
