"""Datasets: files readable with plain OpenCV / Open3D / csv, atomic writes, reruns, check."""

from __future__ import annotations

import csv
import json
import os

import cv2
import numpy as np
import pytest

from synth.products.crosscheck import check_dataset
from synth.__main__ import main
from synth.formats.pixels_csv import PIXELS_HEADER
from synth.products.dataset import read_dataset, read_manifest, write_dataset
from synth.formats.calib_formats import stereo_extrinsics
from measure.geometry.projection import project
from synth.scene import load_scene

from tests.conftest import SMALL_SCENE_SIZE as SMALL
from tests.conftest import SMALL_SCENE_SPP as SPP


@pytest.fixture(scope="module")
def dataset_dir(small_scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "ds"
    manifest = write_dataset(small_scene, out, progress=False)
    assert manifest["skipped"] is False
    return out


@pytest.mark.slow
def test_files_are_readable_with_plain_libraries(small_scene, dataset_dir):
    spec = load_scene(small_scene)
    names = {"left.png", "right.png", "left_preview.png", "right_preview.png", "calib.yaml",
             "targets.ply", "pixels.csv", "manifest.json"}
    assert names <= set(os.listdir(dataset_dir))
    for view in ("left", "right"):
        img = cv2.imread(str(dataset_dir / f"{view}.png"), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint16 and img.shape == (SMALL[1], SMALL[0])
        prev = cv2.imread(str(dataset_dir / f"{view}_preview.png"), cv2.IMREAD_UNCHANGED)
        assert prev.dtype == np.uint8 and prev.shape == img.shape
    both = [cv2.imread(str(dataset_dir / f"{v}.png"), cv2.IMREAD_UNCHANGED) for v in ("left", "right")]
    assert max(int(i.max()) for i in both) == 65535  # brightest pixel at full scale, no clipping

    fs = cv2.FileStorage(str(dataset_dir / "calib.yaml"), cv2.FILE_STORAGE_READ)
    assert int(fs.getNode("image_width").real()) == SMALL[0]
    assert int(fs.getNode("image_height").real()) == SMALL[1]
    np.testing.assert_allclose(fs.getNode("K1").mat(), spec.rig.left.K)
    np.testing.assert_allclose(fs.getNode("K2").mat(), spec.rig.right.K)
    assert fs.getNode("D1").mat().size == 5 and not np.any(fs.getNode("D2").mat())
    R, T = fs.getNode("R").mat(), fs.getNode("T").mat().ravel()
    X_left = np.array([[10.0, -20.0, 900.0]])
    X_right = spec.rig.right.to_camera(X_left)  # left frame = reference frame
    np.testing.assert_allclose(X_left @ R.T + T, X_right, atol=1e-9)
    np.testing.assert_allclose(T, [-199.2389, 0.0, 17.4311], atol=1e-3)  # R_r^T (t_l - t_r)
    port = fs.getNode("port")
    np.testing.assert_allclose(port.getNode("normal").mat().ravel(), [0, 0, 1])
    assert port.getNode("distance").real() == 100.0
    th = port.getNode("thicknesses")
    assert [th.at(i).real() for i in range(th.size())] == [5.0]
    ind = port.getNode("indices")
    assert [ind.at(i).real() for i in range(ind.size())] == [1.0, 1.54, 1.33]
    fs.release()

    import open3d as o3d
    cloud = o3d.io.read_point_cloud(str(dataset_dir / "targets.ply"))
    np.testing.assert_allclose(np.asarray(cloud.points), spec.targets, atol=1e-9)

    with open(dataset_dir / "pixels.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == PIXELS_HEADER
    table = np.array(rows[1:], dtype=float)
    assert table.shape == (spec.targets.shape[0], 8)
    np.testing.assert_array_equal(table[:, 0], spec.target_ids)
    np.testing.assert_allclose(table[:, 4:6], project(spec.rig.left, spec.rig.port, spec.targets),
                               atol=1e-9)

    manifest = json.loads((dataset_dir / "manifest.json").read_text())
    assert manifest["scene"]["sha256"] == spec.sha256 and manifest["spp"] == SPP
    assert manifest["variant"] in ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
    assert {"mitsuba", "drjit", "numpy"} <= set(manifest["versions"])
    assert {"render_left", "render_right", "write_images", "total"} <= set(manifest["seconds"])


@pytest.mark.slow
def test_read_dataset_round_trip(small_scene, dataset_dir):
    spec = load_scene(small_scene)
    data = read_dataset(dataset_dir)
    R, T = stereo_extrinsics(spec.rig.left, spec.rig.right)
    np.testing.assert_allclose(data.rig.right.R, spec.rig.right.R, atol=1e-12)
    np.testing.assert_allclose(data.rig.right.t, spec.rig.right.t, atol=1e-9)
    assert data.rig.port.indices == spec.rig.port.indices and data.has_port
    assert data.left.dtype == np.float32 and data.left.shape == (SMALL[1], SMALL[0])
    for view, img in (("left", data.left), ("right", data.right)):  # linear units restored
        assert img.max() == pytest.approx(data.manifest["images"][view]["max"], rel=1e-4)
    np.testing.assert_allclose(data.targets, spec.targets, atol=1e-9)
    np.testing.assert_allclose(data.pixels_right,
                               project(spec.rig.right, spec.rig.port, spec.targets), atol=1e-9)


@pytest.mark.slow
def test_check_finds_every_target_within_the_bounds(dataset_dir):
    report = check_dataset(dataset_dir)
    for view in ("left", "right"):
        assert report[view]["in_image"] > 40
        assert report[view]["found"] == report[view]["in_image"], report[view]
    assert report["rms_px"] <= 0.05 and report["max_px"] <= 0.15, report
    assert report["passed"]


@pytest.mark.slow
def test_rerun_is_a_no_op_and_other_arguments_replace(small_scene, dataset_dir, tmp_path):
    before = {n: os.stat(dataset_dir / n).st_mtime_ns for n in os.listdir(dataset_dir)}
    again = write_dataset(small_scene, dataset_dir, progress=False)
    assert again["skipped"] is True
    assert {n: os.stat(dataset_dir / n).st_mtime_ns for n in os.listdir(dataset_dir)} == before

    out = tmp_path / "ds2"
    first = write_dataset(small_scene, out, spp=4, progress=False)
    second = write_dataset(small_scene, out, spp=9, progress=False)  # another request: replaced
    assert not second["skipped"] and second["request_key"] != first["request_key"]
    assert json.loads((out / "manifest.json").read_text())["spp"] == 9
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds2"]  # no temporary left behind


@pytest.mark.slow
def test_manifest_says_how_it_was_rendered_and_full_film_keeps_the_old_key(small_scene,
                                                                           tmp_path):
    """An adaptive dataset's manifest states, per view, the lit fraction and the samples on and
    off the mask; ``--full-film`` is another request, whose key is the key every dataset had
    before adaptive rendering (a manifest without ``render`` is read as a full-film one, so
    earlier datasets stay readable)."""
    import copy

    from synth.products.dataset import manifest_request_key

    assert main(["dataset", small_scene, "--out", str(tmp_path / "a"), "--quiet",
                 "--spp", "4"]) == 0
    assert main(["dataset", small_scene, "--out", str(tmp_path / "f"), "--quiet",
                 "--spp", "4", "--full-film"]) == 0
    a, f = (read_manifest(tmp_path / name) for name in ("a", "f"))
    assert a["render"]["settings"]["mode"] == "adaptive" and f["render"]["settings"] is None
    left = a["render"]["left"]
    assert left["mode"] == "adaptive" and 0 < left["lit_fraction"] < 0.5
    assert left["samples_on_mask"] == 4 * left["mask_pixels"]
    assert left["samples_off_mask"] == SMALL[0] * SMALL[1] - left["mask_pixels"]
    assert a["passes"]["left"] == [1, 4] and len(a["seeds"]["left"]) == 2
    assert f["render"]["left"]["mode"] == "full film" and f["passes"]["left"] == [4]
    assert a["request_key"] != f["request_key"]
    old = copy.deepcopy(f)
    del old["render"]  # as written before adaptive rendering
    assert manifest_request_key(old) == f["request_key"]
    edited = copy.deepcopy(a)
    edited["render"]["settings"]["margin_px"] = 5
    assert manifest_request_key(edited) != a["request_key"]


@pytest.mark.slow
def test_spp_option_and_define_mean_the_same(small_scene, tmp_path):
    """``--spp 4`` and ``-D spp=4`` are one request, and the manifest's scene parameters record
    what was rendered (issue 22: they held the scene's default, 36)."""
    for name, extra in (("option", ["--spp", "4"]), ("define", ["-D", "spp=4"])):
        assert main(["dataset", small_scene, "--out", str(tmp_path / name), "--quiet",
                     *extra]) == 0
    a, b = (read_manifest(tmp_path / name) for name in ("option", "define"))
    assert a["scene"]["params"]["spp"] == "4" and a["spp"] == 4
    assert a["request_key"] == b["request_key"]
    assert (tmp_path / "option" / "left.png").read_bytes() == (tmp_path / "define" / "left.png").read_bytes()


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["delete", "truncate", "change"])
def test_a_rerun_renders_again_unless_every_file_is_whole(small_scene, tmp_path, capsys, damage):
    """A dataset is up to date only when every file it wrote is whole (issue 22: with
    left.png deleted or cut the rerun said 'up to date … nothing to do')."""
    out = tmp_path / "ds"
    argv = ["dataset", small_scene, "--out", str(out), "--spp", "4", "--quiet"]
    assert main(argv) == 0
    whole = (out / "left.png").read_bytes()
    if damage == "delete":
        (out / "left.png").unlink()
    elif damage == "truncate":
        (out / "left.png").write_bytes(whole[:len(whole) // 2])
    else:
        (out / "pixels.csv").write_text((out / "pixels.csv").read_text().replace("1", "2"))
    capsys.readouterr()
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "nothing to do" not in printed and "rendering it again" in printed, printed
    assert (out / "left.png").read_bytes() == whole
    assert main(argv) == 0 and "nothing to do" in capsys.readouterr().out


def test_failed_write_leaves_nothing(small_scene, tmp_path, monkeypatch):
    import synth.products.dataset as ds

    def boom(*args, **kwargs):
        raise RuntimeError("render failed")

    monkeypatch.setattr(ds, "render_views", boom)
    with pytest.raises(RuntimeError):
        write_dataset(small_scene, tmp_path / "ds", progress=False)
    assert list(tmp_path.iterdir()) == []


def test_refuses_to_replace_a_foreign_directory(small_scene, tmp_path):
    from synth.infra.fileio import OutputError

    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    with pytest.raises(OutputError, match="holds files this command did not write"):
        write_dataset(small_scene, tmp_path / "mine", progress=False)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]


@pytest.mark.slow
def test_refuses_an_earlier_dataset_that_someone_added_a_file_to(small_scene, tmp_path):
    from synth.infra.fileio import OutputError

    out = tmp_path / "ds"
    write_dataset(small_scene, out, spp=4, progress=False)
    (out / "notes.txt").write_text("keep me")
    with pytest.raises(OutputError, match="did not write"):
        write_dataset(small_scene, out, spp=9, progress=False)
    assert (out / "notes.txt").read_text() == "keep me"
    assert json.loads((out / "manifest.json").read_text())["spp"] == 4


@pytest.mark.slow
def test_cli_dataset_and_check(small_scene, tmp_path, capsys):
    from synth.__main__ import main

    out = tmp_path / "cli"
    argv = ["dataset", small_scene, "--out", str(out), "--spp", "16", "--quiet", "--exr",
            "-D", "n_water=1.34"]
    assert main(argv) == 0
    assert "spp" in capsys.readouterr().out
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["scene"]["params"]["n_water"] == "1.34" and manifest["spp"] == 16
    exr = cv2.imread(str(out / "left.exr"), cv2.IMREAD_UNCHANGED) if os.environ.get(
        "OPENCV_IO_ENABLE_OPENEXR") else None
    assert (out / "left.exr").stat().st_size > 0 and (exr is None or exr.dtype == np.float32)
    assert main(argv) == 0 and "nothing to do" in capsys.readouterr().out
    code = main(["check", str(out)])
    text = capsys.readouterr().out
    assert code in (0, 1) and "left :" in text and "right:" in text


def test_targets_ply_keeps_every_bit(tmp_path):
    """The truth is stored exactly (Open3D's ASCII PLY would keep 6 significant digits)."""
    from synth.products.dataset import write_targets_ply

    points = np.random.default_rng(3).uniform(-700, 2000, (50, 3))
    write_targets_ply(tmp_path / "t.ply", points)
    import open3d as o3d
    assert np.array_equal(np.asarray(o3d.io.read_point_cloud(str(tmp_path / "t.ply")).points),
                          points)


def test_pixels_csv_with_a_byte_order_mark_is_read(tmp_path):
    """A pixels.csv saved by Excel ("CSV UTF-8") starts with a byte-order mark: same values."""
    from synth.formats.pixels_csv import read_pixels_csv, write_pixels_csv

    plain = tmp_path / "pixels.csv"
    write_pixels_csv(plain, [0, 1], [[1.0, 2.0, 3.0], [4.0, 5.0, 6.5]], [[10.0, 11.0], [12, 13]],
                     [[20.0, 21.0], [22, 23]])
    with_bom = tmp_path / "bom.csv"
    with_bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    ours, theirs = read_pixels_csv(plain), read_pixels_csv(with_bom)
    for key in ("id", "points", "left", "right"):
        np.testing.assert_array_equal(theirs[key], ours[key])


def _calib_text(tmp_path):
    """A calib.yaml of the small rig behind the paper's port, as text."""
    from measure import StereoRig
    from synth.products.dataset import write_calib
    from synth.scene.rig import paper_cameras, paper_port

    path = tmp_path / "calib.yaml"
    write_calib(path, StereoRig(*paper_cameras((320, 268), 150.0), paper_port()))
    return path, path.read_text()


def test_port_present_0_means_in_air_and_other_values_are_refused(tmp_path):
    """``present: 0`` with a real port's indices: read as in air (it was reported in air and
    measured through the port); ``present: 2`` or ``yes``: one error naming the file and the
    field."""
    from measure import triangulate
    from synth.products.dataset import DatasetError, read_calib

    path, text = _calib_text(tmp_path)
    assert "present: 1" in text
    through_port = read_calib(path)
    assert through_port["has_port"] and max(through_port["port"].indices) > 1.3
    path.write_text(text.replace("present: 1", "present: 0"))
    air = read_calib(path)
    assert air["has_port"] is False and set(air["port"].indices) == {1.0}
    # the points are measured in air: a pixel pair triangulates as without the port
    from measure import StereoRig

    no_port = StereoRig(air["rig"].left, air["rig"].right, None)
    uv_l, uv_r = np.array([[180.0, 130.0]]), np.array([[120.0, 130.0]])
    np.testing.assert_allclose(triangulate(air["rig"], uv_l, uv_r).points,
                               triangulate(no_port, uv_l, uv_r).points, rtol=1e-9)
    for bad in ("2", "0.5", "-1", "yes"):
        path.write_text(text.replace("present: 1", f"present: {bad}"))
        with pytest.raises(DatasetError, match=rf"calib.yaml: port: present: {bad}: must be 0"):
            read_calib(path)


@pytest.mark.parametrize("units", ["m", "inches", "cm", "1"])
def test_units_other_than_mm_are_refused(tmp_path, units):
    """``units:`` was written and never read: ``units: m`` measured as mm."""
    from synth.products.dataset import DatasetError, read_calib

    path, text = _calib_text(tmp_path)
    assert 'units: mm' in text
    path.write_text(text.replace("units: mm", f"units: {units}"))
    with pytest.raises(DatasetError, match="calib.yaml: units: .*only mm is read"):
        read_calib(path)
    path.write_text(text.replace("units: mm\n", ""))  # no units: mm, as before
    assert read_calib(path)["has_port"]
