"""The glass of a port whose cameras each have their own — a dome per camera (a
:class:`measure.geometry.dome.DomePair`, or a list of one :class:`measure.geometry.dome.DomePort`
per camera of N > 2), a flat window per camera (a :class:`measure.geometry.flat_pair.FlatPair`,
or a list of one :class:`measure.FlatPort` per camera of N > 2), a mix of them and cameras in
air (:mod:`synth.scene.mixed`) — and how a scene holds it
(:data:`PER_CAMERA_GLASS`): the check of a rig and its targets, the XML of its shapes
(:func:`synth.scene.write.scene_xml`) and its Mitsuba dictionary shapes
(:func:`synth.scene.write.port_shapes`). Units mm, the left camera's frame."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from measure import StereoRig
from synth.scene.dome import (check_field_of_view, check_targets, dome_placements,
                              facing_cameras, sphere_xml)
from synth.scene.mixed import (check_mixed, check_mixed_targets, glass_of_rig, is_mixed,
                               mixed_shapes, mixed_xml)
from synth.scene.windows import (camera_names, check_windows, fit_windows, window_placements,
                                 window_xml)


def glass_of(port):
    """How a scene holds ``port``'s glass (:data:`PER_CAMERA_GLASS`), or None for one shared
    flat port or none; a list of one port per camera is held as a mix when
    :func:`synth.scene.mixed.is_mixed`, as domes when every one is a DomePort, else as windows
    (flat ports)."""
    if port is None:
        return None
    if is_mixed(port):
        return PER_CAMERA_GLASS["mixed"]
    if isinstance(port, (list, tuple)):
        kinds = {getattr(p, "kind", None) for p in port}
        return PER_CAMERA_GLASS["dome" if kinds == {"dome"} else "flat pair"]
    return PER_CAMERA_GLASS.get(port.kind)


def glass_rig(cameras, port, names=None):
    """The rig whose cameras each have their own glass: a StereoRig of two cameras and their
    FlatPair or DomePair, or a Rig of N cameras and a list of their flat ports or
    domes."""
    from measure.stereo.rig import Rig

    if isinstance(port, (list, tuple)):
        return Rig(tuple(cameras), list(port), names)
    return StereoRig(cameras[0], cameras[1], port)



def _rig_port(rig):
    """What the dome functions take as a rig's domes: the list of its cameras' DomePorts (of a
    pair behind a DomePair: its two domes, named ``left`` and ``right`` as the DomePair's)."""
    return list(rig.ports)


def _dome_xml(rig) -> str:
    """The spheres of a dome scene (:func:`synth.scene.dome.dome_placements`)."""
    parts = ["\n    <!-- The domes: per camera two concentric spheres (normals outwards, "
             "ext_ior outside): air inside the inner one, glass between, water outside. -->"]
    for sid, centre, radius, ext_ior, int_ior in dome_placements(_rig_port(rig)):
        # the outer sphere's ext_ior is the water's: $n_water
        parts.append(sphere_xml(sid, centre, radius, ext_ior, int_ior, sid.endswith("outer")))
    return "\n".join(parts)


def _check_domes(rig, targets, target_radius, target_normals) -> None:
    check_field_of_view(rig)
    check_targets(_rig_port(rig), targets, target_radius)
    if not np.all(facing_cameras(rig.cameras, targets, target_normals)):
        raise ValueError("every target must face the cameras (its normal towards them)")


def _dome_shapes(mi, port, cameras, half_side_mm: float) -> dict:
    return {sid: {"type": "sphere", "center": [float(c) for c in centre],
                  "radius": float(radius),
                  "bsdf": {"type": "dielectric", "ext_ior": float(ext_ior),
                           "int_ior": float(int_ior)}}
            for sid, centre, radius, ext_ior, int_ior in dome_placements(port)}


def _window_xml(rig) -> str:
    """The windows of a scene of a port per camera (:mod:`synth.scene.windows`); the last
    interface of each looks into ``$n_water``."""
    names = camera_names(rig)
    ports = [rig.view_port(k) for k in range(len(rig.cameras))]
    waters = {p.n_water for p in ports}
    if len(waters) > 1:
        raise ValueError(f"the ports look into different water (n_water "
                         f"{', '.join(f'{p.n_water:g}' for p in ports)})")
    parts = [f"\n    <!-- {'Two housings' if len(ports) == 2 else f'{len(ports)} housings'}: each "
             f"camera behind its own flat port, a finite window (one rectangle per interface, "
             f"normal towards the cameras, ext_ior on their side). -->"]
    parts += window_xml(fit_windows(rig), names)
    return "\n".join(parts)


def _check_windows(rig, targets, target_radius, target_normals) -> None:
    check_windows(rig, fit_windows(rig))
    for k, name in enumerate(camera_names(rig)):
        port = rig.view_port(k)
        beyond = targets @ port.normal - port.offsets[-1]
        if np.any(beyond <= 0):
            raise ValueError(f"every target must lie in the water, beyond the {name} port's last "
                             f"interface")
        if np.any(beyond <= target_radius):
            raise ValueError(f"targets closer to the {name} port than their radius")
        if np.any(target_normals @ port.normal >= 0):
            raise ValueError(f"every target must face the cameras (its normal towards the {name} "
                             f"port)")


def _window_shapes(mi, port, cameras, half_side_mm: float) -> dict:
    if cameras is None:
        raise ValueError("the windows of a port per camera are sized to the cameras: pass "
                         "cameras")
    rig = glass_rig(cameras, port)
    windows = fit_windows(rig)
    shapes = {}
    for sid, centre, target, up, half, ext_ior, int_ior in window_placements(
            windows, camera_names(rig)):
        to_world = (mi.ScalarTransform4f().look_at(origin=centre.tolist(), target=target.tolist(),
                                                   up=up.tolist())
                    @ mi.ScalarTransform4f().scale([float(half[0]), float(half[1]), 1.0]))
        shapes[sid] = {"type": "rectangle", "to_world": to_world,
                       "bsdf": {"type": "dielectric", "ext_ior": float(ext_ior),
                                "int_ior": float(int_ior)}}
    return shapes


def _check_mixed(rig, targets, target_radius, target_normals) -> None:
    check_mixed(rig, glass_of_rig(rig))
    check_mixed_targets(rig, targets, target_radius, target_normals)


def _mixed_shapes(mi, port, cameras, half_side_mm: float) -> dict:
    if cameras is None:
        raise ValueError("the glass of mixed ports is sized to the cameras: pass cameras")
    return mixed_shapes(mi, glass_rig(cameras, port))


@dataclass(frozen=True)
class PerCameraGlass:
    """How a scene holds a port whose glass is per camera: its name in messages, the check of
    a rig and its targets, the XML of its shapes, its Mitsuba dictionary shapes."""

    name: str
    check: Callable
    xml: Callable
    shapes: Callable


#: The kinds of port (:attr:`measure.geometry.port.RigPort.kind`) whose cameras each have
#: their own glass, and how a scene holds them; the shared flat port is the rest of
#: :func:`synth.scene.write.scene_xml` and :func:`synth.scene.write.port_shapes`.
PER_CAMERA_GLASS = {
    "dome": PerCameraGlass("dome", _check_domes, _dome_xml, _dome_shapes),
    "flat pair": PerCameraGlass("two-housing", _check_windows, _window_xml, _window_shapes),
    "mixed": PerCameraGlass("mixed-port", _check_mixed, mixed_xml, _mixed_shapes),
}
