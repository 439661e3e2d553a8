"""The rig: ``N ≥ 1`` named cameras, each looking through its own port — a share of one flat
port, its own flat port, a dome, or none (in air) — in any mix. A pair is a rig of two.

Conventions (docs/architecture.md): millimetres; reference frame = the first camera's (OpenCV
axes); each camera's pose ``X_ref = R · X_cam + t``. A :class:`Rig` holds ``cameras``, per
camera the port it looks through (``ports``: a :class:`measure.FlatPort` — the same value for
several cameras is one port they share —, a :class:`measure.geometry.dome.DomePort`, or
``None``: no port, in air, an index-matched stand-in along that camera's optical axis,
:func:`measure.geometry.port.index_matched_port`, through which every trace is the pinhole
one), and ``names``.

Two ways to build one:

* ``Rig(cameras, ports, names)``: N cameras and their ports. Checked (``ValueError``, one line
  naming the camera): two cameras at the same centre, a camera not on the air side of its own
  port, a camera inside another camera's port glass (between its interfaces), names that
  repeat.
* :func:`StereoRig` ``(left, right, port)`` (:meth:`Rig.stereo_pair`): a pair behind one
  :class:`measure.geometry.port.RigPort` — one shared :class:`measure.FlatPort` (``None``: the
  index-matched one, all air), a :class:`measure.geometry.dome.DomePair`, a
  :class:`measure.geometry.flat_pair.FlatPair` (two housings) or a :class:`ViewPorts` (each
  camera its own port, any mix). Checked by the port (``check_cameras``: both cameras on its
  air side). Its ``ports`` are the port's views (``port.view(k)``).

A rig of two also holds ``port``, the pair's :class:`measure.geometry.port.RigPort` (what
reports describe: its ``kind``, ``describe()``…): the one it was built with, or, built from
ports, the port of :meth:`Rig.pair` ``(0, 1)``; with it come the pair's conveniences ``left``,
``right``, :attr:`Rig.depth_axis` and :meth:`Rig.with_port` (``AttributeError`` for a rig of
any other size, whose ``port`` is None).

What uses the rig asks the port interface, never the kind: :meth:`Rig.views` gives the
:class:`measure.stereo.multiview.View` of every camera (:func:`triangulate_views`),
:meth:`Rig.pair` the pair of two of its cameras (the pairwise matching of
:mod:`measure.stereo.multimatch`): a shared flat port stays that port, other ports become a
:class:`ViewPorts`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera, ValueEquality
from ..geometry.port import RigPort, index_matched_port
from .multiview import View

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
    of a :meth:`Rig.pair` rig. Depths are measured along the first camera's optical
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


def _air_port(left: Camera, right: Camera):
    """A pair's "no port" (all air): :func:`index_matched_port` along the left camera's
    optical axis, 1 mm beyond the farther centre."""
    return index_matched_port(left.R[:, 2], np.stack([left.center, right.center]))


def _checked_names(names, n: int) -> tuple:
    """``names`` as a tuple of strings (None: :func:`default_names`); ValueError for a count
    other than ``n`` or a name given twice."""
    names = default_names(n) if names is None else tuple(str(name) for name in names)
    if len(names) != n:
        raise ValueError(f"{len(names)} names for {n} cameras")
    if len(set(names)) != len(names):
        repeated = next(name for name in names if names.count(name) > 1)
        raise ValueError(f"camera name {repeated!r} is given twice")
    return names


@dataclass(frozen=True, eq=False)
class Rig(ValueEquality):
    """``cameras`` (``N ≥ 1`` :class:`measure.Camera`), ``ports`` (per camera: a FlatPort —
    equal values are one shared port —, a DomePort, or None for a camera in air), ``names``
    (default :func:`default_names`) and, for a pair, ``port`` (the pair's
    :class:`measure.geometry.port.RigPort`; None for any other number of cameras). Built from
    cameras and ports (``Rig(cameras, ports, names)``) or as a pair behind one RigPort
    (:func:`StereoRig`, :meth:`stereo_pair`). See the module docs for what is checked."""

    cameras: tuple
    ports: tuple
    names: tuple
    port: RigPort | None

    def __init__(self, cameras, ports, names=None):
        cameras = tuple(cameras)
        if not cameras:
            raise ValueError("a rig needs at least one camera, got 0")
        names = _checked_names(names, len(cameras))
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
        self._hold(cameras, ports, names, None)
        self.check()
        if len(cameras) == 2:
            port = self._pair_port(0, 1)
            object.__setattr__(self, "port", _air_port(*cameras) if port is None else port)

    def _hold(self, cameras, ports, names, port) -> None:
        object.__setattr__(self, "cameras", cameras)
        object.__setattr__(self, "ports", ports)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "port", port)

    @classmethod
    def stereo_pair(cls, left: Camera, right: Camera, port: RigPort | None = None,
                    names=None) -> Rig:
        """The pair of ``left`` and ``right`` behind ``port`` (a RigPort; None: no port, all
        air — the :func:`index_matched_port` along the left camera's optical axis, 1 mm beyond
        the farther centre). Both centres must be on the air side of the port (inside their
        domes). The rig keeps ``port`` itself; its ``ports`` are ``port.view(0)``,
        ``port.view(1)``."""
        if not isinstance(left, Camera) or not isinstance(right, Camera):
            raise ValueError("left and right must be measure.Camera instances")
        if port is None:
            port = _air_port(left, right)
        if not isinstance(port, RigPort):
            raise ValueError("port must be a measure.FlatPort, a measure.geometry.dome.DomePair or None")
        port.check_cameras(left, right)
        rig = object.__new__(cls)
        rig._hold((left, right), (port.view(0), port.view(1)), _checked_names(names, 2), port)
        return rig

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
    def from_stereo(cls, rig: Rig, names=("left", "right")) -> Rig:
        """The two cameras of a pair and the ports they look through, as a rig built from
        ports (its ``port`` that of :meth:`pair`, e.g. a :class:`ViewPorts` for a DomePair)."""
        return cls(rig.cameras, (rig.view_port(0), rig.view_port(1)), names)

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def refracts(self) -> bool:
        """Whether any camera's port bends a ray."""
        return any(p is not None and len(set(p.indices)) > 1 for p in self.ports)

    def view_port(self, k: int):
        """The port camera ``k`` looks through (an index-matched plane for a camera in air):
        a FlatPort (shared or its own) or a DomePort."""
        port = self.ports[k]
        if port is None:
            camera = self.cameras[k]
            return index_matched_port(camera.R[:, 2], camera.center[None])
        return port

    def views(self) -> list[View]:
        """The :class:`measure.stereo.multiview.View` of every camera, in order."""
        return [View(camera, self.view_port(k)) for k, camera in enumerate(self.cameras)]

    def trace(self, view: int, directions: np.ndarray, keep_interface_points: bool = False):
        """Water rays (:class:`measure.WaterRays`) of unit camera rays ``directions``
        ``(N, 3)`` (reference frame) from camera ``view``'s centre through its port:
        :func:`measure.trace_through_port` or :func:`measure.geometry.dome.trace_through_dome`."""
        return self.view_port(view).trace(self.cameras[view].center, directions,
                                          keep_interface_points=keep_interface_points)

    def _pair_port(self, i: int, j: int):
        """The RigPort of cameras ``i`` and ``j``: the one flat port they share, None (both in
        air: the pair's index-matched port), or each camera's own (:class:`ViewPorts`)."""
        a, b = self.ports[i], self.ports[j]
        if a is not None and a == b and isinstance(a, RigPort):
            return a
        if a is None and b is None:
            return None
        return ViewPorts(self.view_port(i), self.view_port(j))

    def pair(self, i: int, j: int) -> Rig:
        """Cameras ``i`` and ``j`` as a pair (:meth:`stereo_pair`, ``i`` its left camera):
        behind the one flat port they share, or each behind its own (:class:`ViewPorts`)."""
        return Rig.stereo_pair(self.cameras[i], self.cameras[j], self._pair_port(i, j))

    def _two(self, what: str) -> None:
        if len(self.cameras) != 2:
            raise AttributeError(f"{what}: only a rig of two cameras has it, this one has "
                                 f"{len(self.cameras)} ({', '.join(self.names)})")

    @property
    def left(self) -> Camera:
        """The first camera of a pair."""
        self._two("left")
        return self.cameras[0]

    @property
    def right(self) -> Camera:
        """The second camera of a pair."""
        self._two("right")
        return self.cameras[1]

    @property
    def depth_axis(self) -> np.ndarray:
        """The unit axis along which a pair's depths are measured (reference frame): the port
        normal of a flat port, the left camera's optical axis for domes (no shared normal)."""
        self._two("depth_axis")
        return self.port.depth_axis(self.left)

    def with_port(self, port: RigPort) -> Rig:
        """The same pair (cameras, names) behind another port (e.g. a deviated water index)."""
        self._two("with_port")
        return Rig.stereo_pair(self.left, self.right, port, self.names)

    def stereo(self) -> Rig | None:
        """The rig as a pair behind one of today's kinds of RigPort (one flat port, a flat
        port per camera, a dome per camera, all air), or None when it is not one (other than
        two cameras, a mix of ports)."""
        if len(self.cameras) != 2:
            return None
        from ..geometry.dome import DomePair
        from ..geometry.flat_pair import FlatPair

        left, right = self.cameras
        port = self._pair_port(0, 1)
        if not isinstance(port, ViewPorts):  # one shared flat port, or all air
            return Rig.stereo_pair(left, right, port)
        for pair in (FlatPair, DomePair):
            try:
                return Rig.stereo_pair(left, right, pair(*self.ports))
            except ValueError:
                continue
        return None


def StereoRig(left: Camera, right: Camera, port: RigPort | None = None) -> Rig:
    """A pair: :meth:`Rig.stereo_pair` — ``left`` and ``right`` behind ``port`` (a FlatPort
    both share, a DomePair, a FlatPair, a :class:`ViewPorts`; None: no port, all air). Not a
    class of its own: the rig of two cameras, named ``left`` and ``right``."""
    return Rig.stereo_pair(left, right, port)


__all__ = ["OVERLAP_MM", "Rig", "StereoRig", "ViewPorts", "default_names", "in_glass"]
