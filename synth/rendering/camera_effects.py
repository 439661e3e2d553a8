"""What a real camera does to the light before it is stored, applied to a rendered linear
image: vignetting.

Vignetting (:func:`vignetting_map`) is the product of two factors, each optional:

* the natural **cos⁴ law**: a pixel whose ray leaves the camera at angle θ from the optical
  axis receives ``cos⁴ θ`` of the irradiance an on-axis pixel receives from the same radiance
  (the pupil foreshortened twice, the distance and the pixel's obliquity). θ is the exact ray of
  the pixel's centre — the camera's lens distortion included (:meth:`measure.Camera.rays`) —
  not its distance from the principal point;
* a **lens falloff** (mechanical vignetting, the barrel cutting the pupil): ``1 − F · (r /
  r_max)²``, ``r`` the pixel centre's distance from the principal point (px) and ``r_max``
  that of the image corner farthest from it, so the corner keeps ``1 − F``.

Both multiply the image's radiance (linear values, as rendered) pixel by pixel; the geometry,
and so every truth pixel, is unchanged.
"""

from __future__ import annotations

import numpy as np


def pixel_grid(size) -> np.ndarray:
    """Every pixel centre ``(H·W, 2)`` of an image of ``size`` (w, h), row by row (OpenCV
    pixels: integer coordinates are centres)."""
    w, h = (int(v) for v in size)
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    return np.column_stack([u.ravel(), v.ravel()])


def cos4_map(camera) -> np.ndarray:
    """``cos⁴ θ`` ``(H, W)`` of every pixel centre's ray of ``camera`` (a
    :class:`measure.Camera`) against its optical axis (the third column of its R)."""
    w, h = camera.size
    rays = camera.rays(pixel_grid(camera.size))  # unit, reference frame
    cos = rays @ camera.R[:, 2]
    return (cos ** 4).reshape(h, w)


def lens_falloff_map(camera, falloff: float) -> np.ndarray:
    """``1 − falloff · (r / r_max)²`` ``(H, W)`` (module docs)."""
    if not 0.0 <= falloff < 1.0:
        raise ValueError(f"lens falloff must lie in [0, 1), got {falloff!r}")
    w, h = camera.size
    centre = camera.K[:2, 2]
    corners = np.array([[0.0, 0.0], [w - 1.0, 0.0], [0.0, h - 1.0], [w - 1.0, h - 1.0]])
    r_max2 = np.max(np.sum((corners - centre) ** 2, axis=1))
    r2 = np.sum((pixel_grid(camera.size) - centre) ** 2, axis=1)
    return (1.0 - falloff * r2 / r_max2).reshape(h, w)


def vignetting_map(camera, cos4: bool = False, lens_falloff: float = 0.0) -> np.ndarray | None:
    """The factor ``(H, W)`` float32 a rendered image of ``camera`` is multiplied by, or None
    when neither effect is asked for."""
    if not cos4 and lens_falloff == 0.0:
        return None
    factor = np.ones(camera.size[::-1])
    if cos4:
        factor = factor * cos4_map(camera)
    if lens_falloff:
        factor = factor * lens_falloff_map(camera, lens_falloff)
    return factor.astype(np.float32)


__all__ = ["cos4_map", "lens_falloff_map", "pixel_grid", "vignetting_map"]
