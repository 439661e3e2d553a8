"""Rendered images as a camera would have stored them: 8-bit sRGB photos that no longer know
where they came from.

:func:`export_photos` takes a ``synth boards`` folder (``left_PP.png`` / ``right_PP.png``) or a
``synth dataset`` (``left.png`` / ``right.png``) and writes ``OUT/left/NAME.EXT`` and
``OUT/right/NAME.EXT`` (``NAME`` the pose number ``PP``, or ``pair`` for a dataset) — for
boards of N > 2 cameras (``cam0_PP.png``, …) ``OUT/cam0/PP.EXT``, …, for a dataset of N > 2
cameras (``cam0/image.png``, …) ``OUT/cam0/image.EXT``, ``OUT/cam1/image.EXT``, … — and nothing
else: no calibration, no truth, no manifest — the
layout ``eval calibrate`` and ``eval measure`` read from a user. Each 16-bit linear image is
divided by 65535 (its folder's one exposure, the brightest rendered pixel at white),
sRGB-encoded (:func:`synth.rendering.image_files.srgb_preview`) and written as JPEG (``quality``,
OpenCV's default 4:2:0 grey) or 8-bit PNG.
"""

from __future__ import annotations

import json
import os
import re

import numpy as np
from synth.infra.images import imread

PHOTO_FORMATS = ("jpg", "png")


class PhotoExportError(ValueError):
    """A folder that holds no rendered stereo images to export."""


def rendered_views(src) -> tuple[tuple[str, ...], list[tuple]]:
    """``(views, [(name, file of view 0, file of view 1, …), …])`` of a boards folder or a
    dataset: ``views`` ``("left", "right")``, or ``("cam0", "cam1", …)`` for a dataset of more
    than two cameras (:mod:`synth.products.dataset_layout`, its images ``camK/image.png``, the
    name ``image``)."""
    src = os.fspath(src)
    try:
        with open(os.path.join(src, "manifest.json")) as fh:
            manifest = json.load(fh)
        command = manifest.get("command", "")
    except (OSError, ValueError, AttributeError):
        raise PhotoExportError(f"{src}: not a synth boards folder or dataset (no readable "
                               f"manifest.json)") from None
    from synth.products.dataset_layout import VIEW_FILES, is_views_dataset

    views = ("left", "right")
    if command == "synth boards":
        views = _board_views(src)
        names = sorted(m.group(1) for f in os.listdir(src)
                       if (m := re.fullmatch(rf"{views[0]}_(\d+)\.png", f)))
        pairs = [(n, *(os.path.join(src, f"{view}_{n}.png") for view in views)) for n in names]
    elif is_views_dataset(src):
        from synth.products.dataset import DatasetError, read_dataset

        try:  # the folders, the manifest and every file's SHA-256
            views = read_dataset(src).names
        except DatasetError as exc:
            raise PhotoExportError(str(exc)) from None
        stem = os.path.splitext(VIEW_FILES["image"])[0]
        pairs = [(stem, *(os.path.join(src, view, VIEW_FILES["image"]) for view in views))]
    else:
        pairs = [("pair", os.path.join(src, "left.png"), os.path.join(src, "right.png"))]
    missing = [p for pair in pairs for p in pair[1:] if not os.path.isfile(p)]
    if not pairs or missing:
        raise PhotoExportError(f"{src}: no rendered image "
                               f"{missing[0] if missing else views[0] + '_PP.png'}")
    return tuple(views), pairs


def _board_views(src) -> tuple[str, ...]:
    """The views of a ``synth boards`` folder: ``left``, ``right``, or ``cam0``, ``cam1``, …
    of a scene of N cameras (``cam0_PP.png``, …)."""
    cameras = sorted({int(m.group(1)) for f in os.listdir(src)
                      if (m := re.fullmatch(r"cam(\d+)_\d+\.png", f))})
    if cameras and not any(re.fullmatch(r"left_\d+\.png", f) for f in os.listdir(src)):
        return tuple(f"cam{k}" for k in range(max(cameras) + 1))
    return ("left", "right")


def to_photo(png16: np.ndarray) -> np.ndarray:
    """8-bit sRGB of a 16-bit linear image (65535 is white)."""
    from synth.rendering.image_files import srgb_preview

    return srgb_preview(np.asarray(png16, dtype=np.float64), white=65535.0)


def export_photos(src, out_dir, fmt: str = "jpg", quality: int = 90) -> int:
    """Write the photos of ``src`` into ``out_dir`` (module docs; created, must not hold
    photos already): one folder per view (``left/``, ``right/``, or ``cam0/``, … for a dataset
    of more cameras); the number of photos per view."""
    return export_views(src, out_dir, fmt, quality)[1]


def export_views(src, out_dir, fmt: str = "jpg", quality: int = 90) -> tuple[tuple, int]:
    """:func:`export_photos`, returning ``(views, photos per view)``."""
    import cv2

    if fmt not in PHOTO_FORMATS:
        raise PhotoExportError(f"photo format {fmt!r}: choose from {', '.join(PHOTO_FORMATS)}")
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)] if fmt == "jpg" else []
    views, pairs = rendered_views(src)
    for view in views:
        os.makedirs(os.path.join(out_dir, view), exist_ok=True)
    for name, *files in pairs:
        for view, file in zip(views, files):
            image = imread(file, cv2.IMREAD_UNCHANGED)
            if image is None or image.dtype != np.uint16 or image.ndim != 2:
                raise PhotoExportError(f"{file}: not a 16-bit grey rendered image")
            target = os.path.join(out_dir, view, f"{name}.{fmt}")
            tmp = os.path.join(out_dir, view, f".{name}.tmp.{fmt}")
            if not cv2.imwrite(tmp, to_photo(image), params):
                raise OSError(f"cannot write {target}")
            os.replace(tmp, target)
    return views, len(pairs)


__all__ = ["PHOTO_FORMATS", "PhotoExportError", "export_photos", "export_views", "rendered_views",
           "to_photo"]
