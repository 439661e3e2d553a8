"""A drawn sea scene (:mod:`synth.scene.sea_draw`) as files: a Mitsuba 3 scene, the sea floor's
mesh and its texture — ``scene.xml``, ``seabed.ply``, ``seabed_texture.png`` — which together
render its images (the XML holds ``spp`` and ``seed`` as ``<default>`` values).

The scene file is a genuine Mitsuba 3 XML scene in millimetres in the reference frame (the left
camera's, OpenCV axes), with the shape ids :func:`synth.scene.load_scene` knows (``left`` and
``right`` sensors; ``interface_<k>`` rectangles of one flat port, ``<camera>_interface_<k>``
windows of two housings or ``dome_<camera>_{inner,outer}`` spheres; the mesh ``surface``, its
texture ``speckle``). The water (a Petzold preset of :mod:`synth.rendering.water`; none when
clear) is the ``homogeneous`` medium on the water side of the port's last interface: the
``interior`` of the last flat rectangle(s), the ``exterior`` of each dome's outer sphere. Lights
are ``spot`` emitters in the water: two ``lamps`` 150 mm to each side of the housing, 30 mm
beyond the glass, aimed at the floor point the rig looks at; or the ``sun``, 3 m from that
point at a drawn zenith angle of 35–55° on the far side from the rig (the renderer's glass
passes no light to a sampled light, so a sun behind the housing would shade the floor with
its window), wide enough to light the whole patch (its intensity grows with the water's
attenuation over its path, so that the floor is about as bright in every water).

The sea floor is a heightfield (:mod:`synth.scene.seabed`) over the patch both cameras see (their
border and a grid of rays traced through the port to the floor's lowest plane, 15 % more on each
side, at most 3.5 × the rig's distance from the point it looks at), optionally with the user's
object meshes set on it (merged into the one mesh: the truth traces what the renderer sees).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from synth.rendering.water import PRESETS as WATER_PRESETS
from synth.scene.dome import dome_placements
from synth.scene.model import SPECKLE_ID, SURFACE_ID
from synth.scene.sea_draw import SeaScene, seed_streams
from synth.scene.sea_objects import (STRIP_TEXELS, object_strip, object_uv, place_objects,
                                     read_object)
from synth.scene.seabed import (MAX_TEXELS, MIN_TEXEL_MM, grid_axes, seabed_heights, seabed_mesh,
                                seabed_texture)
from synth.scene.surfaces import SurfaceMesh, write_ply
from synth.scene.windows import camera_names, fit_windows, window_placements
from synth.scene.write import WATER_MAX_DEPTH, interface_placements, sensor_xml

SCENE_FILE, MESH_FILE, TEXTURE_FILE = "scene.xml", "seabed.ply", "seabed_texture.png"
#: Radiant intensity of each lamp at a rig 1 m from the floor (scaled with the distance²), and
#: the floor irradiance the sun gives after its path through the water (scene units).
LAMP_INTENSITY_AT_1M, SUN_IRRADIANCE = 1.5e6, 4.0
#: The lamps: this far beside the housing's outer edge, this far beyond the glass (mm); their
#: beam and cut-off half-angles (degrees). The sun's height above the floor (mm).
LAMP_SIDE_MM, LAMP_AHEAD_MM, LAMP_BEAM_DEG, LAMP_CUTOFF_DEG = 150.0, 30.0, 50.0, 70.0
SUN_HEIGHT_MM = 3000.0
#: Pixels between the rays traced to find the floor patch, and the patch's reach.
FOOTPRINT_STEP_PX, FOOTPRINT_MARGIN, MAX_REACH = 32, 0.15, 3.5
DEFAULT_LEARN_SPP = 8
#: Glass beyond the outermost ray of a shared flat port's window, mm.
WINDOW_MARGIN_MM = 20.0
PATH_MAX_DEPTH = 5


@dataclass(frozen=True)
class SeaFloor:
    """The floor of a scene: its ``mesh`` (reference frame, objects included), the heightfield
    grid ``x``, ``y`` (mm, seabed frame), the texture's ``lower`` corner and texel size (mm), its
    size (texels, rows first), and what was drawn of each object placed on it."""

    mesh: SurfaceMesh
    x: np.ndarray
    y: np.ndarray
    lower: np.ndarray
    texel_mm: float
    texture_shape: tuple
    objects: list = field(default_factory=list)


def _fmt(x) -> str:
    x = float(x)
    return str(int(x)) if x.is_integer() and abs(x) < 1e15 else repr(x)


def _vec(v) -> str:
    return ", ".join(_fmt(x) for x in v)


def _to_sea(scene: SeaScene):
    """``(R, t)`` taking reference-frame points into the seabed frame."""
    R, t = scene.to_reference
    return R.T, -R.T @ t


def _pixel_border_grid(size, step: int) -> np.ndarray:
    w, h = size
    u = np.r_[np.arange(0, w, step), w - 1]
    v = np.r_[np.arange(0, h, step), h - 1]
    uu, vv = np.meshgrid(u.astype(float), v.astype(float))
    return np.column_stack([uu.ravel(), vv.ravel()])


def floor_patch(scene: SeaScene, depth_margin_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` corners (mm, seabed frame ``x, y``) of the floor both cameras see
    (module docs); ``depth_margin_mm`` lowers the plane the rays are cut with (the relief)."""
    R_sea, t_sea = _to_sea(scene)
    look = np.asarray(scene.drawn["look_at_mm"][:2])
    gx, gy = scene.seabed.slope
    normal = np.array([-gx, -gy, 1.0])
    level = normal @ np.r_[look, 0.0] - depth_margin_mm
    reach = MAX_REACH * scene.distance_mm
    points = []
    for view, camera in enumerate(scene.rig.cameras):
        uv = _pixel_border_grid(camera.size, FOOTPRINT_STEP_PX)
        water = scene.rig.trace(view, camera.rays(uv))
        o = water.origins @ R_sea.T + t_sea
        d = water.directions @ R_sea.T
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (level - o @ normal) / (d @ normal)
        s = np.where(np.isfinite(s) & (s > 0), s, reach)
        hits = o[:, :2] + np.minimum(s, reach)[:, None] * d[:, :2]
        points.append(hits[np.all(np.isfinite(hits), axis=1)])
    points = np.concatenate(points)
    points = look + np.clip(points - look, -reach, reach)
    lower, upper = points.min(axis=0), points.max(axis=0)
    margin = FOOTPRINT_MARGIN * (upper - lower)
    return lower - margin, upper + margin


def build_floor(scene: SeaScene) -> tuple[SeaFloor, np.ndarray]:
    """The floor's mesh (the user's objects set on it and merged in,
    :mod:`synth.scene.sea_objects`) and texture grid, and the texture itself (float
    reflectance, row 0 at the lowest seabed ``y``; the objects' strip after the floor's rows)."""
    _, seabed_rng, texture_rng, objects_rng = seed_streams(scene.seed)
    params = scene.seabed
    depth_margin = 3.0 * params.relief_mm + params.ripple_amplitude_mm
    lower, upper = floor_patch(scene, depth_margin)
    x, y = grid_axes(lower, upper)
    look = scene.drawn["look_at_mm"][:2]
    heights, rocks = seabed_heights(seabed_rng, x, y, params, look)
    mesh = seabed_mesh(x, y, heights, scene.to_reference,
                       f"generated sea floor, seed {scene.seed}")
    focal = scene.rig.left.K[0, 0] * scene.rig.port.view(0).n_water
    nearest = max(float(np.min(np.linalg.norm(mesh.vertices, axis=1))), 100.0)
    extent = float(np.max(upper - lower))
    texel = max(extent / MAX_TEXELS, MIN_TEXEL_MM, 0.5 * nearest / focal)
    shape = tuple(int(np.ceil(s / texel)) + 1 for s in (upper[1] - lower[1], upper[0] - lower[0]))
    texture, _ = seabed_texture(texture_rng, shape, texel, params, rocks > 1.0)
    placed = place_objects(objects_rng, [read_object(p) for p in scene.objects], x, y, heights,
                           look)
    if placed:
        mesh, texture = _with_objects(scene, mesh, texture, placed, lower, texel, objects_rng)
    floor = SeaFloor(mesh, x, y, lower, texel, texture.shape, [p[2] for p in placed])
    return floor, texture


def _with_objects(scene, mesh, texture, placed, lower, texel, rng):
    """The floor's mesh and texture with the placed objects merged in (module docs)."""
    strip, _ = object_strip(rng, texture.shape[1])
    start = np.array([lower[0], lower[1] + texel * texture.shape[0]])
    strip_mm = texel * (STRIP_TEXELS - 1)
    R, t = scene.to_reference
    vertices, triangles, uv = [mesh.vertices], [mesh.triangles], [mesh.uv_mm]
    count = mesh.vertices.shape[0]
    for sea_vertices, faces, _ in placed:
        vertices.append(sea_vertices @ R.T + t)
        triangles.append(faces + count)
        uv.append(object_uv(sea_vertices - sea_vertices.min(axis=0), start, strip_mm, strip_mm))
        count += sea_vertices.shape[0]
    merged = SurfaceMesh(np.concatenate(vertices), np.concatenate(triangles), np.concatenate(uv),
                         mesh.description + f" with {len(placed)} object(s)")
    return merged, np.vstack([texture, strip])


def _lights(scene: SeaScene, water) -> list:
    """``[(origin, target, intensity, beam°, cut-off°)]`` of the scene's spot lights (mm)."""
    rig = scene.rig
    R, t = scene.to_reference
    look = R @ np.r_[scene.drawn["look_at_mm"][:2], 0.0] + t
    c = 0.0 if water is None else water.c_per_m / 1000.0
    if scene.light == "sun":
        zenith, azimuth = np.radians(scene.drawn["sun_zenith_deg"]), np.radians(
            scene.drawn["sun_azimuth_deg"])
        towards = R @ np.array([np.sin(zenith) * np.cos(azimuth),
                                np.sin(zenith) * np.sin(azimuth), np.cos(zenith)])
        origin = look + SUN_HEIGHT_MM * towards
        patch = MAX_REACH * scene.distance_mm
        cutoff = min(float(np.degrees(np.arctan(patch / SUN_HEIGHT_MM))) + 5.0, 89.0)
        intensity = SUN_IRRADIANCE * SUN_HEIGHT_MM ** 2 * np.exp(c * SUN_HEIGHT_MM)
        return [(origin, look, intensity, cutoff - 2.0, cutoff)]
    centre = 0.5 * (rig.left.center + rig.right.center)
    across = rig.right.center - rig.left.center
    across /= np.linalg.norm(across)
    ahead = rig.left.R[:, 2] + rig.right.R[:, 2]
    ahead /= np.linalg.norm(ahead)
    glass = rig.port.glass_depth(rig.left) if scene.port_kind != "dome" else (
        scene.drawn["dome_radius_mm"] + scene.drawn["dome_thickness_mm"])
    half = 0.5 * float(np.linalg.norm(rig.right.center - rig.left.center))
    intensity = LAMP_INTENSITY_AT_1M * (scene.distance_mm / 1000.0) ** 2 * np.exp(
        c * scene.distance_mm)
    lights = []
    for sign in (-1.0, 1.0):
        side = half + glass + LAMP_SIDE_MM
        origin = centre + sign * side * across + (glass + LAMP_AHEAD_MM) * ahead
        lights.append((origin, look, intensity, LAMP_BEAM_DEG, LAMP_CUTOFF_DEG))
    return lights


def _perpendicular(n) -> np.ndarray:
    n = np.asarray(n, float) / np.linalg.norm(n)
    axis = np.array([0.0, -1.0, 0.0]) if abs(n[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    v = axis - n * (axis @ n)
    return v / np.linalg.norm(v)


def _rectangle(sid, centre, target, up, half, ext_ior, int_ior, medium: str) -> str:
    return f"""    <shape type="rectangle" id="{sid}">
        <transform name="to_world">
            <scale x="{_fmt(half[0])}" y="{_fmt(half[1])}"/>
            <lookat origin="{_vec(centre)}" target="{_vec(target)}" up="{_vec(up)}"/>
        </transform>
        <bsdf type="dielectric">
            <float name="ext_ior" value="{_fmt(ext_ior)}"/>
            <float name="int_ior" value="{int_ior}"/>
        </bsdf>{medium}
    </shape>"""


def flat_window_half_side(scene: SeaScene) -> float:
    """Half side (mm) of the square rectangles of a shared flat port: every ray of both cameras'
    image borders crosses every interface inside it, with :data:`WINDOW_MARGIN_MM` to spare (a
    finite window, so that the sun above may light the floor past the housing)."""
    rig, port = scene.rig, scene.rig.port
    reach = 0.0
    for view, camera in enumerate(rig.cameras):
        uv = _pixel_border_grid(camera.size, FOOTPRINT_STEP_PX)
        crossings = rig.trace(view, camera.rays(uv), keep_interface_points=True).interface_points
        for k, offset in enumerate(port.offsets):
            reach = max(reach, float(np.nanmax(np.linalg.norm(
                crossings[k] - port.normal * offset, axis=1))))
    return reach + WINDOW_MARGIN_MM


def port_xml(scene: SeaScene, with_water: bool) -> str:
    """The port's glass (module docs); the water medium on its water side when ``with_water``."""
    rig, parts = scene.rig, []
    if scene.port_kind == "dome":
        for sid, centre, radius, ext_ior, int_ior in dome_placements(rig.port):
            outer = sid.endswith("outer")
            medium = ('\n        <ref name="exterior" id="water"/>' if outer and with_water
                      else "")
            parts.append(f"""    <shape type="sphere" id="{sid}">
        <point name="center" value="{_vec(centre)}"/>
        <float name="radius" value="{_fmt(radius)}"/>
        <bsdf type="dielectric">
            <float name="ext_ior" value="{'$n_water' if outer else _fmt(ext_ior)}"/>
            <float name="int_ior" value="{_fmt(int_ior)}"/>
        </bsdf>{medium}
    </shape>""")
        return "\n".join(parts)
    medium = '\n        <ref name="interior" id="water"/>' if with_water else ""
    if scene.port_kind == "per-camera":
        windows = fit_windows(rig)
        last = {f"{n}_interface_{w.port.n_interfaces - 1}"
                for n, w in zip(camera_names(rig), windows)}
        for sid, centre, target, up, half, ext_ior, int_ior in window_placements(
                windows, camera_names(rig)):
            water_side = sid in last
            parts.append(_rectangle(sid, centre, target, up, half, ext_ior,
                                    "$n_water" if water_side else _fmt(int_ior),
                                    medium if water_side else ""))
        return "\n".join(parts)
    port = rig.port
    half = (flat_window_half_side(scene),) * 2
    for k, centre, target, up, ext_ior, int_ior in interface_placements(port):
        water_side = k == port.n_interfaces - 1
        parts.append(_rectangle(f"interface_{k}", centre, target, up, half, ext_ior,
                                "$n_water" if water_side else _fmt(int_ior),
                                medium if water_side else ""))
    return "\n".join(parts)


def scene_xml(scene: SeaScene, spp: int = DEFAULT_LEARN_SPP) -> str:
    """The text of the scene file (module docs)."""
    water = WATER_PRESETS.get(scene.water)
    rig = scene.rig
    w, h = rig.left.size
    defaults = [("spp", int(spp)), ("seed", int(scene.seed) % 2 ** 31), ("width", w),
                ("height", h), ("n_water", _fmt(rig.port.view(0).n_water)),
                ("max_depth", WATER_MAX_DEPTH if water else PATH_MAX_DEPTH)]
    if water is not None:
        defaults += [("water_c", _fmt(water.c_per_m)), ("water_albedo", _fmt(water.albedo)),
                     ("water_g", _fmt(water.g))]
    parts = ['<?xml version="1.0" encoding="utf-8"?>',
             f"<!-- written by python -m synth learn: sea scene of seed {scene.seed} "
             f"({scene.port_kind} port, {scene.water} water, {scene.light}) -->",
             '<scene version="3.0.0">',
             "    <!-- Units: mm. Frame: the left camera's, OpenCV axes (x right, y down, "
             "z forward). -->"]
    parts += [f'    <default name="{k}" value="{v}"/>' for k, v in defaults]
    parts.append(f"""    <integrator type="{'volpath' if water else 'path'}">
        <integer name="max_depth" value="$max_depth"/>
    </integrator>""")
    if water is not None:
        parts.append(f"""    <!-- The water: {water.name}. Coefficients per metre (scale 0.001: mm). -->
    <medium type="homogeneous" id="water">
        <float name="scale" value="0.001"/>
        <float name="sigma_t" value="$water_c"/>
        <float name="albedo" value="$water_albedo"/>
        <phase type="hg">
            <float name="g" value="$water_g"/>
        </phase>
    </medium>""")
    for name, camera in zip(("left", "right"), rig.cameras):
        parts.append(sensor_xml(name, camera, True))
    for k, (origin, target, intensity, beam, cutoff) in enumerate(_lights(scene, water)):
        up = _vec(_perpendicular(target - origin))
        parts.append(f"""    <emitter type="spot" id="light_{k}">
        <transform name="to_world">
            <lookat origin="{_vec(origin)}" target="{_vec(target)}" up="{up}"/>
        </transform>
        <rgb name="intensity" value="{_fmt(intensity)}"/>
        <float name="cutoff_angle" value="{_fmt(cutoff)}"/>
        <float name="beam_width" value="{_fmt(beam)}"/>
    </emitter>""")
    parts.append(port_xml(scene, water is not None))
    parts.append(f"""    <!-- The sea floor's reflectance (8-bit grey, linear: value / 255). -->
    <texture type="bitmap" id="{SPECKLE_ID}">
        <string name="filename" value="{TEXTURE_FILE}"/>
        <boolean name="raw" value="true"/>
        <string name="filter_type" value="bilinear"/>
    </texture>
    <shape type="ply" id="{SURFACE_ID}">
        <string name="filename" value="{MESH_FILE}"/>
        <bsdf type="twosided">
            <bsdf type="diffuse">
                <ref name="reflectance" id="{SPECKLE_ID}"/>
            </bsdf>
        </bsdf>
    </shape>
</scene>
""")
    return "\n".join(parts)


def write_sea_scene(directory: str, scene: SeaScene, spp: int = DEFAULT_LEARN_SPP) -> SeaFloor:
    """Write ``scene.xml``, ``seabed.ply`` and ``seabed_texture.png`` into ``directory`` (which
    exists); returns the floor (its mesh in float64 as written: the float32 values widened)."""
    import cv2

    from synth.infra.fileio import atomic_write_bytes, atomic_write_text

    floor, texture = build_floor(scene)
    lower = floor.lower
    upper = lower + floor.texel_mm * (np.array(floor.texture_shape[::-1]) - 1)
    # Mitsuba puts a PLY's v = 0 on the bitmap's first (top) row: the texture's row 0, the
    # lowest seabed y (seen on a render: the rock texture lies on the rocks)
    write_ply(os.path.join(directory, MESH_FILE),
              SurfaceMesh(floor.mesh.vertices, floor.mesh.triangles, floor.mesh.uv_mm,
                          floor.mesh.description), lower, upper)
    ok, png = cv2.imencode(".png", np.round(texture * 255).astype(np.uint8))
    if not ok:
        raise OSError("cannot encode the sea floor texture")
    atomic_write_bytes(os.path.join(directory, TEXTURE_FILE), png.tobytes())
    atomic_write_text(os.path.join(directory, SCENE_FILE), scene_xml(scene, spp))
    vertices = floor.mesh.vertices.astype(np.float32).astype(np.float64)
    return SeaFloor(SurfaceMesh(vertices, floor.mesh.triangles, floor.mesh.uv_mm,
                                floor.mesh.description), floor.x, floor.y, floor.lower,
                    floor.texel_mm, floor.texture_shape, floor.objects)


__all__ = ["DEFAULT_LEARN_SPP", "MESH_FILE", "SCENE_FILE", "SeaFloor", "TEXTURE_FILE",
           "build_floor", "flat_window_half_side", "floor_patch", "port_xml", "scene_xml",
           "write_sea_scene"]
