"""The absorbed baseline (a pinhole calibration of boards seen through the port) and the length
errors every method is scored by."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.cli import main
from eval.core.absorbed import analytic_absorbed_calibration
from eval.core.cloud_metrics import length_errors
from measure import triangulate
from measure.geometry.projection import project
from synth.products.dataset import write_calib
from synth.scene.rig import paper_rig


def test_length_errors_of_a_scaled_and_of_a_moved_cloud():
    """A cloud scaled by 1.01 has every length 1 % too long; a rigid motion changes no length;
    pairs closer than the minimum are not counted."""
    rng = np.random.default_rng(0)
    truth = rng.uniform(-500, 500, (60, 3))
    scaled = length_errors(1.01 * truth, truth)
    assert scaled["length_median_pct"] == pytest.approx(1.0, abs=1e-9)
    assert scaled["length_worst_pct"] == pytest.approx(1.0, abs=1e-9)
    moved = truth @ Rotation.from_rotvec([0.3, -0.2, 0.1]).as_matrix().T + [10.0, -40.0, 7.0]
    assert abs(length_errors(moved, truth)["length_worst_pct"]) < 1e-10
    n_far = int(np.sum(np.linalg.norm(truth[:, None] - truth[None], axis=2) >= 100.0) // 2)
    assert scaled["length_pairs"] == n_far < 60 * 59 // 2


def test_with_a_port_that_bends_nothing_the_absorbed_calibration_is_the_true_pinhole_rig():
    """Behind an index-matched port the cameras are pinhole cameras: the absorbed calibration
    must find them (focal length, baseline) and triangulate exactly — the machinery checked
    against the physics, independent of the port's model."""
    rig = paper_rig(in_air=True, size=(480, 402), focal_px=225.0)
    absorbed = analytic_absorbed_calibration(rig)
    assert absorbed.summary["stereo_rms_px"] < 1e-3
    assert absorbed.rig.left.K[0, 0] == pytest.approx(225.0, rel=1e-5)
    assert absorbed.rig.right.t == pytest.approx(rig.right.t, abs=1e-3)


def test_behind_the_paper_port_the_absorbed_lengths_err_where_the_optical_path_does_not():
    """The paper's port at 2 m: pinhole rays cannot follow refraction that depends on the
    point's position (the paper's introduction), so lengths between targets err by a fraction of a
    percent to percents; the optical path on the same pixels is exact."""
    from synth.scene.layouts import paper_plane

    rig = paper_rig(size=(480, 402), focal_px=225.0)
    absorbed = analytic_absorbed_calibration(rig)
    points = paper_plane(2000.0)
    uv_left, uv_right = project(rig.left, rig.port, points), project(rig.right, rig.port, points)
    inside = rig.left.in_image(uv_left) & rig.right.in_image(uv_right)
    measured = triangulate(absorbed.rig, uv_left[inside], uv_right[inside], "optical_path").points
    exact = triangulate(rig, uv_left[inside], uv_right[inside], "optical_path").points
    wrong, right = length_errors(measured, points[inside]), length_errors(exact, points[inside])
    assert wrong["length_median_abs_pct"] > 0.05 and abs(wrong["length_worst_pct"]) > 1.0
    assert abs(right["length_worst_pct"]) < 1e-8


def test_an_absorbed_calibration_file_must_have_no_port(small_scene, tmp_path, capsys):
    calib = tmp_path / "calib.yaml"
    write_calib(calib, paper_rig(size=(320, 268), focal_px=150.0))
    out = tmp_path / "out"
    assert main(["run", small_scene, "--out", str(out), "--no-progress",
                 "--methods", "optical_path,absorbed", "--absorbed-calib", str(calib)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "without a port" in err[0] and str(calib) in err[0]
    assert not out.exists()
