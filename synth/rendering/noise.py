"""Noise models for the simulations: pixel noise and deviated refraction parameters.

* :func:`add_pixel_noise` — Gaussian noise on matched pixel coordinates, independent on u and v
  (Li et al. 2024, section 3.3.2: "Gaussian noise (variance 0.01 pixel)", i.e. variance
  0.01 px², σ = 0.1 px).
* :func:`deviate_port` — a flat port with one refraction parameter off by a relative amount
  (section 3.3.3: the water index off by 0.15 %).

Every random draw takes a seed or a ``numpy.random.Generator``: same seed, same bytes.
Units: pixels (OpenCV convention) and millimetres.
"""

from __future__ import annotations

import numpy as np

from measure import FlatPort
from measure.geometry.port import require_flat_port

#: Parameters :func:`deviate_port` knows. ``n_layer`` / ``thickness`` take ``layer`` (0 = the
#: layer next to the air); ``n_glass`` is ``n_layer`` of layer 0.
PORT_PARAMETERS = ("n_water", "n_air", "n_glass", "n_layer", "distance", "thickness")


def _generator(rng) -> np.random.Generator:
    if rng is None:
        raise ValueError("rng is required: pass a seed (int) or a numpy.random.Generator "
                         "(same seed, same bytes)")
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (bool, np.bool_)) or not isinstance(rng, (int, np.integer)):
        raise ValueError(f"rng must be an int seed or a numpy.random.Generator, got {rng!r}")
    return np.random.default_rng(int(rng))


def pixel_noise(shape, variance: float = 0.01, rng=None) -> np.ndarray:
    """Gaussian pixel offsets of the given shape (px), zero mean, ``variance`` in px².

    ``rng``: an int seed or a ``numpy.random.Generator`` (required).
    """
    variance = float(variance)
    if not np.isfinite(variance) or variance < 0:
        raise ValueError(f"variance must be finite and >= 0 (px²), got {variance}")
    generator = _generator(rng)
    return generator.normal(0.0, np.sqrt(variance), size=tuple(shape))


def add_pixel_noise(uv, variance: float = 0.01, rng=None) -> np.ndarray:
    """Pixels ``(N, 2)`` plus independent Gaussian noise on u and v.

    ``variance`` is in px² (the paper's "variance 0.01 pixel" is 0.01 px², σ = 0.1 px).
    ``rng`` is an int seed or a ``numpy.random.Generator`` (required; a Generator advances).
    Returns a new float64 array; the input is not modified. NaN pixels stay NaN.
    Equivalent to ``uv + pixel_noise(uv.shape, variance, rng)``.
    """
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim < 1 or uv.shape[-1] != 2:
        raise ValueError(f"uv must have shape (N, 2), got {uv.shape}")
    return uv + pixel_noise(uv.shape, variance, rng)


def deviate_port(port: FlatPort, parameter: str = "n_water", relative: float = 0.0015,
                 layer: int = 0) -> FlatPort:
    """A copy of ``port`` with one refraction parameter multiplied by ``1 + relative``.

    ``parameter``: ``"n_water"`` (default), ``"n_air"``, ``"n_glass"`` (index of layer 0),
    ``"n_layer"`` (index of layer ``layer``), ``"distance"`` (D, mm) or ``"thickness"``
    (thickness of layer ``layer``, mm). ``relative = 0.0015`` is the paper's 0.15 %; a negative
    value lowers the parameter. The result is validated by :class:`measure.FlatPort` (an index
    below 1 or a non-positive thickness raises ``ValueError``).
    """
    require_flat_port(port, "port must be a measure.FlatPort")
    relative = float(relative)
    if not np.isfinite(relative) or relative <= -1.0:
        raise ValueError(f"relative must be finite and > -1, got {relative}")
    factor = 1.0 + relative
    indices = list(port.indices)
    thicknesses = list(port.thicknesses)
    n_layers = len(thicknesses)
    if parameter in ("n_glass", "n_layer", "thickness"):
        if parameter == "n_glass":
            layer = 0
        if not 0 <= int(layer) < n_layers:
            raise ValueError(f"{parameter}: layer must be in 0 … {n_layers - 1} for a port with "
                             f"{n_layers} layer(s), got {layer}")
        layer = int(layer)
    if parameter == "n_water":
        indices[-1] *= factor
        return port.replace(indices=tuple(indices))
    if parameter == "n_air":
        indices[0] *= factor
        return port.replace(indices=tuple(indices))
    if parameter in ("n_glass", "n_layer"):
        indices[1 + layer] *= factor
        return port.replace(indices=tuple(indices))
    if parameter == "distance":
        return port.replace(distance=port.distance * factor)
    if parameter == "thickness":
        thicknesses[layer] *= factor
        return port.replace(thicknesses=tuple(thicknesses))
    raise ValueError(f"parameter must be one of {', '.join(PORT_PARAMETERS)}, got {parameter!r}")
