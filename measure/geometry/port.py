"""Flat refractive port: parallel plane interfaces between the cameras' air and the water.

Conventions (docs/architecture.md): millimetres, reference frame = left camera frame. ``normal`` is a
unit vector pointing from the cameras into the water. The first interface is the plane
``normal · X = distance``; interface k (k = 0 … K-1) is the plane
``normal · X = distance + sum(thicknesses[:k])``. ``indices`` run from the camera side,
``(n_air, n_layer…, n_water)``: one more than the number of interfaces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import ValueEquality
from .refraction import trace_through_port


def as_vector(value, name: str) -> tuple[float, ...]:
    """A sequence of numbers as a tuple of floats; one-line ValueError naming ``name``."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a sequence of numbers, got {value!r}") from None
    if array.ndim > 1:
        raise ValueError(f"{name} must be a flat sequence of numbers, got shape {array.shape}")
    return tuple(float(v) for v in np.atleast_1d(array))


class RigPort:
    """The port interface: what a stereo rig looks through, one implementation per kind of
    window — :class:`FlatPort` (one port both cameras share; the index-matched one of
    :func:`index_matched_port` is "no port", all air) and
    :class:`measure.geometry.dome.DomePair` (each camera inside its own dome) and
    :class:`measure.geometry.flat_pair.FlatPair` (each camera behind its own flat port: two
    housings). Code that uses a
    port calls these members and never asks which kind it holds; the port of one camera
    (:meth:`view`: a FlatPort, or a :class:`measure.geometry.dome.DomePort`) traces rays into
    the water (``trace``), is checked against a camera (``check_camera``), says which points are
    in the water (``water_side``) and is projected through by
    :func:`measure.geometry.projection.project`.

    A new kind of port implements these members (and ``trace`` and the projection of its view
    ports); docs/architecture.md lists the few places outside the port modules that still
    branch on the kind, and why."""

    #: The kind, as files and messages name it (``"flat"``, ``"dome"``, ``"flat pair"``).
    kind = ""
    #: The housing's model name in the refractive COLMAP fork's ``cameras.txt`` and calibmar.
    housing = ""
    #: What the rig looks through, in messages (``"a flat port"``, ``"domes"``; ``"the port"``,
    #: ``"the domes"``).
    description = ""
    name = ""
    #: A calibration of this kind, in messages.
    calibration_name = ""
    #: Whether :func:`measure.calibration.selfcal.self_calibrate` estimates this port's
    #: parameters from matched targets.
    self_calibrates = False
    #: Where the glass ends, in messages, and the axis depths are measured along.
    glass_name = ""
    axis_name = ""
    #: Whether both cameras' water rays leave one plane (one port both look through): then the
    #: optical-path triangulation has a fused closed form over pixel rows
    #: (:func:`measure.stereo.triangulate.triangulate`); otherwise each view is traced.
    one_water_plane = False

    def view(self, view: int):
        """The port camera ``view`` (0 left, 1 right) looks through."""
        raise NotImplementedError

    @property
    def refracts(self) -> bool:
        """Whether the port bends any ray (False: "no port", every index the same — a pinhole
        calibration in air, or one that absorbs the port)."""
        raise NotImplementedError

    def check_cameras(self, left, right) -> None:
        """Raise ``ValueError`` unless both cameras' centres are on the air side."""
        raise NotImplementedError

    def apparent_depths(self, depths) -> tuple | None:
        """Where points at ``depths`` (mm along :meth:`depth_axis`) appear to a pinhole that
        ignores the port, where a closed form gives it (one flat port: paraxially); None where
        it must be traced through the rig (each camera's own port)."""
        return None

    def depth_axis(self, left) -> np.ndarray:
        """The unit axis along which depths are measured (reference frame), given the left
        camera."""
        raise NotImplementedError

    @property
    def reference_axis(self) -> np.ndarray:
        """The depth axis without a camera: the port normal, or the reference frame's z (the
        left camera's optical axis by convention)."""
        raise NotImplementedError

    def glass_depth(self, left) -> float:
        """How far the glass reaches along :meth:`depth_axis` from the left camera's centre (mm)."""
        raise NotImplementedError

    def describe(self) -> dict:
        """The port as plain numbers (a report's JSON)."""
        raise NotImplementedError

    def difference(self, other, differs, diff) -> None:
        """``other`` − this port (a port of the same kind) as named entries into ``diff``,
        those where ``differs(a, b)``."""
        raise NotImplementedError

    #: The port's quantities a measurement may be told to assume (``eval run --assume``, in
    #: this order), and the rig in messages.
    assumable: tuple = ()
    rig_name = ""
    rig_detail = ""

    def check_assumption(self, name: str) -> None:
        """ValueError (``"name: why"``) for an assumable quantity this port does not have."""

    def assumed(self, values: dict) -> RigPort:
        """This port with the quantities ``values`` ``{name: value}`` (of :attr:`assumable`)
        set, in order; ValueError for a port they make invalid."""
        raise NotImplementedError

    def check_parameter_names(self, names) -> None:
        """ValueError for a :mod:`measure.stereo.rig_covariance` name of another kind of
        port."""
        raise NotImplementedError

    def moved(self, changes, normal_axes=None) -> RigPort:
        """This port with its named parameters moved: ``changes`` ``[(name, delta), …]`` in
        their units (:func:`measure.stereo.uncertainty.perturbed_rig`)."""
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class FlatPort(RigPort, ValueEquality):
    """A flat port of ``len(thicknesses)`` layers between air and water.

    Parameters
    ----------
    normal : 3-vector, pointing into the water (normalized here; zero is an error).
    distance : D, mm, from the reference origin to the first (air-side) interface along ``normal``.
    thicknesses : layer thicknesses in mm between consecutive interfaces: ``(5.0,)`` for the
        paper's glass window, ``()`` for a bare air-water interface.
    indices : refractive indices from the camera side, ``(n_air, n_layer…, n_water)``.
    """

    normal: np.ndarray
    distance: float
    thicknesses: tuple[float, ...]
    indices: tuple[float, ...]

    def __init__(self, normal, distance, thicknesses, indices):
        normal = np.asarray(as_vector(normal, "normal"))
        if normal.shape != (3,) or not np.all(np.isfinite(normal)):
            raise ValueError(f"normal must be a finite 3-vector, got {normal.tolist()}")
        length = np.linalg.norm(normal)
        if length < 1e-12:
            raise ValueError("normal must not be the zero vector")
        try:
            distance = float(distance)
        except (TypeError, ValueError):
            raise ValueError(f"distance must be a number, got {distance!r}") from None
        if not np.isfinite(distance):
            raise ValueError(f"distance must be finite, got {distance}")
        thicknesses = as_vector(thicknesses, "thicknesses") if np.size(thicknesses) else ()
        if any(not np.isfinite(d) or d <= 0 for d in thicknesses):
            raise ValueError(f"thicknesses must be positive and finite, got {thicknesses}")
        indices = as_vector(indices, "indices")
        if len(indices) != len(thicknesses) + 2:
            raise ValueError(
                f"indices must hold len(thicknesses) + 2 = {len(thicknesses) + 2} values "
                f"(n_air, n_layer…, n_water), got {len(indices)}")
        if any(not np.isfinite(n) or n < 1.0 for n in indices):
            raise ValueError(f"indices must be finite and >= 1, got {indices}")
        object.__setattr__(self, "normal", normal / length)
        object.__setattr__(self, "distance", distance)
        object.__setattr__(self, "thicknesses", thicknesses)
        object.__setattr__(self, "indices", indices)

    @property
    def n_interfaces(self) -> int:
        """Number of plane interfaces (layers + 1)."""
        return len(self.thicknesses) + 1

    @property
    def offsets(self) -> np.ndarray:
        """``normal · X`` of every interface, camera side first (mm), shape ``(K,)``."""
        return self.distance + np.concatenate([[0.0], np.cumsum(self.thicknesses)])

    @property
    def n_water(self) -> float:
        """Refractive index of the last medium (the water)."""
        return self.indices[-1]

    def apparent_depth(self, depth_mm: float) -> float:
        """Where a point at ``depth_mm`` along the normal appears from the air side, paraxially
        (a pinhole that ignores the port sees it there; a lens in air focused there images it
        sharply): ``D + Σ t_i·n_air/n_i + (depth − last interface)·n_air/n_water`` (mm)."""
        n = self.indices
        layers = sum(t * n[0] / n[k + 1] for k, t in enumerate(self.thicknesses))
        return float(self.distance + layers + (depth_mm - self.offsets[-1]) * n[0] / n[-1])

    def replace(self, **changes) -> FlatPort:
        """A copy with some parameters changed (e.g. ``indices=...``)."""
        values = dict(normal=self.normal, distance=self.distance,
                      thicknesses=self.thicknesses, indices=self.indices)
        values.update(changes)
        return FlatPort(**values)

    def check_camera(self, center, name: str = "camera") -> None:
        """Raise ``ValueError`` if a camera centre is not on the air side of the first interface."""
        height = float(np.dot(self.normal, np.asarray(center, dtype=float)))
        if height >= self.distance:
            raise ValueError(
                f"{name} centre lies on the water side of the port's first interface "
                f"(normal·centre = {height:.6g} mm >= distance = {self.distance:.6g} mm)")

    def water_side(self, points: np.ndarray) -> np.ndarray:
        """Whether points ``(N, 3)`` lie strictly beyond the last interface (in the water)."""
        return np.asarray(points, dtype=float) @ self.normal > self.offsets[-1]

    @property
    def refracts(self) -> bool:
        return len(set(self.indices)) > 1

    def transmittance(self, camera, uv) -> np.ndarray | None:
        """``(N,)``: the fraction of light the port's interfaces pass along the rays of pixels
        ``uv`` ``(N, 2)`` of ``camera`` (this port's frame): the product over its interfaces of
        the unpolarized Fresnel transmittance ``1 − (R_s + R_p) / 2`` at each interface's
        incidence angle (Snell's law from the ray's angle to the normal; multiple reflections
        inside the glass left out). 0 beyond total internal reflection; None for a port that
        bends no ray (every index the same: nothing is reflected)."""
        if not self.refracts:
            return None
        d = camera.rays(np.asarray(uv, dtype=np.float64).reshape(-1, 2))
        cos_i = np.abs(d @ self.normal) / np.linalg.norm(d, axis=1)
        total = np.ones_like(cos_i)
        for n1, n2 in zip(self.indices[:-1], self.indices[1:]):
            sin_t = n1 / n2 * np.sqrt(np.maximum(0.0, 1.0 - cos_i ** 2))
            cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin_t ** 2))
            with np.errstate(invalid="ignore", divide="ignore"):
                rs = ((n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)) ** 2
                rp = ((n1 * cos_t - n2 * cos_i) / (n1 * cos_t + n2 * cos_i)) ** 2
            total = total * np.where(sin_t < 1.0, 1.0 - 0.5 * (rs + rp), 0.0)
            cos_i = cos_t
        return total

    # the port interface (RigPort) ---------------------------------------------------------
    kind = "flat"
    housing = "FLATPORT"
    description = "a flat port"
    name = "the port"
    calibration_name = "flat-port calibration"
    self_calibrates = True
    glass_name = "the port's last interface"
    axis_name = "the port normal"
    one_water_plane = True

    def apparent_depths(self, depths) -> tuple:
        """:meth:`apparent_depth` of each of ``depths``."""
        return tuple(self.apparent_depth(d) for d in depths)

    def view(self, view: int) -> FlatPort:
        """Both cameras look through this one port."""
        return self

    def check_cameras(self, left, right) -> None:
        self.check_camera(left.center, "left camera")
        self.check_camera(right.center, "right camera")

    def depth_axis(self, left) -> np.ndarray:
        """The port normal."""
        return self.normal

    @property
    def reference_axis(self) -> np.ndarray:
        return self.normal

    def glass_depth(self, left) -> float:
        """The port's last interface."""
        return self.offsets[-1] - float(self.normal @ left.center)

    def glass_reach(self, origin, axis) -> float:
        """How far the glass reaches along the unit ``axis`` from ``origin`` (mm): where the
        line meets the last interface."""
        return float((self.offsets[-1] - self.normal @ np.asarray(origin))
                     / (self.normal @ np.asarray(axis)))

    def describe(self) -> dict:
        return {"normal": self.normal.tolist(), "distance_mm": self.distance,
                "thicknesses_mm": list(self.thicknesses), "indices": list(self.indices)}

    def difference(self, other, differs, diff) -> None:
        truth, assumed = self, other
        if differs(assumed.distance, truth.distance):
            diff["port_distance_mm"] = assumed.distance - truth.distance
        if len(assumed.indices) == len(truth.indices):
            for k, (a, b) in enumerate(zip(assumed.indices, truth.indices)):
                if differs(a, b):
                    diff[f"index_{k}"] = a - b
        else:
            diff["indices"] = {"truth": list(truth.indices), "assumed": list(assumed.indices)}
        if len(assumed.thicknesses) == len(truth.thicknesses):
            for k, (a, b) in enumerate(zip(assumed.thicknesses, truth.thicknesses)):
                if differs(a, b):
                    diff[f"thickness_{k}_mm"] = a - b
        angle = float(np.degrees(np.arccos(np.clip(assumed.normal @ truth.normal, -1, 1))))
        if differs(assumed.normal, truth.normal):
            diff["port_normal_deg"] = angle

    assumable = ("n_water", "n_glass", "port_distance", "glass_thickness", "port_normal")
    rig_name = "a flat-port rig"
    rig_detail = "both cameras behind one port"

    def check_assumption(self, name: str) -> None:
        if name in ("n_glass", "glass_thickness") and not self.thicknesses:
            raise ValueError(f"{name}: the port has no glass layer")

    def assumed(self, values: dict) -> FlatPort:
        """``n_water`` (the last index), ``n_glass`` (the first layer's), ``glass_thickness``
        (the first layer's, mm), ``port_distance`` (mm), ``port_normal``."""
        indices, thicknesses = list(self.indices), list(self.thicknesses)
        normal, distance = self.normal, self.distance
        for name, v in values.items():
            if name == "n_water":
                indices[-1] = v
            elif name == "n_glass":
                indices[1] = v
            elif name == "glass_thickness":
                thicknesses[0] = v
            elif name == "port_distance":
                distance = v
            elif name == "port_normal":
                normal = v
        return FlatPort(normal, distance, tuple(thicknesses), tuple(indices))

    def check_parameter_names(self, names) -> None:
        domes = [n for n in names if ".dome_center" in n]
        if domes:
            raise ValueError(f"{', '.join(domes)}: dome parameters, but the rig has a flat port")
        own = [n for n in names if n.startswith(("left.port.", "right.port."))]
        if own:
            raise ValueError(f"{', '.join(own)}: parameters of a port per camera, but the rig has "
                             f"one flat port (port.…)")

    def moved(self, changes, normal_axes=None) -> FlatPort:
        """``port.distance``, ``port.tilt[k]`` (about ``normal_axes[k]``), ``port.thickness[k]``,
        ``port.index[k]``."""
        normal, distance = self.normal.copy(), self.distance
        thick = list(self.thicknesses)
        indices = list(self.indices)
        for name, d in changes:
            tail = name.partition(".")[2]
            if name == "port.distance":
                distance += d
            elif tail.startswith("tilt"):
                normal = normal + d * np.asarray(normal_axes, dtype=float)[int(tail[-2])]
            elif tail.startswith("thickness"):
                thick[int(tail[tail.index("[") + 1:-1])] += d
            elif tail.startswith("index"):
                indices[int(tail[tail.index("[") + 1:-1])] += d
        return FlatPort(normal / np.linalg.norm(normal), distance, tuple(thick), tuple(indices))

    def trace(self, origins: np.ndarray, directions: np.ndarray,
              keep_interface_points: bool = True):
        """:func:`measure.trace_through_port` through this port."""
        return trace_through_port(origins, directions, self,
                                  keep_interface_points=keep_interface_points)


def require_flat_port(port, message: str) -> FlatPort:
    """``port`` if it is a :class:`FlatPort`, else ``ValueError(message)``: the precondition of
    what is defined on a flat port only (a design port's deviations, a perturbed port). Not a
    branch: no other kind has another path there."""
    if not isinstance(port, FlatPort):
        raise ValueError(message)
    return port


def index_matched_port(normal, camera_centres) -> FlatPort:
    """A port that bends nothing (no layers, indices (1, 1)): the plane with unit ``normal``
    1 mm beyond the farther of ``camera_centres`` ``(K, 3)``. Through it every trace and
    projection reduces to the pinhole one — what ``port=None`` (no port, all air) means."""
    normal = np.asarray(normal, dtype=np.float64)
    normal = normal / np.linalg.norm(normal)
    centres = np.asarray(camera_centres, dtype=np.float64).reshape(-1, 3)
    return FlatPort(normal + 0.0, float(np.max(centres @ normal)) + 1.0, (), (1.0, 1.0))
