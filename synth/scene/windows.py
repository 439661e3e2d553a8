"""A port per camera in scene files: each camera behind its own flat port, a finite glass window.

Units mm, reference frame = the left camera's (OpenCV axes). The measurement models each port
as infinite planes (:class:`measure.geometry.flat_pair.FlatPair`); a scene must make that true
for every ray it renders: each camera's rays, over its whole image, cross its own window and
nothing of another's. So each window is finite — per interface one Mitsuba ``rectangle``
with a ``dielectric`` BSDF (ids ``left_interface_<k>``, ``right_interface_<k>`` — in a rig of
N > 2 cameras ``cam0_interface_<k>``, ``cam1_interface_<k>``, … —, camera side first; the
rectangle's normal, local +z, turned towards the cameras like the shared port's), all of one
window the same size, aligned with its camera's image axes and covering the
footprint of the camera's image on every interface with :data:`WINDOW_MARGIN_MM` to spare
(:func:`fit_windows`). :func:`check_windows` refuses a rig where two windows overlap, where a
camera's rays leave its window, or where they pass through another camera's window — in the
air before their own port, or in the water after it (the usual cause: the ports too far from
the cameras for their baseline, so two fields of view already overlap at the glass).

A rig here is anything with ``cameras`` and ``view_port(k)``: a :class:`measure.Rig` of two
with a :class:`measure.geometry.flat_pair.FlatPair` (cameras ``left``, ``right``) or a
:class:`measure.stereo.rig.Rig` whose cameras each have their own flat port (named
by its ``names``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from measure import FlatPort, StereoRig
from measure.geometry.flat_pair import VIEWS, FlatPair
from synth.scene.rig import tilted_port_normal

#: ``WINDOW_ID.format(camera="left", k=0)``: the shape id of interface k of a camera's window.
WINDOW_ID = "{camera}_interface_{k}"
#: How far (mm) a window reaches beyond the footprint of its camera's image on each interface.
WINDOW_MARGIN_MM = 2.0
#: Smallest gap (mm) between a camera's rays, or a window, and the other window.
CLEARANCE_MM = 1.0
#: Spacing (px) of the image border's pixels whose rays fit the windows and of the grid of
#: pixels checked (plus the border).
BORDER_STEP_PX, GRID_STEP_PX = 2, 16
#: Defaults of ``synth scene --port per-camera``: each port's distance from its camera (mm,
#: along its normal) and glass thickness. With the paper's cameras (200 mm baseline, ±48°
#: across) the two fields of view meet about 80 mm in front of the cameras, so the ports sit
#: nearer than that (:func:`check_windows`).
DEFAULT_PAIR_DISTANCE_MM = 40.0
DEFAULT_PAIR_THICKNESS_MM = 5.0


@dataclass(frozen=True)
class Window:
    """The glass of one camera's port as a finite slab: the rectangle of its first interface,
    centred at ``centre`` (mm, reference frame) with unit in-plane axes ``axes`` ``(2, 3)`` and
    half sides ``half`` ``(2,)`` mm; every further interface of ``port`` holds the same
    rectangle moved along the normal."""

    port: FlatPort
    centre: np.ndarray
    axes: np.ndarray
    half: np.ndarray

    def centres(self) -> np.ndarray:
        """The rectangle centre of every interface, camera side first ``(K, 3)``."""
        steps = self.port.offsets - self.port.offsets[0]
        return self.centre + steps[:, None] * self.port.normal

    def box(self):
        """The slab as an oriented box: centre, axes ``(3, 3)`` (rows), half extents ``(3,)``."""
        depth = 0.5 * (self.port.offsets[-1] - self.port.offsets[0])
        return (self.centre + depth * self.port.normal,
                np.vstack([self.axes, self.port.normal]), np.r_[self.half, depth])


def flat_ports(cameras, distances, tilts, thicknesses, indices) -> list:
    """A flat port per camera: camera k's port has its unit normal tilted from that camera's
    optical axis by ``tilts[k]`` = (about x, about y) degrees (in the camera's frame,
    :func:`synth.scene.rig.tilted_port_normal`), its first interface ``distances[k]`` mm from
    the camera's centre along that normal, glass ``thicknesses[k]`` mm and ``indices``
    ``(n_air, n_glass, n_water)``; reference frame."""
    ports = []
    for camera, distance, tilt, thickness in zip(cameras, distances, tilts, thicknesses):
        normal = camera.R @ tilted_port_normal(*tilt)
        ports.append(FlatPort(normal, float(distance) + float(normal @ camera.center),
                              (float(thickness),), tuple(indices)))
    return ports


def flat_pair(cameras, distances, tilts, thicknesses, indices) -> FlatPair:
    """The two ports of a rig of two housings (:func:`flat_ports`). ValueError (from
    :class:`measure.Rig` of two) for a camera on the water side of its port or inside the
    other's glass."""
    pair = FlatPair(*flat_ports(cameras[:2], distances, tilts, thicknesses, indices))
    StereoRig(cameras[0], cameras[1], pair)
    return pair


def image_pixels(camera, border_step: int, grid_step: int | None) -> np.ndarray:
    """Pixels ``(N, 2)`` on the image's outer edges (OpenCV: ``[-0.5, W - 0.5]``) every
    ``border_step`` px and, with ``grid_step``, a grid inside."""
    w, h = camera.size
    us = np.r_[-0.5, np.arange(0, w, border_step), w - 0.5]
    vs = np.r_[-0.5, np.arange(0, h, border_step), h - 0.5]
    edges = [np.column_stack([us, np.full_like(us, v)]) for v in (-0.5, h - 0.5)]
    edges += [np.column_stack([np.full_like(vs, u), vs]) for u in (-0.5, w - 0.5)]
    if grid_step:
        u, v = np.meshgrid(np.arange(0, w, grid_step), np.arange(0, h, grid_step))
        edges.append(np.column_stack([u.ravel(), v.ravel()]))
    return np.concatenate(edges).astype(float)


def _trace(rig, view: int, uv):
    camera = rig.cameras[view]
    return rig.view_port(view).trace(camera.center, camera.rays(uv), keep_interface_points=True)


def window_axes(normal: np.ndarray, camera) -> np.ndarray:
    """In-plane unit axes ``(2, 3)`` of a window: the camera's x axis made ⟂ ``normal``, and
    ``normal × u`` (the camera's y, roughly)."""
    u = camera.R[:, 0] - normal * (normal @ camera.R[:, 0])
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(normal, u)])


def camera_names(rig) -> tuple:
    """The names of ``rig``'s cameras in messages and shape ids: a Rig's ``names``, or
    ``left``, ``right``."""
    return tuple(getattr(rig, "names", VIEWS))


def fit_windows(rig, margin: float = WINDOW_MARGIN_MM) -> tuple:
    """Each camera's window (one per camera, in order): the smallest rectangle (on its image
    axes) holding the footprint of the camera's image on every interface of its port, plus
    ``margin`` mm on each side. ValueError when a ray of the image does not reach the water."""
    windows = []
    for view, (name, camera) in enumerate(zip(camera_names(rig), rig.cameras)):
        port = rig.view_port(view)
        uv = image_pixels(camera, BORDER_STEP_PX, None)
        water = _trace(rig, view, uv)
        _refuse_lost(water, uv, name)
        axes = window_axes(port.normal, camera)
        foot = port.normal * port.offsets[0]
        coords = (water.interface_points - foot) @ axes.T  # (K, N, 2)
        low, high = coords.reshape(-1, 2).min(axis=0), coords.reshape(-1, 2).max(axis=0)
        windows.append(Window(port, foot + 0.5 * (low + high) @ axes, axes,
                              0.5 * (high - low) + margin))
    return tuple(windows)


def _refuse_lost(water, uv, name: str) -> None:
    lost = ~np.all(np.isfinite(water.directions), axis=1)
    if lost.any():
        u, v = uv[np.flatnonzero(lost)[0]]
        raise ValueError(f"the {name} camera's field of view does not reach the water through "
                         f"its port (the ray of pixel ({u:g}, {v:g}))")


def boxes_overlap(a, b, clearance: float) -> bool:
    """Whether two oriented boxes (:meth:`Window.box`) come nearer than ``clearance``
    (separating-axis test: the 3 + 3 face axes and their 9 cross products)."""
    (ca, A, ha), (cb, B, hb) = a, b
    axes = [*A, *B] + [np.cross(x, y) for x in A for y in B]
    for axis in axes:
        length = np.linalg.norm(axis)
        if length < 1e-9:
            continue
        axis = axis / length
        reach = np.abs(A @ axis) @ ha + np.abs(B @ axis) @ hb
        if abs((cb - ca) @ axis) > reach + clearance:
            return False
    return True


def window_hits(origins, directions, window: Window, longest, clearance: float) -> np.ndarray:
    """Whether rays ``origins + s·directions`` (``0 < s < longest``) cross any interface
    rectangle of ``window`` grown by ``clearance``."""
    normal = window.port.normal
    hit = np.zeros(origins.shape[0], dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        for centre in window.centres():
            s = ((centre - origins) @ normal) / (directions @ normal)
            points = origins + s[:, None] * directions
            inside = np.all(np.abs((points - centre) @ window.axes.T) <= window.half + clearance,
                            axis=1)
            hit |= (s > 0) & (s < longest) & inside
    return hit


def check_windows(rig, windows) -> None:
    """Raise ``ValueError`` (one line naming the cameras and the overlap) unless every two
    windows (one per camera of ``rig``, in order) keep :data:`CLEARANCE_MM` apart and every ray
    of each camera's image (its border every :data:`BORDER_STEP_PX` px and a grid every
    :data:`GRID_STEP_PX`) crosses each interface of its own window inside its rectangle and
    misses every other window — from the camera to its port and from its port into the
    water."""
    names = camera_names(rig)
    for i in range(len(windows)):
        for j in range(i + 1, len(windows)):
            if boxes_overlap(windows[i].box(), windows[j].box(), CLEARANCE_MM):
                raise ValueError(f"the {names[i]} and {names[j]} windows overlap (their glass "
                                 f"comes nearer than {CLEARANCE_MM:g} mm): move the ports nearer "
                                 f"the cameras or the cameras apart")
    for view, camera in enumerate(rig.cameras):
        name, own = names[view], windows[view]
        uv = image_pixels(camera, BORDER_STEP_PX, GRID_STEP_PX)
        water = _trace(rig, view, uv)
        _refuse_lost(water, uv, name)
        points = water.interface_points  # (K, N, 3)
        coords = np.abs((points - own.centres()[:, None, :]) @ own.axes.T)
        outside = np.any(coords > own.half, axis=(0, 2))
        if outside.any():
            u, v = uv[np.flatnonzero(outside)[0]]
            raise ValueError(f"the {name} camera's field of view does not fit through its "
                             f"window (the ray of pixel ({u:g}, {v:g}) passes beside it)")
        air = points[0] - camera.center
        length = np.linalg.norm(air, axis=1)
        for other_view, other in enumerate(windows):
            if other_view == view:
                continue
            crossing = (window_hits(np.broadcast_to(camera.center, air.shape), air / length[:, None],
                              other, length, CLEARANCE_MM)
                        | window_hits(water.origins, water.directions, other, np.inf, CLEARANCE_MM))
            if crossing.any():
                u, v = uv[np.flatnonzero(crossing)[0]]
                raise ValueError(f"the {name} camera's field of view passes through the "
                                 f"{names[other_view]} window (the ray of pixel ({u:g}, {v:g})): "
                                 f"the two windows overlap in its view; move the ports nearer "
                                 f"the cameras or the cameras apart")


def window_placements(windows, names=VIEWS):
    """Per interface of each window (camera ``names[k]``'s, in order), camera side first:
    ``(shape id, centre, lookat target, up, half sides (2,), ext_ior, int_ior)`` of its
    ``rectangle`` — local +z turned towards the cameras (``ext_ior`` the camera side's), local
    x and y along the window's axes."""
    for name, window in zip(names, windows):
        port = window.port
        n = port.indices
        for k, centre in enumerate(window.centres()):
            yield (WINDOW_ID.format(camera=name, k=k), centre, centre - port.normal,
                   window.axes[1], window.half, n[k], n[k + 1])


def window_xml(windows, names) -> list:
    """The XML of the rectangles of ``windows`` (camera ``names[k]``'s,
    :func:`window_placements`), one per interface; the last interface of each looks into
    ``$n_water``."""
    from synth.scene.xml_text import number_text, vector_text

    last = {f"{name}_interface_{w.port.n_interfaces - 1}" for name, w in zip(names, windows)}
    parts = []
    for sid, centre, target, up, half, ext_ior, int_ior in window_placements(windows, names):
        parts.append(f"""    <shape type="rectangle" id="{sid}">
        <transform name="to_world">
            <scale x="{number_text(half[0])}" y="{number_text(half[1])}"/>
            <lookat origin="{vector_text(centre)}" target="{vector_text(target)}" up="{vector_text(up)}"/>
        </transform>
        <bsdf type="dielectric">
            <float name="ext_ior" value="{number_text(ext_ior)}"/>
            <float name="int_ior" value="{'$n_water' if sid in last else number_text(int_ior)}"/>
        </bsdf>
    </shape>""")
    return parts


def window_from_rectangles(port: FlatPort, name: str, matrices) -> Window:
    """The window of ``port`` from its interfaces' ``to_world`` matrices (camera side first,
    as read from a scene): each rectangle's local x and y columns are its half sides. ValueError
    unless all of them are one rectangle moved along the normal."""
    matrices = [np.asarray(m, dtype=np.float64) for m in matrices]
    first = matrices[0]
    half = np.array([np.linalg.norm(first[:3, 0]), np.linalg.norm(first[:3, 1])])
    axes = np.stack([first[:3, 0] / half[0], first[:3, 1] / half[1]])
    window = Window(port, first[:3, 3] + 0.0, axes, half)
    for matrix, centre in zip(matrices, window.centres()):
        if (not np.allclose(np.abs(matrix[:3, :2] @ np.diag(1.0 / half)), np.abs(axes.T),
                            atol=1e-9)
                or not np.allclose(matrix[:3, 3], centre, atol=1e-6)):
            raise ValueError(f"the {name} window's interfaces are not one rectangle moved along "
                             f"its normal (same size, same place)")
    return window


__all__ = ["BORDER_STEP_PX", "CLEARANCE_MM", "boxes_overlap", "camera_names", "image_pixels",
           "window_axes", "window_hits", "window_xml", "DEFAULT_PAIR_DISTANCE_MM",
           "DEFAULT_PAIR_THICKNESS_MM", "GRID_STEP_PX", "WINDOW_ID", "WINDOW_MARGIN_MM", "Window",
           "check_windows", "fit_windows", "flat_pair", "flat_ports", "window_from_rectangles",
           "window_placements"]
