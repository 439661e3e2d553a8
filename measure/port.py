"""Flat refractive port: parallel plane interfaces between the cameras' air and the water.

Conventions (see DESIGN.md): millimetres, reference frame = left camera frame. ``normal`` is a
unit vector pointing from the cameras into the water. The first interface is the plane
``normal · X = distance``; interface k (k = 0 … K-1) is the plane
``normal · X = distance + sum(thicknesses[:k])``. ``indices`` run from the camera side,
``(n_air, n_layer…, n_water)``: one more than the number of interfaces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FlatPort:
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
        normal = np.asarray(normal, dtype=np.float64).reshape(-1)
        if normal.shape != (3,) or not np.all(np.isfinite(normal)):
            raise ValueError(f"normal must be a finite 3-vector, got {normal!r}")
        length = np.linalg.norm(normal)
        if length < 1e-12:
            raise ValueError("normal must not be the zero vector")
        distance = float(distance)
        if not np.isfinite(distance):
            raise ValueError(f"distance must be finite, got {distance}")
        thicknesses = tuple(float(d) for d in np.atleast_1d(np.asarray(thicknesses, dtype=float)))
        if any(not np.isfinite(d) or d <= 0 for d in thicknesses):
            raise ValueError(f"thicknesses must be positive and finite, got {thicknesses}")
        indices = tuple(float(n) for n in np.atleast_1d(np.asarray(indices, dtype=float)))
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

    def replace(self, **changes) -> "FlatPort":
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
