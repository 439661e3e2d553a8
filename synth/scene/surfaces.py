"""Surfaces as triangle meshes for dense benchmarks: plane, tilted plane, cylinder, sphere cap,
wavy sheet, or a user's mesh; each with texture coordinates in millimetres of surface.

Every generator returns a :class:`SurfaceMesh` in the reference frame (the left camera's, mm,
OpenCV axes), convex side (or front) towards the cameras. Texture coordinates are
*surface* coordinates in mm (arc length along the surface where it bends), so that a speckle
texture drawn in mm keeps its dot size everywhere on the surface; :func:`write_ply` normalises
them to Mitsuba's [0, 1] range over the texture's extent.

Meshes are tessellated finely enough that the chord error (distance of the mesh from the ideal
surface) stays below :data:`MAX_CHORD_ERROR_MM`; the ground truth of a dataset is the *mesh*
(the renderer sees the mesh, the truth maps trace the same mesh), so the chord error only says
how close the mesh is to the named shape.

Vertices are stored as float32 (what Mitsuba keeps) and read back as float64: the mesh the
truth maps trace is bit for bit the mesh the renderer sees.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

#: Largest distance (mm) of a generated mesh from the ideal shape it tessellates.
MAX_CHORD_ERROR_MM = 0.01
#: Most triangles a generated mesh may have (finer tessellations are refused before anything
#: is allocated: a tiny wavelength or a huge radius would otherwise exhaust the memory).
MAX_TRIANGLES = 10_000_000
#: Kinds of surface :func:`make_surface` knows.
SURFACE_KINDS = ("plane", "tilted", "cylinder", "sphere", "wavy", "mesh")


@dataclass(frozen=True)
class SurfaceMesh:
    """A triangle mesh: ``vertices`` ``(V, 3)`` mm (reference frame), ``triangles`` ``(T, 3)``
    vertex indices, ``uv_mm`` ``(V, 2)`` surface coordinates, mm; ``description`` for people."""

    vertices: np.ndarray
    triangles: np.ndarray
    uv_mm: np.ndarray
    description: str

    @property
    def uv_extent(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` corners of the texture coordinates, mm."""
        return self.uv_mm.min(axis=0), self.uv_mm.max(axis=0)


def _grid(s, t, point_of):
    """A mesh over the parameter grid ``s × t`` (1-D arrays) with ``point_of(ss, tt) -> (…, 3)``:
    vertices, two triangles per cell (wound so that the normal faces −z for a front-facing
    sheet: the cameras' side)."""
    ss, tt = np.meshgrid(s, t)  # rows along t
    vertices = point_of(ss, tt).reshape(-1, 3)
    rows, cols = ss.shape
    index = np.arange(rows * cols).reshape(rows, cols)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    triangles = np.concatenate([np.column_stack([a, c, b]), np.column_stack([b, c, d])])
    return vertices, triangles, ss.ravel(), tt.ravel()


def _steps(length: float, spacing: float, other_cells: int = 1, hint: str = "") -> np.ndarray:
    """``n + 1`` evenly spaced values over ``[-length/2, length/2]``, at most ``spacing`` apart;
    ValueError (``hint`` says what to change) if ``n × other_cells`` cells would exceed
    :data:`MAX_TRIANGLES` triangles."""
    cells = length / spacing
    if not np.isfinite(cells) or 2 * max(cells, 1.0) * other_cells > MAX_TRIANGLES:
        raise ValueError(f"the surface would need more than {MAX_TRIANGLES} triangles to stay "
                         f"within {MAX_CHORD_ERROR_MM:g} mm of its shape{hint}")
    n = max(int(np.ceil(cells)), 1)
    return np.linspace(-length / 2, length / 2, n + 1)


def _check_positive(**values) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value}")


def plane(z: float = 1000.0, half_size=(900.0, 750.0), centre_x: float = 100.0,
          tilt_deg=(0.0, 0.0)) -> SurfaceMesh:
    """A rectangle ``2·half_size`` mm centred on ``(centre_x, 0, z)``, facing the cameras, then
    tilted by ``tilt_deg`` = (about x, about y) degrees about its centre (first about y, then
    about x, like :func:`synth.scene.layouts.tilted_plane`)."""
    from scipy.spatial.transform import Rotation

    _check_positive(z=z, half_width=half_size[0], half_height=half_size[1])
    ax, ay = np.radians(np.asarray(tilt_deg, dtype=float))
    rotation = Rotation.from_rotvec([ax, 0.0, 0.0]) * Rotation.from_rotvec([0.0, ay, 0.0])
    centre = np.array([centre_x, 0.0, z])

    def point_of(ss, tt):
        flat = np.stack([ss, tt, np.zeros_like(ss)], axis=-1)
        return rotation.apply(flat.reshape(-1, 3)).reshape(flat.shape) + centre

    s = np.array([-half_size[0], half_size[0]])
    t = np.array([-half_size[1], half_size[1]])
    vertices, triangles, ss, tt = _grid(s, t, point_of)
    what = (f"plane at z {z:g} mm" if not np.any(tilt_deg) else
            f"plane at z {z:g} mm tilted {tilt_deg[0]:g} deg about x, {tilt_deg[1]:g} deg about y")
    return SurfaceMesh(vertices, triangles, np.column_stack([ss, tt]), what)


def cylinder(z: float = 1000.0, radius: float = 400.0, half_angle_deg: float = 60.0,
             height: float = 1600.0) -> SurfaceMesh:
    """The front of a vertical cylinder (axis parallel to y, like a pipe seen from the side)
    whose nearest line is at depth ``z``, within ``±half_angle_deg`` of that line; texture
    coordinates (arc length, y) mm."""
    _check_positive(z=z, radius=radius, height=height)
    if not 0 < half_angle_deg < 90:
        raise ValueError(f"half_angle_deg must lie in (0, 90), got {half_angle_deg}")
    # sagitta of a chord of angle Δ: r(1 − cos(Δ/2)) ≈ rΔ²/8 ≤ MAX_CHORD_ERROR_MM
    step = np.sqrt(8 * MAX_CHORD_ERROR_MM / radius)
    arc = 2 * np.radians(half_angle_deg) * radius
    s = _steps(arc, step * radius, hint=" (use a smaller --surface-radius or --half-angle)")
    t = np.array([-height / 2, height / 2])
    axis_z = z + radius

    def point_of(ss, tt):
        theta = ss / radius
        return np.stack([radius * np.sin(theta), tt, axis_z - radius * np.cos(theta)], axis=-1)

    vertices, triangles, ss, tt = _grid(s, t, point_of)
    return SurfaceMesh(vertices, triangles, np.column_stack([ss, tt]),
                       f"cylinder of radius {radius:g} mm, nearest line at z {z:g} mm, "
                       f"+-{half_angle_deg:g} deg")


def sphere_cap(z: float = 1000.0, radius: float = 400.0, half_angle_deg: float = 60.0) -> SurfaceMesh:
    """The cap of a sphere (convex towards the cameras) whose nearest point is at depth ``z``,
    up to ``half_angle_deg`` from that point; texture coordinates: the azimuthal equidistant
    map around it (arc length from the nearest point along each meridian), mm, which keeps
    speckle sizes within ``θ/sin θ`` (≤ 1.21 at 60°) of their size at the centre."""
    _check_positive(z=z, radius=radius)
    if not 0 < half_angle_deg < 90:
        raise ValueError(f"half_angle_deg must lie in (0, 90), got {half_angle_deg}")
    # a flat triangle of side δ on a sphere of radius r departs from it by about δ²/(8r)... over
    # the triangle's circumscribed circle (side δ·√2 for the diagonal): δ²/(4r)
    spacing = np.sqrt(4 * MAX_CHORD_ERROR_MM * radius)
    extent = np.radians(half_angle_deg) * radius
    cells = 2 * extent / spacing
    s = _steps(2 * extent, spacing, int(min(np.ceil(cells), MAX_TRIANGLES)),
               hint=" (use a smaller --surface-radius or --half-angle)")
    centre = np.array([0.0, 0.0, z + radius])

    def point_of(ss, tt):
        arc = np.hypot(ss, tt)
        polar = np.minimum(arc, extent) / radius
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(arc > 0, np.sin(polar) / np.where(arc > 0, arc, 1.0), 0.0)
        direction = np.stack([ss * scale, tt * scale, -np.cos(polar)], axis=-1)
        return centre + radius * direction

    vertices, triangles, ss, tt = _grid(s, s, point_of)
    inside = np.hypot(ss, tt) <= extent + 1e-9
    keep = inside[triangles].all(axis=1)
    used = np.unique(triangles[keep])
    remap = np.full(vertices.shape[0], -1)
    remap[used] = np.arange(used.size)
    return SurfaceMesh(vertices[used], remap[triangles[keep]],
                       np.column_stack([ss, tt])[used],
                       f"sphere cap of radius {radius:g} mm, nearest point at z {z:g} mm, "
                       f"+-{half_angle_deg:g} deg")


def wavy(z: float = 1000.0, amplitude: float = 20.0, wavelength: float = 300.0,
         half_size=(900.0, 750.0), centre_x: float = 100.0) -> SurfaceMesh:
    """A sinusoidal sheet ``Z = z + amplitude·sin(2π (X − centre_x) / wavelength)`` over the
    rectangle of :func:`plane`; texture coordinates (arc length along X, Y) mm."""
    _check_positive(z=z, amplitude=amplitude, wavelength=wavelength)
    k = 2 * np.pi / wavelength
    # chord error of a step δ on a curve of curvature ≤ A k²: A k² δ² / 8
    step = np.sqrt(8 * MAX_CHORD_ERROR_MM / (amplitude * k * k))
    x = _steps(2 * half_size[0], step,
               hint=" (use a longer --wavelength or a smaller --wave-amplitude)")
    profile = amplitude * np.sin(k * x)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(profile)))])
    arc -= np.interp(0.0, x, arc)
    t = np.array([-half_size[1], half_size[1]])

    def point_of(ss, tt):
        return np.stack([ss + centre_x, tt, z + amplitude * np.sin(k * ss)], axis=-1)

    vertices, triangles, ss, tt = _grid(x, t, point_of)
    arc_of = np.interp(ss, x, arc)
    return SurfaceMesh(vertices, triangles, np.column_stack([arc_of, tt]),
                       f"wavy sheet at z {z:g} mm, amplitude {amplitude:g} mm, wavelength "
                       f"{wavelength:g} mm")


def planar_uv(vertices: np.ndarray, normal) -> np.ndarray:
    """Texture coordinates (mm) of a user's mesh: its vertices projected onto the plane
    perpendicular to ``normal`` (the port normal), in a basis of that plane. Speckles stretch by
    ``1/cos`` of the surface's slope away from that plane."""
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = a - n * (a @ n)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return np.column_stack([vertices @ e1, vertices @ e2])


def from_arrays(vertices, triangles, normal, description: str) -> SurfaceMesh:
    """A :class:`SurfaceMesh` of a user's mesh (texture coordinates by :func:`planar_uv`).
    ValueError (one line) if it is empty, not finite or has out-of-range indices."""
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    if vertices.shape[0] < 3 or triangles.shape[0] == 0:
        raise ValueError("the mesh is empty (no triangles)")
    if not np.all(np.isfinite(vertices)):
        raise ValueError("the mesh has vertices that are not finite")
    if triangles.min() < 0 or triangles.max() >= vertices.shape[0]:
        raise ValueError("the mesh has triangle indices outside its vertex list")
    edges = np.cross(vertices[triangles[:, 1]] - vertices[triangles[:, 0]],
                     vertices[triangles[:, 2]] - vertices[triangles[:, 0]])
    if not np.any(np.linalg.norm(edges, axis=1) > 0):
        raise ValueError("every triangle of the mesh is degenerate (zero area)")
    return SurfaceMesh(vertices, triangles, planar_uv(vertices, normal), description)


# ---------------------------------------------------------------------------------------------
# PLY files (binary little endian): x y z as float32, u v as float32, triangles as int32
# ---------------------------------------------------------------------------------------------
#: The header comment :func:`write_ply` puts after the mesh's description: with the header's
#: layout it tells a mesh ``python -m synth scene`` wrote (:func:`written_by_write_ply`).
PLY_MARK = "comment units mm, reference frame of the left camera"
_PLY_HEAD = ("ply", "format binary_little_endian 1.0")
_PLY_LAYOUT = ("property float x", "property float y", "property float z", "property float u",
               "property float v", "property list uchar int vertex_indices")


def written_by_write_ply(path) -> bool:
    """Whether ``path`` is a mesh file as :func:`write_ply` writes it: its header is
    ``ply``, the binary format, the description comment, :data:`PLY_MARK`, the vertex (x y z u v
    floats) and face elements and nothing else, and the file is exactly as long as the header
    says. Any other file (a user's mesh, one edited by another program, a truncated one) is not."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
            size = os.fstat(handle.fileno()).st_size
    except OSError:
        return False
    end = head.find(b"end_header\n")
    if end < 0:
        return False
    lines = head[:end].decode("ascii", "replace").splitlines()
    if (len(lines) != 12 or tuple(lines[:2]) != _PLY_HEAD or not lines[2].startswith("comment ")
            or lines[3] != PLY_MARK):
        return False
    vertex, face = lines[4].split(), lines[10].split()
    if (vertex[:2] != ["element", "vertex"] or face[:2] != ["element", "face"]
            or len(vertex) != 3 or len(face) != 3 or not (vertex[2] + face[2]).isdigit()
            or tuple(lines[5:10]) + (lines[11],) != _PLY_LAYOUT):
        return False
    return size == end + len(b"end_header\n") + 20 * int(vertex[2]) + 13 * int(face[2])


def write_ply(path, mesh: SurfaceMesh, uv_lower, uv_upper) -> None:
    """Write ``mesh`` as a binary PLY Mitsuba's ``ply`` plugin reads, atomically; texture
    coordinates normalised to [0, 1] over ``[uv_lower, uv_upper]`` (mm)."""
    from synth.infra.fileio import atomic_write_bytes

    lower, upper = np.asarray(uv_lower, float), np.asarray(uv_upper, float)
    uv = (mesh.uv_mm - lower) / (upper - lower)
    n_v, n_t = mesh.vertices.shape[0], mesh.triangles.shape[0]
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"comment {mesh.description}\n{PLY_MARK}\n"
              f"element vertex {n_v}\nproperty float x\nproperty float y\nproperty float z\n"
              "property float u\nproperty float v\n"
              f"element face {n_t}\nproperty list uchar int vertex_indices\nend_header\n")
    vertex_data = np.empty(n_v, dtype=[("p", "<f4", 3), ("uv", "<f4", 2)])
    vertex_data["p"] = mesh.vertices
    vertex_data["uv"] = uv
    face_data = np.empty(n_t, dtype=[("n", "u1"), ("i", "<i4", 3)])
    face_data["n"] = 3
    face_data["i"] = mesh.triangles
    atomic_write_bytes(path, header.encode("ascii") + vertex_data.tobytes() + face_data.tobytes())


def read_ply(path) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3) float64, triangles (T, 3) int64)`` of a PLY written by
    :func:`write_ply` (the float32 values the renderer sees, widened). ValueError otherwise."""
    path = os.fspath(path)
    with open(path, "rb") as handle:
        data = handle.read()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise ValueError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii", "replace").splitlines()
    counts = {line.split()[1]: int(line.split()[2]) for line in header
              if line.startswith("element ")}
    if ("format binary_little_endian 1.0" not in header or "vertex" not in counts
            or "face" not in counts or "property float u" not in header):
        raise ValueError(f"{path}: not a surface mesh written by python -m synth scene")
    body = data[end + len(b"end_header\n"):]
    n_v, n_t = counts["vertex"], counts["face"]
    vertex_dtype = np.dtype([("p", "<f4", 3), ("uv", "<f4", 2)])
    face_dtype = np.dtype([("n", "u1"), ("i", "<i4", 3)])
    expected = n_v * vertex_dtype.itemsize + n_t * face_dtype.itemsize
    if len(body) != expected:
        raise ValueError(f"{path}: truncated or malformed PLY ({len(body)} bytes of data, "
                         f"expected {expected})")
    vertices = np.frombuffer(body, vertex_dtype, n_v)["p"].astype(np.float64)
    faces = np.frombuffer(body, face_dtype, n_t, offset=n_v * vertex_dtype.itemsize)
    return vertices, faces["i"].astype(np.int64)

