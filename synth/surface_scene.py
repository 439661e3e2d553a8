"""``python -m synth scene --layout surface``: a speckled surface behind the port, as three
files — the scene XML, its mesh (``<scene stem>_surface.ply``) and its speckle texture
(``speckle_<dot>mm_<coverage>_<seed>_<W>x<H>mm.png``, named by what determines its bytes, so
scenes with the same pattern share one file) — in the scene file's directory.

Texture space: the surface's texture coordinates (mm of surface, :mod:`synth.surfaces`)
centred on the texture, which covers at least :data:`MIN_TEXTURE_EXTENT_MM` (rounded up to
200 mm steps), so all the default surfaces at 1 m share one texture.
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from synth import speckle, surfaces
from synth.scene import SurfaceFiles, write_scene

#: Smallest extent of a speckle texture, mm (width, height).
MIN_TEXTURE_EXTENT_MM = (2000.0, 1600.0)
#: Surfaces are written only when at least this many pixels of a coarse grid (every
#: :data:`CHECK_STEP_PX`) of the left image see them and the right camera sees them there too.
CHECK_STEP_PX, MIN_OVERLAP_SAMPLES = 8, 20
#: Finest speckle that renders without aliasing: a dot at least this many pixels wide at the
#: surface's nearest depth (the warning threshold).
MIN_DOT_PX = 1.0


def build_mesh(args, port_normal) -> surfaces.SurfaceMesh:
    """The mesh that the ``--surface`` options describe (ValueError, one line, on bad input)."""
    kind = args.surface
    if kind == "plane":
        return surfaces.plane(args.z)
    if kind == "tilted":
        return surfaces.plane(args.z, tilt_deg=tuple(args.tilt))
    if kind in ("cylinder", "sphere"):
        if not args.half_angle < 90:
            raise ValueError(f"--half-angle must lie in (0, 90) degrees, got {args.half_angle:g}")
        mesh = (surfaces.cylinder if kind == "cylinder" else surfaces.sphere_cap)(
            args.z, args.surface_radius, args.half_angle)
        if mesh.triangles.shape[0] == 0:
            raise ValueError(f"--half-angle {args.half_angle:g}: the {kind} is too small to "
                             f"hold a triangle")
        return mesh
    if kind == "wavy":
        return surfaces.wavy(args.z, args.wave_amplitude, args.wavelength)
    if not args.mesh:
        raise ValueError("--surface mesh needs --mesh FILE (PLY or OBJ, mm, reference frame)")
    vertices, triangles = read_user_mesh(args.mesh)
    return surfaces.from_arrays(vertices, triangles, port_normal,
                                f"user mesh {os.path.basename(args.mesh)}")


def read_user_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(V, 3)`` and triangles ``(T, 3)`` of a PLY or OBJ file, read by Mitsuba's
    own loaders (what the renderer would read). ValueError naming the file otherwise."""
    from synth.mitsuba_setup import import_mitsuba

    path = os.fspath(path)
    extension = os.path.splitext(path)[1].lower()
    if extension not in (".ply", ".obj"):
        raise ValueError(f"--mesh {path}: expected a .ply or .obj file")
    if not os.path.isfile(path):
        raise ValueError(f"--mesh {path}: no such file")
    if os.path.getsize(path) == 0:
        raise ValueError(f"--mesh {path}: the file is empty")
    mi, _ = import_mitsuba()
    try:
        mesh = mi.load_dict({"type": extension[1:], "filename": os.path.abspath(path)})
    except Exception as exc:  # Mitsuba raises RuntimeError with a multi-line message
        first = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"--mesh {path}: Mitsuba cannot read it ({first.strip()})") from None
    vertices = np.array(mesh.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
    triangles = np.array(mesh.faces_buffer(), dtype=np.int64).reshape(-1, 3)
    if triangles.shape[0] == 0:
        raise ValueError(f"--mesh {path}: the mesh has no triangles")
    return vertices, triangles


def texture_extent(mesh: surfaces.SurfaceMesh) -> np.ndarray:
    """The speckle texture's extent (width, height), mm, for ``mesh`` (see the module)."""
    lower, upper = mesh.uv_extent
    needed = np.maximum(upper - lower, MIN_TEXTURE_EXTENT_MM)
    return np.ceil(needed / 200.0) * 200.0


def texture_name(dot_mm: float, coverage: float, seed: int, extent) -> str:
    return (f"speckle_{dot_mm:g}mm_{coverage:g}_{seed}_{extent[0]:.0f}x{extent[1]:.0f}mm.png")


def companion_paths(scene_path: str) -> str:
    """The mesh file written beside ``scene_path``."""
    stem, _ = os.path.splitext(scene_path)
    return stem + "_surface.ply"


def write_texture(path: str, dot_mm: float, coverage: float, seed: int, extent) -> bool:
    """Write the speckle texture unless ``path`` already holds it (same name = same bytes);
    returns whether it was written."""
    from synth.fileio import atomic_write_bytes

    if os.path.isfile(path):
        existing = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        rows, cols, _ = speckle.texture_shape(extent, dot_mm)
        if existing is not None and existing.shape == (rows, cols):
            return False
    image = speckle.speckle_texture(extent, dot_mm, coverage, seed)
    ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise OSError(f"cannot encode the speckle texture {path}")
    atomic_write_bytes(path, data.tobytes())
    return True


def overlap_samples(tracer, left, right, port) -> np.ndarray:
    """The surface points ``(M, 3)`` that pixels of a coarse grid of the left image see where
    the right camera sees them too (``tracer`` a :class:`synth.truth_maps.MeshTracer`)."""
    from synth.truth_maps import hits_of_pixels, pixel_grid, seen_by

    points = hits_of_pixels(tracer, left, port, pixel_grid(left.size, CHECK_STEP_PX))
    return points[seen_by(tracer, right, port, points)]


def back_facing_fraction(tracer, camera, port) -> float:
    """The fraction of a coarse grid of ``camera``'s pixels that meet the surface whose first
    hit is the *back* of a triangle (the side its winding turns away; Mitsuba's diffuse and
    area-light surfaces are one-sided, so the back renders black). 0 if no pixel meets it."""
    from measure.refraction import trace_through_port

    from synth.truth_maps import pixel_grid

    water = trace_through_port(camera.center, camera.rays(pixel_grid(camera.size, CHECK_STEP_PX)),
                               port, keep_interface_points=False)
    hit = tracer.first_triangles(water.origins, water.directions)
    seen = hit >= 0
    if not seen.any():
        return 0.0
    v = tracer.vertices[tracer.triangles[hit[seen]]]
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return float(np.mean(np.einsum("ij,ij->i", normal, water.directions[seen]) > 0))


def dot_pixels(points, left, port, dot_mm: float) -> np.ndarray:
    """About how many pixels of the left image a speckle dot spans at each surface point
    ``(M, 3)`` (its width along x, px)."""
    from measure.projection import project

    shifted = points + [dot_mm, 0.0, 0.0]
    return np.linalg.norm(project(left, port, shifted) - project(left, port, points), axis=1)


def write_surface_scene(out: str, args, left, right, port, **scene_options) -> str:
    """Write the scene ``out``, its mesh and (unless present) its texture; returns the summary
    line. ``port`` None: an all-air scene. Nothing is left behind on failure."""
    import sys
    import tempfile

    from synth.truth_maps import MeshTracer

    from measure import StereoRig

    geometry_port = StereoRig(left, right, port).port
    mesh = build_mesh(args, geometry_port.normal)
    move = "move the mesh" if args.surface == "mesh" else "move it with --z"
    if port is not None and not np.all(port.water_side(mesh.vertices)):
        raise ValueError(f"the surface reaches out of the water: every vertex must lie beyond the "
                         f"port's last interface ({move})")
    extent = texture_extent(mesh)
    try:  # refuses an oversized texture early
        rows, cols, _ = speckle.texture_shape(extent, args.speckle_size)
    except ValueError as exc:
        raise ValueError(f"--speckle-size {args.speckle_size:g}: {exc}") from None
    if min(rows, cols) < 4 * speckle.TEXELS_PER_DOT:
        print(f"warning: --speckle-size {args.speckle_size:g} mm: fewer than 4 dots across the "
              f"surface's texture ({extent[0]:.0f} x {extent[1]:.0f} mm), nothing to match",
              file=sys.stderr)
    lower = (mesh.uv_extent[0] + mesh.uv_extent[1]) / 2 - extent / 2
    directory = os.path.dirname(os.path.abspath(out))
    mesh_path = companion_paths(out)
    texture_file = texture_name(args.speckle_size, args.speckle_coverage, args.speckle_seed, extent)
    fd, tmp_mesh = tempfile.mkstemp(prefix=".surface-", suffix=".ply", dir=directory)
    os.close(fd)
    written = []
    try:
        surfaces.write_ply(tmp_mesh, mesh, lower, lower + extent)
        tracer = MeshTracer(tmp_mesh, *surfaces.read_ply(tmp_mesh))
        seen = overlap_samples(tracer, left, right, geometry_port)
        if seen.shape[0] < MIN_OVERLAP_SAMPLES:
            raise ValueError(f"--surface {args.surface}: the surface is not seen by both cameras "
                             f"(fewer than {MIN_OVERLAP_SAMPLES} samples of the left image every "
                             f"{CHECK_STEP_PX} px; {move} or make it larger)")
        back = max(back_facing_fraction(tracer, camera, geometry_port)
                   for camera in (left, right))
        if back > 0.5:
            what = (f"--mesh {args.mesh}: its triangles are wound the other way (reverse their "
                    f"vertex order); " if args.surface == "mesh" else
                    f"--tilt {args.tilt[0]:g} {args.tilt[1]:g}: " if args.surface == "tilted"
                    else f"--surface {args.surface}: ")
            raise ValueError(f"{what}the cameras see the back of the surface, which renders "
                             f"black ({100 * back:.0f} % of the pixels that see it)")
        if back > 0:
            print(f"warning: --surface {args.surface}: the cameras see the back of the surface "
                  f"in {100 * back:.1f} % of the pixels that see it (black in the images)",
                  file=sys.stderr)
        dot_px = dot_pixels(seen, left, geometry_port, args.speckle_size)
        if dot_px.min() < MIN_DOT_PX:
            print(f"warning: --speckle-size {args.speckle_size:g} mm is down to "
                  f"{dot_px.min():.2f} px on the surface: below one pixel the speckle aliases",
                  file=sys.stderr)
        texture_path = os.path.join(directory, texture_file)
        if write_texture(texture_path, args.speckle_size, args.speckle_coverage,
                         args.speckle_seed, extent):
            written.append(texture_path)
        os.replace(tmp_mesh, mesh_path)
        written.append(mesh_path)
        files = SurfaceFiles(mesh=os.path.basename(mesh_path), texture=texture_file)
        write_scene(out, (left, right), port, mesh.vertices, 1.0, surface=files, **scene_options)
    except BaseException:
        for path in [tmp_mesh, *written]:
            if os.path.exists(path):
                os.unlink(path)
        raise
    return (f"wrote {out}: {mesh.description}, {mesh.triangles.shape[0]} triangles "
            f"({os.path.basename(mesh_path)}), speckle {args.speckle_size:g} mm dots "
            f"({np.min(dot_px):.1f}-{np.max(dot_px):.1f} px) at {args.speckle_coverage:g} coverage "
            f"({texture_file}), "
            f"{'port' if port else 'no port'}, {left.size[0]}x{left.size[1]} px")
