"""Eccentricity of disk targets through the port: the outline-centroid model and its correction."""

from __future__ import annotations

import numpy as np
import pytest

from measure import triangulate
from measure.images.eccentricity import (correct_eccentricity, local_normals,
                                  outline_centroid_offsets)
from measure.geometry.projection import project
from synth.scene.layouts import paper_plane
from synth.scene.rig import paper_rig

FACING = np.array([0.0, 0.0, -1.0])  # the paper's targets face the cameras


def _conic_centre(uv: np.ndarray) -> np.ndarray:
    """Centre of the conic a·x² + b·xy + c·y² + d·x + e·y = 1 through points (least squares,
    float64, coordinates relative to their mean)."""
    mean = uv.mean(axis=0)
    x, y = (uv - mean).T
    A = np.column_stack([x * x, x * y, y * y, x, y])
    a, b, c, d, e = np.linalg.lstsq(A, np.ones_like(x), rcond=None)[0]
    centre = np.linalg.solve([[2 * a, b], [b, 2 * c]], [-d, -e])
    return centre + mean


def test_fronto_parallel_disk_in_air_has_no_eccentricity():
    """A circle parallel to the image plane of a pinhole camera images to a circle centred on
    the image of its centre."""
    rig = paper_rig()
    points = np.array([[0.0, 0.0, 1000.0], [400.0, 300.0, 1000.0], [-560.0, 0.0, 1500.0]])
    offsets = outline_centroid_offsets(rig.left, None, points, FACING, 2.5)
    assert np.max(np.abs(offsets)) < 1e-9


def test_tilted_disk_in_air_matches_the_ellipse_centre():
    """Without a port a disk images to an exact ellipse: the polygon's area centroid must be the
    ellipse's centre (fitted independently as a conic through the projected outline)."""
    rig = paper_rig()
    normal = np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])
    points = np.array([[0.0, 0.0, 1000.0], [400.0, 300.0, 1000.0], [-560.0, 0.0, 1000.0]])
    offsets = outline_centroid_offsets(rig.left, None, points, normal, 40.0, n_points=512)
    from measure.images.eccentricity import disk_basis

    u, v = disk_basis(np.tile(normal, (3, 1)))
    angle = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    for i, centre in enumerate(points):
        outline = centre + 40.0 * (np.cos(angle)[:, None] * u[i] + np.sin(angle)[:, None] * v[i])
        expected = _conic_centre(project(rig.left, None, outline)) - project(rig.left, None, centre)[0]
        assert np.max(np.abs(offsets[i] - expected)) < 2e-5  # 512-gon vs exact ellipse
    assert np.max(np.abs(offsets)) > 0.3  # tilted 40 mm disks: a real offset


def test_offsets_through_the_port_converge_and_have_the_expected_size():
    rig = paper_rig()
    targets = paper_plane(1000.0)
    for camera in (rig.left, rig.right):
        coarse = outline_centroid_offsets(camera, rig.port, targets, FACING, 2.5)
        fine = outline_centroid_offsets(camera, rig.port, targets, FACING, 2.5, n_points=1024)
        assert np.max(np.abs(coarse - fine)) < 5e-6
        size = np.linalg.norm(fine, axis=1)
        assert 0.005 < size.max() < 0.02  # ~0.008 px (left) and ~0.010 px (right)
    # the offset grows with the radius squared
    r1 = outline_centroid_offsets(rig.right, rig.port, targets[-5:], FACING, 2.5)
    r2 = outline_centroid_offsets(rig.right, rig.port, targets[-5:], FACING, 5.0)
    assert np.allclose(r2, 4.0 * r1, rtol=0.02)


def test_local_normals_of_a_plane_face_the_cameras():
    normals = local_normals(paper_plane(1000.0), toward=(100.0, 0.0, 0.0))
    assert np.allclose(normals, FACING, atol=1e-9)


@pytest.mark.parametrize("radius", [2.5, 5.0])
def test_correction_removes_the_eccentricity_exactly(radius):
    """Detections that are the outline centroids of the true disks (the ideal detector): the
    uncorrected triangulation is off by the eccentricity, the corrected one is exact."""
    rig = paper_rig()
    truth = paper_plane(1000.0)
    uv = [project(c, rig.port, truth)
          + outline_centroid_offsets(c, rig.port, truth, FACING, radius) for c in rig.cameras]
    plain = triangulate(rig, uv[0], uv[1]).points - truth
    corrected = correct_eccentricity(rig, uv[0], uv[1], radius)
    error = corrected.triangulation.points - truth
    # the eccentricity costs ~0.003 mm RMS at 1 m for 2.5 mm disks (radius squared)
    assert np.sqrt(np.mean(np.sum(plain ** 2, axis=1))) > 0.002 * (radius / 2.5) ** 2
    assert np.max(np.linalg.norm(error, axis=1)) < 1e-5
    assert corrected.iterations == 2 and np.allclose(corrected.normals, FACING, atol=1e-6)


def test_correction_with_a_known_normal_and_bad_arguments():
    rig = paper_rig()
    truth = paper_plane(1000.0)[:40]
    uv = [project(c, rig.port, truth)
          + outline_centroid_offsets(c, rig.port, truth, FACING, 2.5) for c in rig.cameras]
    result = correct_eccentricity(rig, uv[0], uv[1], 2.5, normals=FACING, iterations=1)
    assert np.max(np.linalg.norm(result.triangulation.points - truth, axis=1)) < 1e-5
    with pytest.raises(ValueError, match="radius"):
        correct_eccentricity(rig, uv[0], uv[1], 0.0)
    with pytest.raises(ValueError, match="iterations"):
        correct_eccentricity(rig, uv[0], uv[1], 2.5, iterations=0)
    empty = correct_eccentricity(rig, np.zeros((0, 2)), np.zeros((0, 2)), 2.5)
    assert empty.triangulation.points.shape == (0, 3)


def test_the_ports_transmittance_pulls_the_centroid_inwards():
    """Behind a flat port the image of a disk is dimmer towards the edge of the field (Fresnel):
    its intensity centroid, integrated numerically over the disk (a 241 × 241 grid in the disk's
    plane, each node weighted by its image area — the Jacobian — and by the transmittance of
    its ray), against the offsets' first-order term ``C · ∇ln T``. Reference: the integral, and
    the Fresnel equations at normal incidence for the transmittance."""
    from measure.images.eccentricity import disk_basis

    rig = paper_rig()
    camera, port = rig.left, rig.view_port(0)
    centre = np.array([[650.0, 420.0, 1100.0]])
    normal = np.array([[np.sin(0.5), 0.0, -np.cos(0.5)]])
    radius = 10.0
    on_axis = port.transmittance(camera, np.array([camera.K[:2, 2]]))[0]
    n = port.indices
    expected = np.prod([1 - ((a - b) / (a + b)) ** 2 for a, b in zip(n[:-1], n[1:])])
    assert on_axis == pytest.approx(expected, rel=1e-9)
    u, v = disk_basis(normal)
    g = np.linspace(-radius, radius, 241)
    s, t = np.meshgrid(g, g)
    points = centre[0] + s[..., None] * u[0] + t[..., None] * v[0]
    uv = project(camera, port, points.reshape(-1, 3)).reshape(241, 241, 2)
    du, dv = np.gradient(uv, axis=1), np.gradient(uv, axis=0)
    area = np.abs(du[..., 0] * dv[..., 1] - du[..., 1] * dv[..., 0]) * (s ** 2 + t ** 2 <= radius ** 2)
    bright = area * port.transmittance(camera, uv.reshape(-1, 2)).reshape(241, 241)
    centre_px = project(camera, port, centre)[0]
    uniform = np.einsum("ij,ijk->k", area, uv) / area.sum() - centre_px
    dimmed = np.einsum("ij,ijk->k", bright, uv) / bright.sum() - centre_px
    offset = outline_centroid_offsets(camera, port, centre, normal, radius)[0]
    pull = dimmed - uniform
    assert np.linalg.norm(pull) > 1e-3  # 0.0024 px here, towards the image centre
    assert pull @ (centre_px - camera.K[:2, 2]) < 0
    np.testing.assert_allclose(offset, dimmed, atol=0.05 * np.linalg.norm(pull))
