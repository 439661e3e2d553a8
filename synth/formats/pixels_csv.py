"""``pixels.csv``: the truth's pixel of every target in every view of a dataset — a pair's
(header :data:`PIXELS_HEADER`: ``id,x,y,z,u_left,v_left,u_right,v_right``) and N views'
(``u_<name>,v_<name>`` per camera, :func:`synth.products.dataset_layout.pixels_header`) alike.
Points in mm (reference frame), pixels in the OpenCV convention (integer coordinates are pixel
centres); reals written with 17 significant digits, so that they read back exactly.
"""

from __future__ import annotations

import csv

import numpy as np

from synth.formats.calib_yaml import DatasetError

PIXELS_HEADER = ["id", "x", "y", "z", "u_left", "v_left", "u_right", "v_right"]


def write_pixels_csv(path, ids, points, uv_left, uv_right) -> None:
    """``pixels.csv`` with header :data:`PIXELS_HEADER`; reals with 17 significant digits."""
    write_pixel_rows(path, PIXELS_HEADER, ids, np.column_stack(
        [np.asarray(points, np.float64), np.asarray(uv_left, np.float64),
         np.asarray(uv_right, np.float64)]))


def write_pixel_rows(path, header, ids, rows) -> None:
    """A ``pixels.csv``: ``header``, then per target its id and ``rows`` (reals with 17
    significant digits) — a pair's (:data:`PIXELS_HEADER`) and N views'
    (:func:`synth.products.dataset_layout.pixels_header`) alike."""
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        for i, row in zip(ids, rows):
            writer.writerow([int(i)] + [f"{v:.17g}" for v in row])


def read_pixels_csv(path) -> dict:
    """``{"id": (N,), "points": (N, 3), "left": (N, 2), "right": (N, 2)}`` from ``pixels.csv``."""
    rows = read_pixel_rows(path, PIXELS_HEADER)
    return {"id": rows[:, 0].astype(int), "points": rows[:, 1:4], "left": rows[:, 4:6],
            "right": rows[:, 6:8]}


def read_pixel_rows(path, header) -> np.ndarray:
    """The rows ``(N, len(header))`` of a ``pixels.csv`` whose first line is ``header`` (a
    byte-order mark before it is read past); DatasetError naming the file for another header,
    a row of another length, a value that is not a number or a last row cut short."""
    with open(path, newline="", encoding="utf-8-sig") as fh:
        text = fh.read()
    reader = csv.reader(text.splitlines())
    found = next(reader, None)
    if found != header:
        raise DatasetError(f"{path}: header is {found}, expected {header}")
    values = []
    for line, row in enumerate(reader, start=2):
        if len(row) != len(header):
            raise DatasetError(f"{path}: line {line} has {len(row)} values, the header "
                               f"{len(header)}: truncated or malformed")
        try:
            values.append([float(v) for v in row])
        except ValueError:
            raise DatasetError(f"{path}: line {line}: not a number") from None
    if values and not text.endswith("\n"):  # the writer ends every row: cut mid-row
        raise DatasetError(f"{path}: the last line is not complete: truncated")
    return np.array(values, dtype=np.float64).reshape(-1, len(header))


__all__ = ["PIXELS_HEADER", "read_pixel_rows", "read_pixels_csv", "write_pixel_rows",
           "write_pixels_csv"]
