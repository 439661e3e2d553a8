"""The generated sea floor: its statistics, its mesh's orientation and its reproducibility."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from synth.scene.seabed import (SeabedParams, draw_seabed, fractal_noise, grid_axes,
                                seabed_heights, seabed_mesh, seabed_texture)


def _params(**changes) -> SeabedParams:
    base = dict(slope=(0.0, 0.0), relief_mm=0.0, relief_beta=3.0, ripple_amplitude_mm=0.0,
                ripple_wavelength_mm=100.0, ripple_direction=0.0, rocks=0,
                rock_radius_mm=(100.0, 200.0), gravel_fraction=0.3, sand_albedo=0.45,
                stone_size_mm=20.0)
    base.update(changes)
    return SeabedParams(**base)


@pytest.mark.parametrize("beta", [1.5, 2.0, 3.5])
def test_fractal_noise_has_the_power_law_asked(beta):
    """The radially averaged power spectrum of the noise falls as f^-beta (log-log slope within
    0.1 over a decade of frequencies, 64 fields)."""
    rng = np.random.default_rng(1)
    n = 128
    power = np.zeros((n, n))
    for _ in range(64):
        field = fractal_noise((n, n), beta, rng)
        assert abs(field.mean()) < 1e-9 and abs(field.std() - 1) < 1e-9
        power += np.abs(np.fft.fft2(field)) ** 2
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(n), np.fft.fftfreq(n)))
    bands = np.logspace(np.log10(4 / n), np.log10(40 / n), 12)
    centres, means = [], []
    for lo, hi in zip(bands[:-1], bands[1:]):
        ring = (f >= lo) & (f < hi)
        centres.append(np.sqrt(lo * hi))
        means.append(power[ring].mean())
    slope = np.polyfit(np.log(centres), np.log(means), 1)[0]
    assert slope == pytest.approx(-beta, abs=0.1)


def test_a_floor_without_relief_is_its_slope_plane_through_the_centre():
    x, y = np.linspace(-1000, 1000, 41), np.linspace(0, 3000, 61)
    z, rocks = seabed_heights(np.random.default_rng(0), x, y, _params(slope=(0.1, -0.05)),
                              centre=(200.0, 1500.0))
    expected = 0.1 * (x[None, :] - 200.0) - 0.05 * (y[:, None] - 1500.0)
    np.testing.assert_allclose(z, expected, atol=1e-9)
    assert not rocks.any()


def test_ripples_have_their_wavelength_and_rocks_stand_up():
    x = np.arange(0.0, 4000.0, 5.0)
    params = _params(ripple_amplitude_mm=10.0, ripple_wavelength_mm=200.0, rocks=6)
    z, rocks = seabed_heights(np.random.default_rng(3), x, np.arange(0.0, 400.0, 5.0), params)
    spectrum = np.abs(np.fft.rfft(z - rocks - (z - rocks).mean(axis=1, keepdims=True),
                                  axis=1)).mean(axis=0)
    peak = np.fft.rfftfreq(x.size, 5.0)[np.argmax(spectrum[1:]) + 1]
    assert 1 / peak == pytest.approx(200.0, rel=0.15)  # bent by the phase noise
    assert rocks.max() > 20.0 and np.all(rocks >= 0)


def test_same_seed_same_floor_other_seed_other_floor():
    x, y = grid_axes((0, 0), (1000, 800))
    runs = []
    for seed in (5, 5, 6):
        rng = np.random.default_rng(seed)
        params = draw_seabed(rng)
        z, rocks = seabed_heights(rng, x, y, params)
        texture, _ = seabed_texture(rng, (64, 80), 10.0, params, rocks > 1)
        runs.append((z, texture))
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
    assert not np.array_equal(runs[0][0], runs[2][0])


def test_texture_is_a_reflectance_with_its_materials():
    rng = np.random.default_rng(2)
    params = _params(gravel_fraction=0.4)
    rock_mask = np.zeros((20, 20), bool)
    rock_mask[5:10, 5:10] = True
    texture, material = seabed_texture(rng, (400, 400), 2.0, params, rock_mask)
    assert texture.min() > 0 and texture.max() < 1
    shares = np.bincount(material.ravel(), minlength=3) / material.size
    assert shares[2] == pytest.approx(25 / 400, abs=0.02)  # the rocks' footprint
    off_rock = shares[0] + shares[1]
    assert shares[1] / off_rock == pytest.approx(0.4, abs=0.05)
    # sand is brighter on average than gravel's stones in their dark gaps
    assert texture[material == 0].mean() > texture[material == 1].mean()


def test_grid_axes_cover_the_box_in_square_cells():
    x, y = grid_axes((-100, 50), (900, 2050), max_cells=200, min_cell_mm=1.0)
    assert x[0] == -100 and y[0] == 50 and x[-1] >= 900 and y[-1] >= 2050
    assert np.allclose(np.diff(x), 10.0) and np.allclose(np.diff(y), 10.0)
    x, _ = grid_axes((0, 0), (100, 100), max_cells=200, min_cell_mm=8.0)
    assert np.allclose(np.diff(x), 8.0)


def test_mesh_normals_point_up_in_any_pose():
    """Triangles face up (out of the floor) in the seabed frame, so in the reference frame their
    normals point along the pose's image of +z — the side the one-sided diffuse floor shows."""
    x, y = np.linspace(0, 500, 11), np.linspace(0, 400, 9)
    z, _ = seabed_heights(np.random.default_rng(0), x, y, _params(relief_mm=5.0))
    R = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()
    mesh = seabed_mesh(x, y, z, (R, np.array([10.0, -20.0, 1500.0])), "test")
    v = mesh.vertices[mesh.triangles]
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert np.all(normals @ (R @ [0, 0, 1.0]) > 0)
    np.testing.assert_allclose(mesh.uv_mm[:, 0], np.tile(x, y.size))


def _voronoi_whole(rng, shape, texel_mm, stone_mm):
    """The stones' Voronoi computed over the whole texture at once (as it was before it went
    strip by strip)."""
    h, w = shape
    cell = max(stone_mm / texel_mm, 2.0)
    gh, gw = int(np.ceil(h / cell)) + 2, int(np.ceil(w / cell)) + 2
    jitter = rng.uniform(0.1, 0.9, size=(gh, gw, 2))
    albedo = np.clip(0.3 * np.exp(0.45 * rng.standard_normal((gh, gw))), 0.03, 0.9)
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32) / np.float32(cell)
    ci, cj = np.floor(rows).astype(np.int32), np.floor(cols).astype(np.int32)
    best = np.full(shape, np.inf, np.float32)
    second = np.full(shape, np.inf, np.float32)
    value = np.zeros(shape, np.float32)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            i, j = np.clip(ci + di, 0, gh - 1), np.clip(cj + dj, 0, gw - 1)
            d = (rows - (i + jitter[i, j, 0])) ** 2 + (cols - (j + jitter[i, j, 1])) ** 2
            closer = d < best
            second = np.where(closer, best, np.minimum(second, d))
            value = np.where(closer, albedo[i, j], value)
            best = np.where(closer, d, best)
    return value * np.clip((np.sqrt(second) - np.sqrt(best)) / 0.12, 0.25, 1.0)


@pytest.mark.parametrize("shape, stone_mm", [((70, 50), 9.0), ((32, 41), 3.0), ((5, 300), 40.0)])
def test_the_stones_strip_by_strip_are_the_stones_at_once(shape, stone_mm):
    """Strips of VORONOI_STRIP rows give the whole texture's Voronoi bit for bit (a seed's
    texture does not depend on how it is computed)."""
    from synth.scene.seabed import voronoi_stones

    strips = voronoi_stones(np.random.default_rng(4), shape, 1.5, stone_mm)
    whole = _voronoi_whole(np.random.default_rng(4), shape, 1.5, stone_mm)
    assert strips.dtype == whole.dtype and np.array_equal(strips, whole)
