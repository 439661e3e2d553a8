"""Write a Mitsuba 3 scene of two cameras, a flat port (or none) and targets (or a surface).

A scene written here is a genuine Mitsuba 3 XML scene (``mi.load_file`` loads it with no plugin
of ours), in millimetres, in the reference frame (the left camera's, OpenCV axes). It declares
the ``<default>`` parameters of :mod:`synth.scene.params` and holds:

* two ``perspective`` sensors, first the left, then the right: ``fov`` with ``fov_axis = x``,
  ``principal_point_offset_x/y`` (fractions of the film size), ``to_world`` =
  ``lookat(origin = t, target = t + 1000·R·z, up = −R·y)`` which gives Mitsuba's sensor OpenCV's
  axes; an ``hdrfilm`` (luminance, float32) with a ``box`` reconstruction filter.
* the port: one ``rectangle`` per interface with a ``dielectric`` BSDF, its normal (local +z)
  turned towards the cameras so that ``ext_ior`` is the camera-side index: air-glass
  ``int_ior = n2, ext_ior = n1``, glass-water ``int_ior = $n_water, ext_ior = n2``.
* or, for a dome port (a :class:`measure.geometry.dome.DomePair` — and for N > 2 cameras each
  inside its own dome, a list of :class:`measure.geometry.dome.DomePort`, one per camera), per
  camera two concentric analytic ``sphere`` shapes with ``dielectric`` BSDFs
  (:mod:`synth.scene.dome`);
* or, for two housings (a :class:`measure.geometry.flat_pair.FlatPair`) — and for N > 2 cameras
  each behind its own flat port (a list of :class:`measure.FlatPort`, one per camera) — per
  camera a finite window: one ``rectangle`` per interface of its own port, sized to its field
  of view and clear of every other camera's (:mod:`synth.scene.windows`);
* or, for cameras with different kinds of port (a :class:`synth.scene.mixed.MixedPorts`, or a
  list of one port per camera holding domes and flat ports or a None: a camera in air), each
  glass once — a dome's spheres, a window per flat port, shared by the cameras whose ports are
  equal — and ``<default name="port" value="mixed"/>`` (:mod:`synth.scene.mixed`).
* the targets: ``disk`` shapes with an ``area`` emitter, facing the cameras (normal −z), shape
  ``id = "target_<k>"`` for target number ``k``; radius = the disk's scale.
"""

from __future__ import annotations

import os
import tempfile

import numpy as np

from measure import Camera, FlatPort, StereoRig
from measure.geometry.port import require_flat_port
from synth.scene.model import (DEFAULT_MAX_DEPTH, DEFAULT_SEED, DEFAULT_SPP, SPECKLE_ID,
                               SURFACE_ID, TARGET_ID_PREFIX, SurfaceFiles)
from synth.scene.glass import PER_CAMERA_GLASS, glass_of, glass_rig
from synth.scene.mixed import is_mixed
from synth.scene.xml_text import number_text, vector_text
from synth.rendering.sensor import sensor_parameters

#: Half side (mm) of the square port interfaces: covers both fields of view far beyond 2 m.
INTERFACE_HALF_SIZE_MM = 2000.0
#: Distance (mm) of a sensor's ``lookat`` target from its origin (see :func:`sensor_xml`).
LOOKAT_DISTANCE_MM = 1000.0
#: Smallest max_depth of a scene with a participating medium (scattering events count).
WATER_MAX_DEPTH = 32
#: Radiance of the target emitters (linear units; only the ratios in an image matter).
TARGET_RADIANCE = 1.0
#: How targets are seen: self-luminous disks (LED targets), or white diffuse disks lit by
#: lights beside the housing.
LIGHTINGS = ("led", "lit")
#: Reflectance of lit targets (white paint), default of ``target_albedo``.
LIT_TARGET_ALBEDO = 0.9
#: Intensity of each spot light (radiant intensity, linear units, default ``light_intensity``):
#: a white disk at 1 m in clear water is about as bright as an LED target of radiance 1.
LIGHT_INTENSITY = 3.0e6
#: The spot lights: beam half-angle where the falloff starts, and the cut-off, degrees.
LIGHT_BEAM_WIDTH_DEG, LIGHT_CUTOFF_DEG = 45.0, 60.0
#: Where the lights are, mm: this far to each side of the rig's centre along the baseline, and
#: this far beyond the port's last interface (in the water, like strobes on arms).
LIGHT_SIDE_OFFSET_MM, LIGHT_DEPTH_BEYOND_PORT_MM = 400.0, 20.0


def sensor_xml(name: str, camera: Camera, width_param: bool, thin_lens: bool = False) -> str:
    try:
        p = sensor_parameters(camera.K, camera.size, camera.R, camera.t)
    except ValueError as exc:
        raise ValueError(f"{name} camera: {exc}") from None
    fov, ppx, ppy = p["fov"], p["principal_point_offset_x"], p["principal_point_offset_y"]
    w, h = camera.size
    R, t = camera.R, camera.t
    # Mitsuba builds the sensor's lookat in float32: a target 1 mm from an origin 200 mm away
    # loses ~2.4e-6 rad of direction (~0.003 px); LOOKAT_DISTANCE_MM away it loses ~6e-8 rad.
    target = t + LOOKAT_DISTANCE_MM * R[:, 2]
    up = -R[:, 1]
    width = "$width" if width_param else str(w)
    height = "$height" if width_param else str(h)
    if thin_lens:
        if ppx != 0 or ppy != 0:
            raise ValueError(f"{name} camera: a thin lens needs the principal point at the "
                             f"image centre (Mitsuba's thinlens has no principal point offset)")
        lens = """
        <float name="aperture_radius" value="$aperture_radius"/>
        <float name="focus_distance" value="$focus_distance"/>"""
    else:
        lens = f"""
        <float name="principal_point_offset_x" value="{number_text(ppx)}"/>
        <float name="principal_point_offset_y" value="{number_text(ppy)}"/>"""
    return f"""
    <sensor type="{'thinlens' if thin_lens else 'perspective'}" id="{name}">
        <float name="fov" value="{number_text(fov)}"/>
        <string name="fov_axis" value="x"/>{lens}
        <float name="near_clip" value="1"/>
        <float name="far_clip" value="1000000"/>
        <transform name="to_world">
            <lookat origin="{vector_text(t)}" target="{vector_text(target)}" up="{vector_text(up)}"/>
        </transform>
        <sampler type="multijitter">
            <integer name="sample_count" value="$spp"/>
            <integer name="seed" value="$seed"/>
        </sampler>
        <film type="hdrfilm">
            <integer name="width" value="{width}"/>
            <integer name="height" value="{height}"/>
            <string name="pixel_format" value="luminance"/>
            <string name="component_format" value="float32"/>
            <rfilter type="box"/>
        </film>
    </sensor>"""


def scene_xml(cameras, port: FlatPort | None, targets, target_radius: float, *,
              spp: int = DEFAULT_SPP, seed: int = DEFAULT_SEED, max_depth: int = DEFAULT_MAX_DEPTH,
              interface_half_size: float = INTERFACE_HALF_SIZE_MM, comment: str = "",
              water=None, target_normals=None, lighting: str = "led",
              thin_lens=None, surface: SurfaceFiles | None = None) -> str:
    """The text of a Mitsuba 3 scene of two cameras, a flat port (or none) and disk targets.

    ``cameras`` (left, right) :class:`measure.Camera` (same image size; square pixels), or N > 2
    of them (``cam0``, ``cam1``, …);
    ``port`` a :class:`measure.FlatPort`, a :class:`measure.geometry.dome.DomePair` (a dome around each
    camera: :mod:`synth.scene.dome`), a FlatPair (a window per camera), a list of one
    FlatPort per camera of N > 2 (a window each) or of one DomePort per camera (a dome each),
    or None for an all-air scene; ``targets`` ``(N, 3)`` mm,
    reference frame, all in the water; ``target_radius`` mm. When all targets share one ``z``,
    it becomes the ``target_z`` default. ``comment`` goes into an XML comment (for people only).
    ``water`` (a :class:`synth.rendering.water.Water`, needs a port): the water behind the port becomes a
    homogeneous participating medium (defaults ``water_c`` per metre, ``water_albedo``,
    ``water_g``) and the integrator ``volpath``.
    ``target_normals`` ``(N, 3)``: the direction each disk faces (default: all face the cameras,
    ``(0, 0, -1)``); each must point back towards the cameras' side of its target.
    ``lighting``: ``"led"`` (self-luminous disks, the default) or ``"lit"`` (white diffuse disks,
    reflectance ``$target_albedo``, lit by two ``spot`` lights beside the housing in the water —
    :func:`light_placements` — so that scattering water shows backscatter).
    ``thin_lens`` ``(aperture_radius_mm, focus_distance_mm)``: Mitsuba ``thinlens`` sensors in
    place of the pinholes (defaults ``aperture_radius``, ``focus_distance``); needs the
    principal point at the image centre (Mitsuba's thin lens has no offset).
    ``surface`` (:class:`SurfaceFiles`): a dense scene — one textured mesh instead of disks;
    ``targets`` are then the mesh's vertices (for the checks and the lights' aim) and
    ``target_radius`` is ignored; ``lighting`` ``"lit"`` makes the speckle texture the
    reflectance of a diffuse surface lit by the spot lights, ``"led"`` its radiance
    (self-luminous).
    """
    cameras = tuple(cameras)
    names = _checked_names(cameras, port, surface, thin_lens)
    targets, target_radius, target_normals = _checked_targets(
        targets, target_radius, target_normals, port, lighting, surface)
    glass = glass_of(port)
    rig = _checked_port(cameras, names, port, glass, targets, target_radius, target_normals,
                        (water, lighting, thin_lens, surface))
    plane = surface is None and bool(np.all(targets[:, 2] == targets[0, 2]))
    defaults = _defaults(cameras, names, port, targets, target_radius, plane, spp=spp, seed=seed,
                         max_depth=max_depth, water=water, lighting=lighting, thin_lens=thin_lens,
                         surface=surface)
    parts = _head_xml(comment, defaults, water)
    for name, cam in zip(names, cameras):
        parts.append(sensor_xml(name, cam, True, thin_lens is not None))
    if lighting == "lit":
        parts += _lights_xml(cameras[0], cameras[1], port, targets)
    if glass is not None:
        parts.append(glass.xml(rig))
    elif port is not None:
        parts += _flat_port_xml(port, interface_half_size, water)
    if surface is not None:
        parts.append(_surface_xml(surface, lighting))
    else:
        parts += _targets_xml(targets, target_normals, plane, lighting)
    parts.append("</scene>\n")
    return "\n".join(parts)


def _checked_names(cameras, port, surface, thin_lens) -> tuple:
    """The sensors' ids of ``cameras`` (``left``, ``right``; ``cam0``, ``cam1``, … of N > 2);
    ValueError for cameras a scene cannot hold (see :func:`_check_more_cameras`)."""
    left, right = cameras[:2]
    if left.size != right.size:
        raise ValueError(f"both cameras must have the same image size, got {left.size} and "
                         f"{right.size}")
    names = ("left", "right") if len(cameras) == 2 else tuple(f"cam{k}" for k in range(len(cameras)))
    if len(cameras) > 2:
        _check_more_cameras(cameras, names, port, surface, thin_lens)
    return names


def _checked_targets(targets, target_radius, target_normals, port, lighting: str,
                     surface) -> tuple:
    """``(targets (N, 3), target radius, unit normals (N, 3))``, mm, reference frame, as
    :func:`scene_xml` writes them (a surface's radius is 0); ValueError for targets, a radius,
    normals or a ``lighting`` it cannot write."""
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(targets)) or targets.shape[0] == 0:
        raise ValueError("targets must be a non-empty finite (N, 3) array")
    if surface is not None:
        target_radius = 0.0
    elif not (target_radius > 0 and np.isfinite(target_radius)):
        raise ValueError(f"target_radius must be positive, got {target_radius}")
    if lighting not in LIGHTINGS:
        raise ValueError(f"lighting must be one of {', '.join(LIGHTINGS)}, got {lighting!r}")
    if lighting == "lit" and port is None:
        raise ValueError("lit targets need a port: the lights are in the water beside the housing")
    if target_normals is None:
        target_normals = np.tile([0.0, 0.0, -1.0], (targets.shape[0], 1))
    target_normals = np.asarray(target_normals, dtype=np.float64).reshape(-1, 3)
    if target_normals.shape != targets.shape or not np.all(np.isfinite(target_normals)):
        raise ValueError("target_normals must be a finite (N, 3) array like targets")
    target_normals = target_normals / np.linalg.norm(target_normals, axis=1, keepdims=True)
    return targets, target_radius, target_normals


def _checked_port(cameras, names, port, glass, targets, target_radius, target_normals,
                  looks: tuple):
    """The rig of a port whose cameras each have their own glass (``glass``, checked with its
    targets), else None (a shared flat port checked here: cameras on its air side, targets in
    the water facing it). ``looks``: ``(water, lighting, thin_lens, surface)`` of
    :func:`scene_xml`, which glass per camera refuses. ValueError for what does not fit."""
    water, lighting, thin_lens, surface = looks
    left, right = cameras[:2]
    rig = None
    if glass is not None:
        if water is not None or lighting == "lit" or thin_lens is not None or surface is not None:
            raise ValueError(f"a {glass.name} scene holds LED disk targets seen by pinhole "
                             f"cameras in clear water (no water medium, lit targets, thin lens "
                             f"or surface)")
        rig = glass_rig(cameras, port, names)  # each camera behind or inside its own glass
        glass.check(rig, targets, target_radius, target_normals)
    elif port is not None:
        StereoRig(left, right, port)  # cameras on the air side
        if not np.all(port.water_side(targets)):
            raise ValueError("every target must lie in the water, beyond the port's last interface")
        if np.any(targets @ port.normal - port.offsets[-1] <= target_radius):
            raise ValueError("targets closer to the port than their radius")
        if surface is None and np.any(target_normals @ port.normal >= 0):
            raise ValueError("every target must face the cameras (its normal towards the port)")
    return rig


def _defaults(cameras, names, port, targets, target_radius, plane: bool, *, spp, seed, max_depth,
              water, lighting, thin_lens, surface) -> list:
    """The scene's ``<default>`` parameters, ``[(name, text), …]`` (:func:`scene_xml`'s
    arguments; ``max_depth`` raised for water and for the port's interfaces)."""
    w, h = cameras[0].size
    defaults = [("spp", str(int(spp))), ("seed", str(int(seed))), ("width", str(w)),
                ("height", str(h))]
    if port is not None:
        defaults.append(("n_water", number_text(_views_of(port, len(cameras))[0].n_water)))
        if is_mixed(port):  # the reader's sign of a scene of mixed ports
            defaults.append(("port", "mixed"))
    else:
        defaults.append(("port", "none"))
    if water is not None:
        if port is None:
            raise ValueError("a participating medium needs a port (the water is behind it)")
        defaults += [("water_c", number_text(water.c_per_m)), ("water_albedo", number_text(water.albedo)),
                     ("water_g", number_text(water.g))]
        max_depth = max(int(max_depth), WATER_MAX_DEPTH)
    if port is not None:  # a path crosses every interface once: room for them and a few more
        crossed = max(p.n_interfaces for p in _views_of(port, len(cameras)))
        max_depth = max(int(max_depth), 2 * crossed + 4)
    if surface is None:
        defaults.append(("target_radius", number_text(target_radius)))
    if lighting == "lit":
        defaults += [("target_albedo", number_text(LIT_TARGET_ALBEDO)),
                     ("light_intensity", number_text(LIGHT_INTENSITY))]
    if thin_lens is not None:
        aperture, focus = (float(v) for v in thin_lens)
        if not (aperture > 0 and focus > 0 and np.isfinite(aperture) and np.isfinite(focus)):
            raise ValueError(f"thin lens aperture radius and focus distance must be positive, "
                             f"got {thin_lens}")
        defaults += [("aperture_radius", number_text(aperture)), ("focus_distance", number_text(focus))]
    if plane:
        defaults.append(("target_z", number_text(targets[0, 2])))
    defaults.append(("max_depth", str(int(max_depth))))
    for name, cam in zip(names, cameras):
        dist = np.zeros(5) if cam.dist is None else cam.dist
        defaults.append((f"{name}_dist", " ".join(number_text(c) for c in dist)))
    return defaults


def _head_xml(comment: str, defaults: list, water) -> list:
    """The first parts of the scene: the XML declaration, the ``comment``, ``<scene>``, the
    ``defaults``, the integrator and the water's medium."""
    parts = ['<?xml version="1.0" encoding="utf-8"?>']
    if comment:
        parts.append(f"<!-- {comment.replace('--', '-')} -->")
    parts.append('<scene version="3.0.0">')
    parts.append("    <!-- Units: mm. Frame: the left camera's, OpenCV axes (x right, y down, "
                 "z forward). Override any default with -D name=value. -->")
    for name, value in defaults:
        parts.append(f'    <default name="{name}" value="{value}"/>')
    parts.append(f"""
    <integrator type="{'path' if water is None else 'volpath'}">
        <integer name="max_depth" value="$max_depth"/>
    </integrator>""")
    if water is not None:
        parts.append(f"""
    <!-- The water: {water.name}. Coefficients per metre (scale 0.001: the scene is in mm). -->
    <medium type="homogeneous" id="water">
        <float name="scale" value="0.001"/>
        <float name="sigma_t" value="$water_c"/>
        <float name="albedo" value="$water_albedo"/>
        <phase type="hg">
            <float name="g" value="$water_g"/>
        </phase>
    </medium>""")
    return parts


def _lights_xml(left: Camera, right: Camera, port, targets) -> list:
    """The two spot lights of a lit scene (:func:`light_placements`)."""
    parts = []
    for k, (origin, target) in enumerate(light_placements(left, right, port, targets)):
        parts.append(f"""
    <emitter type="spot" id="light_{k}">
        <transform name="to_world">
            <lookat origin="{vector_text(origin)}" target="{vector_text(target)}" up="{vector_text(_perpendicular(target - origin))}"/>
        </transform>
        <rgb name="intensity" value="$light_intensity"/>
        <float name="cutoff_angle" value="{number_text(LIGHT_CUTOFF_DEG)}"/>
        <float name="beam_width" value="{number_text(LIGHT_BEAM_WIDTH_DEG)}"/>
    </emitter>""")
    return parts


def _flat_port_xml(port: FlatPort, interface_half_size: float, water) -> list:
    """One ``rectangle`` per interface of a shared flat port, camera side first; the last
    looks into ``$n_water`` (and holds the water's medium)."""
    parts = []
    for k, centre, target, up, ext_ior, int_ior in interface_placements(port):
        ext = number_text(ext_ior)
        last = k == port.n_interfaces - 1
        inner = "$n_water" if last else number_text(int_ior)
        medium = ('\n        <ref name="interior" id="water"/>'
                  if last and water is not None else "")
        parts.append(f"""
    <shape type="rectangle" id="interface_{k}">
        <transform name="to_world">
            <scale x="{number_text(interface_half_size)}" y="{number_text(interface_half_size)}"/>
            <lookat origin="{vector_text(centre)}" target="{vector_text(target)}" up="{vector_text(up)}"/>
        </transform>
        <bsdf type="dielectric">
            <float name="ext_ior" value="{ext}"/>
            <float name="int_ior" value="{inner}"/>
        </bsdf>{medium}
    </shape>""")
    return parts


def _targets_xml(targets, target_normals, plane: bool, lighting: str) -> list:
    """The disk targets: their BSDF (LED: black, an area emitter; lit: white diffuse) and one
    ``disk`` per target, facing the cameras or turned to its normal; ``plane``: all share
    ``$target_z``."""
    parts = []
    if lighting == "led":
        parts.append("""
    <bsdf type="diffuse" id="target_back">
        <rgb name="reflectance" value="0"/>
    </bsdf>""")
        look = ("        <ref id=\"target_back\"/>\n        <emitter type=\"area\"><rgb "
                f"name=\"radiance\" value=\"{number_text(TARGET_RADIANCE)}\"/></emitter>")
    else:
        parts.append("""
    <bsdf type="diffuse" id="target_white">
        <rgb name="reflectance" value="$target_albedo"/>
    </bsdf>""")
        look = "        <ref id=\"target_white\"/>"
    facing = np.all(target_normals == [0.0, 0.0, -1.0], axis=1)
    for k, (x, y, z) in enumerate(targets):
        zval = "$target_z" if plane else number_text(z)
        if facing[k]:
            orient = '<rotate x="1" angle="180"/>\n            <scale value="$target_radius"/>'
        else:
            n = target_normals[k]
            orient = (f'<scale value="$target_radius"/>\n            <lookat origin="0, 0, 0" '
                      f'target="{vector_text(n)}" up="{vector_text(_perpendicular(n))}"/>')
        parts.append(f"""    <shape type="disk" id="{TARGET_ID_PREFIX}{k}">
        <transform name="to_world">
            {orient}
            <translate x="{number_text(x)}" y="{number_text(y)}" z="{zval}"/>
        </transform>
{look}
    </shape>""")
    return parts


def _check_more_cameras(cameras, names, port, surface, thin_lens) -> None:
    """A scene of more than two cameras: the same film for all, all behind one flat port, each
    behind its own flat port or inside its own dome (a list of them, one per camera, all flat
    or all domes), a mix (:mod:`synth.scene.mixed`) or none, no camera at another's centre or inside another's glass; LED disk
    targets seen by pinholes."""
    from measure.stereo.rig import Rig

    for name, camera in zip(names, cameras):
        if camera.size != cameras[0].size:
            raise ValueError(f"{name}: every camera must have the same image size, got "
                             f"{camera.size} and {cameras[0].size}")
    if isinstance(port, (list, tuple)):
        message = (f"a port per camera of {len(cameras)} cameras is a list of {len(cameras)} "
                   f"flat ports (a window each) or of {len(cameras)} domes, got {len(port)} "
                   f"values")
        if len(port) != len(cameras):
            raise ValueError(message)
        if not is_mixed(port) and {getattr(each, "kind", None) for each in port} != {"dome"}:
            for each in port:
                require_flat_port(each, message + " (a mix of flat ports and domes is not "
                                                  "written)")
    elif port is not None and PER_CAMERA_GLASS.get(port.kind) is not None:
        raise ValueError(f"a scene of {len(cameras)} cameras has one flat port for all of them, "
                         f"a flat port or a dome each (a list of one per camera), or none; not "
                         f"{port.description}")
    if surface is not None or thin_lens is not None:
        raise ValueError(f"a scene of {len(cameras)} cameras holds disk targets seen by pinhole "
                         f"cameras (no surface, no thin lens)")
    if port is not None:
        ports = list(port) if isinstance(port, (list, tuple)) else [port] * len(cameras)
        Rig(cameras, ports, names)


def _views_of(port, count: int) -> list:
    """The port each of ``count`` cameras looks through (a shared port, a pair's, or a list's)."""
    if isinstance(port, (list, tuple)):
        return [p for p in port if p is not None]  # a camera in air (a mix) has none
    return [port.view(min(v, 1)) for v in range(count)]


def _surface_xml(surface: SurfaceFiles, lighting: str) -> str:
    """The speckle texture and the mesh of a surface scene (see :func:`scene_xml`)."""
    if lighting == "lit":
        look = f"""<bsdf type="diffuse">
            <ref name="reflectance" id="{SPECKLE_ID}"/>
        </bsdf>"""
    else:
        look = f"""<bsdf type="diffuse">
            <rgb name="reflectance" value="0"/>
        </bsdf>
        <emitter type="area">
            <ref name="radiance" id="{SPECKLE_ID}"/>
        </emitter>"""
    return f"""
    <!-- The speckle pattern (8-bit grey, linear: {'reflectance' if lighting == 'lit' else 'radiance'} = value / 255). -->
    <texture type="bitmap" id="{SPECKLE_ID}">
        <string name="filename" value="{surface.texture}"/>
        <boolean name="raw" value="true"/>
        <string name="filter_type" value="bilinear"/>
    </texture>

    <!-- The surface: a triangle mesh in the reference frame (mm), texture coordinates per vertex. -->
    <shape type="ply" id="{SURFACE_ID}">
        <string name="filename" value="{surface.mesh}"/>
        {look}
    </shape>"""


def light_placements(left: Camera, right: Camera, port: FlatPort, targets):
    """The two spot lights of a lit scene: ``[(origin, aim point), …]``, mm, reference frame.

    Each light sits :data:`LIGHT_SIDE_OFFSET_MM` to one side of the rig's centre along the
    baseline (projected onto the port's plane) and :data:`LIGHT_DEPTH_BEYOND_PORT_MM` beyond
    the port's last interface, in the water; both aim at the point of the rig's axis (through
    its centre along the port normal) at the targets' mean depth.
    """
    N = port.normal
    centre = 0.5 * (left.center + right.center)
    baseline = right.center - left.center
    side = baseline - N * (baseline @ N)
    side = side / np.linalg.norm(side)
    depth = port.offsets[-1] + LIGHT_DEPTH_BEYOND_PORT_MM
    foot = centre - N * (centre @ N)
    aim = foot + N * float(np.mean(np.asarray(targets) @ N))
    return [(foot + N * depth + sign * LIGHT_SIDE_OFFSET_MM * side, aim) for sign in (-1.0, 1.0)]


def port_shapes(mi, port, half_side_mm: float = 2000.0, cameras=None) -> dict:
    """The glass of ``port`` as Mitsuba dictionary shapes (``mi.load_dict``; the board scenes'
    form of what :func:`scene_xml` writes as XML): two spheres per dome
    (:func:`synth.scene.dome.dome_placements`), a finite window per camera for two housings
    (:mod:`synth.scene.windows`: needs ``cameras`` (left, right; or N of them with a list of
    their flat ports), whose fields of view size them), or one ``rectangle`` of half side ``half_side_mm`` per flat interface
    (:func:`interface_placements`), each a ``dielectric`` whose ``ext_ior`` is the camera
    side's. ``{shape id: shape}``."""
    glass = glass_of(port)
    if glass is not None:
        return glass.shapes(mi, port, cameras, half_side_mm)
    shapes = {}
    for k, centre, target, up, ext_ior, int_ior in interface_placements(port):
        to_world = (mi.ScalarTransform4f().look_at(origin=centre.tolist(), target=target.tolist(),
                                                   up=up.tolist())
                    @ mi.ScalarTransform4f().scale([half_side_mm, half_side_mm, 1.0]))
        shapes[f"interface_{k}"] = {"type": "rectangle", "to_world": to_world,
                                    "bsdf": {"type": "dielectric", "ext_ior": float(ext_ior),
                                             "int_ior": float(int_ior)}}
    return shapes


def interface_placements(port: FlatPort):
    """Per interface of ``port``, camera side first: ``(k, centre, lookat target, up, ext_ior,
    int_ior)`` of the ``rectangle`` that models it — centred on the reference normal, its local
    +z turned towards the cameras so that ``ext_ior`` is the camera-side index."""
    N = port.normal
    up = _perpendicular(N)
    n = list(port.indices)
    for k, offset in enumerate(port.offsets):
        centre = N * offset
        yield k, centre, centre - N, up, n[k], n[k + 1]


def _perpendicular(n) -> np.ndarray:
    """A unit vector perpendicular to ``n`` (the 'up' of a lookat whose direction is ±n)."""
    n = np.asarray(n, dtype=float)
    axis = np.array([0.0, -1.0, 0.0]) if abs(n[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    v = axis - n * np.dot(axis, n)
    return v / np.linalg.norm(v)


#: The last line of a scene file ``write_scene`` wrote: the SHA-256 of the lines above it
#: (:func:`scene_edited`).
SEAL_PREFIX = "<!-- content sha256 "


def seal(text: str) -> str:
    """``text`` (ending in a newline) with :data:`SEAL_PREFIX` and its SHA-256 appended."""
    import hashlib

    text = text if text.endswith("\n") else text + "\n"
    return f"{text}{SEAL_PREFIX}{hashlib.sha256(text.encode('utf-8')).hexdigest()} -->\n"


def scene_edited(path) -> bool:
    """Whether a scene file ``write_scene`` wrote was changed since (its content no longer
    matches its seal); False for a file without a seal (written before the seal existed)."""
    import hashlib

    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            text = fh.read()
    except OSError:
        return False
    head, _, last = text.rstrip("\n").rpartition("\n")
    if not last.startswith(SEAL_PREFIX):
        return False
    digest = last[len(SEAL_PREFIX):].split()[0]
    return hashlib.sha256((head + "\n").encode("utf-8")).hexdigest() != digest


def write_scene(path, cameras, port, targets, target_radius, **kwargs) -> str:
    """Write :func:`scene_xml` atomically (temporary file + rename) to ``path``, sealed
    (:func:`seal`); returns path."""
    text = seal(scene_xml(cameras, port, targets, target_radius, **kwargs))
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".scene-", suffix=".xml", dir=directory)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
