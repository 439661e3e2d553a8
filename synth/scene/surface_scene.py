"""``python -m synth scene --layout surface``: a speckled surface behind the port, as three
files — the scene XML, its mesh (``<scene stem>_surface.ply``) and its speckle texture
(``speckle_<dot>mm_<coverage>_<seed>_<W>x<H>mm.png``, named by what determines its bytes, so
scenes with the same pattern share one file) — in the scene file's directory. None of them is
written over a file this command did not write: the mesh is replaced only if it is a mesh as
:func:`synth.scene.surfaces.write_ply` writes it, the texture is used only if its pixels are the
texture (:func:`write_texture`); anything else is refused, one line, nothing written
(docs/scenes.md, "Files beside the scene").

Texture space: the surface's texture coordinates (mm of surface, :mod:`synth.scene.surfaces`)
centred on the texture, which covers at least :data:`MIN_TEXTURE_EXTENT_MM` (rounded up to
200 mm steps), so all the default surfaces at 1 m share one texture.
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from synth.rendering import speckle
from synth.scene import surfaces
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
    from synth.rendering.mitsuba_setup import import_mitsuba

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


def texture_problem(path: str, dot_mm: float, extent) -> str | None:
    """Why the file at the texture's ``path`` is not this command's texture, judged cheaply
    (unreadable as an 8-bit grey PNG, or another size); None if it may be (its pixels are
    compared in :func:`write_texture`) or if there is no file."""
    if not os.path.lexists(path):
        return None
    rows, cols, _ = speckle.texture_shape(extent, dot_mm)
    existing = cv2.imread(path, cv2.IMREAD_UNCHANGED) if os.path.isfile(path) else None
    if existing is None or existing.dtype != np.uint8:
        return "is not an 8-bit grey PNG"
    if existing.shape != (rows, cols):
        return (f"is {existing.shape[1]} x {existing.shape[0]} "
                f"{'texels' if existing.ndim == 2 else 'px in colour'}, not {cols} x {rows}")
    return None


def texture_error(path: str, why: str, dot_mm: float, coverage: float, seed: int,
                  label: str = "--out") -> str:
    """The one-line refusal of a file at the texture's ``path`` that is not the texture
    (``label`` says whose: ``--out SCENE``)."""
    return (f"{label}: the speckle texture {path} exists and {why}, not the texture python -m "
            f"synth scene writes for --speckle-size {dot_mm:g} --speckle-coverage {coverage:g} "
            f"--speckle-seed {seed} (move it away or write the scene into another directory)")


def write_texture(path: str, dot_mm: float, coverage: float, seed: int, extent,
                  label: str = "--out") -> bool:
    """Write the speckle texture at ``path`` unless the file there already is it (same name,
    same pixels: scenes share it); returns whether it was written. A file there that holds
    anything else was not written by this command: ValueError naming it, nothing written."""
    from synth.infra.fileio import atomic_create_bytes

    problem = texture_problem(path, dot_mm, extent)
    if problem:
        raise ValueError(texture_error(path, problem, dot_mm, coverage, seed, label))
    image = speckle.speckle_texture(extent, dot_mm, coverage, seed)
    if os.path.lexists(path):
        if np.array_equal(cv2.imread(path, cv2.IMREAD_UNCHANGED), image):
            return False
        raise ValueError(texture_error(path, "holds other pixels", dot_mm, coverage, seed, label))
    ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise OSError(f"cannot encode the speckle texture {path}")
    try:
        atomic_create_bytes(path, data.tobytes())
    except FileExistsError:  # appeared meanwhile: judge it like any other
        return write_texture(path, dot_mm, coverage, seed, extent, label)
    return True


def mesh_problem(mesh_path: str, label: str = "--out") -> str | None:
    """The error (one line) when the mesh file beside the scene exists and was not written by
    ``python -m synth scene`` (:func:`synth.scene.surfaces.written_by_write_ply`); None otherwise."""
    if not os.path.lexists(mesh_path) or (os.path.isfile(mesh_path)
                                          and surfaces.written_by_write_ply(mesh_path)):
        return None
    return (f"{label}: the scene's mesh {mesh_path} exists and is not a surface mesh python -m "
            f"synth scene wrote (move it away or choose another --out)")


def overlap_samples(tracer, left, right, port) -> np.ndarray:
    """The surface points ``(M, 3)`` that pixels of a coarse grid of the left image see where
    the right camera sees them too (``tracer`` a :class:`synth.products.truth_maps.MeshTracer`)."""
    from synth.products.truth_maps import hits_of_pixels, pixel_grid, seen_by

    points = hits_of_pixels(tracer, left, port, pixel_grid(left.size, CHECK_STEP_PX))
    return points[seen_by(tracer, right, port, points)]


def back_facing_fraction(tracer, camera, port) -> float:
    """The fraction of a coarse grid of ``camera``'s pixels that meet the surface whose first
    hit is the *back* of a triangle (the side its winding turns away; Mitsuba's diffuse and
    area-light surfaces are one-sided, so the back renders black). 0 if no pixel meets it."""
    from measure.geometry.refraction import trace_through_port

    from synth.products.truth_maps import pixel_grid

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
    from measure.geometry.projection import project

    shifted = points + [dot_mm, 0.0, 0.0]
    return np.linalg.norm(project(left, port, shifted) - project(left, port, points), axis=1)


def write_surface_scene(out: str, args, left, right, port, **scene_options) -> str:
    """Write the scene ``out``, its mesh and (unless present) its texture; returns the summary
    line. ``port`` None: an all-air scene. Nothing is left behind on failure."""
    import tempfile

    from synth.products.truth_maps import MeshTracer

    from measure import StereoRig

    geometry_port = StereoRig(left, right, port).port
    mesh = build_mesh(args, geometry_port.normal)
    move = "move the mesh" if args.surface == "mesh" else "move it with --z"
    if port is not None and not np.all(port.water_side(mesh.vertices)):
        raise ValueError(f"the surface reaches out of the water: every vertex must lie beyond the "
                         f"port's last interface ({move})")
    extent = _texture_extent(args, mesh)
    lower = (mesh.uv_extent[0] + mesh.uv_extent[1]) / 2 - extent / 2
    directory = os.path.dirname(os.path.abspath(out))
    mesh_path = companion_paths(out)
    texture_file = texture_name(args.speckle_size, args.speckle_coverage, args.speckle_seed, extent)
    texture_path = os.path.join(directory, texture_file)
    texture_display = os.path.join(os.path.dirname(out), texture_file)
    # the files beside the scene: replaced (the mesh) or used (the texture) only if ours
    label = f"--out {out}"
    problem = mesh_problem(mesh_path, label)
    if problem:
        raise ValueError(problem)
    problem = texture_problem(texture_path, args.speckle_size, extent)
    if problem:
        raise ValueError(texture_error(texture_display, problem, args.speckle_size,
                                       args.speckle_coverage, args.speckle_seed, label))
    fd, tmp_mesh = tempfile.mkstemp(prefix=".surface-", suffix=".ply", dir=directory)
    os.close(fd)
    written, old_mesh = [], None
    try:
        surfaces.write_ply(tmp_mesh, mesh, lower, lower + extent)
        tracer = MeshTracer(tmp_mesh, *surfaces.read_ply(tmp_mesh))
        dot_px = _check_sight(args, tracer, left, right, geometry_port, move)
        if write_texture(texture_display, args.speckle_size, args.speckle_coverage,
                         args.speckle_seed, extent, label):
            written.append(texture_path)
        problem = mesh_problem(mesh_path, label)  # again: it may have appeared meanwhile
        if problem:
            raise ValueError(problem)
        old_mesh = _set_aside(mesh_path, directory)
        os.replace(tmp_mesh, mesh_path)
        written.append(mesh_path)
        files = SurfaceFiles(mesh=os.path.basename(mesh_path), texture=texture_file)
        write_scene(out, (left, right), port, mesh.vertices, 1.0, surface=files, **scene_options)
    except BaseException:
        for path in [tmp_mesh, *written]:
            if os.path.exists(path):
                os.unlink(path)
        if old_mesh is not None:
            os.replace(old_mesh, mesh_path)
        raise
    if old_mesh is not None:
        os.unlink(old_mesh)
    return (f"wrote {out}: {mesh.description}, {mesh.triangles.shape[0]} triangles "
            f"({os.path.basename(mesh_path)}), speckle {args.speckle_size:g} mm dots "
            f"({np.min(dot_px):.1f}-{np.max(dot_px):.1f} px) at {args.speckle_coverage:g} coverage "
            f"({texture_file}), "
            f"{'port' if port else 'no port'}, {left.size[0]}x{left.size[1]} px")


def _texture_extent(args, mesh) -> np.ndarray:
    """The speckle texture's extent (mm) over ``mesh``; ValueError for a texture too large, a
    warning for one with fewer than 4 dots across."""
    import sys

    extent = texture_extent(mesh)
    try:  # refuses an oversized texture early
        rows, cols, _ = speckle.texture_shape(extent, args.speckle_size)
    except ValueError as exc:
        raise ValueError(f"--speckle-size {args.speckle_size:g}: {exc}") from None
    if min(rows, cols) < 4 * speckle.TEXELS_PER_DOT:
        print(f"warning: --speckle-size {args.speckle_size:g} mm: fewer than 4 dots across the "
              f"surface's texture ({extent[0]:.0f} x {extent[1]:.0f} mm), nothing to match",
              file=sys.stderr)
    return extent


def _check_sight(args, tracer, left, right, geometry_port, move) -> np.ndarray:
    """The speckle dots' size (px) where the left camera sees the surface; ValueError for a
    surface both cameras do not see or whose back they see, warnings for some back or dots
    below a pixel."""
    import sys

    seen = overlap_samples(tracer, left, right, geometry_port)
    if seen.shape[0] < MIN_OVERLAP_SAMPLES:
        raise ValueError(f"--surface {args.surface}: the surface is not seen by both cameras "
                         f"(fewer than {MIN_OVERLAP_SAMPLES} samples of the left image every "
                         f"{CHECK_STEP_PX} px; {move} or make it larger)")
    back = max(back_facing_fraction(tracer, camera, geometry_port) for camera in (left, right))
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
    return dot_px


def _set_aside(mesh_path, directory):
    """An earlier mesh of ours moved to a temporary name beside it (put back if the new one
    fails); its path, or None when there was none."""
    import tempfile

    if not os.path.lexists(mesh_path):
        return None
    fd, kept = tempfile.mkstemp(prefix=".surface-old-", suffix=".ply", dir=directory)
    os.close(fd)
    try:
        os.replace(mesh_path, kept)
    except BaseException:
        os.unlink(kept)
        raise
    return kept
