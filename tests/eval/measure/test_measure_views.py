"""``eval measure`` of one capture of three cameras (small renders of a grid of large targets):
the points against the scene's true targets, every target two views see triangulated, and bad
input one line."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from eval.cli import main as eval_main
from eval.core.analytic import visible_targets
from synth.__main__ import main as synth_main
from synth.products.rig_file import write_rig_file
from synth.scene import load_scene

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("capture")
    scene = root / "three.xml"
    assert synth_main(["scene", "--cameras", "3", "--layout", "grid", "--spacing", "150",
                       "--half-width", "600", "--target-radius", "10", "--size", "320", "268",
                       "--out", str(scene)]) == 0
    assert synth_main(["render", str(scene), "--spp", "16", "--out", str(root / "img"),
                       "--no-progress"]) == 0
    spec = load_scene(str(scene))
    write_rig_file(root / "calib.yaml", spec.multirig)
    return root, spec


def test_three_photos_give_the_true_targets(capture, tmp_path, capsys):
    root, spec = capture
    photos = [str(root / "img" / f"cam{k}.png") for k in range(3)]
    out = tmp_path / "m"
    assert eval_main(["measure", "--calib", str(root / "calib.yaml"), *photos, "--out",
                      str(out), "--no-progress", "--json"]) == 0
    import json

    printed = json.loads(capsys.readouterr().out)  # --json: the report alone on stdout
    assert printed["triangulated"] > 0 and printed["cameras"] == ["cam0", "cam1", "cam2"]
    data = np.genfromtxt(out / "points.csv", delimiter=",", names=True)
    points = np.column_stack([data["x_mm"], data["y_mm"], data["z_mm"]])
    rig = spec.multirig
    seen = sum(visible_targets(c, rig.view_port(k), spec.targets, spec.target_radius)[1]
               for k, c in enumerate(rig.cameras))
    assert len(points) >= (seen >= 2).sum() - 1
    distance, index = cKDTree(spec.targets).query(points)
    assert len(set(index)) == len(index)  # one point per target
    # the depth that 0.1 px of disparity moves a point at the targets' distance over the
    # first baseline (z² / (f·b) · 0.1): the raw centroids of 10 mm disks on 320 px images
    z = float(np.mean(spec.targets[:, 2]))
    focal = rig.cameras[0].K[0, 0]
    baseline = np.linalg.norm(rig.cameras[1].center - rig.cameras[0].center)
    assert distance.max() < 0.1 * z ** 2 / (focal * baseline), distance.max()
    assert set(np.unique(data["views"])) <= {2.0, 3.0}
    # every point's covariance in its pixels' noise (the σ its residuals show: no truth), in
    # the pair's schema, and its file row by row
    entry = printed["uncertainty"]
    assert entry["methods"] == ["optical_path"] and entry["pixel_sigma"]["median_px"] > 0
    assert entry["summaries"]["optical_path"]["sigma"]["n"] == printed["triangulated"]
    assert "coverage" not in entry["summaries"]["optical_path"]  # no truth here
    rows = np.genfromtxt(out / "uncertainty_optical_path.csv", delimiter=",", names=True)
    np.testing.assert_allclose(np.column_stack([rows["x"], rows["y"], rows["z"]]), points)
    assert np.all(rows["sigma_z"] > rows["sigma_x"])  # depth is the least certain axis
    # a stated σ scales every covariance by its square
    stated = tmp_path / "stated"
    assert eval_main(["measure", "--calib", str(root / "calib.yaml"), *photos, "--out",
                      str(stated), "--no-progress", "--pixel-sigma", "0.2"]) == 0
    rows2 = np.genfromtxt(stated / "uncertainty_optical_path.csv", delimiter=",", names=True)
    ratio = 0.2 / entry["pixel_sigma"]["median_px"]
    np.testing.assert_allclose(rows2["sigma_z"], rows["sigma_z"] * ratio, rtol=1e-6)


def test_bad_captures_are_refused(capture, tmp_path, capsys):
    root, _ = capture
    photos = [str(root / "img" / f"cam{k}.png") for k in range(3)]
    calib = str(root / "calib.yaml")
    for argv, fragment in (([*photos[:2]], "3 cameras"),
                           ([*photos, photos[0]], "4 photos"),
                           ([*photos, "--dense"], "--dense"),
                           ([*photos, "--methods", "su"], "--methods")):
        assert eval_main(["measure", "--calib", calib, *argv, "--out", str(tmp_path / "x"),
                          "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not (tmp_path / "x").exists()
    swapped = [photos[2], photos[1], photos[0]]  # not the rig's capture: never exit 0
    assert eval_main(["measure", "--calib", calib, *swapped, "--out", str(tmp_path / "s"),
                      "--no-progress"]) in (1, 2)


def test_every_camera_of_the_capture_is_checked(capture, tmp_path, capsys):
    """A black photo in one camera, and two cameras' photos swapped: exit 1 (everything
    written), the failing camera named — not only the one with the fewest detections."""
    import cv2

    root, _ = capture
    photos = [str(root / "img" / f"cam{k}.png") for k in range(3)]
    black = tmp_path / "black.png"
    cv2.imwrite(str(black), np.zeros((268, 320), np.uint8))
    calib = str(root / "calib.yaml")
    assert eval_main(["measure", "--calib", calib, photos[0], photos[1], str(black), "--out",
                      str(tmp_path / "b"), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "cam2" in err and "no target detected" in err, err
    swapped = [photos[0], photos[2], photos[1]]
    assert eval_main(["measure", "--calib", calib, *swapped, "--out", str(tmp_path / "s"),
                      "--no-progress"]) in (1, 2)
    err = capsys.readouterr().err
    assert "cam1" in err or "cam2" in err, err
