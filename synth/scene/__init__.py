"""Mitsuba 3 scene files as the single source of truth of a run: write them, read them back.

A scene written here is a genuine Mitsuba 3 XML scene (``mi.load_file`` loads it with no plugin
of ours), in millimetres, in the reference frame (the left camera's, OpenCV axes):

* ``<default>`` parameters that users vary, overridable as ``-D name=value``: ``spp``, ``seed``,
  ``width``, ``height`` (the focal length in pixels scales with ``width``: the field of view is
  fixed), ``n_water``, ``target_radius`` (mm), ``target_z`` (mm, plane layouts only),
  ``max_depth``, and ``left_dist`` / ``right_dist`` -- the OpenCV distortion coefficients of each
  sensor (``"k1 k2 p1 p2 k3"``), which Mitsuba has no notion of and which it tolerates only as
  defaults (an unknown property inside a plugin is an error in Mitsuba 3's loader). A scene
  without a port declares ``<default name="port" value="none"/>``.
* two ``perspective`` sensors, first the left, then the right: ``fov`` with ``fov_axis = x``,
  ``principal_point_offset_x/y`` (fractions of the film size), ``to_world`` =
  ``lookat(origin = t, target = t + 1000·R·z, up = −R·y)`` which gives Mitsuba's sensor OpenCV's
  axes; an ``hdrfilm`` (luminance, float32) with a ``box`` reconstruction filter.
* the port: one ``rectangle`` per interface with a ``dielectric`` BSDF, its normal (local +z)
  turned towards the cameras so that ``ext_ior`` is the camera-side index: air-glass
  ``int_ior = n2, ext_ior = n1``, glass-water ``int_ior = $n_water, ext_ior = n2``.
* the targets: ``disk`` shapes with an ``area`` emitter, facing the cameras (normal −z), shape
  ``id = "target_<k>"`` for target number ``k``; radius = the disk's scale.

Reading back (:func:`load_scene`) uses Mitsuba's own parser (``mitsuba.parser.parse_file``: ``<default>``,
``$name`` substitution and transforms composed in double precision, no plugin built), so the rig,
port and targets live only in the scene file. Conversions:
``f = (W/2) / tan(fov/2)`` px (fov along x), ``cx = W/2 − 0.5 − ppx·W``,
``cy = H/2 − 0.5 − ppy·H`` (Mitsuba's film pixel i covers [i, i+1); measured sign of the offset),
``R = M[:3, :3]·diag(−1, −1, 1)``, ``t = M[:3, 3]`` for the sensor's ``to_world`` matrix ``M``.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from measure import Camera, FlatPort, StereoRig
from measure.port import index_matched_port

from synth.sensor import intrinsics_from_sensor, pose_from_to_world, sensor_parameters

#: Half side (mm) of the square port interfaces: covers both fields of view far beyond 2 m.
INTERFACE_HALF_SIZE_MM = 2000.0
#: Distance (mm) of a sensor's ``lookat`` target from its origin (see :func:`_sensor_xml`).
LOOKAT_DISTANCE_MM = 1000.0
#: Defaults written into every scene unless given.
DEFAULT_SPP = 36
DEFAULT_SEED = 0
DEFAULT_MAX_DEPTH = 8
#: Smallest max_depth of a scene with a participating medium (scattering events count).
WATER_MAX_DEPTH = 32
#: Target disk radius, mm: at 1 m behind the paper's port the innermost circle's neighbours
#: (7.6 mm apart, ~10.8 px) keep a ~3.7 px gap, and each disk covers ~40-50 px.
DEFAULT_TARGET_RADIUS_MM = 2.5
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
#: Prefix of the target shapes' ids.
TARGET_ID_PREFIX = "target_"
#: Id of the surface mesh shape of a dense (surface) scene, and of its speckle texture.
SURFACE_ID, SPECKLE_ID = "surface", "speckle"


@dataclass(frozen=True)
class SurfaceFiles:
    """The files of a surface scene, as the XML names them (relative to the scene file's
    directory): ``mesh`` a PLY of :func:`synth.surfaces.write_ply`, ``texture`` an 8-bit grey
    speckle PNG (linear reflectance, or radiance when self-luminous)."""

    mesh: str
    texture: str


@dataclass(frozen=True)
class SceneSurface:
    """The surface of a scene read back: ``mesh_path`` and ``texture_path`` (resolved),
    ``vertices`` ``(V, 3)`` mm (float32 values widened: what the renderer sees), ``triangles``
    ``(T, 3)``, ``sha256`` of the mesh and texture bytes together."""

    mesh_path: str
    texture_path: str
    vertices: np.ndarray
    triangles: np.ndarray
    sha256: str


class SceneError(ValueError):
    """A scene file that cannot be used: missing, malformed, or not a port/stereo scene."""


@dataclass(frozen=True)
class SceneSpec:
    """What a scene file says, after ``<default>`` values and ``-D`` overrides are applied.

    ``rig`` is a :class:`measure.StereoRig`. In a scene with no port (``has_port`` False) its port
    is an index-matched stand-in: ``FlatPort(N = left optical axis, D = 1 mm beyond the farther
    camera centre, no layers, indices (1, 1))``, through which every projection and triangulation
    reduces to the pinhole one. ``targets`` ``(N, 3)`` ground-truth centres (mm, reference frame)
    in target-number order; ``target_ids`` ``(N,)`` their numbers; ``target_radii`` ``(N,)`` mm;
    ``target_normals`` ``(N, 3)`` the unit normals of the disks (their emitting side);
    ``params`` the resolved ``<default>`` values (strings) ; ``path`` the file; ``sha256`` of its
    bytes.
    """

    rig: StereoRig
    has_port: bool
    targets: np.ndarray
    target_ids: np.ndarray
    target_radii: np.ndarray
    params: dict
    path: str | None
    sha256: str
    referenced: frozenset = frozenset()
    target_normals: np.ndarray | None = None
    surface: SceneSurface | None = None

    @property
    def mitsuba_params(self) -> dict:
        """The resolved defaults that the XML references as ``$name`` (Mitsuba's loader rejects
        parameters a file does not use), as keyword arguments for ``mi.load_file``."""
        return {k: str(v) for k, v in self.params.items() if k in self.referenced}

    @property
    def cameras(self) -> tuple[Camera, Camera]:
        return self.rig.left, self.rig.right

    @property
    def port(self) -> FlatPort | None:
        """The port, or None in an all-air scene."""
        return self.rig.port if self.has_port else None

    @property
    def target_radius(self) -> float:
        """The (largest) target radius, mm."""
        return float(np.max(self.target_radii)) if self.target_radii.size else float("nan")

    @property
    def size(self) -> tuple[int, int]:
        return self.rig.left.size

    @property
    def spp(self) -> int:
        return int(float(self.params.get("spp", DEFAULT_SPP)))

    @property
    def seed(self) -> int:
        return int(float(self.params.get("seed", DEFAULT_SEED)))


# ---------------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------------
def _num(x: float) -> str:
    """Shortest round-trip text of a float (``1.0`` -> ``"1"``)."""
    x = float(x)
    if x == 0:
        return "0"
    if x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return repr(x)


def _vec(v) -> str:
    return ", ".join(_num(x) for x in v)


def _sensor_xml(name: str, camera: Camera, width_param: bool, thin_lens: bool = False) -> str:
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
        <float name="principal_point_offset_x" value="{_num(ppx)}"/>
        <float name="principal_point_offset_y" value="{_num(ppy)}"/>"""
    return f"""
    <sensor type="{'thinlens' if thin_lens else 'perspective'}" id="{name}">
        <float name="fov" value="{_num(fov)}"/>
        <string name="fov_axis" value="x"/>{lens}
        <float name="near_clip" value="1"/>
        <float name="far_clip" value="1000000"/>
        <transform name="to_world">
            <lookat origin="{_vec(t)}" target="{_vec(target)}" up="{_vec(up)}"/>
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

    ``cameras`` (left, right) :class:`measure.Camera` (same image size; square pixels);
    ``port`` a :class:`measure.FlatPort` or None for an all-air scene; ``targets`` ``(N, 3)`` mm,
    reference frame, all in the water; ``target_radius`` mm. When all targets share one ``z``,
    it becomes the ``target_z`` default. ``comment`` goes into an XML comment (for people only).
    ``water`` (a :class:`synth.water.Water`, needs a port): the water behind the port becomes a
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
    left, right = cameras
    if left.size != right.size:
        raise ValueError(f"both cameras must have the same image size, got {left.size} and "
                         f"{right.size}")
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
    if port is not None:
        StereoRig(left, right, port)  # cameras on the air side
        if not np.all(port.water_side(targets)):
            raise ValueError("every target must lie in the water, beyond the port's last interface")
        if np.any(targets @ port.normal - port.offsets[-1] <= target_radius):
            raise ValueError("targets closer to the port than their radius")
        if surface is None and np.any(target_normals @ port.normal >= 0):
            raise ValueError("every target must face the cameras (its normal towards the port)")
    w, h = left.size
    plane = surface is None and bool(np.all(targets[:, 2] == targets[0, 2]))
    defaults = [("spp", str(int(spp))), ("seed", str(int(seed))), ("width", str(w)),
                ("height", str(h))]
    if port is not None:
        defaults.append(("n_water", _num(port.n_water)))
    else:
        defaults.append(("port", "none"))
    if water is not None:
        if port is None:
            raise ValueError("a participating medium needs a port (the water is behind it)")
        defaults += [("water_c", _num(water.c_per_m)), ("water_albedo", _num(water.albedo)),
                     ("water_g", _num(water.g))]
        max_depth = max(int(max_depth), WATER_MAX_DEPTH)
    if port is not None:  # a path crosses every interface once: room for them and a few more
        max_depth = max(int(max_depth), 2 * port.n_interfaces + 4)
    if surface is None:
        defaults.append(("target_radius", _num(target_radius)))
    if lighting == "lit":
        defaults += [("target_albedo", _num(LIT_TARGET_ALBEDO)),
                     ("light_intensity", _num(LIGHT_INTENSITY))]
    if thin_lens is not None:
        aperture, focus = (float(v) for v in thin_lens)
        if not (aperture > 0 and focus > 0 and np.isfinite(aperture) and np.isfinite(focus)):
            raise ValueError(f"thin lens aperture radius and focus distance must be positive, "
                             f"got {thin_lens}")
        defaults += [("aperture_radius", _num(aperture)), ("focus_distance", _num(focus))]
    if plane:
        defaults.append(("target_z", _num(targets[0, 2])))
    defaults.append(("max_depth", str(int(max_depth))))
    for name, cam in (("left", left), ("right", right)):
        dist = np.zeros(5) if cam.dist is None else cam.dist
        defaults.append((f"{name}_dist", " ".join(_num(c) for c in dist)))

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
    parts.append(_sensor_xml("left", left, True, thin_lens is not None))
    parts.append(_sensor_xml("right", right, True, thin_lens is not None))
    if lighting == "lit":
        for k, (origin, target) in enumerate(light_placements(left, right, port, targets)):
            parts.append(f"""
    <emitter type="spot" id="light_{k}">
        <transform name="to_world">
            <lookat origin="{_vec(origin)}" target="{_vec(target)}" up="{_vec(_perpendicular(target - origin))}"/>
        </transform>
        <rgb name="intensity" value="$light_intensity"/>
        <float name="cutoff_angle" value="{_num(LIGHT_CUTOFF_DEG)}"/>
        <float name="beam_width" value="{_num(LIGHT_BEAM_WIDTH_DEG)}"/>
    </emitter>""")

    if port is not None:
        for k, centre, target, up, ext_ior, int_ior in interface_placements(port):
            ext = _num(ext_ior)
            last = k == port.n_interfaces - 1
            inner = "$n_water" if last else _num(int_ior)
            medium = ('\n        <ref name="interior" id="water"/>'
                      if last and water is not None else "")
            parts.append(f"""
    <shape type="rectangle" id="interface_{k}">
        <transform name="to_world">
            <scale x="{_num(interface_half_size)}" y="{_num(interface_half_size)}"/>
            <lookat origin="{_vec(centre)}" target="{_vec(target)}" up="{_vec(up)}"/>
        </transform>
        <bsdf type="dielectric">
            <float name="ext_ior" value="{ext}"/>
            <float name="int_ior" value="{inner}"/>
        </bsdf>{medium}
    </shape>""")

    if surface is not None:
        parts.append(_surface_xml(surface, lighting))
        parts.append("</scene>\n")
        return "\n".join(parts)
    if lighting == "led":
        parts.append(f"""
    <bsdf type="diffuse" id="target_back">
        <rgb name="reflectance" value="0"/>
    </bsdf>""")
        surface = ("        <ref id=\"target_back\"/>\n        <emitter type=\"area\"><rgb "
                   f"name=\"radiance\" value=\"{_num(TARGET_RADIANCE)}\"/></emitter>")
    else:
        parts.append("""
    <bsdf type="diffuse" id="target_white">
        <rgb name="reflectance" value="$target_albedo"/>
    </bsdf>""")
        surface = "        <ref id=\"target_white\"/>"
    facing = np.all(target_normals == [0.0, 0.0, -1.0], axis=1)
    for k, (x, y, z) in enumerate(targets):
        zval = "$target_z" if plane else _num(z)
        if facing[k]:
            orient = '<rotate x="1" angle="180"/>\n            <scale value="$target_radius"/>'
        else:
            n = target_normals[k]
            orient = (f'<scale value="$target_radius"/>\n            <lookat origin="0, 0, 0" '
                      f'target="{_vec(n)}" up="{_vec(_perpendicular(n))}"/>')
        parts.append(f"""    <shape type="disk" id="{TARGET_ID_PREFIX}{k}">
        <transform name="to_world">
            {orient}
            <translate x="{_num(x)}" y="{_num(y)}" z="{zval}"/>
        </transform>
{surface}
    </shape>""")
    parts.append("</scene>\n")
    return "\n".join(parts)


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


def write_scene(path, cameras, port, targets, target_radius, **kwargs) -> str:
    """Write :func:`scene_xml` atomically (temporary file + rename) to ``path``; returns path."""
    text = scene_xml(cameras, port, targets, target_radius, **kwargs)
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


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_SUBST = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


def parse_defines(items) -> dict:
    """``["name=value", ...]`` (the ``-D`` arguments) to a dict; SceneError on a malformed one."""
    defines = {}
    for item in items or ():
        name, sep, value = str(item).partition("=")
        name = name.strip()
        if not sep or not _NAME.fullmatch(name):
            raise SceneError(f"malformed -D {item!r}: expected name=value")
        defines[name] = value.strip()
    return defines


def apply_seed(defines: dict, seed: int | None) -> dict:
    """``--seed S`` is ``-D seed=S``: put it into ``defines`` (returned); a ``-D seed`` with
    another value is an error naming both."""
    if seed is None:
        return defines
    if "seed" in defines:
        try:
            same = float(defines["seed"]) == float(seed)
        except ValueError:
            same = False
        if not same:
            raise SceneError(f"--seed {seed} conflicts with -D seed={defines['seed']}")
    defines["seed"] = str(seed)
    return defines


def _floats(text: str, what: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in re.split(r"[,\s]+", str(text).strip()) if v],
                          dtype=float)
    except ValueError:
        raise SceneError(f"{what}: not a list of numbers: {text!r}") from None
    if not np.all(np.isfinite(values)):
        raise SceneError(f"{what}: not finite: {text!r}")
    return values


def declared_defaults(data: bytes, label: str):
    """The ``<default name value>`` declarations of the scene's root (in order) and the names
    the file references as ``$name`` — read, not interpreted: Mitsuba's parser does the rest."""
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise SceneError(f"{label}: malformed XML ({exc})") from None
    if root.tag != "scene":
        raise SceneError(f"{label}: root element is <{root.tag}>, expected <scene>")
    params = {}
    for d in root.findall("default"):
        name, value = d.get("name"), d.get("value")
        if not name or value is None:
            raise SceneError(f"{label}: <default> needs name and value")
        params[name] = value
    referenced = frozenset(name for elem in root.iter() for value in elem.attrib.values()
                           for name in _SUBST.findall(value))
    return params, referenced


#: Scene parameters that must be numbers, with their bounds: (kind, lower bound, strict).
_NUMERIC_PARAMS = {"spp": ("int", 1, False), "seed": ("int", 0, False),
                   "width": ("int", 1, False), "height": ("int", 1, False),
                   "max_depth": ("int", 0, False), "n_water": ("float", 1.0, False),
                   "target_radius": ("float", 0.0, True), "target_z": ("float", 0.0, True),
                   "water_c": ("float", 0.0, False), "water_albedo": ("float", 0.0, False),
                   "water_g": ("float", -1.0, True), "target_albedo": ("float", 0.0, False),
                   "light_intensity": ("float", 0.0, False),
                   "aperture_radius": ("float", 0.0, True), "focus_distance": ("float", 0.0, True)}
#: Upper bounds (inclusive unless marked strict) of the water's parameters.
_UPPER_BOUNDS = {"water_albedo": (1.0, False), "water_g": (1.0, True),
                 "target_albedo": (1.0, False)}


def check_params(params: dict, label: str) -> None:
    """One-line errors for parameter values Mitsuba would reject or mis-render."""
    for name, (kind, lower, strict) in _NUMERIC_PARAMS.items():
        if name not in params:
            continue
        text = str(params[name]).strip()
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        ok = math.isfinite(value) and (value > lower if strict else value >= lower)
        if kind == "int":
            ok = ok and value == int(value)
        if not ok:
            bound = f"> {lower:g}" if strict else f">= {lower:g}"
            raise SceneError(f"{label}: parameter {name}={text!r} must be a finite "
                             f"{'integer' if kind == 'int' else 'number'} {bound}")
        if name in _UPPER_BOUNDS:
            upper, strict_upper = _UPPER_BOUNDS[name]
            if not (value < upper if strict_upper else value <= upper):
                raise SceneError(f"{label}: parameter {name}={text!r} must be "
                                 f"{'<' if strict_upper else '<='} {upper:g}")
        if kind == "int":
            params[name] = str(int(value))


def _parse_with_mitsuba(path: str, params: dict, referenced, label: str):
    """Mitsuba's own parser (``mitsuba.parser.parse_file``): ``$`` substitution, transforms
    composed in double precision, references; no plugin is built."""
    from synth.mitsuba_setup import import_mitsuba

    mi, variant = import_mitsuba()
    import mitsuba.parser as mp

    config = mp.ParserConfig(variant)
    used = {k: str(v) for k, v in params.items() if k in referenced}
    try:
        return mi, mp.parse_file(config, path, **used)
    except RuntimeError as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        message = re.sub(r"^\[[^\]]*\]\s*", "", " ".join(lines[:2]))
        raise SceneError(f"{label}: Mitsuba cannot parse the scene: {message}") from None


class _Nodes:
    """The parsed scene graph: typed property access and child lookup by reference."""

    def __init__(self, mi, state):
        self.mi, self.state = mi, state
        self.types = mi.Properties.Type
        self.by_id = dict(state.id_to_index)

    def children(self, node):
        for key in node.props.keys():
            kind = node.props.type(key)
            if kind == self.types.ResolvedReference:
                yield self.state.nodes[node.props[key].index()]
            elif kind == self.types.Reference:
                index = self.by_id.get(node.props[key].id())
                if index is not None:
                    yield self.state.nodes[index]

    def child(self, node, object_type):
        return next((c for c in self.children(node) if c.type == object_type), None)

    def value(self, node, name, default, what):
        props = node.props
        if name not in props:
            return default
        try:
            return props[name]
        except (RuntimeError, TypeError):
            raise SceneError(f"{what}: property {name!r} has an unsupported type") from None

    def matrix(self, node) -> np.ndarray:
        if "to_world" not in node.props:
            return np.eye(4)
        return np.array(node.props["to_world"].matrix, dtype=np.float64).reshape(4, 4)


def _read_sensor(nodes: _Nodes, node, params, label) -> Camera:
    ObjectType = nodes.mi.ObjectType
    sid = node.props.id() or "?"
    what = f"{label}: sensor {sid!r}"
    if node.props.plugin_name() not in ("perspective", "thinlens"):
        raise SceneError(f"{what}: type {node.props.plugin_name()!r}, expected 'perspective' "
                         f"or 'thinlens'")
    film = nodes.child(node, ObjectType.Film)
    if film is None:
        raise SceneError(f"{what}: no <film>")
    try:
        w = int(nodes.value(film, "width", 768, what))
        h = int(nodes.value(film, "height", 576, what))
    except (TypeError, ValueError):
        raise SceneError(f"{what}: film width/height must be integers") from None
    if w <= 0 or h <= 0:
        raise SceneError(f"{what}: film size must be positive, got {w}x{h}")
    if "fov" not in node.props:
        raise SceneError(f"{what}: needs a 'fov' (focal_length is not supported)")
    fov = float(nodes.value(node, "fov", 0.0, what))
    if not 0 < fov < 180:
        raise SceneError(f"{what}: fov must lie in (0, 180) degrees, got {fov}")
    axis = str(nodes.value(node, "fov_axis", "x", what))
    if axis not in ("x", "y"):
        raise SceneError(f"{what}: fov_axis {axis!r} is not supported (use x or y)")
    K = intrinsics_from_sensor(fov, axis,
                               float(nodes.value(node, "principal_point_offset_x", 0.0, what)),
                               float(nodes.value(node, "principal_point_offset_y", 0.0, what)),
                               (w, h))
    R, t = pose_from_to_world(nodes.matrix(node))
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
        raise SceneError(f"{what}: to_world must be a rigid motion (no scale or shear)")
    dist = None
    if f"{sid}_dist" in params:
        dist = _floats(params[f"{sid}_dist"], f"{label}: parameter {sid}_dist")
        if dist.size not in (4, 5, 8):
            raise SceneError(f"{label}: parameter {sid}_dist must hold 4, 5 or 8 OpenCV "
                             f"distortion coefficients, got {dist.size}")
    try:
        return Camera(K, (w, h), dist=dist, R=_orthonormalize(R), t=t)
    except ValueError as exc:
        raise SceneError(f"{what}: {exc}") from None


def _orthonormalize(R: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def _read_shapes(nodes: _Nodes, label: str):
    """``(interfaces, targets)`` of the parsed scene: interfaces ``(id, normal towards the
    cameras' side reversed, centre, ext_ior, int_ior)``; targets ``(number, centre, radius,
    normal)``; surfaces ``(id, mesh filename as written, texture filename or None)``."""
    ObjectType = nodes.mi.ObjectType
    interfaces, targets, surfaces = [], [], []
    for node in nodes.state.nodes:
        if node.type != ObjectType.Shape:
            continue
        sid = node.props.id() or ""
        kind = node.props.plugin_name()
        what = f"{label}: shape {sid!r}"
        M = nodes.matrix(node)
        if sid == SURFACE_ID or kind in ("ply", "obj"):
            if kind != "ply" or sid != SURFACE_ID:
                raise SceneError(f"{what}: a surface must be the ply shape with id "
                                 f"'{SURFACE_ID}' (written by python -m synth scene --layout "
                                 f"surface), got a {kind!r} shape")
            if not np.allclose(M, np.eye(4)):
                raise SceneError(f"{what}: the surface mesh must have no to_world transform "
                                 f"(its vertices are in the reference frame)")
            surfaces.append((sid, str(nodes.value(node, "filename", "", what)),
                             _texture_filename(nodes, what)))
            continue
        if nodes.child(node, ObjectType.Emitter) is not None or sid.startswith(TARGET_ID_PREFIX):
            if kind != "disk":
                raise SceneError(f"{what}: targets must be disks, got {kind!r}")
            if not sid.startswith(TARGET_ID_PREFIX) or not sid[len(TARGET_ID_PREFIX):].isdigit():
                raise SceneError(f"{what}: target ids must be '{TARGET_ID_PREFIX}<number>'")
            radius = float(np.linalg.norm(M[:3, 0]))
            normal_length = float(np.linalg.norm(M[:3, 2]))
            if not (radius > 0 and normal_length > 0 and np.all(np.isfinite(M))):
                raise SceneError(f"{what}: the target radius (its scale) must be positive")
            targets.append((int(sid[len(TARGET_ID_PREFIX):]), M[:3, 3].copy(), radius,
                            M[:3, 2] / normal_length))
            continue
        if kind != "rectangle":
            raise SceneError(f"{what}: port interfaces must be rectangles, got {kind!r}")
        bsdf = nodes.child(node, ObjectType.BSDF)
        if bsdf is None or bsdf.props.plugin_name() != "dielectric":
            found = "none" if bsdf is None else repr(bsdf.props.plugin_name())
            raise SceneError(f"{what}: port interface BSDF is {found}, expected 'dielectric'")
        iors = []
        for name, default in (("ext_ior", 1.000277), ("int_ior", 1.5046)):  # Mitsuba's defaults
            value = nodes.value(bsdf, name, default, what)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 1:
                raise SceneError(f"{what}: {name} must be a number >= 1 (named media such as "
                                 f"'water' are not supported), got {value!r}")
            iors.append(float(value))
        normal = M[:3, 2] / np.linalg.norm(M[:3, 2])
        interfaces.append((sid, -normal, M[:3, 3].copy(), iors[0], iors[1]))
    return interfaces, targets, surfaces


def _texture_filename(nodes: _Nodes, what: str) -> str | None:
    """The filename of the speckle bitmap of the scene (None if there is none)."""
    for node in nodes.state.nodes:
        if node.type == nodes.mi.ObjectType.Texture and node.props.id() == SPECKLE_ID:
            return str(nodes.value(node, "filename", "", what))
    return None


def _read_surface(surfaces, scene_path: str, label: str) -> SceneSurface:
    """The scene's one surface, its files resolved next to the scene file and the mesh read."""
    from synth.surfaces import read_ply

    if len(surfaces) != 1:
        raise SceneError(f"{label}: a surface scene holds exactly one surface, found "
                         f"{len(surfaces)}")
    _, mesh_name, texture_name = surfaces[0]
    base = os.path.dirname(os.path.abspath(scene_path))
    paths = []
    for kind, name in (("mesh", mesh_name), ("speckle texture", texture_name)):
        if not name:
            raise SceneError(f"{label}: the surface has no {kind} file")
        full = name if os.path.isabs(name) else os.path.join(base, name)
        if not os.path.isfile(full):
            raise SceneError(f"{label}: the surface's {kind} {name!r} does not exist "
                             f"(looked for {os.path.relpath(full)})")
        paths.append(full)
    try:
        vertices, triangles = read_ply(paths[0])
    except (OSError, ValueError) as exc:
        raise SceneError(f"{label}: surface mesh: {exc}") from None
    digest = hashlib.sha256()
    for full in paths:
        with open(full, "rb") as handle:
            digest.update(handle.read())
    return SceneSurface(paths[0], paths[1], vertices, triangles, digest.hexdigest())


def load_scene(path, defines: dict | None = None) -> SceneSpec:
    """Read the rig, the port and the ground-truth targets from a scene file.

    ``defines`` overrides ``<default>`` values like Mitsuba's ``-D`` (values as strings or
    numbers); a name with no ``<default>`` in the file is an error. The file is parsed by
    Mitsuba's own parser (``mitsuba.parser.parse_file``: ``$`` substitution, transforms composed
    in double precision). Raises :class:`SceneError` (a ``ValueError``) with one line naming the
    file for anything that makes the scene unusable.
    """
    path = os.fspath(path)
    label = path
    if os.path.isdir(path):
        raise SceneError(f"{label}: is a directory, not a scene file")
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise SceneError(f"{label}: cannot read scene file ({exc.strerror or exc})") from None
    params, referenced = declared_defaults(data, label)
    for name, value in (defines or {}).items():
        if name not in params:
            known = ", ".join(sorted(params)) or "none"
            raise SceneError(f"{label}: unknown parameter -D {name} (the scene's defaults: {known})")
        params[name] = str(value)
    check_params(params, label)
    mi, state = _parse_with_mitsuba(path, params, referenced, label)
    nodes = _Nodes(mi, state)

    sensors = [n for n in state.nodes if n.type == mi.ObjectType.Sensor]
    if len(sensors) < 2:
        raise SceneError(f"{label}: a stereo scene needs two sensors (left, then right), "
                         f"found {len(sensors)}")
    left = _read_sensor(nodes, sensors[0], params, label)
    right = _read_sensor(nodes, sensors[1], params, label)
    if left.size != right.size:
        raise SceneError(f"{label}: the two sensors have different film sizes")
    interfaces, targets, surfaces = _read_shapes(nodes, label)
    surface = _read_surface(surfaces, path, label) if surfaces else None
    if surface is not None and targets:
        raise SceneError(f"{label}: a scene holds targets or a surface, not both")

    if not targets and surface is None:
        raise SceneError(f"{label}: no targets (disk shapes with an area emitter, "
                         f"or with ids '{TARGET_ID_PREFIX}<number>')")
    targets.sort(key=lambda item: item[0])
    ids = np.array([t[0] for t in targets], dtype=int)
    if np.unique(ids).size != ids.size:
        raise SceneError(f"{label}: duplicate target ids")
    centres = np.array([t[1] for t in targets]).reshape(-1, 3)
    radii = np.array([t[2] for t in targets], dtype=float)

    has_port = bool(interfaces)
    if not interfaces:
        if params.get("port") != "none":
            raise SceneError(f"{label}: no port (no dielectric rectangle); an all-air scene "
                             f"must declare <default name=\"port\" value=\"none\"/>")
        port = index_matched_port(left.R[:, 2], np.stack([left.center, right.center]))
    else:
        if params.get("port") == "none":
            raise SceneError(f"{label}: port=none but the scene has port interfaces")
        port = _port_from_interfaces(interfaces, label)
    try:
        rig = StereoRig(left, right, port)
    except ValueError as exc:
        raise SceneError(f"{label}: {exc}") from None
    if surface is not None and has_port and not np.all(port.water_side(surface.vertices)):
        raise SceneError(f"{label}: the surface mesh reaches out of the water (through the port)")
    if has_port and not np.all(port.water_side(centres)):
        bad = ids[~port.water_side(centres)]
        raise SceneError(f"{label}: targets {bad[:5].tolist()} are not in the water")
    normals = np.array([t[3] for t in targets]).reshape(-1, 3)
    facing = normals @ port.normal
    if np.any(facing >= 0):
        bad = ids[facing >= 0]
        raise SceneError(f"{label}: targets {bad[:5].tolist()} do not face the cameras")
    return SceneSpec(rig=rig, has_port=has_port, targets=centres, target_ids=ids,
                     target_radii=radii, params=params, path=path,
                     sha256=(hashlib.sha256(data).hexdigest() if surface is None else
                             hashlib.sha256(data + surface.sha256.encode()).hexdigest()),
                     referenced=referenced, target_normals=normals, surface=surface)


def _port_from_interfaces(interfaces, label) -> FlatPort:
    normal = interfaces[0][1]
    for sid, n, _, _, _ in interfaces:
        if not np.allclose(n, normal, atol=1e-9):
            raise SceneError(f"{label}: interface {sid!r} is not parallel to the others, or its "
                             f"normal does not face the cameras like theirs")
    offsets = np.array([normal @ c for _, _, c, _, _ in interfaces])
    order = np.argsort(offsets)
    interfaces = [interfaces[i] for i in order]
    offsets = offsets[order]
    if offsets[0] <= 0:  # the normal must point from the cameras (origin) into the water
        raise SceneError(f"{label}: the port's interfaces must face the cameras (their "
                         f"rectangle normals point back towards the cameras)")
    indices = [interfaces[0][3]]
    for k, (sid, _, _, ext, inner) in enumerate(interfaces):
        if abs(ext - indices[-1]) > 1e-9:
            raise SceneError(f"{label}: interface {sid!r} has ext_ior {ext} but the medium "
                             f"before it has index {indices[-1]}")
        indices.append(inner)
    try:
        return FlatPort(normal + 0.0, offsets[0], tuple(np.diff(offsets)), tuple(indices))
    except ValueError as exc:
        raise SceneError(f"{label}: {exc}") from None
