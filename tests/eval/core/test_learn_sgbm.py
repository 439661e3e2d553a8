"""StereoSGBM three ways on sea scenes: the pinhole rectification's truth and triangulation
agree with each other where the cameras are pinholes (no port) and disagree by the water's index
behind a flat port; SGBM itself finds a known shift."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from eval.core import learn_sgbm
from measure import StereoRig
from measure.geometry.port import index_matched_port
from synth.products.truth_maps import MeshTracer
from synth.scene.sea_draw import SeaRanges, draw_scene
from synth.scene.surfaces import SurfaceMesh, write_ply


def _plane_tracer(tmp_path, distance):
    corners = np.array([[-1e4, -1e4, distance], [1e4, -1e4, distance], [-1e4, 1e4, distance],
                        [1e4, 1e4, distance]])
    triangles = np.array([[0, 2, 1], [1, 2, 3]])
    path = str(tmp_path / "plane.ply")
    write_ply(path, SurfaceMesh(corners, triangles, corners[:, :2], "plane"),
              corners[:, :2].min(axis=0), corners[:, :2].max(axis=0))
    return MeshTracer(path, corners, triangles)


def _item(tmp_path, port_kind, in_air):
    scene = draw_scene(5, SeaRanges(size=(160, 128), ports=(port_kind,)))
    rig = scene.rig
    if in_air:
        rig = StereoRig(rig.left, rig.right, index_matched_port(
            rig.left.R[:, 2], np.stack([rig.left.center, rig.right.center])))
    return SimpleNamespace(scene=SimpleNamespace(rig=rig), tracer=_plane_tracer(tmp_path, 1500.0))


def test_pinhole_truth_triangulates_onto_the_truth_in_air(tmp_path):
    """Without a port the pinhole rectification is exact: its truth disparities, triangulated
    by its own Q, are the truth points."""
    item = _item(tmp_path, "per-camera", in_air=True)
    rig = item.scene.rig
    rect = learn_sgbm.pinhole_rectification(rig.left, rig.right)
    truth, points = learn_sgbm.pinhole_truth(item, rect)
    assert np.isfinite(truth).mean() > 0.4
    predicted = learn_sgbm.pinhole_points(rect, truth)
    both = np.all(np.isfinite(predicted), axis=1) & np.all(np.isfinite(points), axis=1)
    assert np.max(np.linalg.norm(predicted[both] - points[both], axis=1)) < 1e-3


def test_behind_a_flat_port_the_pinhole_sees_the_floor_nearer(tmp_path):
    """Behind a flat port a pinhole pair ignoring it puts the plane nearer by about the water's
    index (apparent depth ≈ D + (z − D) / n)."""
    item = _item(tmp_path, "flat", in_air=False)
    rig = item.scene.rig
    rect = learn_sgbm.pinhole_rectification(rig.left, rig.right)
    truth, points = learn_sgbm.pinhole_truth(item, rect)
    predicted = learn_sgbm.pinhole_points(rect, truth)
    ratio = np.nanmedian(predicted[:, 2] / points[:, 2])
    n = rig.port.n_water
    assert 0.9 / n < ratio < 1.1 / n + 0.05


def test_sgbm_finds_a_known_shift():
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (200, 300)), (0, 0), 1.2)
    left = texture[:, 40:240].astype(np.uint8)
    right = texture[:, 52:252].astype(np.uint8)  # left pixel u is right pixel u - 12
    found = learn_sgbm.sgbm(left, right, np.full(left.shape, 12.0))
    assert np.nanmedian(found) == pytest.approx(12.0, abs=0.1)


def _spy_on_the_matcher(monkeypatch):
    """The (minDisparity, numDisparities) of every StereoSGBM made while the test runs."""
    made, create = [], cv2.StereoSGBM_create

    def recording(**kwargs):
        made.append((kwargs["minDisparity"], kwargs["numDisparities"]))
        return create(**kwargs)

    monkeypatch.setattr(cv2, "StereoSGBM_create", recording)
    return made


def test_sgbm_searches_a_wide_truth_around_its_median(monkeypatch):
    """A truth spanning more than MAX_DISPARITIES (a few far outliers) is searched over
    MAX_DISPARITIES around its median, and the shift most pixels have is still found (a search
    of the whole span would not fit the image: OpenCV fails on it)."""
    made = _spy_on_the_matcher(monkeypatch)
    rng = np.random.default_rng(1)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (80, 1000)), (0, 0), 1.2).astype(np.uint8)
    left, right = texture[:, :700], texture[:, 300:]  # left pixel u is right pixel u - 300
    truth = np.full(left.shape, 300.0)
    truth[0, :3] = [0.0, 900.0, 5.0]
    found = learn_sgbm.sgbm(left, right, truth)
    assert made == [(32, learn_sgbm.MAX_DISPARITIES)]
    assert np.nanmedian(found[:, 350:]) == pytest.approx(300.0, abs=0.1)


def test_sgbm_gives_nothing_where_no_search_fits(monkeypatch):
    """No truth, a truth beyond the image's width, or one entirely at negative disparities
    (both of which OpenCV cannot search): all NaN, and no matcher made."""
    made = _spy_on_the_matcher(monkeypatch)
    image = np.random.default_rng(2).integers(0, 255, (40, 200), dtype=np.uint8)
    for value in (np.nan, 300.0, -600.0):
        found = learn_sgbm.sgbm(image, image, np.full(image.shape, value))
        assert found.shape == image.shape and np.isnan(found).all()
    assert made == []
    found = learn_sgbm.sgbm(image, image, np.full(image.shape, -40.0))  # reaches 16: searched
    assert made == [(-64, 80)] and np.isfinite(found).any()
