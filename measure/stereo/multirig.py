"""A rig of N cameras, each looking through its own port or a share of one flat port.

Conventions (docs/architecture.md): millimetres; reference frame = the first camera's (OpenCV
axes); each camera's pose ``X_ref = R · X_cam + t``. A :class:`MultiRig` holds ``N ≥ 2``
cameras and, per camera, the port it looks through: a :class:`measure.FlatPort` (the same
value for several cameras is one port they share), a :class:`measure.geometry.dome.DomePort`,
or ``None`` (no port, in air: an index-matched stand-in along that camera's optical axis,
:func:`measure.geometry.port.index_matched_port`, through which every trace is the pinhole one).

What uses the rig asks the port interface, never the kind: :meth:`MultiRig.views` gives the
:class:`measure.stereo.multiview.View` of every camera (:func:`triangulate_views`),
:meth:`MultiRig.pair` a :class:`measure.stereo.triangulate.StereoRig` of two of its cameras
(the pairwise matching of :mod:`measure.stereo.multimatch`): a shared flat port stays that
port (the two-camera rig of today), other ports become a :class:`ViewPorts` (each camera its
own port, any mix).

Checked on construction (``ValueError``, one line naming the camera): two cameras at the same
centre, a camera not on the air side of its own port, a camera inside another camera's port
glass (between its interfaces), names that repeat.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera, ValueEquality
from ..geometry.port import RigPort, index_matched_port
from .multiview import View
from .triangulate import StereoRig

#: Two camera centres nearer than this (mm) are one place: the cameras overlap.
OVERLAP_MM = 1e-6


def default_names(n: int) -> tuple[str, ...]:
    """``cam0``, ``cam1``, …: the cameras of a rig of ``n`` (two: ``left``, ``right``)."""
    return ("left", "right") if n == 2 else tuple(f"cam{k}" for k in range(n))


def _on_air_side(port, center) -> bool:
    try:
        port.check_camera(center)
    except ValueError:
        return False
    return True


def in_glass(port, center) -> bool:
    """Whether a point lies inside ``port``'s glass: neither on its air side (where its camera
    sits) nor in the water beyond it. Any kind of view port (``check_camera``,
    ``water_side``)."""
    center = np.asarray(center, dtype=float)
    return not _on_air_side(port, center) and not bool(port.water_side(center[None])[0])


@dataclass(frozen=True, eq=False)
class ViewPorts(RigPort, ValueEquality):
    """The ports of two cameras that do not share one: each camera's own view port (a
    :class:`measure.FlatPort`, a :class:`measure.geometry.dome.DomePort`, any mix) — the port
    of a :meth:`MultiRig.pair` rig. Depths are measured along the first camera's optical
    axis."""

    left: object
    right: object

    kind = "ports per view"
    description = "a port per camera"
    name = "the cameras' ports"
    glass_name = "the cameras' ports"
    axis_name = "the first camera's optical axis"
    rig_name = "a pair of cameras of a rig of N"
    rig_detail = "each camera behind its own port"

    def view(self, view: int):
        return (self.left, self.right)[view]

    @property
    def refracts(self) -> bool:
        return any(len(set(p.indices)) > 1 for p in (self.left, self.right))

    def check_cameras(self, left, right) -> None:
        self.left.check_camera(left.center, "first camera")
        self.right.check_camera(right.center, "second camera")

    def depth_axis(self, left) -> np.ndarray:
        return left.R[:, 2].copy()

    @property
    def reference_axis(self) -> np.ndarray:
        return np.array([0.0, 0.0, 1.0])

    def water_side(self, points: np.ndarray) -> np.ndarray:
        return self.left.water_side(points) & self.right.water_side(points)

    def glass_depth(self, left) -> float:
        """The farther of the two ports' glass along :meth:`depth_axis` from the first camera's
        centre (mm)."""
        axis = self.depth_axis(left)
        return max(port.glass_reach(left.center, axis) for port in (self.left, self.right))


@dataclass(frozen=True, eq=False)
class MultiRig(ValueEquality):
    """``cameras`` (``N ≥ 2`` :class:`measure.Camera`), ``ports`` (per camera: a FlatPort —
    equal values are one shared port —, a DomePort, or None for a camera in air) and ``names``
    (default :func:`default_names`). See the module docs for what is checked."""

    cameras: tuple
    ports: tuple
    names: tuple

    def __init__(self, cameras, ports, names=None):
        cameras = tuple(cameras)
        if len(cameras) < 2:
            raise ValueError(f"a rig needs at least two cameras, got {len(cameras)}")
        names = default_names(len(cameras)) if names is None else tuple(str(n) for n in names)
        if len(names) != len(cameras):
            raise ValueError(f"{len(names)} names for {len(cameras)} cameras")
        if len(set(names)) != len(names):
            repeated = next(n for n in names if names.count(n) > 1)
            raise ValueError(f"camera name {repeated!r} is given twice")
        for name, camera in zip(names, cameras):
            if not isinstance(camera, Camera):
                raise ValueError(f"{name}: not a measure.Camera")
        if isinstance(ports, (list, tuple)):
            ports = tuple(ports)
        else:
            raise ValueError(f"ports: one value where {len(cameras)} are needed (one per camera: "
                             f"{', '.join(names)})")
        if len(ports) != len(cameras):
            why = (f"no port for {names[len(ports)]}" if len(ports) < len(cameras)
                   else f"{len(ports) - len(cameras)} more than the cameras")
            raise ValueError(f"ports: {len(ports)} for {len(cameras)} cameras ({why})")
        object.__setattr__(self, "cameras", cameras)
        object.__setattr__(self, "ports", ports)
        object.__setattr__(self, "names", names)
        self.check()

    def check(self) -> None:
        """ValueError (one line naming the camera) for cameras that overlap, a camera off the
        air side of its own port, or inside another camera's port glass."""
        centres = np.array([c.center for c in self.cameras])
        for i in range(len(centres)):
            near = np.linalg.norm(centres[i + 1:] - centres[i], axis=1) < OVERLAP_MM
            if near.any():
                j = i + 1 + int(np.flatnonzero(near)[0])
                raise ValueError(f"cameras {self.names[i]} and {self.names[j]} overlap (the same "
                                 f"centre, ({', '.join(f'{v:.6g}' for v in centres[i])}) mm)")
        for k, name in enumerate(self.names):
            try:
                self.view_port(k).check_camera(centres[k], name)
            except ValueError as exc:
                raise ValueError(str(exc)) from None
        for k, name in enumerate(self.names):
            for j, other in enumerate(self.names):
                port = self.ports[j]
                if j == k or port is None or port == self.ports[k]:
                    continue
                if in_glass(port, centres[k]):
                    raise ValueError(f"{name} centre lies inside {other}'s port glass "
                                     f"(({', '.join(f'{v:.6g}' for v in centres[k])}) mm)")

    @classmethod
    def from_stereo(cls, rig: StereoRig, names=("left", "right")) -> MultiRig:
        """The two cameras of a stereo rig and the ports they look through."""
        return cls(rig.cameras, (rig.view_port(0), rig.view_port(1)), names)

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def refracts(self) -> bool:
        """Whether any camera's port bends a ray."""
        return any(p is not None and len(set(p.indices)) > 1 for p in self.ports)

    def view_port(self, k: int):
        """The port camera ``k`` looks through (an index-matched plane for a camera in air)."""
        port = self.ports[k]
        if port is None:
            camera = self.cameras[k]
            return index_matched_port(camera.R[:, 2], camera.center[None])
        return port

    def views(self) -> list[View]:
        """The :class:`measure.stereo.multiview.View` of every camera, in order."""
        return [View(camera, self.view_port(k)) for k, camera in enumerate(self.cameras)]

    def pair(self, i: int, j: int) -> StereoRig:
        """Cameras ``i`` and ``j`` as a :class:`StereoRig` (``i`` its left camera): behind the
        one flat port they share, or each behind its own (:class:`ViewPorts`)."""
        a, b = self.ports[i], self.ports[j]
        if a is not None and a == b and isinstance(a, RigPort):
            port = a
        elif a is None and b is None:
            port = None
        else:
            port = ViewPorts(self.view_port(i), self.view_port(j))
        return StereoRig(self.cameras[i], self.cameras[j], port)

    def stereo(self) -> StereoRig | None:
        """The rig as a two-camera :class:`StereoRig` of today's kinds (one flat port, a flat
        port per camera, a dome per camera, all air), or None when it is not one (more than
        two cameras, a mix of ports)."""
        if len(self.cameras) != 2:
            return None
        from ..geometry.dome import DomePair
        from ..geometry.flat_pair import FlatPair

        left, right = self.cameras
        a, b = self.ports
        if a is None and b is None:
            return StereoRig(left, right, None)
        if a is not None and a == b and isinstance(a, RigPort):
            return StereoRig(left, right, a)
        for pair in (FlatPair, DomePair):
            try:
                return StereoRig(left, right, pair(a, b))
            except ValueError:
                continue
        return None


__all__ = ["MultiRig", "OVERLAP_MM", "ViewPorts", "default_names", "in_glass"]
