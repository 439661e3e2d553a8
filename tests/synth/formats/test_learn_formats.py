"""The files learned tools read, against their formats' own definitions."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from measure import Camera
from synth.formats import learn_formats as lf
from synth.formats.exchange import read_pfm


def test_kitti_disparity_png_is_disparity_times_256(tmp_path):
    d = np.array([[0.0, 1.0 / 256, 57.3], [np.nan, -2.0, 255.99], [300.0, 12.5, 0.001]])
    path = str(tmp_path / "d.png")
    beyond = lf.write_kitti_disparity(path, d)
    codes = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    assert codes.dtype == np.uint16 and beyond == 1
    # KITTI's devkit: disparity = png / 256, valid = png > 0
    np.testing.assert_array_equal(codes, [[0, 1, round(57.3 * 256)], [0, 0, round(255.99 * 256)],
                                          [0, 3200, 0]])
    back = lf.read_kitti_disparity(path)
    assert back[0, 2] == pytest.approx(57.3, abs=1 / 512) and np.isnan(back[1, 0])


def test_sceneflow_pfm_has_zero_where_no_truth(tmp_path):
    path = str(tmp_path / "d.pfm")
    lf.write_sceneflow_disparity(path, np.array([[1.5, np.nan], [-1.0, 3.25]]))
    np.testing.assert_array_equal(read_pfm(path), [[1.5, 0.0], [0.0, 3.25]])
    with open(path, "rb") as handle:  # SceneFlow's header: Pf, width height, negative scale
        assert handle.read(12) == b"Pf\n2 2\n-1.0\n"


def _colmap_read_array(path):
    """COLMAP's own reader (scripts/python/read_write_dense.py), transcribed."""
    with open(path, "rb") as fid:
        width, height, channels = np.genfromtxt(fid, delimiter="&", max_rows=1,
                                                usecols=(0, 1, 2), dtype=int)
        fid.seek(0)
        num_delimiter, byte = 0, fid.read(1)
        while True:
            if byte == b"&":
                num_delimiter += 1
                if num_delimiter >= 3:
                    break
            byte = fid.read(1)
        array = np.fromfile(fid, np.float32)
    array = array.reshape((width, height, channels), order="F")
    return np.transpose(array, (1, 0, 2)).squeeze()


def test_colmap_depth_map_reads_with_colmaps_reader(tmp_path):
    depth = np.arange(12, dtype=float).reshape(3, 4) * 100.0 + 500.0
    depth[1, 2] = np.nan
    path = str(tmp_path / "left.png.geometric.bin")
    lf.write_colmap_depth(path, depth)
    expected = np.where(np.isfinite(depth), depth / 1000.0, 0.0)
    np.testing.assert_allclose(_colmap_read_array(path), expected, rtol=1e-7)
    np.testing.assert_allclose(lf.read_colmap_depth(path), expected, rtol=1e-7)


def test_pinhole_colmap_model_uses_colmaps_pixel_convention(tmp_path):
    K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    cameras = (Camera(K, (640, 480)), Camera(K, (640, 480), t=(100.0, 0, 0)))
    points = np.array([[10.0, -20.0, 1000.0]])
    pixels = np.stack([c.project(points) for c in cameras], axis=1)
    lf.write_pinhole_colmap(str(tmp_path), cameras, ("a.png", "b.png"), points, pixels)
    line = (tmp_path / "cameras.txt").read_text().splitlines()[2].split()
    assert line[:4] == ["1", "PINHOLE", "640", "480"]
    assert [float(v) for v in line[4:]] == [500.0, 500.0, 320.0, 240.0]
    images = (tmp_path / "images.txt").read_text().splitlines()
    pose = images[5].split()
    assert [float(v) for v in pose[5:8]] == pytest.approx([-0.1, 0.0, 0.0])  # world to camera
    u, v, pid = images[6].split()
    assert float(u) == pytest.approx(pixels[0, 1, 0] + 0.5) and pid == "1"


def test_photo_is_srgb_encoded_and_fireflies_go():
    linear = np.array([[0.0, 0.5, 1.0, 2.0]])
    np.testing.assert_array_equal(lf.photo_8bit(linear, 1.0), [[0, 188, 255, 255]])
    ramp = np.tile(np.linspace(0.2, 0.4, 20, dtype=np.float32), (20, 1))
    hot = ramp.copy()
    hot[10, 10] = 50.0
    cleaned = lf.remove_fireflies(hot)
    assert cleaned[10, 10] < 0.5 and np.array_equal(cleaned[ramp == hot], ramp[ramp == hot])
    assert lf.exposure(np.full((10, 10), 0.25)) == pytest.approx(lf.WHITE_LEVEL / 0.25)
