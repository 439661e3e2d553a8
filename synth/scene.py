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
  ``lookat(origin = t, target = t + R·z, up = −R·y)`` which gives Mitsuba's sensor OpenCV's
  axes; an ``hdrfilm`` (luminance, float32) with a ``box`` reconstruction filter.
* the port: one ``rectangle`` per interface with a ``dielectric`` BSDF, its normal (local +z)
  turned towards the cameras so that ``ext_ior`` is the camera-side index: air-glass
  ``int_ior = n2, ext_ior = n1``, glass-water ``int_ior = $n_water, ext_ior = n2``.
* the targets: ``disk`` shapes with an ``area`` emitter, facing the cameras (normal −z), shape
  ``id = "target_<k>"`` for target number ``k``; radius = the disk's scale.

Reading back (:func:`load_scene`) uses ``xml.etree`` with Mitsuba's ``<default>`` / ``$name``
substitution, so the rig, port and targets live only in the scene file. Conversions:
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
from dataclasses import dataclass, field

import numpy as np

from measure import Camera, FlatPort, StereoRig

#: Half side (mm) of the square port interfaces: covers both fields of view far beyond 2 m.
INTERFACE_HALF_SIZE_MM = 2000.0
#: Defaults written into every scene unless given.
DEFAULT_SPP = 36
DEFAULT_SEED = 0
DEFAULT_MAX_DEPTH = 8
#: Target disk radius, mm: at 1 m behind the paper's port the innermost circle's neighbours
#: (7.6 mm apart, ~10.8 px) keep a ~3.7 px gap, and each disk covers ~40-50 px.
DEFAULT_TARGET_RADIUS_MM = 2.5
#: Radiance of the target emitters (linear units; only the ratios in an image matter).
TARGET_RADIANCE = 1.0
#: Prefix of the target shapes' ids.
TARGET_ID_PREFIX = "target_"


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
    sensor_ids: tuple = ("left", "right")
    interface_ids: tuple = field(default_factory=tuple)
    referenced: frozenset = frozenset()

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


def _sensor_xml(name: str, camera: Camera, width_param: bool) -> str:
    K = camera.K
    w, h = camera.size
    if abs(K[0, 0] - K[1, 1]) > 1e-9 * K[0, 0] or K[0, 1] != 0:
        raise ValueError(f"{name} camera: Mitsuba's perspective sensor needs square pixels and no "
                         f"skew (fx = fy, s = 0), got fx={K[0, 0]}, fy={K[1, 1]}, s={K[0, 1]}")
    f = K[0, 0]
    fov = math.degrees(2.0 * math.atan(w / (2.0 * f)))
    ppx = (w / 2.0 - 0.5 - K[0, 2]) / w
    ppy = (h / 2.0 - 0.5 - K[1, 2]) / h
    R, t = camera.R, camera.t
    target = t + R[:, 2]
    up = -R[:, 1]
    width = "$width" if width_param else str(w)
    height = "$height" if width_param else str(h)
    return f"""
    <sensor type="perspective" id="{name}">
        <float name="fov" value="{_num(fov)}"/>
        <string name="fov_axis" value="x"/>
        <float name="principal_point_offset_x" value="{_num(ppx)}"/>
        <float name="principal_point_offset_y" value="{_num(ppy)}"/>
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
              interface_half_size: float = INTERFACE_HALF_SIZE_MM, comment: str = "") -> str:
    """The text of a Mitsuba 3 scene of two cameras, a flat port (or none) and disk targets.

    ``cameras`` (left, right) :class:`measure.Camera` (same image size; square pixels);
    ``port`` a :class:`measure.FlatPort` or None for an all-air scene; ``targets`` ``(N, 3)`` mm,
    reference frame, all in the water; ``target_radius`` mm. When all targets share one ``z``,
    it becomes the ``target_z`` default. ``comment`` goes into an XML comment (for people only).
    """
    left, right = cameras
    if left.size != right.size:
        raise ValueError(f"both cameras must have the same image size, got {left.size} and "
                         f"{right.size}")
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(targets)) or targets.shape[0] == 0:
        raise ValueError("targets must be a non-empty finite (N, 3) array")
    if not (target_radius > 0 and np.isfinite(target_radius)):
        raise ValueError(f"target_radius must be positive, got {target_radius}")
    if port is not None:
        StereoRig(left, right, port)  # cameras on the air side
        if not np.all(port.water_side(targets)):
            raise ValueError("every target must lie in the water, beyond the port's last interface")
        if np.any(targets @ port.normal - port.offsets[-1] <= target_radius):
            raise ValueError("targets closer to the port than their radius")
    w, h = left.size
    plane = bool(np.all(targets[:, 2] == targets[0, 2]))
    defaults = [("spp", str(int(spp))), ("seed", str(int(seed))), ("width", str(w)),
                ("height", str(h))]
    if port is not None:
        defaults.append(("n_water", _num(port.n_water)))
    else:
        defaults.append(("port", "none"))
    defaults.append(("target_radius", _num(target_radius)))
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
    parts.append("""
    <integrator type="path">
        <integer name="max_depth" value="$max_depth"/>
    </integrator>""")
    parts.append(_sensor_xml("left", left, True))
    parts.append(_sensor_xml("right", right, True))

    if port is not None:
        N = port.normal
        up = _perpendicular(N)
        n = list(port.indices)
        for k, offset in enumerate(port.offsets):
            ext = _num(n[k])
            inner = "$n_water" if k == port.n_interfaces - 1 else _num(n[k + 1])
            centre = N * offset
            parts.append(f"""
    <shape type="rectangle" id="interface_{k}">
        <transform name="to_world">
            <scale x="{_num(interface_half_size)}" y="{_num(interface_half_size)}"/>
            <lookat origin="{_vec(centre)}" target="{_vec(centre - N)}" up="{_vec(up)}"/>
        </transform>
        <bsdf type="dielectric">
            <float name="ext_ior" value="{ext}"/>
            <float name="int_ior" value="{inner}"/>
        </bsdf>
    </shape>""")

    parts.append(f"""
    <bsdf type="diffuse" id="target_back">
        <rgb name="reflectance" value="0"/>
    </bsdf>""")
    for k, (x, y, z) in enumerate(targets):
        zval = "$target_z" if plane else _num(z)
        parts.append(f"""    <shape type="disk" id="{TARGET_ID_PREFIX}{k}">
        <transform name="to_world">
            <rotate x="1" angle="180"/>
            <scale value="$target_radius"/>
            <translate x="{_num(x)}" y="{_num(y)}" z="{zval}"/>
        </transform>
        <ref id="target_back"/>
        <emitter type="area"><rgb name="radiance" value="{_num(TARGET_RADIANCE)}"/></emitter>
    </shape>""")
    parts.append("</scene>\n")
    return "\n".join(parts)


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
_SUBST = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


def parse_defines(items) -> dict:
    """``["name=value", ...]`` (the ``-D`` arguments) to a dict; SceneError on a malformed one."""
    defines = {}
    for item in items or ():
        name, sep, value = str(item).partition("=")
        name = name.strip()
        if not sep or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise SceneError(f"malformed -D {item!r}: expected name=value")
        defines[name] = value.strip()
    return defines


def _floats(text: str, what: str) -> np.ndarray:
    try:
        return np.array([float(v) for v in re.split(r"[,\s]+", text.strip()) if v], dtype=float)
    except ValueError:
        raise SceneError(f"{what}: not a list of numbers: {text!r}") from None


def _float(text: str, what: str) -> float:
    values = _floats(text, what)
    if values.size != 1:
        raise SceneError(f"{what}: expected one number, got {text!r}")
    return float(values[0])


def _lookat(origin, target, up) -> np.ndarray:
    """Mitsuba's look_at: columns (left, up', dir, origin)."""
    direction = target - origin
    direction = direction / np.linalg.norm(direction)
    left = np.cross(up, direction)
    norm = np.linalg.norm(left)
    if norm < 1e-12:
        raise SceneError("lookat: 'up' is parallel to the viewing direction")
    left /= norm
    new_up = np.cross(direction, left)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = left, new_up, direction, origin
    return M


def _rotation(axis, angle_deg) -> np.ndarray:
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    x, y, z = axis
    K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    M = np.eye(4)
    M[:3, :3] = c * np.eye(3) + s * K + (1 - c) * np.outer(axis, axis)
    return M


def _transform(elem, what: str) -> np.ndarray:
    """4x4 matrix of a Mitsuba ``<transform>`` (each child left-multiplies, in order)."""
    M = np.eye(4)
    for op in elem:
        a = op.attrib
        T = np.eye(4)
        if op.tag == "translate":
            if "value" in a:
                T[:3, 3] = _floats(a["value"], what)
            else:
                T[:3, 3] = [_float(a.get(k, "0"), what) for k in "xyz"]
        elif op.tag == "scale":
            if "value" in a:
                v = _floats(a["value"], what)
                v = np.repeat(v, 3) if v.size == 1 else v
            else:
                v = [_float(a.get(k, "1"), what) for k in "xyz"]
            T[:3, :3] = np.diag(v)
        elif op.tag == "rotate":
            if "value" in a:
                axis = _floats(a["value"], what)
            else:
                axis = [_float(a.get(k, "0"), what) for k in "xyz"]
            T = _rotation(axis, _float(a.get("angle", "0"), what))
        elif op.tag == "matrix":
            v = _floats(a.get("value", ""), what)
            if v.size == 16:
                T = v.reshape(4, 4)
            elif v.size == 9:
                T[:3, :3] = v.reshape(3, 3)
            else:
                raise SceneError(f"{what}: a matrix needs 9 or 16 values")
        elif op.tag == "lookat":
            T = _lookat(*(_floats(a.get(k, ""), what) for k in ("origin", "target", "up")))
        else:
            raise SceneError(f"{what}: unsupported transform element <{op.tag}>")
        M = T @ M
    return M


def _props(elem) -> dict:
    """``{name: (tag, value-or-element)}`` of an element's direct property children."""
    out = {}
    for child in elem:
        name = child.get("name")
        if name is not None:
            out[name] = (child.tag, child.get("value") if child.tag != "transform" else child)
    return out


def _substitute(root, params: dict, path_label: str) -> None:
    for elem in root.iter():
        for key, value in elem.attrib.items():
            if "$" in value:
                def repl(match):
                    name = match.group(1)
                    if name not in params:
                        raise SceneError(f"{path_label}: ${name} is used but has no <default>")
                    return params[name]
                elem.set(key, _SUBST.sub(repl, value))


def _read_sensor(elem, params, label) -> Camera:
    sid = elem.get("id", "?")
    what = f"{label}: sensor {sid!r}"
    if elem.get("type") != "perspective":
        raise SceneError(f"{what}: type {elem.get('type')!r}, expected 'perspective'")
    props = _props(elem)
    film = elem.find("film")
    if film is None:
        raise SceneError(f"{what}: no <film>")
    fprops = _props(film)
    try:
        w = int(fprops.get("width", ("", "768"))[1])
        h = int(fprops.get("height", ("", "576"))[1])
    except ValueError:
        raise SceneError(f"{what}: film width/height must be integers") from None
    if w <= 0 or h <= 0:
        raise SceneError(f"{what}: film size must be positive, got {w}x{h}")
    if "fov" not in props:
        raise SceneError(f"{what}: needs a 'fov' (focal_length is not supported)")
    fov = _float(props["fov"][1], what)
    axis = props.get("fov_axis", ("", "x"))[1]
    if axis == "x":
        f = (w / 2.0) / math.tan(math.radians(fov) / 2.0)
    elif axis == "y":
        f = (h / 2.0) / math.tan(math.radians(fov) / 2.0)
    else:
        raise SceneError(f"{what}: fov_axis {axis!r} is not supported (use x or y)")
    ppx = _float(props.get("principal_point_offset_x", ("", "0"))[1], what)
    ppy = _float(props.get("principal_point_offset_y", ("", "0"))[1], what)
    K = np.array([[f, 0.0, w / 2.0 - 0.5 - ppx * w], [0.0, f, h / 2.0 - 0.5 - ppy * h],
                  [0.0, 0.0, 1.0]])
    M = np.eye(4)
    if "to_world" in props:
        M = _transform(props["to_world"][1], what)
    R = M[:3, :3] @ np.diag([-1.0, -1.0, 1.0])
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
        raise SceneError(f"{what}: to_world must be a rigid motion (no scale or shear)")
    dist = None
    if f"{sid}_dist" in params:
        dist = _floats(params[f"{sid}_dist"], f"{label}: default {sid}_dist")
        if dist.size not in (4, 5, 8):
            raise SceneError(f"{label}: default {sid}_dist must hold 4, 5 or 8 OpenCV "
                             f"distortion coefficients, got {dist.size}")
    R = _orthonormalize(R)
    return Camera(K, (w, h), dist=dist, R=R, t=M[:3, 3])


def _orthonormalize(R: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def _find_bsdf(shape, refs, what):
    bsdf = shape.find("bsdf")
    if bsdf is None:
        for ref in shape.findall("ref"):
            target = refs.get(ref.get("id"))
            if target is not None and target.tag == "bsdf":
                bsdf = target
                break
    return bsdf


def load_scene(path, defines: dict | None = None) -> SceneSpec:
    """Read the rig, the port and the ground-truth targets from a scene file.

    ``defines`` overrides ``<default>`` values like Mitsuba's ``-D`` (values as strings or
    numbers); a name with no ``<default>`` in the file is an error. Raises :class:`SceneError`
    (a ``ValueError``) with one line naming the file for anything that makes the scene unusable.
    """
    path = os.fspath(path)
    label = path
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise SceneError(f"{label}: cannot read scene file ({exc.strerror or exc})") from None
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
    for name, value in (defines or {}).items():
        if name not in params:
            known = ", ".join(sorted(params)) or "none"
            raise SceneError(f"{label}: unknown parameter -D {name} (the scene's defaults: {known})")
        params[name] = str(value)
    referenced = frozenset(name for elem in root.iter() for value in elem.attrib.values()
                           for name in _SUBST.findall(value))
    _substitute(root, params, label)

    sensors = [s for s in root.findall("sensor")]
    if len(sensors) < 2:
        raise SceneError(f"{label}: a stereo scene needs two sensors (left, then right), "
                         f"found {len(sensors)}")
    left = _read_sensor(sensors[0], params, label)
    right = _read_sensor(sensors[1], params, label)
    if left.size != right.size:
        raise SceneError(f"{label}: the two sensors have different film sizes")

    refs = {e.get("id"): e for e in root if e.get("id")}
    interfaces, targets = [], []
    for shape in root.findall("shape"):
        sid = shape.get("id", "")
        what = f"{label}: shape {sid!r}"
        props = _props(shape)
        M = _transform(props["to_world"][1], what) if "to_world" in props else np.eye(4)
        if shape.find("emitter") is not None:
            if shape.get("type") != "disk":
                raise SceneError(f"{what}: targets must be disks, got {shape.get('type')!r}")
            if not sid.startswith(TARGET_ID_PREFIX) or not sid[len(TARGET_ID_PREFIX):].isdigit():
                raise SceneError(f"{what}: target ids must be '{TARGET_ID_PREFIX}<number>'")
            radius = float(np.linalg.norm(M[:3, 0]))
            normal = M[:3, 2] / np.linalg.norm(M[:3, 2])
            targets.append((int(sid[len(TARGET_ID_PREFIX):]), M[:3, 3].copy(), radius, normal))
            continue
        bsdf = _find_bsdf(shape, refs, what)
        if shape.get("type") != "rectangle":
            raise SceneError(f"{what}: port interfaces must be rectangles, got "
                             f"{shape.get('type')!r}")
        if bsdf is None or bsdf.get("type") != "dielectric":
            kind = "none" if bsdf is None else repr(bsdf.get("type"))
            raise SceneError(f"{what}: port interface BSDF is {kind}, expected 'dielectric'")
        bprops = _props(bsdf)
        try:
            ext = _float(bprops.get("ext_ior", ("", "1.000277"))[1], what)
            inner = _float(bprops.get("int_ior", ("", "1.5046"))[1], what)
        except SceneError:
            raise SceneError(f"{what}: ext_ior/int_ior must be numbers (named media such as "
                             f"'water' are not supported)") from None
        normal = M[:3, 2] / np.linalg.norm(M[:3, 2])
        interfaces.append((sid, -normal, M[:3, 3].copy(), ext, inner))

    if not targets:
        raise SceneError(f"{label}: no targets (disk shapes with an area emitter)")
    targets.sort(key=lambda item: item[0])
    ids = np.array([t[0] for t in targets])
    if np.unique(ids).size != ids.size:
        raise SceneError(f"{label}: duplicate target ids")
    centres = np.array([t[1] for t in targets])
    radii = np.array([t[2] for t in targets])

    has_port = bool(interfaces)
    if not interfaces:
        if params.get("port") != "none":
            raise SceneError(f"{label}: no port (no dielectric rectangle); an all-air scene "
                             f"must declare <default name=\"port\" value=\"none\"/>")
        normal = left.R[:, 2]
        distance = max(float(normal @ left.t), float(normal @ right.t)) + 1.0
        port = FlatPort(normal + 0.0, distance, (), (1.0, 1.0))
    else:
        if params.get("port") == "none":
            raise SceneError(f"{label}: port=none but the scene has port interfaces")
        port = _port_from_interfaces(interfaces, label)
    try:
        rig = StereoRig(left, right, port)
    except ValueError as exc:
        raise SceneError(f"{label}: {exc}") from None
    if has_port and not np.all(port.water_side(centres)):
        bad = ids[~port.water_side(centres)]
        raise SceneError(f"{label}: targets {bad[:5].tolist()} are not in the water")
    facing = np.einsum("ij,j->i", np.array([t[3] for t in targets]), port.normal)
    if np.any(facing >= 0):
        bad = ids[facing >= 0]
        raise SceneError(f"{label}: targets {bad[:5].tolist()} do not face the cameras")
    return SceneSpec(rig=rig, has_port=has_port, targets=centres, target_ids=ids,
                     target_radii=radii, params=params, path=path,
                     sha256=hashlib.sha256(data).hexdigest(),
                     sensor_ids=(sensors[0].get("id", "left"), sensors[1].get("id", "right")),
                     interface_ids=tuple(i[0] for i in interfaces), referenced=referenced)


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
