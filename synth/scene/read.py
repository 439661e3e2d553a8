"""Read the rig, the port and the ground-truth targets (or surface) back from a scene file.

Reading back (:func:`load_scene`) uses Mitsuba's own parser (``mitsuba.parser.parse_file``:
``<default>``, ``$name`` substitution and transforms composed in double precision, no plugin
built), so the rig, port and targets live only in the scene file; units mm, reference frame (the
left camera's, OpenCV axes). Conversions:
``f = (W/2) / tan(fov/2)`` px (fov along x), ``cx = W/2 − 0.5 − ppx·W``,
``cy = H/2 − 0.5 − ppy·H`` (Mitsuba's film pixel i covers [i, i+1); measured sign of the offset),
``R = M[:3, :3]·diag(−1, −1, 1)``, ``t = M[:3, 3]`` for the sensor's ``to_world`` matrix ``M``.
"""

from __future__ import annotations

import hashlib
import math
import os
import re

import numpy as np

from measure import Camera, FlatPort, StereoRig
from measure.geometry.dome import DomePair
from measure.geometry.flat_pair import FlatPair
from measure.geometry.port import index_matched_port
from synth.scene.dome import check_field_of_view, domes_from_spheres, facing_cameras
from synth.scene.model import (SPECKLE_ID, SURFACE_ID, TARGET_ID_PREFIX, SceneError, SceneSpec,
                               SceneSurface)
from synth.scene.params import check_params, declared_defaults, override_defaults
from synth.scene.windows import check_windows, window_from_rectangles
from synth.rendering.sensor import intrinsics_from_sensor, pose_from_to_world


def _floats(text: str, what: str) -> np.ndarray:
    """A parameter's list of numbers (separated by commas or spaces), all finite."""
    try:
        values = np.array([float(v) for v in re.split(r"[,\s]+", str(text).strip()) if v],
                          dtype=float)
    except ValueError:
        raise SceneError(f"{what}: not a list of numbers: {text!r}") from None
    if not np.all(np.isfinite(values)):
        raise SceneError(f"{what}: not finite: {text!r}")
    return values


def _parse_with_mitsuba(path: str, params: dict, referenced, label: str):
    """Mitsuba's own parser (``mitsuba.parser.parse_file``): ``$`` substitution, transforms
    composed in double precision, references; no plugin is built."""
    from synth.rendering.mitsuba_setup import import_mitsuba

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
    interfaces, targets, surfaces, spheres = [], [], [], {}
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
        if kind not in ("rectangle", "sphere"):
            raise SceneError(f"{what}: port interfaces must be rectangles (a flat port) or "
                             f"spheres (a dome), got {kind!r}")
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
        if kind == "sphere":
            spheres[sid] = _sphere(nodes, node, M, what) + tuple(iors)
            continue
        normal = M[:3, 2] / np.linalg.norm(M[:3, 2])
        interfaces.append((sid, -normal, M[:3, 3].copy(), iors[0], iors[1], M))
    return interfaces, targets, surfaces, spheres


def _sphere(nodes: _Nodes, node, M: np.ndarray, what: str):
    """``(centre, radius)`` of a dome sphere (mm): its ``center`` and ``radius`` properties
    (Mitsuba's defaults 0 and 1), with no ``to_world`` and no ``flip_normals`` (the dielectric's
    ``ext_ior`` must be outside)."""
    if not np.allclose(M, np.eye(4)):
        raise SceneError(f"{what}: a dome sphere is given by its 'center' and 'radius' (no "
                         f"to_world transform)")
    if bool(nodes.value(node, "flip_normals", False, what)):
        raise SceneError(f"{what}: a dome sphere must not flip its normals (ext_ior is the "
                         f"outside's index)")
    centre = np.array(nodes.value(node, "center", (0.0, 0.0, 0.0), what), dtype=np.float64)
    radius = float(nodes.value(node, "radius", 1.0, what))
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise SceneError(f"{what}: the sphere's center must be a finite point")
    if not (np.isfinite(radius) and radius > 0):
        raise SceneError(f"{what}: the sphere's radius must be positive, got {radius:g}")
    return centre, radius


def _texture_filename(nodes: _Nodes, what: str) -> str | None:
    """The filename of the speckle bitmap of the scene (None if there is none)."""
    for node in nodes.state.nodes:
        if node.type == nodes.mi.ObjectType.Texture and node.props.id() == SPECKLE_ID:
            return str(nodes.value(node, "filename", "", what))
    return None


def _read_surface(surfaces, scene_path: str, label: str) -> SceneSurface:
    """The scene's one surface, its files resolved next to the scene file and the mesh read."""
    from synth.scene.surfaces import read_ply

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
    data = _read_bytes(path)
    params, referenced = declared_defaults(data, label)
    override_defaults(params, defines, label)
    check_params(params, label)
    mi, state = _parse_with_mitsuba(path, params, referenced, label)
    nodes = _Nodes(mi, state)
    left, right, extra = _sensors(mi, nodes, state, params, label)
    interfaces, targets, surfaces, spheres = _read_shapes(nodes, label)
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
    normals = np.array([t[3] for t in targets]).reshape(-1, 3)
    has_port = bool(interfaces or spheres)
    if params.get("port") == "mixed":
        rig, extra_ports, ports = _mixed_rig(interfaces, spheres, (left, right) + extra,
                                             surface, label)
        _check_mixed_targets(ports, (left, right) + extra, centres, radii, normals, label)
    else:
        rig, extra_ports = _rig(params, interfaces, spheres, left, right, extra, surface, label)
        _check_targets(rig, (extra, extra_ports), bool(spheres), has_port, surface, ids,
                       centres, normals, label)
        ports = ()
    return SceneSpec(rig=rig, has_port=has_port, targets=centres, target_ids=ids,
                     target_radii=radii, params=params, path=path,
                     sha256=(hashlib.sha256(data).hexdigest() if surface is None else
                             hashlib.sha256(data + surface.sha256.encode()).hexdigest()),
                     referenced=referenced, target_normals=normals, surface=surface,
                     extra_cameras=extra, extra_ports=tuple(extra_ports), ports=ports)


def _read_bytes(path) -> bytes:
    """The scene file's bytes; SceneError for a folder or a file that cannot be read."""
    if os.path.isdir(path):
        raise SceneError(f"{path}: is a directory, not a scene file")
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except OSError as exc:
        raise SceneError(f"{path}: cannot read scene file ({exc.strerror or exc})") from None


def _sensors(mi, nodes, state, params, label):
    """``(left, right, extra)``: the cameras of the scene's sensors in order (two at least, all
    of one film size)."""
    sensors = [n for n in state.nodes if n.type == mi.ObjectType.Sensor]
    if len(sensors) < 2:
        raise SceneError(f"{label}: a stereo scene needs two sensors (left, then right), "
                         f"found {len(sensors)}")
    left = _read_sensor(nodes, sensors[0], params, label)
    right = _read_sensor(nodes, sensors[1], params, label)
    if left.size != right.size:
        raise SceneError(f"{label}: the two sensors have different film sizes")
    extra = tuple(_read_sensor(nodes, s, params, label) for s in sensors[2:])
    if any(camera.size != left.size for camera in extra):
        raise SceneError(f"{label}: the sensors have different film sizes")
    return left, right, extra


def _rig(params, interfaces, spheres, left, right, extra, surface, label):
    """``(rig, extra_ports)``: the stereo rig of the first two cameras behind the scene's port
    (domes from its spheres, flat windows from its dielectric rectangles, or none: index
    matched) and the further cameras' own ports; SceneError for a port that contradicts the
    ``port`` parameter, windows that overlap a field of view, domes that cut it."""
    windows = None
    if interfaces and spheres:
        raise SceneError(f"{label}: a scene holds a flat port (rectangles) or domes (spheres), "
                         f"not both")
    if spheres:
        if params.get("port") == "none":
            raise SceneError(f"{label}: port=none but the scene has dome spheres")
        from measure.stereo.rig import default_names

        try:
            port = tuple(domes_from_spheres(spheres, default_names(2 + len(extra))))
        except ValueError as exc:
            raise SceneError(f"{label}: {exc}") from None
    elif not interfaces:
        if params.get("port") != "none":
            raise SceneError(f"{label}: no port (no dielectric rectangle); an all-air scene "
                             f"must declare <default name=\"port\" value=\"none\"/>")
        port = index_matched_port(left.R[:, 2], np.stack(
            [left.center, right.center] + [c.center for c in extra]))
    else:
        if params.get("port") == "none":
            raise SceneError(f"{label}: port=none but the scene has port interfaces")
        port, windows = _ports_from_interfaces(interfaces, (left, right) + extra, label)
    extra_ports = ()
    if isinstance(port, tuple):  # each camera behind its own window or inside its own dome
        port, extra_ports = (DomePair if spheres else FlatPair)(*port[:2]), port[2:]
    try:
        rig = StereoRig(left, right, port)
        if windows is not None and not extra_ports:
            check_windows(rig, windows)
    except ValueError as exc:
        raise SceneError(f"{label}: {exc}") from None
    if spheres and surface is not None:
        raise SceneError(f"{label}: a dome scene holds disk targets, not a surface")
    if extra:
        _check_extra_cameras(rig, extra, extra_ports, windows, bool(spheres), label)
    elif spheres:
        try:
            check_field_of_view(rig)
        except ValueError as exc:
            raise SceneError(f"{label}: {exc}") from None
    return rig, extra_ports


def _mixed_rig(interfaces, spheres, cameras, surface, label):
    """``(pair rig, extra ports, ports)`` of a scene of mixed ports (``port=mixed``,
    :mod:`synth.scene.mixed`): the first two cameras as a pair, the ports the others look
    through, every camera's port (None: in air); SceneError for shapes that name no camera or
    glass that overlaps a field of view."""
    from measure.stereo.rig import Rig, default_names

    from synth.scene.mixed import check_mixed, read_mixed

    if surface is not None:
        raise SceneError(f"{label}: a scene of mixed ports holds disk targets, not a surface")
    names = default_names(len(cameras))
    try:
        ports, glass = read_mixed(interfaces, spheres, cameras, names, lambda items, centre, what:
                                  _port_from_interfaces(items, label, centre, what))
        rig = Rig(cameras, ports, names)
        check_mixed(rig, glass)
    except ValueError as exc:
        raise SceneError(f"{label}: {exc}") from None
    return rig.pair(0, 1), tuple(rig.view_port(k) for k in range(2, len(cameras))), ports


def _check_mixed_targets(ports, cameras, centres, radii, normals, label) -> None:
    from measure.stereo.rig import Rig

    from synth.scene.mixed import check_mixed_targets

    try:
        check_mixed_targets(Rig(cameras, ports), centres, float(np.max(radii)), normals)
    except ValueError as exc:
        raise SceneError(f"{label}: {exc}") from None


def _check_targets(rig, extra, domes: bool, has_port: bool, surface, ids, centres, normals,
                   label) -> None:
    """SceneError for targets (or a surface) out of the water, or targets that do not face
    the cameras; ``extra`` ``(extra cameras, their ports)`` (:attr:`SceneSpec.extra_ports`)."""
    port = rig.port
    extra_cameras, extra_ports = extra
    if surface is not None and has_port and not np.all(port.water_side(surface.vertices)):
        raise SceneError(f"{label}: the surface mesh reaches out of the water (through the "
                         f"port)")
    in_water = port.water_side(centres) if has_port else np.ones(len(centres), dtype=bool)
    for extra_port in extra_ports:
        in_water &= extra_port.water_side(centres)
    if not np.all(in_water):
        bad = ids[~in_water]
        raise SceneError(f"{label}: targets {bad[:5].tolist()} are not in the water")
    facing = (facing_cameras(rig.cameras + tuple(extra_cameras), centres, normals) if domes
              else np.all([normals @ p.normal < 0
                           for p in (rig.view_port(0), rig.view_port(1), *extra_ports)], axis=0))
    if not np.all(facing):
        bad = ids[~facing]
        raise SceneError(f"{label}: targets {bad[:5].tolist()} do not face the cameras")

def _check_extra_cameras(rig, extra, extra_ports, windows, domes: bool, label) -> None:
    """A scene of more than two sensors: every camera behind the one flat port, its own window
    or inside its own dome (``extra_ports`` the ports of the cameras after the first two,
    ``windows`` every camera's window) or none, none at another's centre or inside another's
    glass (:class:`measure.stereo.rig.Rig`), every field of view through its own
    window (:func:`synth.scene.windows.check_windows`) or dome and past every other
    (:func:`synth.scene.dome.check_field_of_view`)."""
    from measure.stereo.rig import Rig

    count = 2 + len(extra)
    try:
        if extra_ports:
            multirig = Rig((rig.left, rig.right) + extra,
                                [rig.view_port(0), rig.view_port(1), *extra_ports])
            if domes:
                check_field_of_view(multirig)
            else:
                check_windows(multirig, windows)
        else:
            Rig((rig.left, rig.right) + extra, [rig.port] * count)
    except ValueError as exc:
        raise SceneError(f"{label}: {exc}") from None


def _ports_from_interfaces(interfaces, cameras, label):
    """``(port, windows)``: one flat port of every rectangle (``windows`` None), or — when the
    ids name the cameras (``left_interface_<k>``, ``right_interface_<k>``; of N > 2 cameras
    ``cam0_interface_<k>``, …: :mod:`synth.scene.windows`) — a
    :class:`measure.geometry.flat_pair.FlatPair` (of N > 2 cameras a tuple of their flat
    ports) and the finite windows its rectangles make, one per camera."""
    from measure.stereo.rig import default_names

    names = default_names(len(cameras))
    own = {name: [i for i in interfaces if i[0].startswith(name + "_")] for name in names}
    if not any(own.values()):
        return _port_from_interfaces(interfaces, label), None
    stray = [i[0] for i in interfaces if not i[0].startswith(tuple(f"{n}_" for n in names))]
    missing = [name for name in names if not own[name]]
    if stray or missing:
        what = ("two housings holds the rectangles left_interface_<k> and right_interface_<k>"
                if len(names) == 2 else
                f"{len(names)} housings holds the rectangles {names[0]}_interface_<k> … "
                f"{names[-1]}_interface_<k>")
        raise SceneError(f"{label}: a scene of {what} only; "
                         + (f"found {stray[0]!r}" if stray else f"no {missing[0]} window"))
    ports, windows = [], []
    for name, camera in zip(names, cameras):
        port = _port_from_interfaces(own[name], label, camera.center, f"the {name} port")
        ports.append(port)
        matrices = [i[5] for i in sorted(own[name], key=lambda i: port.normal @ i[2])]
        try:
            windows.append(window_from_rectangles(port, name, matrices))
        except ValueError as exc:
            raise SceneError(f"{label}: {exc}") from None
    waters = {p.n_water for p in ports}
    if max(waters) - min(waters) > 1e-12:
        raise SceneError(f"{label}: the windows look into different water (int_ior "
                         f"{', '.join(f'{p.n_water:g}' for p in ports)})")
    if len(ports) > 2:
        return tuple(ports), windows
    return FlatPair(*ports), windows


def _port_from_interfaces(interfaces, label, center=(0.0, 0.0, 0.0), what="the port") -> FlatPort:
    normal = interfaces[0][1]
    for sid, n, *_ in interfaces:
        if not np.allclose(n, normal, atol=1e-9):
            raise SceneError(f"{label}: interface {sid!r} is not parallel to the others, or its "
                             f"normal does not face the cameras like theirs")
    offsets = np.array([normal @ i[2] for i in interfaces])
    order = np.argsort(offsets)
    interfaces = [interfaces[i] for i in order]
    offsets = offsets[order]
    # the normal must point from the camera into the water
    if offsets[0] <= normal @ np.asarray(center, dtype=float):
        raise SceneError(f"{label}: {what}'s interfaces must face the cameras (their "
                         f"rectangle normals point back towards the cameras)")
    indices = [interfaces[0][3]]
    for sid, _, _, ext, inner, _ in interfaces:
        if abs(ext - indices[-1]) > 1e-9:
            raise SceneError(f"{label}: interface {sid!r} has ext_ior {ext} but the medium "
                             f"before it has index {indices[-1]}")
        indices.append(inner)
    try:
        return FlatPort(normal + 0.0, offsets[0], tuple(np.diff(offsets)), tuple(indices))
    except ValueError as exc:
        raise SceneError(f"{label}: {exc}") from None
