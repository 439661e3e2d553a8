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


def as_vector(value, name: str) -> tuple[float, ...]:
    """A sequence of numbers as a tuple of floats; one-line ValueError naming ``name``."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a sequence of numbers, got {value!r}") from None
    if array.ndim > 1:
        raise ValueError(f"{name} must be a flat sequence of numbers, got shape {array.shape}")
    return tuple(float(v) for v in np.atleast_1d(array))


@dataclass(frozen=True, eq=False)
class FlatPort(ValueEquality):
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


def index_matched_port(normal, camera_centres) -> FlatPort:
    """A port that bends nothing (no layers, indices (1, 1)): the plane with unit ``normal``
    1 mm beyond the farther of ``camera_centres`` ``(K, 3)``. Through it every trace and
    projection reduces to the pinhole one — what ``port=None`` (no port, all air) means."""
    normal = np.asarray(normal, dtype=np.float64)
    normal = normal / np.linalg.norm(normal)
    centres = np.asarray(camera_centres, dtype=np.float64).reshape(-1, 3)
    return FlatPort(normal + 0.0, float(np.max(centres @ normal)) + 1.0, (), (1.0, 1.0))
