"""A user's own detections of a calibration board, instead of photos: what MATLAB, Kalibr or
one's own detector writes.

Layout, as for photos (:mod:`eval.core.photos`): one camera's files directly in ``DIR``; a pair
in ``DIR/left/`` and ``DIR/right/``, files paired by name (the stem; the extension may
differ). A file is one photo's detections (``.txt`` or ``.csv``), one board point a line:

* ``u v`` — the board's points in order, the line number (from 0, comment and blank lines not
  counted) is the point's id;
* ``id u v`` — the id first (an integer), any subset of the points in any order.

Numbers are separated by spaces, tabs or commas; ``#`` starts a comment; one header line of
words is skipped. Point ids follow :meth:`measure.calibration.board.Board.corners` (row by row
from the board's origin; a circle grid's as OpenCV's ``findCirclesGrid`` numbers them). Pixels
are OpenCV's (the centre of the top-left pixel is 0, 0) unless ``origin`` says where the file's
convention puts that centre (MATLAB 1, COLMAP 0.5): ``origin`` is subtracted from u and v.

Every problem is one :class:`DetectionError` naming the file (and the line).
"""

from __future__ import annotations

import os
import re

import numpy as np

#: File extensions read as detections (lower case).
DETECTION_EXTENSIONS = (".txt", ".csv")
#: Where a file's convention puts the centre of the top-left pixel, by name (``--pixel-origin``).
PIXEL_ORIGINS = {"opencv": 0.0, "colmap": 0.5, "matlab": 1.0}
_SPLIT = re.compile(r"[\s,;]+")


class DetectionError(ValueError):
    """A detections file or folder that cannot be used."""


def _rows(path) -> list[tuple[int, list[str]]]:
    """``[(line number, fields)]`` of a detections file: comments and blank lines dropped, one
    header line of words skipped."""
    out = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for number, line in enumerate(fh, start=1):
            fields = [f for f in _SPLIT.split(line.split("#", 1)[0].strip()) if f]
            if fields:
                out.append((number, fields))
    if out and not _numeric(out[0][1][0]):
        out = out[1:]
    return out


def _numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_detection_file(path, n_points: int, origin: float = 0.0):
    """``(ids (M,), pixels (M, 2))`` of one detections file (module docs) of a board of
    ``n_points`` points; :class:`DetectionError` naming the file and line of a problem."""
    path = os.fspath(path)
    rows = _rows(path)
    if not rows:
        raise DetectionError(f"{path}: no detections (expected 'u v' or 'id u v' lines)")
    widths = {len(f) for _, f in rows}
    if len(widths) > 1 or widths.pop() not in (2, 3):
        line = next(n for n, f in rows if len(f) != len(rows[0][1]) or len(f) not in (2, 3))
        raise DetectionError(f"{path}, line {line}: expected 'u v' or 'id u v' on every line")
    try:
        values = np.array([[float(v) for v in f] for _, f in rows])
    except ValueError:
        line = next(n for n, f in rows if not all(_numeric(v) for v in f))
        raise DetectionError(f"{path}, line {line}: not a number") from None
    if values.shape[1] == 2:
        ids = np.arange(len(values))
        pixels = values
    else:
        if not np.all(values[:, 0] == np.round(values[:, 0])):
            line = rows[int(np.flatnonzero(values[:, 0] != np.round(values[:, 0]))[0])][0]
            raise DetectionError(f"{path}, line {line}: the point id must be an integer")
        ids, pixels = values[:, 0].astype(int), values[:, 1:]
    bad = np.flatnonzero(~np.all(np.isfinite(pixels), axis=1))
    if bad.size:
        raise DetectionError(f"{path}, line {rows[int(bad[0])][0]}: u and v must be finite")
    outside = np.flatnonzero((ids < 0) | (ids >= n_points))
    if outside.size:
        raise DetectionError(f"{path}, line {rows[int(outside[0])][0]}: point {ids[outside[0]]} "
                             f"is not on the board (ids 0–{n_points - 1}; "
                             f"{'a line each: more lines than' if values.shape[1] == 2 else ''} "
                             f"the board has {n_points} points)")
    unique, counts = np.unique(ids, return_counts=True)
    if np.any(counts > 1):
        raise DetectionError(f"{path}: point {unique[counts > 1][0]} is given twice")
    order = np.argsort(ids)
    return ids[order], pixels[order] - origin


def detection_files(folder) -> dict:
    """``{stem: path}`` of the detections files in ``folder``; two files of one stem refused."""
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise DetectionError(f"{folder}: no such folder")
    out = {}
    for name in sorted(os.listdir(folder)):
        stem, ext = os.path.splitext(name)
        if name.startswith(".") or ext.lower() not in DETECTION_EXTENSIONS:
            continue
        if stem in out:
            raise DetectionError(f"{folder}: two detections files named {stem}")
        out[stem] = os.path.join(folder, name)
    return out


def detection_layout(path) -> tuple:
    """The camera folders of a detections folder: ``()`` for one camera's files in ``path``,
    ``("left", "right")`` for a pair. :class:`DetectionError` when it holds neither."""
    path = os.fspath(path)
    if not os.path.isdir(path):
        raise DetectionError(f"{path}: no such folder")
    if any(os.path.isdir(os.path.join(path, side)) for side in ("left", "right")):
        for side in ("left", "right"):
            if not os.path.isdir(os.path.join(path, side)):
                raise DetectionError(f"{path}: a {('right', 'left')[side == 'right']}/ folder "
                                     f"but no {side}/ (a pair's detections are in left/ and "
                                     f"right/)")
        return ("left", "right")
    if detection_files(path):
        return ()
    raise DetectionError(f"{path}: no detections files ({', '.join(DETECTION_EXTENSIONS)}) "
                         f"and no left/ and right/ folders")


def read_detections(path, n_points: int, origin: float = 0.0):
    """Every photo's detections of a folder (module docs): ``(names, views, per_view)`` with
    ``views`` the camera folders (:func:`detection_layout`) and ``per_view[k][v]`` ``(ids,
    pixels)`` of photo ``k`` in view ``v`` (empty where a camera has no file of that name)."""
    views = detection_layout(path)
    folders = [os.path.join(os.fspath(path), v) for v in views] or [os.fspath(path)]
    files = [detection_files(f) for f in folders]
    for folder, found in zip(folders, files):
        if not found:
            raise DetectionError(f"{folder}: no detections files")
    names = sorted(set().union(*files))
    empty = (np.empty(0, int), np.empty((0, 2)))
    per_view = [[read_detection_file(f[name], n_points, origin) if name in f else empty
                 for f in files] for name in names]
    return names, views, per_view


__all__ = ["DETECTION_EXTENSIONS", "DetectionError", "PIXEL_ORIGINS", "detection_files",
           "detection_layout", "read_detection_file", "read_detections"]
