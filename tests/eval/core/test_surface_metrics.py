"""Scoring of dense surface reconstructions (eval.core.surface_metrics, eval.run.dense_figures) on small
synthetic arrays with known answers: planes, a tessellated cylinder, noise of known sigma."""

from __future__ import annotations

import json
import os

import numpy as np
import open3d as o3d
import pytest
from matplotlib import image as mpimg

from eval.run.dense_figures import write_colored_cloud, write_distance_histogram, write_error_map
from eval.core.surface_metrics import (SurfaceCase, fit_plane, mesh_is_planar, score_surface,
                                  surface_arrays, surface_table)
from synth.infra.fileio import jsonable

from tests.conftest import rotation

Z0 = 1000.0  # mm: the surfaces sit 1 m in front of the left camera
# Float64 arithmetic on coordinates of ~1000 mm: one ulp is 1.1e-13 mm, and the per-pixel
# quantities are a handful of operations, so 1e-11 mm is ~100 ulps of margin and still far
# below any effect a test looks for.
F64_TOL_MM = 1e-11
# Point-to-mesh distances are float64 (RaycastingScene only proposes the triangle). The module
# returns one float64 ulp of the largest centred coordinate as distance_resolution_mm; the
# centring and the closest-point arithmetic (a dozen operations, products of two coordinates)
# stay within 64 ulps.
def p2m_tol(scores: dict) -> float:
    return 64 * scores["distance_resolution_mm"]


def plane_mesh(centre, basis, half: float = 300.0):
    """A square of two triangles, side 2·half mm, centred at ``centre``, spanned by the first two
    columns of the rotation ``basis`` (its third column is the normal)."""
    e1, e2 = basis[:, 0], basis[:, 1]
    corners = np.array([centre + half * (sx * e1 + sy * e2) for sx, sy in
                        ((-1, -1), (1, -1), (-1, 1), (1, 1))])
    return corners, np.array([[0, 1, 2], [1, 3, 2]])


def plane_grid(centre, basis, shape=(40, 60), spacing: float = 2.0) -> np.ndarray:
    """``(H, W, 3)`` points on the plane, ``spacing`` mm apart, pixel (u, v) ↦ centre + …"""
    rows, cols = shape
    v, u = np.mgrid[0:rows, 0:cols]
    a = (u - (cols - 1) / 2) * spacing
    b = (v - (rows - 1) / 2) * spacing
    return centre + a[..., None] * basis[:, 0] + b[..., None] * basis[:, 1]


def case(vertices, triangles, measured, truth, overlap=None, normal=(0.0, 0.0, 1.0)):
    overlap = np.ones(truth.shape[:2], bool) if overlap is None else overlap
    return SurfaceCase(vertices, triangles, measured, truth, overlap, np.asarray(normal))


CENTRE = np.array([5.0, -3.0, Z0])
FRONTAL = np.eye(3)  # plane z = 1000, normal +z (into the water)
TILTED = rotation(np.radians(25.0), np.radians(-10.0), 0.0)


def test_constant_offset_along_the_normal():
    truth = plane_grid(CENTRE, FRONTAL)
    scores = score_surface(case(*plane_mesh(CENTRE, FRONTAL), truth + [0, 0, 0.2], truth))
    tol = p2m_tol(scores)
    # centred on the mesh: the largest coordinate is the 300 mm half-side, not the 1000 mm depth
    assert scores["distance_resolution_mm"] == np.spacing(300.0)
    for key in ("p2m_rms_mm", "p2m_mean_mm", "p2m_median_mm", "p2m_p95_mm", "p2m_max_mm",
                "p2m_signed_mean_mm", "mean_measured_to_mesh_mm"):
        assert scores[key] == pytest.approx(0.2, abs=tol), key  # + : beyond the surface
    # every truth point's nearest measured point is its own pixel's (spacing 2 mm >> 0.2 mm)
    assert scores["mean_truth_to_measured_mm"] == pytest.approx(0.2, abs=F64_TOL_MM)
    assert scores["chamfer_mm"] == pytest.approx(0.2, abs=tol)  # the average of the two
    for tau in ("0.5", "1", "5"):
        assert scores[f"precision_{tau}mm"] == scores[f"recall_{tau}mm"] == 1.0
        assert scores[f"fscore_{tau}mm"] == 1.0
    assert scores["p2m_count"] == scores["measured_pixels"] == scores["overlap_pixels"] == 2400
    assert scores["measured_fraction"] == 1.0 and scores["measured_outside_overlap"] == 0
    assert scores["depth_rms_mm"] == pytest.approx(0.2, abs=F64_TOL_MM)
    assert scores["depth_max_abs_mm"] == pytest.approx(0.2, abs=F64_TOL_MM)
    assert scores["lateral_rms_mm"] < 1e-6  # sqrt of a float64 cancellation: sqrt(1e-13)
    assert scores["planar"] and scores["flatness_rms_mm"] < F64_TOL_MM
    assert scores["normal_angle_deg"] < 1e-9
    # 0.7 mm: outside τ = 0.5, inside τ = 1 (both far from 0.7 compared with float64 rounding)
    far = score_surface(case(*plane_mesh(CENTRE, FRONTAL), truth + [0, 0, -0.7], truth))
    assert far["precision_0.5mm"] == far["recall_0.5mm"] == far["fscore_0.5mm"] == 0.0
    assert far["precision_1mm"] == far["recall_1mm"] == 1.0
    assert far["p2m_signed_mean_mm"] == pytest.approx(-0.7, abs=p2m_tol(far))  # in front
    json.dumps(jsonable(scores), allow_nan=False)
    assert all(isinstance(v, (int, float, bool)) for v in scores.values())


def test_depth_error_map_is_the_injected_offset():
    """Per-pixel offsets along a port normal tilted 6° from z, with holes in both maps."""
    truth = plane_grid(CENTRE, TILTED)
    vertices, triangles = plane_mesh(CENTRE, TILTED)
    port_normal = rotation(np.radians(6.0), 0.0, 0.0)[:, 2]
    offset = np.random.default_rng(1).uniform(-1.0, 1.0, truth.shape[:2])
    measured = truth + offset[..., None] * port_normal
    measured[3:7, 10:20] = np.nan
    truth = truth.copy()
    truth[30:, :5] = np.nan
    arrays = surface_arrays(case(vertices, triangles, measured, truth, normal=3 * port_normal))
    missing = np.isnan(measured[..., 0]) | np.isnan(truth[..., 0])
    assert np.array_equal(np.isnan(arrays["depth_error"]), missing)
    np.testing.assert_allclose(arrays["depth_error"][~missing], offset[~missing], rtol=0,
                               atol=F64_TOL_MM)
    np.testing.assert_allclose(arrays["error_3d"][~missing], np.abs(offset[~missing]), rtol=0,
                               atol=F64_TOL_MM)
    # the point-to-mesh distance is the offset's component along the surface normal
    expected = np.abs(offset * (port_normal @ TILTED[:, 2]))[~np.isnan(measured[..., 0])]
    scores = score_surface(case(vertices, triangles, measured, truth, normal=port_normal))
    np.testing.assert_allclose(arrays["distance"], expected, rtol=0, atol=p2m_tol(scores))


def test_gaussian_noise_statistics():
    """Noise N(0, σ²) along the normal of a tilted plane, n = 10,000 points (seeded). For the
    bounds, 5 standard errors of each estimator: RMS, sd σ/√(2n) (χ² with n dof); median of
    |e| (0.6745σ), sd √(1/4n)/f with f = 2φ(0.6745)/σ the density of |e| there; precision at
    0.5 mm, p = 2Φ(0.5/σ) − 1, binomial sd √(p(1−p)/n)."""
    sigma, n = 0.3, 100 * 100
    truth = plane_grid(CENTRE, TILTED, shape=(100, 100), spacing=3.0)
    noise = np.random.default_rng(7).normal(0.0, sigma, truth.shape[:2])
    measured = truth + noise[..., None] * TILTED[:, 2]
    scores = score_surface(case(*plane_mesh(CENTRE, TILTED), measured, truth))
    assert abs(scores["p2m_rms_mm"] - sigma) < 5 * sigma / np.sqrt(2 * n)
    density = 2 * np.exp(-0.6745 ** 2 / 2) / np.sqrt(2 * np.pi) / sigma
    assert abs(scores["p2m_median_mm"] - 0.6745 * sigma) < 5 * np.sqrt(0.25 / n) / density
    from scipy.stats import norm

    p = 2 * norm.cdf(0.5 / sigma) - 1
    assert abs(scores["precision_0.5mm"] - p) < 5 * np.sqrt(p * (1 - p) / n)
    # the signed mean is the noise mean: sd σ/√n
    assert abs(scores["p2m_signed_mean_mm"]) < 5 * sigma / np.sqrt(n)
    # flatness: the least-squares plane absorbs 3 of n dof, so the same RMS bound holds
    assert abs(scores["flatness_rms_mm"] - sigma) < 5 * sigma / np.sqrt(2 * n)
    # depth is measured along z, the noise along the plane normal: depth = e · cos(tilt)
    cos_tilt = TILTED[2, 2]
    assert scores["depth_rms_mm"] == pytest.approx(np.sqrt(np.mean((noise * cos_tilt) ** 2)),
                                                   abs=F64_TOL_MM)


def test_cylinder_distance_is_the_chord_error():
    """Points on a true cylinder (R 150 mm, axis along y through (0, 0, 1 m)) against its
    90-facet tessellation: the distance to the facet of angles [θk, θk+Δ] is
    R (cos(φ − θmid) − cos(Δ/2)), 0 at the vertices, the sagitta R (1 − cos(Δ/2)) mid-facet.
    Points face the camera, outside the facets, so they are in front: signed < 0."""
    radius, facets = 150.0, 90
    step = 2 * np.pi / facets
    theta = np.arange(facets) * step
    ring = np.column_stack([radius * np.sin(theta), np.zeros(facets), Z0 - radius * np.cos(theta)])
    vertices = np.vstack([ring + [0, -100, 0], ring + [0, 100, 0]])
    k, k1 = np.arange(facets), (np.arange(facets) + 1) % facets
    triangles = np.vstack([np.column_stack([k, facets + k, k1]),
                           np.column_stack([facets + k, facets + k1, k1])])
    phi = np.radians(np.linspace(-70.0, 70.0, 141))  # every 1°: on vertices and mid-facets
    y = np.linspace(-80.0, 80.0, 9)
    phi_grid, y_grid = np.meshgrid(phi, y)
    truth = np.stack([radius * np.sin(phi_grid), y_grid, Z0 - radius * np.cos(phi_grid)], -1)
    arrays = surface_arrays(case(vertices, triangles, truth, truth))
    mid = (np.floor(phi_grid / step) + 0.5) * step
    expected = (radius * (np.cos(phi_grid - mid) - np.cos(step / 2))).ravel()
    scores = score_surface(case(vertices, triangles, truth, truth), arrays=arrays)
    tol = p2m_tol(scores)
    np.testing.assert_allclose(arrays["distance"], expected, rtol=0, atol=tol)
    np.testing.assert_allclose(arrays["signed_distance"], -expected, rtol=0, atol=tol)
    assert scores["p2m_max_mm"] == pytest.approx(radius * (1 - np.cos(step / 2)), abs=tol)
    assert not scores["planar"] and "flatness_rms_mm" not in scores
    assert not mesh_is_planar(vertices)
    assert scores["depth_rms_mm"] == 0.0 and scores["recall_0.5mm"] == 1.0
    forced = score_surface(case(vertices, triangles, truth, truth), plane=True, arrays=arrays)
    assert forced["planar"] and forced["flatness_rms_mm"] > 1.0  # a bent surface is not flat


def test_points_on_a_strip_of_sliver_triangles_are_on_it():
    """The committed cylinder's mesh is a strip of 1600 × 5.6 mm triangles. Points built on it
    in float64 (barycentric combinations of a triangle's corners) are at distance 0, and points
    moved 0.3 mm along their triangle's normal towards the camera are 0.3 mm in front. Open3D's
    float32 closest-point search alone puts the foot on the other triangle of the quad, up to
    ~1 mm away; the exact descent must not."""
    from synth.scene.surfaces import cylinder
    mesh = cylinder()
    vertices, triangles = mesh.vertices, mesh.triangles
    corners = vertices[triangles]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    assert edges.max() / edges.min() > 200  # slivers indeed
    rng = np.random.default_rng(7)
    which = rng.integers(0, len(triangles), 4000)
    weights = rng.dirichlet((1.0, 1.0, 1.0), len(which))
    on = np.einsum("nk,nkj->nj", weights, corners[which])
    normal = np.cross(corners[which, 1] - corners[which, 0], corners[which, 2] - corners[which, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    normal *= np.sign(np.einsum("ij,ij->i", normal, on))[:, None]  # away from the camera
    front = on - 0.3 * normal  # the front of a convex surface: the foot stays on its triangle
    points = np.concatenate([on, front]).reshape(2, -1, 3)  # an (H, W, 3) grid, row-major
    arrays = surface_arrays(case(vertices, triangles, points, points))
    tol = 64 * arrays["resolution_mm"]
    assert tol < 1e-9
    np.testing.assert_allclose(arrays["distance"][:len(on)], 0.0, rtol=0, atol=tol)
    np.testing.assert_allclose(arrays["signed_distance"][len(on):], -0.3, rtol=0, atol=tol)


def test_recall_with_half_of_the_overlap_missing():
    """Every other column missing, 2 mm apart: each missing truth point is 2 mm from the
    nearest measured one, so recall is 1/2 below τ = 2 mm and 1 above; precision stays 1."""
    truth = plane_grid(CENTRE, FRONTAL, spacing=2.0)
    measured = truth.copy()
    measured[:, 1::2] = np.nan
    overlap = np.ones(truth.shape[:2], bool)
    overlap[-4:] = False  # pixels the right camera does not see: not counted in recall
    scores = score_surface(case(*plane_mesh(CENTRE, FRONTAL), measured, truth, overlap))
    assert scores["recall_0.5mm"] == scores["recall_1mm"] == 0.5
    assert scores["recall_5mm"] == 1.0 and scores["precision_1mm"] == 1.0
    assert scores["fscore_1mm"] == pytest.approx(2 / 3, abs=1e-15)  # 2·1·½ / (1 + ½)
    assert scores["truth_count"] == scores["overlap_pixels"] == 36 * 60
    assert scores["measured_fraction"] == 0.5
    assert scores["measured_outside_overlap"] == 4 * 30  # the last 4 rows, half their columns
    assert scores["mean_truth_to_measured_mm"] == pytest.approx(1.0, abs=F64_TOL_MM)  # ½·0 + ½·2


def test_flatness_of_a_known_tilted_plane():
    """A ±a checkerboard along the normal of a tilted plane, on an even grid: orthogonal to the
    constant and to both linear terms, so the fitted plane is the true one, RMS a, P-V 2a."""
    a = 0.05
    truth = plane_grid(CENTRE, TILTED, shape=(30, 40))
    v, u = np.mgrid[0:30, 0:40]
    measured = truth + (a * (-1.0) ** (u + v))[..., None] * TILTED[:, 2]
    vertices, triangles = plane_mesh(CENTRE, TILTED)
    assert mesh_is_planar(vertices)
    scores = score_surface(case(vertices, triangles, measured, truth))
    assert scores["flatness_rms_mm"] == pytest.approx(a, abs=F64_TOL_MM)
    assert scores["flatness_pv_mm"] == pytest.approx(2 * a, abs=F64_TOL_MM)
    assert scores["normal_angle_deg"] < 1e-9  # arctan2 of a float64 cross product
    # the measured plane turned 1° about the surface's own x axis: the angle is 1°
    turned = CENTRE + (truth - CENTRE) @ (TILTED @ rotation(np.radians(1.0), 0, 0) @ TILTED.T).T
    scores = score_surface(case(vertices, triangles, turned, truth))
    assert scores["normal_angle_deg"] == pytest.approx(1.0, abs=1e-9)
    assert scores["flatness_rms_mm"] < 1e-9
    assert "flatness_rms_mm" not in score_surface(case(vertices, triangles, turned, truth),
                                                  plane=False)
    normal, d, _ = fit_plane(vertices)
    assert abs(abs(normal @ TILTED[:, 2]) - 1) < 1e-15 and normal[2] > 0


def test_nothing_measured_and_bad_inputs():
    truth = plane_grid(CENTRE, FRONTAL, shape=(4, 5))
    vertices, triangles = plane_mesh(CENTRE, FRONTAL)
    scores = score_surface(case(vertices, triangles, np.full_like(truth, np.nan), truth))
    assert scores["p2m_count"] == scores["depth_count"] == 0 and scores["measured_fraction"] == 0
    assert np.isnan(scores["p2m_rms_mm"]) and np.isnan(scores["flatness_rms_mm"])
    assert scores["recall_1mm"] == 0.0 and np.isnan(scores["precision_1mm"])
    json.dumps(jsonable(scores), allow_nan=False)
    with pytest.raises(ValueError, match="measured_points"):
        case(vertices, triangles, truth[..., :2], truth)
    with pytest.raises(ValueError, match="mesh_triangles"):
        case(vertices, triangles + 10, truth, truth)
    with pytest.raises(ValueError, match="port_normal"):
        case(vertices, triangles, truth, truth, normal=(0.0, 0.0, 0.0))


def test_table_lists_methods_and_marks_missing_values():
    truth = plane_grid(CENTRE, FRONTAL)
    vertices, triangles = plane_mesh(CENTRE, FRONTAL)
    good = score_surface(case(vertices, triangles, truth + [0, 0, 0.2], truth))
    table = surface_table({"optical_path": good, "regular": {"measured_fraction": 0.5}})
    lines = table.splitlines()
    assert len(lines) == 4 and "F@0.5" in lines[0] and "flat RMS" in lines[0]
    assert lines[2].split()[:3] == ["optical_path", "100.0", "0.2000"]
    assert lines[3].split() == ["regular", "50.0"] + ["-"] * 8
    assert len({len(line) for line in lines[:3]}) == 1  # fixed width


def test_figures_and_coloured_cloud_are_written_and_readable(tmp_path):
    truth = plane_grid(CENTRE, TILTED)
    noise = np.random.default_rng(3).normal(0.0, 0.3, truth.shape[:2])
    measured = truth + noise[..., None] * TILTED[:, 2]
    measured[:5, :8] = np.nan
    arrays = surface_arrays(case(*plane_mesh(CENTRE, TILTED), measured, truth))
    error_map = write_error_map(tmp_path / "depth_error.png", arrays["depth_error"], "plane")
    image = mpimg.imread(error_map)
    assert image.ndim == 3 and image.shape[0] > 200
    histogram = write_distance_histogram(tmp_path / "distances.png",
                                         {"optical_path": arrays["distance"],
                                          "regular": arrays["distance"] + 20.0}, (0.5, 1.0, 5.0))
    assert mpimg.imread(histogram).shape[0] > 200
    entry = write_colored_cloud(tmp_path / "cloud.ply", arrays["measured"], arrays["distance"], 1.0)
    cloud = o3d.io.read_point_cloud(str(tmp_path / "cloud.ply"))
    assert len(cloud.points) == entry["points"] == len(arrays["measured"]) == 2400 - 40
    np.testing.assert_array_equal(np.asarray(cloud.points), arrays["measured"])  # binary doubles
    colors = np.asarray(cloud.colors)
    assert cloud.has_colors() and np.ptp(colors, axis=0).max() > 0.5  # distances span [0, 1] mm
    empty = write_colored_cloud(tmp_path / "empty.ply", np.zeros((0, 3)), np.zeros(0), 1.0)
    assert empty["points"] == 0 and (tmp_path / "empty.ply").read_text().startswith("ply\n")
    # no temporary file left behind
    assert sorted(os.listdir(tmp_path)) == ["cloud.ply", "depth_error.png", "distances.png",
                                            "empty.ply"]
