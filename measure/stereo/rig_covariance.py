"""The covariance of a stereo rig's parameters: what a calibration knows about its own error.

A :class:`RigCovariance` is a symmetric positive-definite matrix over *named* rig parameters.
The names (:data:`PARAMETER_NAMES` lists the grammar) are the one vocabulary shared by the
calibration that writes the matrix (``eval calibrate``, into ``calib.yaml``'s ``covariance``
node) and the measurement that propagates it into every point's covariance:

* ``left.fx left.fy left.cx left.cy left.k1 left.k2 left.p1 left.p2 left.k3`` and the same for
  ``right.`` — the intrinsics in OpenCV's convention (px; distortion coefficients unitless);
* ``right.rotation[0..2]`` — rad, a small rotation ``φ`` of the right camera,
  ``R → exp([φ]×) R`` about reference-frame axes (as :class:`measure.geometry.projection.ParameterJacobian`'s
  ``rotation``);
* ``right.center[0..2]`` — mm, the right camera's centre in the reference frame;
* ``port.distance`` — mm, D of the first interface;
* ``port.tilt[0]``, ``port.tilt[1]`` — rad, the normal tilted about :attr:`RigCovariance.normal_axes`
  (``n → normalize(n + a₀·e₀ + a₁·e₁)``, ``e₀``/``e₁`` the two rows, both ⟂ n);
* ``port.thickness[k]`` — mm, layer k; ``port.index[k]`` — the index of medium k, air first
  (a rig of two domes: medium k of both domes, ``(n_air, n_glass, n_water)``);
* ``left.dome_center[0..2]``, ``right.dome_center[0..2]`` — mm, a rig of two domes: that
  camera's dome centre in the **reference frame** (the other parameters held: a change of
  ``right.rotation`` / ``right.center`` moves the camera inside its dome, not the dome). The
  dome calibration estimates each camera's decentring in that camera's frame
  (``o = Rᵀ(M − C)``) and converts its covariance to these names
  (``M = C + R·o``: ``δM = δC − [R·o]× φ + R·δo``);
* ``left.port.distance``, ``left.port.tilt[0/1]``, ``left.port.thickness[k]``,
  ``left.port.index[k]`` and the same for ``right.`` — a rig of two housings
  (:class:`measure.geometry.flat_pair.FlatPair`): that camera's own port, as ``port.…`` above
  (the tilts about the same :attr:`RigCovariance.normal_axes`, which need not be ⟂ that port's
  normal: the normal moves by their components ⟂ it); ``port.index[k]`` is medium k of both.

The left camera is the reference frame: it has intrinsics but no pose parameters. A parameter
not named has no uncertainty (exact). Units: mm, px, rad.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

_INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
#: The grammar of a parameter name (module docs).
PARAMETER_NAMES = (
    tuple(f"{cam}.{p}" for cam in ("left", "right") for p in _INTRINSICS)
    + tuple(f"right.rotation[{k}]" for k in range(3))
    + tuple(f"right.center[{k}]" for k in range(3))
    + ("port.distance", "port.tilt[0]", "port.tilt[1]", "port.thickness[k]", "port.index[k]")
    + tuple(f"{cam}.dome_center[{k}]" for cam in ("left", "right") for k in range(3))
    + tuple(f"{cam}.port.{p}" for cam in ("left", "right")
            for p in ("distance", "tilt[0]", "tilt[1]", "thickness[k]", "index[k]")))
_NAME = re.compile(r"^(?:(?:left|right)\.(?:fx|fy|cx|cy|k1|k2|p1|p2|k3)"
                   r"|right\.(?:rotation|center)\[[012]\]"
                   r"|(?:(?:left|right)\.)?(?:port\.distance|port\.tilt\[[01]\]"
                   r"|port\.(?:thickness|index)\[\d+\])"
                   r"|(?:left|right)\.dome_center\[[012]\])$")
#: Smallest eigenvalue, relative to the largest, a covariance may have (below: singular).
RELATIVE_EIGENVALUE_LIMIT = 1e-15


class CovarianceError(ValueError):
    """A covariance that cannot be used: unknown names, wrong shape, not symmetric positive
    definite."""


#: The largest σ a rig parameter may have (px, mm, rad or unitless): a covariance that says more
#: is not a calibration's (a variance of 1e30 was reported as σ = 1e15 mm without comment).
MAX_SIGMA = 1e6


@dataclass(frozen=True, eq=False)
class RigCovariance:
    """``names`` ``(P,)`` (module docs), ``matrix`` ``(P, P)`` in those names' units, and
    ``normal_axes`` ``(2, 3)``: the tilt axes of ``port.tilt[0/1]`` (unit, ⟂ the port normal;
    required when a tilt is named)."""

    names: tuple
    matrix: np.ndarray
    normal_axes: np.ndarray | None = None

    def __init__(self, names, matrix, normal_axes=None):
        names = tuple(str(n) for n in names)
        bad = [n for n in names if not _NAME.match(n)]
        if bad:
            raise CovarianceError(f"unknown rig parameter name(s) {bad}; expected names like "
                                  f"{', '.join(PARAMETER_NAMES[:4])} … (measure.stereo.rig_covariance)")
        if len(set(names)) != len(names):
            raise CovarianceError(f"rig parameter names repeat: {names}")
        matrix = np.asarray(matrix, dtype=np.float64)
        if matrix.shape != (len(names), len(names)):
            raise CovarianceError(f"covariance of {len(names)} parameters must be "
                                  f"{len(names)}x{len(names)}, got shape {matrix.shape}")
        if not np.all(np.isfinite(matrix)):
            raise CovarianceError("covariance holds non-finite values")
        scale = np.sqrt(np.abs(np.diag(matrix)))
        if np.any(np.diag(matrix) <= 0):
            raise CovarianceError("covariance is not positive: a variance is zero or negative")
        huge = np.flatnonzero(scale > MAX_SIGMA)
        if huge.size:
            raise CovarianceError(f"the σ of {names[huge[0]]} is {scale[huge[0]]:.3g}: no "
                                  f"calibration is that uncertain (σ above {MAX_SIGMA:g} px, mm or "
                                  f"rad); is the matrix in this project's units (px, mm, rad)?")
        if not np.allclose(matrix, matrix.T, rtol=1e-9, atol=0.0):
            raise CovarianceError("covariance is not symmetric")
        matrix = 0.5 * (matrix + matrix.T)
        eig = np.linalg.eigvalsh(matrix / np.outer(scale, scale))
        if eig[0] <= RELATIVE_EIGENVALUE_LIMIT * eig[-1]:
            raise CovarianceError(f"covariance is singular or not positive definite (smallest "
                                  f"eigenvalue of the correlation matrix {eig[0]:.3g})")
        if normal_axes is not None:
            normal_axes = np.asarray(normal_axes, dtype=np.float64)
            if normal_axes.shape != (2, 3) or not np.all(np.isfinite(normal_axes)):
                raise CovarianceError(f"normal_axes must be 2x3, got {normal_axes.shape}")
        elif any("port.tilt" in n for n in names):
            raise CovarianceError("port.tilt[*] named without normal_axes")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "matrix", matrix)
        object.__setattr__(self, "normal_axes", normal_axes)

    @property
    def sigmas(self) -> dict:
        """``{name: σ}`` (the square roots of the diagonal)."""
        return dict(zip(self.names, np.sqrt(np.diag(self.matrix)).tolist()))

    def to_dict(self) -> dict:
        """Plain lists (what ``calib.yaml``'s ``covariance`` node and JSON hold)."""
        out = {"names": list(self.names), "matrix": self.matrix.tolist()}
        if self.normal_axes is not None:
            out["normal_axes"] = self.normal_axes.tolist()
        return out

    @classmethod
    def from_dict(cls, data: dict) -> RigCovariance:
        """The inverse of :meth:`to_dict`; :class:`CovarianceError` on anything malformed."""
        try:
            return cls(data["names"], data["matrix"], data.get("normal_axes"))
        except (KeyError, TypeError) as exc:
            raise CovarianceError(f"covariance node malformed ({exc})") from None
