"""``eval calibrate`` of ``synth boards`` folders of four cameras behind one port (small renders):
in air every camera pose and intrinsic against the folder's truth within its σ × 3, and the
shared port under water given that calibration; bad input is one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from eval.cli import main as eval_main
from synth.__main__ import main as synth_main
from synth.products.rig_file import read_rig_covariance, read_rig_file

pytestmark = pytest.mark.slow

BOARD = ["--squares", "7x6", "--square-mm", "60", "--distance", "450", "900", "--poses", "12"]


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    root = tmp_path_factory.mktemp("four")
    scene = root / "four.xml"
    assert synth_main(["scene", "--cameras", "4", "--size", "612", "512", "--focal", "275",
                       "--out", str(scene)]) == 0
    for name, extra in (("b_air", ["--air", "--seed", "1"]), ("b_water", ["--seed", "2"])):
        assert synth_main(["boards", str(scene), *BOARD, *extra, "--out", str(root / name),
                           "--no-progress"]) == 0
    assert eval_main(["calibrate", str(root / "b_air"), "--out", str(root / "c_air"),
                      "--no-progress"]) == 0
    return root


def test_in_air_every_pose_and_intrinsic_within_three_sigma(chain):
    report = json.loads((chain / "c_air" / "report.json").read_text())
    assert report["parameters"] == 3 * 6 + 4 * 9  # poses of cam1–3; fx fy cx cy k1 k2 p1 p2 k3
    assert report["within_3_sigma"] >= report["parameters"] - 1, report["estimates"]
    assert report["joint_rms_px"] < 0.05
    rig = read_rig_file(chain / "c_air" / "calib.yaml")
    names, matrix = read_rig_covariance(chain / "c_air" / "calib.yaml")
    assert rig.names == ("cam0", "cam1", "cam2", "cam3") and not rig.refracts
    assert len(names) == report["parameters"] and np.all(np.diag(matrix) > 0)


def test_the_shared_port_given_the_in_air_calibration(chain, tmp_path):
    out = tmp_path / "c_water"
    assert eval_main(["calibrate", str(chain / "b_water"), "--intrinsics",
                      str(chain / "c_air" / "calib.yaml"), "--out", str(out),
                      "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["uncertainty"] == "propagate"  # the in-air covariance is in σ
    assert report["joint_rms_px"] < 0.05
    for name, entry in report["estimates"].items():  # D and the two tilts against the truth
        assert abs(entry["error_in_sigma"]) <= 3.0, (name, entry)
    assert read_rig_file(out / "calib.yaml").refracts


def test_bad_input_is_one_line(chain, tmp_path, capsys):
    cases = [
        (["calibrate", str(chain / "b_water"), "--out", str(tmp_path / "a")], "--intrinsics"),
        (["calibrate", str(chain / "b_air"), "--free", "distance", "--out", str(tmp_path / "b")],
         "--free"),
        (["calibrate", str(chain / "b_water"), "--intrinsics", str(chain / "c_air" / "calib.yaml"),
          "--port-distance", "90,110", "--out", str(tmp_path / "c")], "--port-distance"),
    ]
    for argv, fragment in cases:
        assert eval_main([*argv, "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not any((tmp_path / n).exists() for n in "abc")
