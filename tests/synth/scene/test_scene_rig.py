"""``synth scene --rig FILE``: the scene holds exactly the cameras and port(s) of a calibration
file — of three cameras behind one tilted port, and of two housings — and the options that
would describe another rig are refused."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from measure import Camera, FlatPort
from measure.geometry.flat_pair import FlatPair
from measure.stereo.multirig import MultiRig
from synth.__main__ import main as synth_main
from synth.products.rig_file import write_rig_file
from synth.scene import load_scene

K = np.array([[900.0, 0, 640.3], [0, 900.0, 511.2], [0, 0, 1]])


def _cameras(n):
    out = [Camera(K, (1280, 1024), np.array([-0.08, 0.03, 0.001, -0.0005, 0.0]))]
    for k in range(1, n):
        R = Rotation.from_rotvec([0.01 * k, -np.radians(4.0 * k), 0.002]).as_matrix()
        out.append(Camera(K + np.diag([3.0 * k, 3.0 * k, 0]), (1280, 1024),
                          np.array([-0.07, 0.02, 0, 0, 0.001 * k]), R,
                          np.array([180.0 * k, 2.0 * k, -1.0 * k])))
    return out


def _same_camera(a, b):
    np.testing.assert_allclose(a.K, b.K, atol=1e-9)
    np.testing.assert_allclose(a.R, b.R, atol=1e-12)
    np.testing.assert_allclose(a.t, b.t, atol=1e-9)
    np.testing.assert_allclose(np.ravel(a.dist), np.ravel(b.dist), atol=1e-12)
    assert tuple(a.size) == tuple(b.size)


def test_three_cameras_behind_a_tilted_port(tmp_path, capsys):
    port = FlatPort(Rotation.from_rotvec([0, np.radians(1.5), 0]).apply([0, 0, 1.0]), 95.0,
                    (8.0,), (1.0, 1.49, 1.34))
    rig = MultiRig(_cameras(3), [port] * 3)
    write_rig_file(tmp_path / "calib.yaml", rig)
    out = tmp_path / "three.xml"
    assert synth_main(["scene", "--rig", str(tmp_path / "calib.yaml"), "--layout", "grid",
                       "--spacing", "100", "--z", "1200", "--out", str(out)]) == 0
    spec = load_scene(str(out)).multirig
    assert len(spec.cameras) == 3
    for a, b in zip(spec.cameras, rig.cameras):
        _same_camera(a, b)
    for p in spec.ports:
        np.testing.assert_allclose(p.normal, port.normal, atol=1e-12)
        assert abs(p.distance - port.distance) < 1e-9 and p.indices == port.indices
        np.testing.assert_allclose(p.thicknesses, port.thicknesses, atol=1e-9)


def test_two_housings_and_refusals(tmp_path, capsys):
    left, right = _cameras(2)
    pair = FlatPair(FlatPort(left.R[:, 2], 60.0, (5.0,), (1.0, 1.5, 1.33)),
                    FlatPort(right.R[:, 2], 80.0 + right.R[:, 2] @ right.t, (6.0,),
                             (1.0, 1.5, 1.33)))
    write_rig_file(tmp_path / "pair.yaml", MultiRig([left, right], [pair.left, pair.right]))
    out = tmp_path / "pair.xml"
    assert synth_main(["scene", "--rig", str(tmp_path / "pair.yaml"), "--out", str(out)]) == 0
    spec = load_scene(str(out))
    for v, camera in enumerate((left, right)):
        _same_camera(spec.rig.cameras[v], camera)
        got, want = spec.rig.view_port(v), pair.view(v)
        np.testing.assert_allclose(got.normal, want.normal, atol=1e-12)
        assert abs(got.distance - want.distance) < 1e-9
        np.testing.assert_allclose(got.thicknesses, want.thicknesses, atol=1e-9)
    capsys.readouterr()
    for extra, fragment in ((["--focal", "1000"], "--focal"), (["--port", "dome"], "--port"),
                            (["--cameras", "3"], "--cameras")):
        assert synth_main(["scene", "--rig", str(tmp_path / "pair.yaml"), *extra,
                           "--out", str(tmp_path / "x.xml")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and fragment in err[0] and "--rig" in err[0], err
    assert synth_main(["scene", "--rig", str(tmp_path / "missing.yaml"),
                       "--out", str(tmp_path / "x.xml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.yaml" in err[0], err
    odd = _cameras(3)  # fx ≠ fy, as a real calibration has: Mitsuba renders square pixels
    odd[1] = Camera(odd[1].K + np.diag([0.0, 1.5, 0]), odd[1].size, odd[1].dist, odd[1].R,
                    odd[1].t)
    write_rig_file(tmp_path / "odd.yaml", MultiRig(odd, [None] * 3))
    assert synth_main(["scene", "--rig", str(tmp_path / "odd.yaml"),
                       "--out", str(tmp_path / "x.xml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "odd.yaml" in err[0] and "cam1" in err[0] and "fy" in err[0], err
    assert not (tmp_path / "x.xml").exists()
