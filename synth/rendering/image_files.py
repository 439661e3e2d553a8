"""The image files of a render: 16-bit linear PNGs (one scale for the views of a pair or a
rig), 8-bit sRGB previews, float32 OpenEXR (linear, no curve)."""

from __future__ import annotations

import cv2
import numpy as np

from synth.rendering.mitsuba_setup import import_mitsuba


def png16_scale(*images, headroom: float = 1.0) -> float:
    """Factor so that ``image * factor`` of the brightest pixel of all images is 65535 (linear)."""
    peak = max(float(np.max(img)) for img in images)
    return 65535.0 / (peak * headroom) if peak > 0 else 1.0


def to_png16(image: np.ndarray, scale: float) -> np.ndarray:
    """Linear float image to uint16 (``round(image * scale)``, clipped)."""
    return np.clip(np.rint(image.astype(np.float64) * scale), 0, 65535).astype(np.uint16)


def srgb_preview(image: np.ndarray, white: float | None = None) -> np.ndarray:
    """8-bit sRGB-encoded preview of a linear image (``white`` maps to 255; default its max)."""
    white = float(np.max(image)) if white is None else float(white)
    x = np.clip(image.astype(np.float64) / (white if white > 0 else 1.0), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(srgb * 255.0).astype(np.uint8)


def write_png(path, image: np.ndarray) -> None:
    """Write a uint8/uint16 single-channel PNG; raise OSError if OpenCV cannot."""
    if not cv2.imwrite(str(path), image):
        raise OSError(f"cannot write {path}")


def write_exr(path, image: np.ndarray, variant: str | None = None) -> None:
    """Write a float32 single-channel OpenEXR image with Mitsuba's Bitmap (linear, no curve)."""
    mi, _ = import_mitsuba(variant)
    mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32)).write(str(path))
