"""Scenes of cameras with different kinds of port (``synth scene --port mixed --ports …``): per
camera a dome of its own, a flat window of its own, the one flat port it shares with others
(cameras whose flat ports are equal share one window), or none (a camera in air: its rays go
straight). Units mm, reference frame = the first camera's (OpenCV axes).

In a scene file each glass is written once: a dome as the two spheres ``dome_<camera>_inner``
and ``dome_<camera>_outer`` (:data:`synth.scene.dome.DOME_ID`), a window as one ``rectangle``
per interface, camera side first, with the ids ``<cameras>_interface_<k>`` where ``<cameras>``
names every camera behind it joined by ``_`` (``cam2_interface_0`` for cam2's own window,
``cam0_cam1_interface_0`` for the window cam0 and cam1 share; :data:`WINDOW_ID`). A window is
sized to the footprints of all its cameras' images on each of its interfaces
(:data:`synth.scene.windows.WINDOW_MARGIN_MM` to spare). The file declares
``<default name="port" value="mixed"/>``; a camera named by no shape is in air.
:func:`check_mixed` refuses glass that overlaps, a field of view that leaves its own glass or
meets another camera's glass (in the air before its port, in the water after it; a camera in
air along its whole ray), and targets out of the water or inside glass."""

from __future__ import annotations

import numpy as np

from synth.scene.dome import DOME_ID, SPHERE_NAMES, domes_from_spheres, sphere_xml
from synth.scene.windows import (BORDER_STEP_PX, CLEARANCE_MM, GRID_STEP_PX, WINDOW_ID,
                                 WINDOW_MARGIN_MM, Window, boxes_overlap, image_pixels,
                                 window_axes, window_from_rectangles, window_hits, window_xml)

#: The kinds of port ``--ports`` names, one per camera (``synth scene --port`` values).
MIXED_KINDS = ("paper", "per-camera", "dome", "none")


class MixedPorts(tuple):
    """Every camera's port in a rig of different kinds of port, in camera order: a FlatPort
    (equal ones are one shared window), a DomePort, or None (in air). What
    :func:`synth.scene.write.scene_xml` takes as the port of such a rig."""


def _domed(port) -> bool:
    """Whether a camera's ``port`` is a dome: the scene writes its glass as spheres (the kind
    of :data:`synth.scene.glass.PER_CAMERA_GLASS`)."""
    return getattr(port, "kind", None) == "dome"


def is_mixed(port) -> bool:
    """Whether ``port`` (a scene writer's port) is a mix: a :class:`MixedPorts`, or a list
    holding a camera in air or both domes and flat ports."""
    if isinstance(port, MixedPorts):
        return True
    if not isinstance(port, (list, tuple)):
        return False
    kinds = {"air" if p is None else getattr(p, "kind", None) for p in port}
    return "air" in kinds or len(kinds) > 1


def groups(rig) -> list:
    """``[(shape name, camera indices, port)]``: every glass of ``rig`` (a Rig of mixed ports),
    in order of its first camera — a dome (name the camera's), a flat window shared by the
    cameras whose flat ports are equal (names joined by ``_``)."""
    found = []
    for k, port in enumerate(rig.ports):
        if port is None:
            continue
        if _domed(port):
            found.append([rig.names[k], [k], port])
            continue
        for entry in found:
            if not _domed(entry[2]) and entry[2] == port:
                entry[1].append(k)
                entry[0] += f"_{rig.names[k]}"
                break
        else:
            found.append([rig.names[k], [k], port])
    return [tuple(entry) for entry in found]


def _trace(rig, view: int, uv):
    camera = rig.cameras[view]
    return rig.view_port(view).trace(camera.center, camera.rays(uv), keep_interface_points=True)


def fit_window(rig, views, port, margin: float = WINDOW_MARGIN_MM) -> Window:
    """The window of flat ``port`` that cameras ``views`` of ``rig`` look through: on the
    first camera's image axes, the smallest rectangle holding the footprints of all their
    images on every interface, plus ``margin`` mm. ValueError for a ray that does not reach the
    water."""
    axes = window_axes(port.normal, rig.cameras[views[0]])
    foot = port.normal * port.offsets[0]
    coords = []
    for view in views:
        uv = image_pixels(rig.cameras[view], BORDER_STEP_PX, None)
        water = _trace(rig, view, uv)
        _refuse_lost(water, uv, rig.names[view], "port")
        coords.append(((water.interface_points - foot) @ axes.T).reshape(-1, 2))
    coords = np.concatenate(coords)
    low, high = coords.min(axis=0), coords.max(axis=0)
    return Window(port, foot + 0.5 * (low + high) @ axes, axes, 0.5 * (high - low) + margin)


def _refuse_lost(water, uv, name: str, what: str) -> None:
    lost = ~np.all(np.isfinite(water.directions), axis=1)
    if lost.any():
        u, v = uv[np.flatnonzero(lost)[0]]
        raise ValueError(f"the {name} camera's field of view does not reach the water through "
                         f"its {what} (the ray of pixel ({u:g}, {v:g}))")


def glass_of_rig(rig) -> list:
    """``[(shape name, camera indices, Window or DomePort)]`` of :func:`groups`, windows fitted."""
    return [(name, views, port if _domed(port) else fit_window(rig, views, port))
            for name, views, port in groups(rig)]


def _meets_sphere(origins, directions, longest, dome, clearance: float):
    """Whether segments ``origins + s·directions`` (unit, ``0 < s < longest``) come within
    ``clearance`` of ``dome``'s outer sphere."""
    offset = origins - dome.center
    b = np.einsum("ij,ij->i", offset, directions)
    c = np.einsum("ij,ij->i", offset, offset) - (dome.radii[1] + clearance) ** 2
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        near, far = -b - np.sqrt(disc), -b + np.sqrt(disc)
    return (disc >= 0) & (far > 0) & (near < longest)


def _meets(origins, directions, longest, glass) -> np.ndarray:
    if isinstance(glass, Window):
        return window_hits(origins, directions, glass, longest, CLEARANCE_MM)
    return _meets_sphere(origins, directions, longest, glass, CLEARANCE_MM)


def _glass_overlap(a, b) -> bool:
    if not isinstance(a, Window) and not isinstance(b, Window):  # two domes
        return np.linalg.norm(a.center - b.center) <= a.radii[1] + b.radii[1] + CLEARANCE_MM
    if not isinstance(a, Window) or not isinstance(b, Window):
        dome, window = (b, a) if isinstance(a, Window) else (a, b)
        centre, axes, half = window.box()
        local = np.clip(axes @ (dome.center - centre), -half, half)
        return np.linalg.norm(centre + local @ axes - dome.center) <= dome.radii[1] + CLEARANCE_MM
    return boxes_overlap(a.box(), b.box(), CLEARANCE_MM)


def check_mixed(rig, glass) -> None:
    """ValueError (one line naming the cameras) unless no two pieces of ``glass``
    (:func:`glass_of_rig`) overlap and every ray of each camera's image (its border every
    :data:`BORDER_STEP_PX` px and a grid every :data:`GRID_STEP_PX`) passes through its own
    glass (inside its window's rectangles; reaching the water through its dome) and meets no
    other glass — from the camera to its port and from its port into the water (a camera in
    air: its whole ray)."""
    for i in range(len(glass)):
        for j in range(i + 1, len(glass)):
            if _glass_overlap(glass[i][2], glass[j][2]):
                raise ValueError(f"the {_what(glass[i])} and the {_what(glass[j])} overlap (their "
                                 f"glass comes nearer than {CLEARANCE_MM:g} mm): move the cameras "
                                 f"apart or the ports nearer the cameras")
    own = {k: g for g in glass for k in g[1]}
    for view, (name, camera) in enumerate(zip(rig.names, rig.cameras)):
        uv = image_pixels(camera, BORDER_STEP_PX, GRID_STEP_PX)
        water = _trace(rig, view, uv)
        mine = own.get(view)
        _refuse_lost(water, uv, name, "glass" if mine is None else _what(mine))
        legs = [(water.origins, water.directions, np.inf)]
        if mine is not None:
            air = water.interface_points[0] - camera.center
            length = np.linalg.norm(air, axis=1)
            legs.append((np.broadcast_to(camera.center, air.shape), air / length[:, None],
                         length))
            if isinstance(mine[2], Window):
                _check_inside(mine[2], water.interface_points, uv, name)
        for other in glass:
            if other is mine:
                continue
            crossing = np.any([_meets(*leg, other[2]) for leg in legs], axis=0)
            if crossing.any():
                u, v = uv[np.flatnonzero(crossing)[0]]
                raise ValueError(f"the {name} camera's field of view meets the {_what(other)} "
                                 f"(the ray of pixel ({u:g}, {v:g})): move the cameras apart or "
                                 f"the ports nearer the cameras")


def _what(entry) -> str:
    name, views, glass = entry
    if not isinstance(glass, Window):
        return f"{name} dome"
    return f"{name} window" if len(views) == 1 else f"window {name.replace('_', ', ')} share"


def _check_inside(window: Window, points, uv, name: str) -> None:
    coords = np.abs((points - window.centres()[:, None, :]) @ window.axes.T)
    outside = np.any(coords > window.half, axis=(0, 2))
    if outside.any():
        u, v = uv[np.flatnonzero(outside)[0]]
        raise ValueError(f"the {name} camera's field of view does not fit through its window "
                         f"(the ray of pixel ({u:g}, {v:g}) passes beside it)")


def check_mixed_targets(rig, targets, target_radius: float, target_normals) -> None:
    """ValueError unless every target ``(N, 3)`` lies in the water of every camera's port, at
    least its radius beyond each flat port's last interface and outside each dome, and faces
    the cameras (its normal towards the mean of their centres and against every flat port's
    normal)."""
    from synth.scene.dome import facing_cameras

    for k, name in enumerate(rig.names):
        port = rig.view_port(k)
        if not np.all(port.water_side(targets)):
            raise ValueError(f"every target must lie in the water, beyond the {name} port")
        if _domed(port):
            if np.any(np.linalg.norm(targets - port.center, axis=1)
                      <= port.radii[1] + target_radius):
                raise ValueError(f"targets inside the {name} dome or nearer it than their radius")
        elif rig.ports[k] is not None:
            if np.any(targets @ port.normal - port.offsets[-1] <= target_radius):
                raise ValueError(f"targets closer to the {name} port than their radius")
            if np.any(target_normals @ port.normal >= 0):
                raise ValueError(f"every target must face the cameras (its normal towards the "
                                 f"{name} port)")
    if not np.all(facing_cameras(rig.cameras, targets, target_normals)):
        raise ValueError("every target must face the cameras (its normal towards them)")


def mixed_xml(rig) -> str:
    """The glass of a scene of mixed ports: per dome its two spheres, per window (shared or
    own) one rectangle per interface, the last looking into ``$n_water``."""
    glass = glass_of_rig(rig)
    waters = {p.n_water for p in rig.ports if p is not None}
    if len(waters) > 1:
        raise ValueError(f"the ports look into different water (n_water "
                         f"{', '.join(f'{n:g}' for n in sorted(waters))})")
    air = [name for name, port in zip(rig.names, rig.ports) if port is None]
    parts = [f"\n    <!-- Mixed ports: each dome two concentric spheres (air inside, glass between, "
             f"water outside), each flat window one rectangle per interface (normal towards the "
             f"cameras, ext_ior on their side; a window its cameras share is one)"
             f"{'; in air: ' + ', '.join(air) if air else ''}. -->"]
    for name, _, piece in glass:
        if not isinstance(piece, Window):
            n_air, n_glass, n_water = piece.indices
            parts.append(sphere_xml(DOME_ID.format(camera=name, sphere="inner"), piece.center,
                                    piece.radii[0], n_glass, n_air, False))
            parts.append(sphere_xml(DOME_ID.format(camera=name, sphere="outer"), piece.center,
                                    piece.radii[1], n_water, n_glass, True))
        else:
            parts += window_xml([piece], [name])
    return "\n".join(parts)


def mixed_shapes(mi, rig) -> dict:
    """The glass of a rig of mixed ports as Mitsuba dictionary shapes (:func:`mixed_xml`'s)."""
    shapes = {}
    for name, _, piece in glass_of_rig(rig):
        if not isinstance(piece, Window):
            n_air, n_glass, n_water = piece.indices
            for sphere, radius, ext, inner in zip(SPHERE_NAMES, piece.radii, (n_glass, n_water),
                                                  (n_air, n_glass)):
                shapes[DOME_ID.format(camera=name, sphere=sphere)] = {
                    "type": "sphere", "center": [float(c) for c in piece.center],
                    "radius": float(radius),
                    "bsdf": {"type": "dielectric", "ext_ior": float(ext), "int_ior": float(inner)}}
            continue
        n = piece.port.indices
        for k, centre in enumerate(piece.centres()):
            to_world = (mi.ScalarTransform4f().look_at(
                origin=centre.tolist(), target=(centre - piece.port.normal).tolist(),
                up=piece.axes[1].tolist())
                @ mi.ScalarTransform4f().scale([float(piece.half[0]), float(piece.half[1]), 1.0]))
            shapes[WINDOW_ID.format(camera=name, k=k)] = {
                "type": "rectangle", "to_world": to_world,
                "bsdf": {"type": "dielectric", "ext_ior": float(n[k]), "int_ior": float(n[k + 1])}}
    return shapes


def read_mixed(interfaces, spheres, cameras, names, port_from_interfaces) -> tuple:
    """``(ports, glass)`` of a scene of mixed ports (:func:`mixed_xml`): ``interfaces`` its
    rectangles ``(id, normal, centre, ext_ior, int_ior, matrix)``, ``spheres`` its dome
    spheres, ``cameras`` and their ``names``; ``port_from_interfaces(interfaces, centre,
    what)`` the reader's flat port of one window's rectangles; ``glass`` as
    :func:`glass_of_rig` gives it, the windows as the file holds them. ValueError naming what does not
    fit (a shape that names no camera, a camera behind two pieces of glass)."""
    ports = [None] * len(cameras)
    index = {name: k for k, name in enumerate(names)}
    dome_names = sorted({sid.split("_")[1] for sid in spheres if sid.count("_") == 2},
                        key=lambda n: index.get(n, -1))
    unknown = [n for n in dome_names if n not in index]
    if unknown:
        raise ValueError(f"dome sphere of {unknown[0]!r}, which is not a camera")
    for name, dome in zip(dome_names, domes_from_spheres(spheres, dome_names)):
        ports[index[name]] = dome
    glass = [(name, [index[name]], ports[index[name]]) for name in dome_names]
    by_window: dict = {}
    for item in interfaces:
        head, sep, k = item[0].rpartition("_interface_")
        if not sep or not k.isdigit() or any(n not in index for n in head.split("_")):
            raise ValueError(f"rectangle {item[0]!r} names no camera (a window's interfaces are "
                             f"<cameras>_interface_<k>)")
        by_window.setdefault(head, []).append(item)
    for head, items in by_window.items():
        views = [index[n] for n in head.split("_")]
        port = port_from_interfaces(items, cameras[views[0]].center, f"the {head} window")
        matrices = [item[5] for item in sorted(items, key=lambda item: port.normal @ item[2])]
        glass.append((head, views, window_from_rectangles(port, head, matrices)))
        for view in views:
            if ports[view] is not None:
                raise ValueError(f"{names[view]} is behind two pieces of glass")
            ports[view] = port
    glass.sort(key=lambda entry: entry[1][0])
    return MixedPorts(ports), glass


__all__ = ["MIXED_KINDS", "MixedPorts", "check_mixed", "check_mixed_targets", "fit_window",
           "glass_of_rig", "groups", "is_mixed", "mixed_shapes", "mixed_xml", "read_mixed"]
