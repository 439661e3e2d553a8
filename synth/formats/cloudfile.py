"""Point-cloud files are read whole or refused: what a file holds is checked against what it says
it holds before anyone trusts the points read from it.

Open3D reads a truncated binary PLY as far as it goes and returns what it got (with a warning
on the console, and sometimes garbage), and a truncated text file as its first lines. Here:

* **PLY** (``ply_layout``): the header is parsed (format, elements, their counts and
  properties). A binary file's size must be exactly the header's length plus every element's
  count times its record size (elements with list properties, whose size depends on the data,
  set only a lower bound); an ASCII file must hold one line per element with one token per
  property.
* **PCD**: the header's ``POINTS`` (or ``WIDTH`` × ``HEIGHT``), and for ``DATA binary`` the size
  of the data (``SIZE`` × ``COUNT`` per point).
* text formats (``.xyz``, ``.xyzn``, ``.xyzrgb``): every non-empty line holds the same
  number of numbers (at least three).

:func:`expected_points` returns the number of points the file says it holds (the caller compares
it with the number Open3D read); :class:`CloudFileError` (a ``ValueError``: one ``error:`` line,
exit 2, on both command lines) names the file and what is wrong.
"""

from __future__ import annotations

import os

#: Bytes of each PLY scalar type.
PLY_TYPES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
             "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4,
             "double": 8, "float64": 8}
#: Largest header read (a PLY or PCD header is a few hundred bytes).
MAX_HEADER_BYTES = 1 << 16


class CloudFileError(ValueError):
    """A point-cloud file that is not whole (truncated) or not what its header says."""


def _header_lines(path, label: str, end: bytes):
    """``(lines, header length in bytes)``: the header of ``path`` up to and including the line
    ``end``."""
    with open(path, "rb") as handle:
        head = handle.read(MAX_HEADER_BYTES)
    offset, lines = 0, []
    while True:
        stop = head.find(b"\n", offset)
        if stop < 0:
            raise CloudFileError(f"{label}: no complete header (no {end.decode()!r} line in the "
                                 f"first {len(head)} bytes): truncated, or not a point cloud")
        line = head[offset:stop].rstrip(b"\r").decode("ascii", "replace").strip()
        offset = stop + 1
        lines.append(line)
        if line.split()[:1] == [end.decode()] or line == end.decode():
            return lines, offset


def ply_layout(path, label: str) -> dict:
    """The header of a PLY file: ``format``, ``header_bytes`` and ``elements`` — a list of
    ``{"name", "count", "properties": [(name, type or ("list", count type, item type))]}``;
    :class:`CloudFileError` when it is malformed."""
    with open(path, "rb") as handle:
        if handle.read(4).rstrip(b"\r\n") != b"ply":
            raise CloudFileError(f"{label}: not a PLY file (it does not start with 'ply')")
    lines, header_bytes = _header_lines(path, label, b"end_header")
    layout = {"format": None, "header_bytes": header_bytes, "elements": []}
    for line in lines[1:-1]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) >= 2:
            layout["format"] = words[1]
        elif words[0] == "element" and len(words) == 3:
            try:
                count = int(words[2])
            except ValueError:
                count = -1
            if count < 0:
                raise CloudFileError(f"{label}: bad PLY header line {line!r}")
            layout["elements"].append({"name": words[1], "count": count, "properties": []})
        elif words[0] == "property" and layout["elements"]:
            if words[1] == "list" and len(words) == 5:
                kind = ("list", words[2], words[3])
                known = words[2] in PLY_TYPES and words[3] in PLY_TYPES
            else:
                kind = words[1] if len(words) == 3 else None
                known = kind in PLY_TYPES
            if not known:
                raise CloudFileError(f"{label}: bad PLY header line {line!r}")
            layout["elements"][-1]["properties"].append((words[-1], kind))
        else:
            raise CloudFileError(f"{label}: bad PLY header line {line!r}")
    if layout["format"] not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise CloudFileError(f"{label}: PLY header without a known format line")
    return layout


def _ply_expected(path, label: str) -> int:
    """Check a PLY file against its header; the number of vertices it holds."""
    layout = ply_layout(path, label)
    vertices = sum(e["count"] for e in layout["elements"] if e["name"] == "vertex")
    size = os.path.getsize(path)
    if layout["format"] == "ascii":
        _check_ply_ascii(path, label, layout)
        return vertices
    need, exact = layout["header_bytes"], True
    for element in layout["elements"]:
        fixed = sum(PLY_TYPES[kind] for _, kind in element["properties"] if isinstance(kind, str))
        lists = [kind for _, kind in element["properties"] if not isinstance(kind, str)]
        # a list holds at least its count
        need += element["count"] * (fixed + sum(PLY_TYPES[kind[1]] for kind in lists))
        exact = exact and not lists
    if size < need or (exact and size != need):
        counts = ", ".join(f"{e['count']} {e['name']} elements" for e in layout["elements"])
        raise CloudFileError(
            f"{label}: {'truncated' if size < need else 'longer than its header says'}: the "
            f"header promises {counts} ({need} bytes{'' if exact else ' at least'}), the file "
            f"holds {size} bytes")
    return vertices


def _check_ply_ascii(path, label: str, layout: dict) -> None:
    """One line per element, one token per (scalar) property, and no element missing."""
    with open(path, "rb") as handle:
        handle.seek(layout["header_bytes"])
        rows = [line.split() for line in handle.read().decode("ascii", "replace").splitlines()]
    rows = [row for row in rows if row]
    k = 0
    for element in layout["elements"]:
        scalar = all(isinstance(kind, str) for _, kind in element["properties"])
        width = len(element["properties"])
        for i in range(element["count"]):
            if k >= len(rows):
                raise CloudFileError(f"{label}: truncated: the header promises "
                                     f"{element['count']} {element['name']}, the file ends at "
                                     f"number {i}")
            if scalar and len(rows[k]) != width:
                raise CloudFileError(f"{label}: {element['name']} {i} has {len(rows[k])} values, "
                                     f"the header says {width}: truncated or malformed")
            k += 1
    if k != len(rows):
        raise CloudFileError(f"{label}: {len(rows) - k} more lines than the header says")


def _pcd_expected(path, label: str) -> int:
    lines, header_bytes = _header_lines(path, label, b"DATA")
    fields = {line.split()[0].upper(): line.split()[1:] for line in lines
              if line and not line.startswith("#")}
    try:
        if "POINTS" in fields:
            points = int(fields["POINTS"][0])
        else:
            points = int(fields["WIDTH"][0]) * int(fields["HEIGHT"][0])
        sizes = [int(v) for v in fields.get("SIZE", [])]
        counts = [int(v) for v in fields.get("COUNT", ["1"] * len(sizes))]
    except (KeyError, IndexError, ValueError):
        raise CloudFileError(f"{label}: malformed PCD header (POINTS, SIZE, COUNT)") from None
    data = fields["DATA"][0].lower() if fields.get("DATA") else ""
    if data == "binary":
        need = header_bytes + points * sum(s * c for s, c in zip(sizes, counts))
        size = os.path.getsize(path)
        if size != need:
            raise CloudFileError(f"{label}: {'truncated' if size < need else 'longer than its header says'}: "
                                 f"the header promises {points} points ({need} bytes), the file "
                                 f"holds {size} bytes")
    return points


def _text_expected(path, label: str) -> int:
    with open(path, "rb") as handle:
        rows = [line.split() for line in handle.read().decode("ascii", "replace").splitlines()]
    rows = [row for row in rows if row]
    widths = {len(row) for row in rows}
    if len(widths) > 1 or (widths and min(widths) < 3):
        bad = next(i for i, row in enumerate(rows) if len(row) != len(rows[0]) or len(row) < 3)
        raise CloudFileError(f"{label}: line {bad + 1} has {len(rows[bad])} values, the first "
                             f"{len(rows[0])}: truncated or malformed")
    return len(rows)


def expected_points(path, label: str | None = None) -> int | None:
    """The number of points the point-cloud file ``path`` says it holds, after checking that it
    is whole (module docs); None for a format that states nothing checkable. ``label`` names
    the file in messages (default the path)."""
    label = label or os.fspath(path)
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    if suffix == ".ply":
        return _ply_expected(path, label)
    if suffix == ".pcd":
        return _pcd_expected(path, label)
    if suffix in (".xyz", ".xyzn", ".xyzrgb"):
        return _text_expected(path, label)
    return None


def read_cloud_points(path, label: str | None = None):
    """``(N, 3)`` float64 points of a point-cloud file read by Open3D, refused
    (:class:`CloudFileError`) unless the file is whole and Open3D read every point it holds."""
    import numpy as np
    import open3d as o3d

    label = label or os.fspath(path)
    expected = expected_points(path, label)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        cloud = o3d.io.read_point_cloud(os.fspath(path))
    points = np.asarray(cloud.points, dtype=np.float64).reshape(-1, 3)
    if expected is not None and points.shape[0] != expected:
        raise CloudFileError(f"{label}: holds {expected} points, Open3D read {points.shape[0]}")
    return points


__all__ = ["CloudFileError", "PLY_TYPES", "expected_points", "ply_layout", "read_cloud_points"]
