"""Datasets of a scene of three cameras (synth dataset, check, photos): one folder per camera,
checked against independent references — the scene's cameras and targets, the Fermat
simulator's pixels computed here, the files' own SHA-256 — and bad folders refused in one line
naming the file or camera."""

from __future__ import annotations

import hashlib
import json
import os
import shutil

import cv2
import numpy as np
import pytest

from measure.geometry.projection import project
from synth.__main__ import main
from synth.products.crosscheck import check_dataset
from synth.products.photos import to_photo
from synth.products.rig_file import read_rig_file
from synth.products.dataset import read_dataset, write_dataset
from synth.scene import load_scene

SIZE = (320, 268)
SPP = 16


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("three") / "three.xml"
    assert main(["scene", "--cameras", "3", "--layout", "grid", "--spacing", "150",
                 "--half-width", "600", "--target-radius", "10", "--size", *map(str, SIZE),
                 "--out", str(path)]) == 0
    return str(path)


@pytest.fixture(scope="module")
def dataset(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "ds"
    manifest = write_dataset(load_scene(scene), out, spp=SPP, progress=False)
    assert manifest["skipped"] is False
    return out


def _copy(dataset, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    return copy


def _one_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), err
    return err[0]


@pytest.mark.slow
def test_one_folder_per_camera_and_the_truth(scene, dataset):
    spec = load_scene(scene)
    names = ["cam0", "cam1", "cam2"]
    manifest = json.loads((dataset / "manifest.json").read_text())
    assert manifest["cameras"] == names
    visible = sorted(os.path.relpath(os.path.join(d, f), dataset)
                     for d, _, fs in os.walk(dataset) for f in fs if not f.startswith("."))
    colmap = [f"colmap/{f}" for f in ("cameras.txt", "rig_config.json", "images.txt",
                                      "points3D.txt", "README.txt")]
    assert visible == sorted(["calib.yaml", "cameras.json", "manifest.json", "pixels.csv",
                              "targets.ply"] + colmap
                             + [f"{n}/{f}" for n in names for f in ("image.png", "preview.png")])
    images = [cv2.imread(str(dataset / n / "image.png"), cv2.IMREAD_UNCHANGED) for n in names]
    for image in images:
        assert image.dtype == np.uint16 and image.shape == (SIZE[1], SIZE[0])
        assert image.max() > 0  # every view sees targets
    assert max(int(i.max()) for i in images) == 65535  # one scale for every view
    for name in manifest["files"]:  # every file's SHA-256, computed here
        if name != "manifest.json":
            digest = hashlib.sha256((dataset / name).read_bytes()).hexdigest()
            assert manifest["sha256"][name] == digest, name

    rig = read_rig_file(dataset / "calib.yaml")
    assert list(rig.names) == names
    for camera, truth in zip(rig.cameras, spec.all_cameras):
        np.testing.assert_allclose(camera.K, truth.K, atol=1e-12)
        np.testing.assert_allclose(camera.R, truth.R, atol=1e-12)
        np.testing.assert_allclose(camera.t, truth.t, atol=1e-12)
    data = read_dataset(dataset)
    np.testing.assert_array_equal(data.targets, spec.targets)
    np.testing.assert_array_equal(data.ids, spec.target_ids)
    for k, camera in enumerate(spec.all_cameras):  # the simulator through the one port
        expected = project(camera, spec.rig.port, spec.targets)
        np.testing.assert_array_equal(np.isnan(data.pixels[:, k]), np.isnan(expected))
        np.testing.assert_allclose(data.pixels[:, k], expected, atol=1e-9, equal_nan=True)
        linear = images[k].astype(np.float32) / np.float32(manifest["png_scale"])
        np.testing.assert_array_equal(data.images[k], linear)


@pytest.mark.slow
def test_cameras_json_and_the_colmap_model(scene, dataset):
    """``cameras.json`` holds the scene's cameras and port; ``colmap/`` the same cameras in the
    fork's files (COLMAP's pixels +0.5, metres), one image per camera, and every target that
    lies inside two or more images (by the simulator's pixels computed here) with its track."""
    from synth.formats.calib_formats import read_colmap_rig

    spec = load_scene(scene)
    data = json.loads((dataset / "cameras.json").read_text())
    assert list(data["cameras"]) == ["cam0", "cam1", "cam2"] and data["shared_port"] is True
    for entry, truth in zip(data["cameras"].values(), spec.all_cameras):
        np.testing.assert_allclose(entry["K"], truth.K, atol=1e-12)
        np.testing.assert_allclose(entry["pose_camera_to_reference"]["t"], truth.t, atol=1e-12)
        np.testing.assert_allclose(entry["port"]["normal"], spec.rig.port.normal, atol=1e-12)
        assert entry["port"]["distance"] == pytest.approx(spec.rig.port.distance, abs=1e-12)
    rig = read_colmap_rig(dataset / "colmap" / "cameras.txt")
    for camera, truth in zip(rig.cameras, spec.all_cameras):
        np.testing.assert_allclose(camera.K, truth.K, atol=1e-9)
        np.testing.assert_allclose(camera.t, truth.t, atol=1e-9)
    for port in rig.ports:
        assert port.distance == pytest.approx(spec.rig.port.distance, abs=1e-9)
    expected = np.stack([project(c, spec.rig.port, spec.targets) for c in spec.all_cameras], 1)
    w, h = SIZE
    inside = ((expected[..., 0] >= -0.5) & (expected[..., 0] <= w - 0.5)
              & (expected[..., 1] >= -0.5) & (expected[..., 1] <= h - 0.5))
    points = [line.split() for line in (dataset / "colmap" / "points3D.txt").read_text()
              .splitlines() if not line.startswith("#")]
    want = {int(spec.target_ids[i]) + 1: int(inside[i].sum()) for i in range(len(inside))
            if inside[i].sum() >= 2}
    assert {int(p[0]): (len(p) - 8) // 2 for p in points} == want
    images = [line.split() for line in (dataset / "colmap" / "images.txt").read_text()
              .splitlines() if not line.startswith("#")]
    assert [row[-1] for row in images[0::2]] == [f"cam{k}/image.png" for k in range(3)]
    for view, row in enumerate(images[1::2]):
        xy = np.array(row, dtype=float).reshape(-1, 3)
        index = {int(i): k for k, i in enumerate(spec.target_ids)}
        for x, y, pid in xy:
            np.testing.assert_allclose([x - 0.5, y - 0.5], expected[index[int(pid) - 1], view],
                                       atol=1e-9)


@pytest.mark.slow
def test_rerun_does_nothing(scene, dataset, capsys):
    assert main(["dataset", scene, "--out", str(dataset), "--spp", str(SPP),
                 "--no-progress"]) == 0
    assert "up to date" in capsys.readouterr().out


@pytest.mark.slow
def test_check_compares_every_camera_with_the_simulator(dataset, capsys):
    report = check_dataset(dataset, rms_px=0.2, max_px=0.5)
    assert report["views"] == ["cam0", "cam1", "cam2"]
    for view in report["views"]:
        r = report[view]
        assert r["in_image"] > 20 and r["found"] == r["in_image"] and not r["missed"], view
        assert r["rms_px"] < 0.2, (view, r["rms_px"])
    assert report["passed"]
    assert main(["check", str(dataset), "--rms", "0.2", "--max", "0.5"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split(":")[0].strip() for line in lines] == ["cam0", "cam1", "cam2", "all"]
    assert lines[-1].endswith("PASS")


@pytest.mark.slow
def test_photos_one_folder_per_camera(dataset, tmp_path, capsys):
    out = tmp_path / "photos"
    assert main(["photos", str(dataset), "--out", str(out), "--format", "png"]) == 0
    assert "cam0/, cam1/, cam2/" in capsys.readouterr().out
    visible = sorted(os.path.relpath(os.path.join(d, f), out)
                     for d, _, fs in os.walk(out) for f in fs if not f.startswith("."))
    assert visible == ["cam0/image.png", "cam1/image.png", "cam2/image.png"]
    for view in ("cam0", "cam1", "cam2"):
        png16 = cv2.imread(str(dataset / view / "image.png"), cv2.IMREAD_UNCHANGED)
        stored = cv2.imread(str(out / view / "image.png"), cv2.IMREAD_UNCHANGED)
        assert stored.dtype == np.uint8
        np.testing.assert_array_equal(stored, to_photo(png16))
    assert main(["photos", str(dataset), "--out", str(tmp_path / "jpg")]) == 0
    assert (tmp_path / "jpg" / "cam2" / "image.jpg").is_file()


def _gap(d):
    os.rename(d / "cam2", d / "cam3")
    return "cam3"


def _missing(d):
    os.remove(d / "cam1" / "image.png")
    return "cam1"


def _changed(d):
    image = cv2.imread(str(d / "cam1" / "image.png"), cv2.IMREAD_UNCHANGED)
    image[0, 0] += 1
    cv2.imwrite(str(d / "cam1" / "image.png"), image)
    return "cam1/image.png"


def _manifest(d):
    m = json.loads((d / "manifest.json").read_text())
    m["png_scale"] *= 2
    (d / "manifest.json").write_text(json.dumps(m))
    return "manifest.json"


def _preview(d):
    os.remove(d / "cam2" / "preview.png")
    return "cam2/preview.png"


@pytest.mark.slow
@pytest.mark.parametrize("damage", [_gap, _missing, _changed, _manifest, _preview])
def test_a_bad_folder_is_one_line_naming_it(dataset, tmp_path, capsys, damage):
    d = _copy(dataset, tmp_path)
    named = damage(d)
    for argv, out in ((["check", str(d)], None),
                      (["photos", str(d), "--out", str(tmp_path / "p")], tmp_path / "p")):
        assert main(argv) == 2
        assert named in _one_error(capsys)
        assert out is None or not out.exists()


def test_a_surface_scene_of_three_cameras_is_refused(surface_scene_of_three_cameras, tmp_path,
                                                     capsys):
    """The committed speckled plane with a third sensor added by hand: one line, nothing
    written (a surface's truth maps are written for two cameras)."""
    path = surface_scene_of_three_cameras
    out = tmp_path / "ds"
    assert main(["dataset", str(path), "--out", str(out), "--no-progress"]) == 2
    line = _one_error(capsys)
    assert "surface scene of 3 cameras" in line, line
    assert not out.exists()


@pytest.mark.slow
def test_a_sensor_and_exr_for_three_cameras(scene, dataset, tmp_path, capsys):
    """``--sensor`` and ``--exr`` of a scene of three cameras: every camera's PNG holds the
    sensor's raw codes of its noise-free EXR, one exposure for all (the brightest pixel of any
    view), each camera's noise its own; read back linear, as bright as the plain dataset's;
    the same command again does nothing."""
    from synth.rendering.sensor_model import PRESETS, expose, view_generator

    out = tmp_path / "noisy"
    command = ["dataset", scene, "--out", str(out), "--spp", str(SPP), "--sensor", "imx174",
               "--exr", "--no-progress"]
    assert main(command) == 0
    capsys.readouterr()
    manifest = json.loads((out / "manifest.json").read_text())
    sensor = PRESETS["imx174"]
    assert manifest["png_offset"] == sensor.dark_level_dn
    assert manifest["sensor"]["model"]["name"] == "imx174"
    assert sorted(manifest["view_files"]) == ["exr", "image", "preview"]
    radiance = [_read_exr(out / name / "image.exr") for name in ("cam0", "cam1", "cam2")]
    peak = max(float(image.max()) for image in radiance)
    assert manifest["sensor"]["peak"] == pytest.approx(peak, rel=1e-6)
    codes = []
    for k, name in enumerate(("cam0", "cam1", "cam2")):
        png = cv2.imread(str(out / name / "image.png"), cv2.IMREAD_UNCHANGED)
        expected, _ = expose(radiance[k], sensor, view_generator(load_scene(scene).seed, k), peak=peak)
        assert png.dtype == np.uint16 and np.array_equal(png, expected), name
        assert set(manifest["sensor"][name]) == {"saturated_pixels"}
        codes.append(png)
    assert not np.array_equal(codes[0], codes[1])  # each camera's own noise
    noisy, plain = read_dataset(out), read_dataset(dataset)
    for a, b in zip(noisy.images, plain.images):
        assert a.max() == pytest.approx(b.max(), rel=0.05)
    assert main(command) == 0
    assert "up to date" in capsys.readouterr().out


def _read_exr(path) -> np.ndarray:
    """A single-channel float32 EXR, ``(H, W)``, read with Mitsuba's Bitmap."""
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba(None)
    return np.array(mi.Bitmap(str(path)), dtype=np.float32).reshape(SIZE[1], SIZE[0])


@pytest.mark.slow
def test_eval_score_takes_points_of_a_dataset_of_three_cameras(dataset, tmp_path, capsys):
    """``eval score DIR --points`` of a dataset of three cameras: the truth moved by a known
    offset scores that offset (RMS dP = |offset|, every visible target associated); --pixels
    (pairs of two views) is refused in one line."""
    from eval.cli import main as eval_main

    data = read_dataset(dataset)
    offset = np.array([0.03, -0.04, 0.12])  # |offset| = 0.13 mm
    ply = tmp_path / "mine.ply"
    lines = ["ply", "format ascii 1.0", f"element vertex {len(data.targets)}",
             "property double x", "property double y", "property double z", "end_header"]
    lines += [" ".join(f"{v:.9f}" for v in p) for p in data.targets + offset]
    ply.write_text("\n".join(lines) + "\n")
    out = tmp_path / "score"
    assert eval_main(["score", str(dataset), "--points", str(ply), "--out", str(out),
                      "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["association"]["visible_in_both_scored"] == report["association"]["visible_in_both"]
    assert report["methods"]["theirs"]["rms_dp_mm"] == pytest.approx(0.13, abs=1e-6)
    assert "two or more views" in capsys.readouterr().out
    assert eval_main(["score", str(dataset), "--pixels", str(ply), "--out",
                      str(tmp_path / "x"), "--no-progress"]) == 2
    assert "dataset of N cameras" in _one_error(capsys)
