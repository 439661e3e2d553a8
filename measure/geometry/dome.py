"""Dome port: a spherical glass shell between a camera's air and the water.

Conventions (docs/architecture.md): millimetres, reference frame = left camera frame. A dome is
the shell between two concentric spheres, centre ``center`` (reference frame), inner radius
``radius`` and thickness ``thickness``; ``indices`` run from the camera side,
``(n_air, n_glass, n_water)``. Each camera of a stereo rig sits inside its own dome
(:class:`DomePair`); a dome whose centre is the camera's centre of projection bends no ray
through that centre, a decentred one makes the camera non-central.

Tracing (:func:`trace_through_dome`) intersects each ray with the inner sphere, then the outer
one (the exit of a ray that starts inside: the far root), refracting with the vector form of
Snell's law (:func:`measure.geometry.refraction.refract`) about the outward sphere normal at each point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import ValueEquality
from .port import RigPort, as_vector
from ..reasons import Reason
from .refraction import WaterRays, refract


@dataclass(frozen=True, eq=False)
class DomePort(ValueEquality):
    """A spherical shell port.

    Parameters
    ----------
    center : 3-vector, mm, the spheres' common centre in the reference frame.
    radius : inner (air-side) radius, mm, > 0.
    thickness : glass thickness, mm, > 0 (outer radius = radius + thickness).
    indices : ``(n_air, n_glass, n_water)``, each finite and >= 1.
    """

    center: np.ndarray
    radius: float
    thickness: float
    indices: tuple[float, ...]

    #: The kind, as the scene writer's table of glass per camera names it (a FlatPort's is
    #: ``"flat"``; the DomePair of two domes is ``"dome"`` too).
    kind = "dome"

    def __init__(self, center, radius, thickness, indices):
        center = np.asarray(as_vector(center, "center"))
        if center.shape != (3,) or not np.all(np.isfinite(center)):
            raise ValueError(f"dome center must be a finite 3-vector, got {center.tolist()}")
        for name, value in (("radius", radius), ("thickness", thickness)):
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"dome {name} must be a number, got {value!r}") from None
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"dome {name} must be positive and finite, got {value}")
        indices = as_vector(indices, "indices")
        if len(indices) != 3:
            raise ValueError(f"dome indices must be (n_air, n_glass, n_water), got {indices}")
        if any(not np.isfinite(n) or n < 1.0 for n in indices):
            raise ValueError(f"dome indices must be finite and >= 1, got {indices}")
        object.__setattr__(self, "center", center + 0.0)
        object.__setattr__(self, "radius", float(radius))
        object.__setattr__(self, "thickness", float(thickness))
        object.__setattr__(self, "indices", indices)

    @property
    def radii(self) -> np.ndarray:
        """Inner and outer radius, mm, shape ``(2,)``."""
        return np.array([self.radius, self.radius + self.thickness])

    @property
    def n_interfaces(self) -> int:
        """Number of spherical interfaces (2: inner, outer)."""
        return 2

    def glass_reach(self, origin, axis) -> float:
        """How far the glass reaches along the unit ``axis`` from ``origin`` (mm): the outer
        sphere's farthest point along it."""
        return float(np.asarray(axis) @ (self.center - np.asarray(origin))) + float(self.radii[1])

    @property
    def n_water(self) -> float:
        """Refractive index of the last medium (the water)."""
        return self.indices[-1]

    def replace(self, **changes) -> DomePort:
        """A copy with some parameters changed (e.g. ``center=...``)."""
        values = dict(center=self.center, radius=self.radius, thickness=self.thickness,
                      indices=self.indices)
        values.update(changes)
        return DomePort(**values)

    def depth_axis(self, left) -> np.ndarray:
        """The axis depths are measured along when the rig's first camera ``left`` sits in
        this dome: that camera's optical axis (a dome has no normal; as :class:`DomePair`)."""
        return left.R[:, 2].copy()

    def difference(self, other, differs, diff, prefix: str = "") -> None:
        """``other`` − this dome as named entries into ``diff`` (``{prefix}dome_center_mm``,
        ``…_radius_mm``, ``…_thickness_mm``, ``…_index_k``), those where ``differs(a, b)``."""
        if differs(other.center, self.center):
            diff[f"{prefix}dome_center_mm"] = (other.center - self.center).tolist()
        if differs(other.radius, self.radius):
            diff[f"{prefix}dome_radius_mm"] = other.radius - self.radius
        if differs(other.thickness, self.thickness):
            diff[f"{prefix}dome_thickness_mm"] = other.thickness - self.thickness
        for k, (x, y) in enumerate(zip(other.indices, self.indices)):
            if differs(x, y):
                diff[f"{prefix}dome_index_{k}"] = x - y

    def transmittance(self, camera, uv) -> None:
        """Not modelled for a dome (None): its rays cross the glass near normal incidence when
        the camera sits near the centre, so the Fresnel gradient a flat port has is small."""
        return None

    def check_camera(self, center, name: str = "camera") -> None:
        """Raise ``ValueError`` unless a camera centre lies strictly inside the inner sphere."""
        distance = float(np.linalg.norm(np.asarray(center, dtype=float) - self.center))
        if distance >= self.radius:
            raise ValueError(f"{name} centre lies outside its dome (|centre − dome centre| = "
                             f"{distance:.6g} mm >= inner radius {self.radius:.6g} mm)")

    def water_side(self, points: np.ndarray) -> np.ndarray:
        """Whether points ``(N, 3)`` lie strictly outside the outer sphere (in the water)."""
        offsets = np.asarray(points, dtype=float) - self.center
        return np.einsum("ij,ij->i", offsets, offsets) > self.radii[1] ** 2

    def trace(self, origins: np.ndarray, directions: np.ndarray,
              keep_interface_points: bool = True) -> WaterRays:
        """:func:`trace_through_dome` through this dome."""
        return trace_through_dome(origins, directions, self,
                                  keep_interface_points=keep_interface_points)


@dataclass(frozen=True, eq=False)
class DomePair(RigPort, ValueEquality):
    """The two domes of a stereo rig: ``left`` around the left camera, ``right`` around the
    right one (reference frame)."""

    left: DomePort
    right: DomePort

    def __post_init__(self):
        if not isinstance(self.left, DomePort) or not isinstance(self.right, DomePort):
            raise ValueError("a DomePair holds two measure.geometry.dome.DomePort instances")

    def __getitem__(self, view: int) -> DomePort:
        """The dome of camera ``view`` (0 left, 1 right)."""
        return (self.left, self.right)[view]

    @property
    def n_water(self) -> float:
        """The water index (the left dome's; both see the same water)."""
        return self.left.n_water

    def water_side(self, points: np.ndarray) -> np.ndarray:
        """Whether points ``(N, 3)`` lie in the water: outside both domes' outer spheres."""
        return self.left.water_side(points) & self.right.water_side(points)

    # the port interface (RigPort) ---------------------------------------------------------
    kind = "dome"
    housing = "DOMEPORT"
    description = "domes"
    name = "the domes"
    calibration_name = "dome-port calibration (DOMEPORT)"
    glass_name = "both domes' outer spheres"
    axis_name = "the left camera's optical axis"

    def view(self, view: int) -> DomePort:
        """Each camera looks through its own dome."""
        return self[view]

    @property
    def refracts(self) -> bool:
        return any(len(set(d.indices)) > 1 for d in (self.left, self.right))

    def check_cameras(self, left, right) -> None:
        self.left.check_camera(left.center, "left camera")
        self.right.check_camera(right.center, "right camera")

    def depth_axis(self, left) -> np.ndarray:
        """The left camera's optical axis (two domes share no normal)."""
        return left.R[:, 2].copy()

    @property
    def reference_axis(self) -> np.ndarray:
        return np.array([0.0, 0.0, 1.0])

    def describe(self) -> dict:
        def dome(d: DomePort) -> dict:
            return {"center_mm": d.center.tolist(), "radius_mm": d.radius,
                    "thickness_mm": d.thickness, "indices": list(d.indices)}

        return {"kind": "dome", "left": dome(self.left), "right": dome(self.right)}

    def difference(self, other, differs, diff) -> None:
        for view in ("left", "right"):
            getattr(self, view).difference(getattr(other, view), differs, diff, f"{view}_")

    assumable = ("n_water", "n_glass")
    rig_name = "a dome rig"
    rig_detail = "each camera inside its own dome"

    def check_assumption(self, name: str) -> None:
        """Both assumable quantities apply to every rig of two domes."""

    def assumed(self, values: dict) -> DomePair:
        """``n_water``, ``n_glass``: the water's or the glass's index of both domes."""
        domes = [self.left, self.right]
        for name, v in values.items():
            k = 2 if name == "n_water" else 1
            domes = [d.replace(indices=tuple(v if i == k else n for i, n in enumerate(d.indices)))
                     for d in domes]
        return DomePair(*domes)

    def check_parameter_names(self, names) -> None:
        flat = [n for n in names if (n.startswith("port.") and not n.startswith("port.index"))
                or n.startswith(("left.port.", "right.port."))]
        if flat:
            raise ValueError(f"{', '.join(flat)}: flat-port parameters, but the rig looks "
                             f"through domes")

    def moved(self, changes, normal_axes=None) -> DomePair:
        """``left/right.dome_center[k]`` move that dome's centre (reference frame),
        ``port.index[k]`` medium k of both domes."""
        centers = [self.left.center.copy(), self.right.center.copy()]
        normal, distance, thick = None, None, []
        indices = list(self.left.indices)
        for name, d in changes:
            head, _, tail = name.partition(".")
            if tail.startswith("dome_center"):
                centers[0 if head == "left" else 1][int(tail[-2])] += d
            elif name == "port.distance":
                distance += d
            elif tail.startswith("tilt"):
                normal = normal + d * np.asarray(normal_axes, dtype=float)[int(tail[-2])]
            elif tail.startswith("thickness"):
                thick[int(tail[tail.index("[") + 1:-1])] += d
            elif tail.startswith("index"):
                indices[int(tail[tail.index("[") + 1:-1])] += d
        return DomePair(*(dome.replace(center=c, indices=tuple(indices))
                          for dome, c in zip((self.left, self.right), centers)))

    def glass_depth(self, left) -> float:
        """The farther of the two domes' outer spheres."""
        axis = self.depth_axis(left)
        return max(dome.glass_reach(left.center, axis) for dome in (self.left, self.right))


def _exit_parameter(origins, directions, center, radius):
    """Ray parameter ``h`` of the far intersection of rays starting inside a sphere (NaN where
    the ray starts outside or misses)."""
    offset = origins - center
    b = np.einsum("...j,...j->...", offset, directions)
    c = np.einsum("...j,...j->...", offset, offset) - radius * radius
    with np.errstate(invalid="ignore"):
        h = -b + np.sqrt(b * b - c)
    return np.where(c < 0, h, np.nan)


def trace_through_dome(origins: np.ndarray, directions: np.ndarray, dome: DomePort,
                       keep_interface_points: bool = True) -> WaterRays:
    """Trace rays from inside the dome through its two spheres into the water.

    ``origins`` ``(N, 3)`` or one 3-vector (a camera centre, inside the inner sphere);
    ``directions`` unit vectors ``(N, 3)``. At each sphere the ray leaves through the far root
    and refracts about the outward unit normal ``(I − centre) / r``. Rows whose origin is not
    inside the inner sphere are NaN with ``MISSES_PORT``; total internal reflection (possible at
    the outer sphere of a strongly decentred dome) with its own reason.
    """
    directions = np.asarray(directions, dtype=np.float64)
    n_rays = directions.shape[0]
    origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), directions.shape)
    reason = np.zeros(n_rays, dtype=np.int8)
    reason[~np.all(np.isfinite(directions), axis=1) | ~np.all(np.isfinite(origins), axis=1)] = \
        Reason.INVALID_INPUT
    points, position, heading = [], origins, directions
    n = dome.indices
    with np.errstate(invalid="ignore", divide="ignore"):
        for k, r in enumerate(dome.radii):
            h = _exit_parameter(position, heading, dome.center, r)
            reason[(reason == Reason.OK) & ~np.isfinite(h)] = Reason.MISSES_PORT
            position = position + h[:, None] * heading
            points.append(position)
            normals = (position - dome.center) / r
            heading, tir = refract(heading, normals, n[k], n[k + 1])
            reason[(reason == Reason.OK) & tir] = Reason.TOTAL_INTERNAL_REFLECTION
    interface_points = np.stack(points) if keep_interface_points else None
    bad = reason != Reason.OK
    if bad.any():
        position = position.copy()
        position[bad] = np.nan
        heading[bad] = np.nan
        if interface_points is not None:
            interface_points[:, bad] = np.nan
    return WaterRays(position, heading, interface_points, reason)


__all__ = ["DomePort", "DomePair", "trace_through_dome"]
