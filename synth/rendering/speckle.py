"""Speckle textures like the ones stereo-DIC users spray: random dark dots on a white ground.

The generator (documented because users compare it with their own patterns):

* dot centres are a Poisson process over the texture's extent (``numpy.random.default_rng(seed)``,
  uniform positions), all dots the same diameter ``dot_mm``;
* their number is chosen so that the expected dark fraction of the surface is ``coverage``
  (overlapping dots merge: for a Boolean model of disks of area ``a`` and density ``λ`` the
  covered fraction is ``1 − exp(−λ a)``, so ``λ = −ln(1 − coverage) / a``);
* each texel's value is the ink of the nearest dot, anti-aliased over one texel:
  ``clip((distance to the nearest centre − dot_mm / 2) / texel_mm + 0.5, 0, 1)``, mapped to
  reflectance ``dark + (white − dark) · value`` — 8-bit grey PNG, texel ``texel_mm`` on a side
  (default a fifth of the dot diameter).

Same arguments, same bytes.
"""

from __future__ import annotations

import numpy as np

#: Defaults: dot diameter (mm; about 3.5 px at 1 m behind the paper's port), dark fraction,
#: reflectances of the ink and of the white ground.
DOT_MM, COVERAGE, DARK, WHITE = 2.5, 0.5, 0.05, 0.85
#: Texels per dot diameter.
TEXELS_PER_DOT = 5
#: Largest texture, texels (an 8-bit grey image of this many texels is ~15-25 MB as PNG).
MAX_TEXELS = 40_000_000


def texture_shape(extent_mm, dot_mm: float = DOT_MM) -> tuple[int, int, float]:
    """``(rows, cols, texel_mm)`` of a texture covering ``extent_mm`` = (width, height)."""
    texel = dot_mm / TEXELS_PER_DOT
    cols = max(int(np.ceil(extent_mm[0] / texel)), 2)
    rows = max(int(np.ceil(extent_mm[1] / texel)), 2)
    if rows * cols > MAX_TEXELS:
        raise ValueError(f"a speckle texture of {cols} x {rows} texels ({dot_mm:g} mm dots over "
                         f"{extent_mm[0]:.0f} x {extent_mm[1]:.0f} mm) is larger than "
                         f"{MAX_TEXELS} texels: use larger dots or a smaller surface")
    return rows, cols, texel


def speckle_texture(extent_mm, dot_mm: float = DOT_MM, coverage: float = COVERAGE,
                    seed: int = 0, dark: float = DARK, white: float = WHITE) -> np.ndarray:
    """An 8-bit grey speckle image ``(rows, cols)`` covering ``extent_mm`` = (width, height) mm;
    row 0 is texture coordinate v = 0. See the module docstring for the generator."""
    from scipy.spatial import cKDTree

    if not (np.isfinite(dot_mm) and dot_mm > 0):
        raise ValueError(f"speckle dot size must be positive, got {dot_mm}")
    if not 0 < coverage < 1:
        raise ValueError(f"speckle coverage must lie in (0, 1), got {coverage}")
    rows, cols, texel = texture_shape(extent_mm, dot_mm)
    rng = np.random.default_rng(seed)
    radius = dot_mm / 2
    # dots beyond the edge by up to a radius ink the border too
    width, height = cols * texel + 2 * radius, rows * texel + 2 * radius
    density = -np.log1p(-coverage) / (np.pi * radius * radius)
    count = rng.poisson(density * width * height)
    centres = rng.uniform((-radius, -radius), (cols * texel + radius, rows * texel + radius),
                          size=(count, 2))
    tree = cKDTree(centres)
    image = np.empty((rows, cols), dtype=np.uint8)
    x = (np.arange(cols) + 0.5) * texel
    for start in range(0, rows, 256):  # rows in blocks: bounded memory
        y = (np.arange(start, min(start + 256, rows)) + 0.5) * texel
        xx, yy = np.meshgrid(x, y)
        distance, _ = tree.query(np.column_stack([xx.ravel(), yy.ravel()]), workers=-1)
        ink = np.clip((distance - radius) / texel + 0.5, 0.0, 1.0)
        value = dark + (white - dark) * ink
        image[start:start + y.size] = np.round(255 * value).reshape(y.size, cols)
    return image
