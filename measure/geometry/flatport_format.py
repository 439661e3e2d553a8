"""The flat port and the dome port in the form of the refractive COLMAP fork and calibmar:
``FLATPORT`` and ``DOMEPORT``.

Their parameter list, per camera: ``Nx, Ny, Nz, int_dist, int_thick, na, ng, nw`` — the unit
normal of the interface in *that camera's* frame (pointing away from the camera into the water;
(0, 0, 1) is along the optical axis), the distance from the camera centre to the first (inner,
air–glass) interface and the glass thickness, in **metres** (their examples and navigation
data are metric), and the indices of air, glass and water. One glass layer only.

This project keeps one port in the reference frame (the left camera's, mm) for both cameras, so
the right camera's ``FLATPORT`` has its own normal ``R_rightᵀ·N`` and distance
``D − N·t_right``. :func:`to_flatport` and :func:`from_flatport` convert one camera's view; the
round trip is exact to floating point (tests).

``DOMEPORT`` (the fork's ``src/colmap/sensor/models_refrac.h``, the comment above ``struct
DomePort`` and ``DomePort::InitializeRefracParamsInfo``): ``Cx, Cy, Cz, int_radius, int_thick,
na, ng, nw`` — the dome centre in *that camera's* frame (the offset from the camera centre to
the dome centre), the inner radius and the glass thickness, in metres, and the indices of air,
glass and water. This project keeps each dome in the reference frame (mm):
:func:`to_domeport` gives ``R_cameraᵀ·(M − t_camera)`` in metres, :func:`from_domeport` the
inverse.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera
from .dome import DomePort
from .port import FlatPort

FLATPORT_NAMES = ("Nx", "Ny", "Nz", "int_dist", "int_thick", "na", "ng", "nw")
DOMEPORT_NAMES = ("Cx", "Cy", "Cz", "int_radius", "int_thick", "na", "ng", "nw")
#: Metres per millimetre: FLATPORT distances are in metres, this project's in millimetres.
METRES_PER_MM = 1e-3


def to_flatport(port: FlatPort, camera: Camera) -> list[float]:
    """``FLATPORT`` parameters of ``port`` as seen by ``camera`` (module docs)."""
    if len(port.thicknesses) != 1:
        raise ValueError(f"FLATPORT describes one glass layer; this port has "
                         f"{len(port.thicknesses)} layers")
    normal_cam = camera.R.T @ port.normal
    distance = port.distance - float(port.normal @ camera.t)
    na, ng, nw = port.indices
    return [*(float(v) for v in normal_cam), distance * METRES_PER_MM,
            port.thicknesses[0] * METRES_PER_MM, float(na), float(ng), float(nw)]


def from_flatport(params, camera: Camera) -> FlatPort:
    """The port (reference frame, mm) whose ``FLATPORT`` for ``camera`` is ``params``."""
    values = np.asarray(params, dtype=np.float64).ravel()
    if values.size != len(FLATPORT_NAMES) or not np.all(np.isfinite(values)):
        raise ValueError(f"FLATPORT needs {len(FLATPORT_NAMES)} finite numbers "
                         f"({', '.join(FLATPORT_NAMES)}), got {values.tolist()}")
    normal_cam = values[:3]
    length = np.linalg.norm(normal_cam)
    if abs(length - 1.0) > 1e-6:
        raise ValueError(f"FLATPORT normal (Nx, Ny, Nz) must be a unit vector, got length "
                         f"{length:.9g}")
    normal = camera.R @ (normal_cam / length)
    distance = values[3] / METRES_PER_MM + float(normal @ camera.t)
    return FlatPort(normal, distance, (values[4] / METRES_PER_MM,), tuple(values[5:8]))


def to_domeport(dome: DomePort, camera: Camera) -> list[float]:
    """``DOMEPORT`` parameters of ``dome`` for ``camera`` (module docs): the dome centre in the
    camera's frame, the inner radius and the thickness (metres), the indices."""
    center_cam = camera.R.T @ (dome.center - camera.t)
    na, ng, nw = dome.indices
    return [*(float(v) * METRES_PER_MM for v in center_cam), dome.radius * METRES_PER_MM,
            dome.thickness * METRES_PER_MM, float(na), float(ng), float(nw)]


def from_domeport(params, camera: Camera) -> DomePort:
    """The dome (reference frame, mm) whose ``DOMEPORT`` for ``camera`` is ``params``;
    ``ValueError`` for a wrong count, a non-finite number, a radius or thickness <= 0 or
    indices < 1 (:class:`~measure.geometry.dome.DomePort`)."""
    values = np.asarray(params, dtype=np.float64).ravel()
    if values.size != len(DOMEPORT_NAMES) or not np.all(np.isfinite(values)):
        raise ValueError(f"DOMEPORT needs {len(DOMEPORT_NAMES)} finite numbers "
                         f"({', '.join(DOMEPORT_NAMES)}), got {values.tolist()}")
    center = camera.R @ (values[:3] / METRES_PER_MM) + camera.t
    return DomePort(center, values[3] / METRES_PER_MM, values[4] / METRES_PER_MM,
                    tuple(values[5:8]))


def flatport_text(port: FlatPort, cameras: dict) -> str:
    """Lines ``<name> FLATPORT Nx Ny Nz int_dist int_thick na ng nw`` for ``{name: camera}``."""
    lines = ["# camera FLATPORT " + " ".join(FLATPORT_NAMES)
             + "  (normal in the camera's frame; distances in metres)"]
    for name, camera in cameras.items():
        lines.append(f"{name} FLATPORT " + " ".join(repr(v) for v in to_flatport(port, camera)))
    return "\n".join(lines) + "\n"


def parse_flatport_text(text: str) -> dict:
    """``{name: [8 numbers]}`` from :func:`flatport_text` (comments and blank lines skipped)."""
    out = {}
    for number, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 2 + len(FLATPORT_NAMES) or parts[1] != "FLATPORT":
            raise ValueError(f"line {number}: expected '<camera> FLATPORT' and "
                             f"{len(FLATPORT_NAMES)} numbers")
        try:
            out[parts[0]] = [float(v) for v in parts[2:]]
        except ValueError:
            raise ValueError(f"line {number}: not numbers: {' '.join(parts[2:])}") from None
    return out


__all__ = ["DOMEPORT_NAMES", "FLATPORT_NAMES", "METRES_PER_MM", "flatport_text", "from_domeport",
           "from_flatport", "parse_flatport_text", "to_domeport", "to_flatport"]
