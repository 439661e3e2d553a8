"""A generated sea floor: a heightfield (slope, fractal relief, sand ripples, rocks) and a
procedural reflectance texture of natural statistics (sand, gravel, rock), both from one seed.

Frames and units: the *seabed frame* is right-handed, millimetres, ``x``, ``y`` horizontal and
``z`` up, with the mean sea floor near ``z = 0``; :func:`seabed_mesh` carries the heightfield
into the reference frame (the left camera's, OpenCV axes) with the pose the scene gives it.
Texture coordinates are the seabed frame's ``(x, y)`` in mm (a top-down planar map, as a
photomosaic would drape it).

Statistics (generated, never downloaded):

* relief: Gaussian noise whose power spectrum falls as ``f^-beta_relief`` (``beta`` 3–4: the
  fractional Brownian surfaces measured on natural terrain and sea floors), a plane slope, and
  sand ripples — a sinusoid along a drawn direction whose phase is bent by low-frequency noise
  (ripples are never straight) and whose amplitude a mask lets come and go;
* rocks: ellipsoidal caps, rough on top (the same fractal noise), set into the relief;
* reflectance: sand (grain noise plus a ``1/f``-amplitude low-frequency mottle, mean 0.35–0.55),
  gravel (a jittered-grid Voronoi of stones with log-normal albedos and dark gaps) and rock
  (``1/f`` texture of higher contrast with dark pits), chosen per texel by a low-frequency field
  and the rocks' footprints. Natural images have amplitude spectra close to ``1/f``: every
  texture here is built from such fields.

All generators take a :class:`numpy.random.Generator` and draw everything from it, so one seed
gives one sea floor bit for bit.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from synth.scene.surfaces import SurfaceMesh

#: Most heightfield cells along a side (the mesh has at most ``2 · MAX_CELLS²`` triangles).
MAX_CELLS = 512
#: Finest heightfield cell, mm (ripples of the shortest drawn wavelength get 6 cells).
MIN_CELL_MM = 8.0
#: Largest side of the texture, texels, and its finest texel, mm.
MAX_TEXELS, MIN_TEXEL_MM = 2048, 0.75
#: Materials of the texture, in the order of :func:`material_map`'s codes.
MATERIALS = ("sand", "gravel", "rock")


@dataclass(frozen=True)
class SeabedParams:
    """What a sea floor is drawn with (:func:`draw_seabed`); lengths mm, slopes unitless
    (rise over run), angles radians, albedos linear reflectance."""

    slope: tuple
    relief_mm: float
    relief_beta: float
    ripple_amplitude_mm: float
    ripple_wavelength_mm: float
    ripple_direction: float
    rocks: int
    rock_radius_mm: tuple
    gravel_fraction: float
    sand_albedo: float
    stone_size_mm: float

    def describe(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def draw_seabed(rng: np.random.Generator) -> SeabedParams:
    """A sea floor's parameters drawn from ``rng`` (ranges of shallow sandy to rocky floors)."""
    slope_angle = np.radians(rng.uniform(0.0, 15.0))
    slope_dir = rng.uniform(0.0, 2 * np.pi)
    return SeabedParams(
        slope=(float(np.tan(slope_angle) * np.cos(slope_dir)),
               float(np.tan(slope_angle) * np.sin(slope_dir))),
        relief_mm=float(rng.uniform(10.0, 80.0)), relief_beta=float(rng.uniform(3.0, 4.0)),
        ripple_amplitude_mm=float(rng.choice([0.0, rng.uniform(5.0, 25.0)], p=[0.25, 0.75])),
        ripple_wavelength_mm=float(rng.uniform(60.0, 250.0)),
        ripple_direction=float(rng.uniform(0.0, np.pi)),
        rocks=int(rng.integers(0, 13)),
        rock_radius_mm=(float(rng.uniform(60.0, 150.0)), float(rng.uniform(150.0, 450.0))),
        gravel_fraction=float(rng.uniform(0.0, 0.6)),
        sand_albedo=float(rng.uniform(0.35, 0.55)),
        stone_size_mm=float(rng.uniform(8.0, 40.0)))


def fractal_noise(shape, beta: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise ``(H, W)`` whose power spectrum falls as ``f^-beta`` (zero mean, unit
    standard deviation; the lowest frequency is one period over the field)."""
    h, w = shape
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    f = np.sqrt(fx ** 2 + fy ** 2)
    f[0, 0] = np.inf
    amplitude = f ** (-beta / 2.0)
    spectrum = amplitude * (rng.standard_normal(f.shape) + 1j * rng.standard_normal(f.shape))
    field = np.fft.irfft2(spectrum, s=(h, w))
    return (field - field.mean()) / max(float(field.std()), 1e-30)


def _rock_caps(rng, x, y, params: SeabedParams):
    """Heights (mm above the local floor) of the rocks over the grid ``x`` ``(W,)``, ``y``
    ``(H,)``: ellipsoidal caps of drawn radii and aspect, and the rocks' mask (height > 1 mm)."""
    height = np.zeros((y.size, x.size))
    low, high = params.rock_radius_mm
    for _ in range(params.rocks):
        cx, cy = rng.uniform(x[0], x[-1]), rng.uniform(y[0], y[-1])
        a = rng.uniform(low, high)
        b = a * rng.uniform(0.5, 1.0)
        c = a * rng.uniform(0.3, 0.7)
        turn = rng.uniform(0.0, np.pi)
        dx, dy = x[None, :] - cx, y[:, None] - cy
        u = (dx * np.cos(turn) + dy * np.sin(turn)) / a
        v = (-dx * np.sin(turn) + dy * np.cos(turn)) / b
        inside = np.clip(1.0 - u ** 2 - v ** 2, 0.0, None)
        height = np.maximum(height, c * np.sqrt(inside) - 0.15 * c)
    return np.clip(height, 0.0, None)


def seabed_heights(rng: np.random.Generator, x: np.ndarray, y: np.ndarray,
                   params: SeabedParams, centre=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Heights ``z(y, x)`` mm of the sea floor over the grid ``x`` ``(W,)``, ``y`` ``(H,)`` (mm,
    seabed frame), and the rocks' height above the floor (same shape; 0 off the rocks). The
    slope's plane passes through ``z = 0`` at ``centre`` (mm)."""
    shape = (y.size, x.size)
    gx, gy = params.slope
    z = gx * (x[None, :] - centre[0]) + gy * (y[:, None] - centre[1])
    z = z + params.relief_mm * fractal_noise(shape, params.relief_beta, rng)
    if params.ripple_amplitude_mm > 0:
        along = (np.cos(params.ripple_direction) * x[None, :]
                 + np.sin(params.ripple_direction) * y[:, None])
        bend = 0.6 * fractal_noise(shape, 3.0, rng)
        come_and_go = np.clip(0.6 + 0.5 * fractal_noise(shape, 3.5, rng), 0.0, 1.0)
        phase = 2 * np.pi * along / params.ripple_wavelength_mm + 2 * np.pi * bend
        # sand ripples are asymmetric: a steep lee side (the second harmonic)
        ripple = np.sin(phase) + 0.25 * np.sin(2 * phase + 0.5 * np.pi)
        z = z + params.ripple_amplitude_mm * come_and_go * ripple
    rocks = _rock_caps(rng, x, y, params)
    if params.rocks:
        roughness = 0.08 * np.sqrt(np.maximum(rocks, 0)) * fractal_noise(shape, 2.5, rng)
        rocks = np.where(rocks > 0, rocks + roughness * np.sqrt(np.maximum(rocks, 0)), 0.0)
    return z + rocks, rocks


def _smooth_upsample(field: np.ndarray, shape) -> np.ndarray:
    import cv2

    return cv2.resize(field.astype(np.float32), (shape[1], shape[0]),
                      interpolation=cv2.INTER_LINEAR).astype(np.float64)


#: Texture rows the stones' Voronoi is computed over at a time (the same texels, in cache).
VORONOI_STRIP = 32


def voronoi_stones(rng, shape, texel_mm: float, stone_mm: float):
    """A jittered-grid Voronoi of stones over a texture ``shape`` of ``texel_mm`` texels: the
    albedo of each texel's stone (log-normal, median 0.3) darkened in the gaps between stones."""
    h, w = shape
    cell = max(stone_mm / texel_mm, 2.0)
    gh, gw = int(np.ceil(h / cell)) + 2, int(np.ceil(w / cell)) + 2
    jitter = rng.uniform(0.1, 0.9, size=(gh, gw, 2))
    albedo = np.clip(0.3 * np.exp(0.45 * rng.standard_normal((gh, gw))), 0.03, 0.9)
    cols = np.arange(w, dtype=np.float32)[None, :] / np.float32(cell)
    out = np.empty(shape)
    for top in range(0, h, VORONOI_STRIP):
        rows = np.arange(top, min(top + VORONOI_STRIP, h), dtype=np.float32)[:, None]
        out[top:top + rows.shape[0]] = _voronoi_strip(rows / np.float32(cell), cols, jitter,
                                                      albedo)
    return out


def _voronoi_strip(rows, cols, jitter, albedo):
    """:func:`voronoi_stones` on the texels of ``rows`` ``(S, 1)`` × ``cols`` ``(1, W)`` (in
    cells)."""
    gh, gw = albedo.shape
    ci, cj = np.floor(rows).astype(np.int32), np.floor(cols).astype(np.int32)
    shape = (rows.shape[0], cols.shape[1])
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
    gap = np.sqrt(second) - np.sqrt(best)  # in cells: 0 on the border between two stones
    shade = np.clip(gap / 0.12, 0.25, 1.0)
    return value * shade


def seabed_texture(rng: np.random.Generator, shape, texel_mm: float, params: SeabedParams,
                   rock_mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The reflectance texture ``(H, W)`` float in (0, 1) over the seabed's ``(x, y)`` extent
    (row 0 at the lowest ``y``, column 0 at the lowest ``x``; ``texel_mm`` per texel) and its
    material codes (:data:`MATERIALS`). ``rock_mask`` ``(h, w)`` bool on the heightfield grid
    says where the rocks are (resized to the texture)."""
    h, w = shape
    grain = rng.standard_normal(shape)
    mottle = fractal_noise(shape, 2.0, rng)
    sand = params.sand_albedo * np.exp(0.10 * grain + 0.12 * mottle)
    selector = fractal_noise((max(h // 8, 8), max(w // 8, 8)), 3.0, rng)
    selector = _smooth_upsample(selector, shape)
    threshold = np.quantile(selector, 1.0 - params.gravel_fraction) if params.gravel_fraction else np.inf
    gravel_here = selector > threshold
    stones = voronoi_stones(rng, shape, texel_mm, params.stone_size_mm) * np.exp(0.12 * grain)
    rock = 0.22 * np.exp(0.35 * fractal_noise(shape, 2.0, rng))
    pits = fractal_noise(shape, 1.5, rng) > 1.6
    rock = np.where(pits, rock * 0.35, rock)
    rocky = _smooth_upsample(rock_mask.astype(np.float32), shape) > 0.5
    albedo = np.where(rocky, rock, np.where(gravel_here, stones, sand))
    material = np.where(rocky, 2, np.where(gravel_here, 1, 0)).astype(np.uint8)
    return np.clip(albedo, 0.02, 0.95), material


def grid_axes(lower, upper, max_cells: int = MAX_CELLS, min_cell_mm: float = MIN_CELL_MM):
    """The heightfield's ``x`` and ``y`` samples (mm) over the box ``lower``–``upper`` (2-vectors,
    mm): cells of one size, as fine as :data:`MIN_CELL_MM` allows within ``max_cells`` a side."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    cell = max(float(np.max(upper - lower)) / max_cells, min_cell_mm)
    counts = np.maximum(np.ceil((upper - lower) / cell).astype(int), 1)
    return (lower[0] + cell * np.arange(counts[0] + 1), lower[1] + cell * np.arange(counts[1] + 1))


def seabed_mesh(x: np.ndarray, y: np.ndarray, heights: np.ndarray, to_reference,
                description: str) -> SurfaceMesh:
    """The heightfield as a triangle mesh in the reference frame: ``to_reference`` ``(R, t)``
    takes seabed-frame points to the reference frame (``X_ref = R·X_sea + t``); triangles are
    wound so that their normals point up (out of the floor, towards a camera above it)."""
    R, t = to_reference
    xx, yy = np.meshgrid(x, y)
    sea = np.column_stack([xx.ravel(), yy.ravel(), heights.ravel()])
    vertices = sea @ np.asarray(R, float).T + np.asarray(t, float)
    rows, cols = heights.shape
    index = np.arange(rows * cols).reshape(rows, cols)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    # (a, b, c): x then y, counter-clockwise seen from +z (above) in the seabed frame
    triangles = np.concatenate([np.column_stack([a, b, c]), np.column_stack([b, d, c])])
    return SurfaceMesh(vertices, triangles, np.column_stack([xx.ravel(), yy.ravel()]), description)


__all__ = ["MATERIALS", "SeabedParams", "draw_seabed", "fractal_noise", "grid_axes",
           "seabed_heights", "seabed_mesh", "seabed_texture"]
