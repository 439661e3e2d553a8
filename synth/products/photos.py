"""Rendered images as a camera would have stored them: 8-bit sRGB photos that no longer know
where they came from.

:func:`export_photos` takes a ``synth boards`` folder (``left_PP.png`` / ``right_PP.png``) or a
``synth dataset`` (``left.png`` / ``right.png``) and writes ``OUT/left/NAME.EXT`` and
``OUT/right/NAME.EXT`` (``NAME`` the pose number ``PP``, or ``pair`` for a dataset) and nothing
else: no calibration, no truth, no manifest — the layout ``eval calibrate`` and ``eval measure``
read from a user. Each 16-bit linear image is divided by 65535 (its folder's one exposure, the
brightest rendered pixel at white), sRGB-encoded (:func:`synth.rendering.render.srgb_preview`) and written
as JPEG (``quality``, OpenCV's default 4:2:0 grey) or 8-bit PNG.
"""

from __future__ import annotations

import json
import os
import re

import numpy as np

PHOTO_FORMATS = ("jpg", "png")


class PhotoExportError(ValueError):
    """A folder that holds no rendered stereo images to export."""


def rendered_pairs(src) -> list[tuple[str, str, str]]:
    """``[(name, left_png, right_png), …]`` of a boards folder or a dataset."""
    src = os.fspath(src)
    try:
        with open(os.path.join(src, "manifest.json")) as fh:
            command = json.load(fh).get("command", "")
    except (OSError, ValueError):
        raise PhotoExportError(f"{src}: not a synth boards folder or dataset (no readable "
                               f"manifest.json)") from None
    if command == "synth boards":
        names = sorted(m.group(1) for f in os.listdir(src)
                       if (m := re.fullmatch(r"left_(\d+)\.png", f)))
        pairs = [(n, os.path.join(src, f"left_{n}.png"), os.path.join(src, f"right_{n}.png"))
                 for n in names]
    else:
        pairs = [("pair", os.path.join(src, "left.png"), os.path.join(src, "right.png"))]
    missing = [p for pair in pairs for p in pair[1:] if not os.path.isfile(p)]
    if not pairs or missing:
        raise PhotoExportError(f"{src}: no rendered image {missing[0] if missing else 'left_PP.png'}")
    return pairs


def to_photo(png16: np.ndarray) -> np.ndarray:
    """8-bit sRGB of a 16-bit linear image (65535 is white)."""
    from synth.rendering.render import srgb_preview

    return srgb_preview(np.asarray(png16, dtype=np.float64), white=65535.0)


def export_photos(src, out_dir, fmt: str = "jpg", quality: int = 90) -> int:
    """Write the photos of ``src`` into ``out_dir`` (module docs; created, must not hold
    photos already); the number of pairs written."""
    import cv2

    if fmt not in PHOTO_FORMATS:
        raise PhotoExportError(f"photo format {fmt!r}: choose from {', '.join(PHOTO_FORMATS)}")
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if fmt == "jpg" else []
    pairs = rendered_pairs(src)
    for view in ("left", "right"):
        os.makedirs(os.path.join(out_dir, view), exist_ok=True)
    for name, *files in pairs:
        for view, file in zip(("left", "right"), files):
            image = cv2.imread(file, cv2.IMREAD_UNCHANGED)
            if image is None or image.dtype != np.uint16 or image.ndim != 2:
                raise PhotoExportError(f"{file}: not a 16-bit grey rendered image")
            target = os.path.join(out_dir, view, f"{name}.{fmt}")
            tmp = os.path.join(out_dir, view, f".{name}.tmp.{fmt}")
            if not cv2.imwrite(tmp, to_photo(image), params):
                raise OSError(f"cannot write {target}")
            os.replace(tmp, target)
    return len(pairs)


__all__ = ["PHOTO_FORMATS", "PhotoExportError", "export_photos", "rendered_pairs", "to_photo"]
