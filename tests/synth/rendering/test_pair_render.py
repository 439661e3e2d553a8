"""A rendered scene of two housings (small): synth dataset / check through a finite window per
camera — the renderer's target centres against measure's forward projection through each
camera's own port, and the files of the dataset."""

from __future__ import annotations

import json

import numpy as np
import pytest

from measure.geometry.projection import project
from synth.__main__ import main as synth_main
from synth.products.dataset import read_dataset
from synth.scene import load_scene, write_scene
from synth.scene.layouts import grid_plane
from synth.scene.rig import paper_cameras
from synth.scene.windows import flat_pair

#: Every test here renders with Mitsuba.
pytestmark = pytest.mark.slow

SIZE, FOCAL = (320, 268), 150.0


def test_dataset_and_check_through_two_housings(tmp_path, capsys):
    """Ports 40 and 60 mm from their cameras, the right one tilted 2° more and of thicker,
    lower-index glass; 9 x 9 disks of radius 16 mm at 1 m: every target found, the centres
    within the check's bounds of the Fermat pixels through each camera's own port."""
    cameras = paper_cameras(SIZE, FOCAL)
    pair = flat_pair(cameras, (40.0, 60.0), ((0.0, 0.0), (0.0, 2.0)), (5.0, 8.0),
                     (1.0, 1.5, 1.33))
    scene = str(write_scene(tmp_path / "pair.xml", cameras, pair,
                            grid_plane(1000.0, 320.0, 80.0) + np.array([40.0, -2.0, 0.0]), 16.0,
                            spp=64))
    out = tmp_path / "ds"
    assert synth_main(["dataset", scene, "--out", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    assert synth_main(["check", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["passed"] and report["all_found"]
    assert report["left"]["found"] == report["left"]["in_image"] > 40
    assert report["rms_px"] < 0.03, report["rms_px"]
    data, spec = read_dataset(out), load_scene(scene)
    assert data.rig.port.kind == "flat pair" and data.rig.port == spec.rig.port
    for view, camera in enumerate(data.rig.cameras):  # pixels.csv: through its own port
        want = project(camera, spec.rig.view_port(view), data.targets)
        got = (data.pixels_left, data.pixels_right)[view]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    ports = json.loads((out / "cameras.json").read_text())["port"]["ports"]
    assert ports["right"]["thicknesses"] == pytest.approx([8.0], rel=1e-12)
    assert ports["left"]["thicknesses"] == pytest.approx([5.0], rel=1e-12)
    rows = [row.split() for row in (out / "colmap" / "cameras.txt").read_text().splitlines()
            if not row.startswith("#")]
    assert [row[12] for row in rows] == ["FLATPORT", "FLATPORT"]
    # int_dist, int_thick in metres: each port from its own camera
    assert [float(row[16]) for row in rows] == pytest.approx([0.04, 0.06], rel=1e-12)
    assert [float(row[17]) for row in rows] == pytest.approx([0.005, 0.008], rel=1e-12)
