"""Point-cloud files are read whole or refused (synth.formats.cloudfile): each format's header against
the file's size or lines."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from synth.formats.cloudfile import CloudFileError, expected_points, read_cloud_points

POINTS = np.array([[1.5, -2.0, 1000.0], [3.0, 4.0, 1001.0], [-5.0, 6.0, 999.0]])


def _write(path, ascii=False):
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(POINTS))
    assert o3d.io.write_point_cloud(str(path), cloud, write_ascii=ascii)
    return path


def _cut(path, keep):
    data = path.read_bytes()
    path.write_bytes(data[:keep] if keep >= 0 else data[:len(data) + keep])


@pytest.mark.parametrize("name, ascii", [("a.ply", False), ("b.ply", True), ("c.pcd", False),
                                         ("d.xyz", True)])
def test_whole_files_are_read(tmp_path, name, ascii):
    path = _write(tmp_path / name, ascii)
    assert expected_points(path) == 3
    np.testing.assert_allclose(read_cloud_points(path), POINTS, rtol=1e-6)


@pytest.mark.parametrize("name, ascii, cut, fragment", [
    ("a.ply", False, -1, "truncated: the header promises 3 vertex"),
    ("a.ply", False, -24, "truncated"),
    ("b.ply", True, -12, "truncated"),
    ("c.pcd", False, -4, "truncated"),
    ("d.xyz", True, -20, "line 3 has"),
    ("e.ply", False, 20, "no complete header"),
])
def test_truncated_files_are_refused(tmp_path, name, ascii, cut, fragment):
    path = _write(tmp_path / name, ascii)
    _cut(path, cut)
    with pytest.raises(CloudFileError, match=fragment):
        read_cloud_points(path)


def test_a_file_longer_than_its_header_is_refused(tmp_path):
    path = _write(tmp_path / "a.ply")
    path.write_bytes(path.read_bytes() + b"\0" * 8)
    with pytest.raises(CloudFileError, match="longer than its header says"):
        expected_points(path)


def test_ascii_rows_with_a_value_missing_are_refused(tmp_path):
    path = tmp_path / "a.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty double x\n"
                    "property double y\nproperty double z\nend_header\n1 2 3\n4 5\n")
    with pytest.raises(CloudFileError, match="vertex 1 has 2 values"):
        expected_points(path)
