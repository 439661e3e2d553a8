"""The flat port and the dome port in the form of the refractive COLMAP fork and calibmar:
``FLATPORT`` and ``DOMEPORT``.

Their parameter list, per camera: ``Nx, Ny, Nz, int_dist, int_thick, na, ng, nw`` — the unit
normal of the interface in *that camera's* frame (pointing away from the camera into the water;
(0, 0, 1) is along the optical axis), the distance from the camera centre to the first (inner,
air–glass) interface and the glass thickness, in **metres** (their examples and navigation
data are metric), and the indices of air, glass and water. One glass layer only.

This project keeps a port in the reference frame (the left camera's, mm). One port shared by
both cameras (:class:`~measure.geometry.port.FlatPort`) gives the right camera's ``FLATPORT``
its own normal ``R_rightᵀ·N`` and distance ``D − N·t_right``; a rig of two housings
(:class:`~measure.geometry.flat_pair.FlatPair`) writes each camera's own port the same way.
:func:`to_flatport` and :func:`from_flatport` convert one camera's view; the round trip is
exact to floating point (tests).

``DOMEPORT`` (the fork's ``src/colmap/sensor/models_refrac.h``, the comment above ``struct
DomePort`` and ``DomePort::InitializeRefracParamsInfo``): ``Cx, Cy, Cz, int_radius, int_thick,
na, ng, nw`` — the dome centre in *that camera's* frame (the offset from the camera centre to
the dome centre), the inner radius and the glass thickness, in metres, and the indices of air,
glass and water. This project keeps each dome in the reference frame (mm):
:func:`to_domeport` gives ``R_cameraᵀ·(M − t_camera)`` in metres, :func:`from_domeport` the
inverse.
"""

from __future__ import annotations

import cv2
import numpy as np

from .camera import Camera
from .dome import DomePair, DomePort
from .flat_pair import VIEWS, FlatPair
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


def view_port_params(port, camera: Camera):
    """``(housing, parameters)`` of the port one camera looks through: ``("FLATPORT",
    to_flatport)`` for a :class:`FlatPort` that bends rays, ``("DOMEPORT", to_domeport)`` for a
    :class:`DomePort`, ``(None, None)`` for none (a camera in air)."""
    if port is None or not port_refracts(port):
        return None, None
    if isinstance(port, DomePort):
        return "DOMEPORT", to_domeport(port, camera)
    return "FLATPORT", to_flatport(port, camera)


def view_port_from_params(housing: str | None, params, camera: Camera):
    """The inverse of :func:`view_port_params` (reference frame, mm): a FlatPort, a DomePort
    or None."""
    if housing is None:
        return None
    return (from_domeport if housing == "DOMEPORT" else from_flatport)(params, camera)


def port_refracts(port) -> bool:
    """Whether one camera's port (FlatPort or DomePort) bends any ray."""
    return len(set(port.indices)) > 1


def flatport_text(port: FlatPort | FlatPair, cameras: dict) -> str:
    """Lines ``<name> FLATPORT Nx Ny Nz int_dist int_thick na ng nw`` for ``{name: camera}``
    (a :class:`~measure.geometry.flat_pair.FlatPair`: ``left`` and ``right``, each its own
    port)."""
    lines = ["# camera FLATPORT " + " ".join(FLATPORT_NAMES)
             + "  (normal in the camera's frame; distances in metres)"]
    for name, camera in cameras.items():
        if isinstance(port, FlatPair) and name not in VIEWS:
            raise ValueError(f"camera {name!r}: a port per camera names them {', '.join(VIEWS)}")
        own = port.view(VIEWS.index(name)) if isinstance(port, FlatPair) else port
        lines.append(f"{name} FLATPORT " + " ".join(repr(v) for v in to_flatport(own, camera)))
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


def one_port_per_plane(ports) -> list:
    """``ports`` with the flat ports that describe one plane — the same glass seen from several
    cameras, each FLATPORT line in its own camera's frame, equal but for round-off (1e-12 in
    the normal, 1e-9 mm) — made the one port they share (the first of them)."""
    out = list(ports)
    for k, port in enumerate(out):
        if not isinstance(port, FlatPort):
            continue
        for earlier in out[:k]:
            if (isinstance(earlier, FlatPort) and earlier.indices == port.indices
                    and np.allclose(earlier.normal, port.normal, rtol=0, atol=1e-12)
                    and abs(earlier.distance - port.distance) <= 1e-9
                    and np.allclose(earlier.thicknesses, port.thicknesses, rtol=0, atol=1e-9)):
                out[k] = earlier
                break
    return out


__all__ = ["DOMEPORT_NAMES", "FLATPORT_NAMES", "METRES_PER_MM", "flatport_text", "from_domeport",
           "one_port_per_plane",
           "from_flatport", "parse_flatport_text", "to_domeport", "to_flatport"]


def housing_params(port: FlatPort | FlatPair | DomePair, left: Camera, right: Camera,
                   error=ValueError) -> tuple[str, list, list]:
    """``(housing, left parameters, right parameters)`` of a rig's port: ``FLATPORT`` (one
    glass layer, else ``error``) or ``DOMEPORT``, each camera's own (metres): the port it looks
    through (:meth:`~measure.geometry.port.RigPort.view`)."""
    if isinstance(port, DomePair):
        return ("DOMEPORT", to_domeport(port.left, left), to_domeport(port.right, right))
    views = (port.view(0), port.view(1))
    for name, view in zip(VIEWS, views):
        if len(view.thicknesses) != 1:
            whose = "this" if view is port else f"the {name} camera's"
            raise error(f"FLATPORT holds one glass layer; {whose} port has "
                        f"{len(view.thicknesses)}")
    return "FLATPORT", to_flatport(views[0], left), to_flatport(views[1], right)


def _floats(matrix) -> list:
    return np.asarray(matrix, dtype=np.float64).tolist()


def cameras_json_port(port: FlatPort | DomePair, has_port: bool = True) -> dict:
    """The ``port`` entry of a dataset's ``cameras.json`` (:func:`synth.formats.exchange.cameras_json`):
    the flat port's interfaces, or each camera's dome."""
    if isinstance(port, FlatPair):
        return {"present": True,
                "model": "a flat port per camera (two housings): each port's interfaces N · X = "
                         "distance + cumulative thicknesses, in the reference frame; indices "
                         "from the camera side (air, glass…, water)",
                "ports": {name: _flat_entry(view) for name, view in
                          (("left", port.left), ("right", port.right))}}
    if isinstance(port, DomePair):
        port_entry = {"present": True,
                      "model": "dome port: each camera inside its own spherical glass shell "
                               "(inner radius, thickness; centre in the reference frame); "
                               "indices from the camera side (air, glass, water)",
                      "domes": {name: {"center": _floats(dome.center), "radius": dome.radius,
                                       "thickness": dome.thickness,
                                       "indices": [float(v) for v in dome.indices]}
                                for name, dome in (("left", port.left), ("right", port.right))}}
    else:
        port_entry = {
            "present": bool(has_port),
            "model": "flat port: interfaces N · X = distance + cumulative thicknesses, in the "
                     "reference frame; indices from the camera side (air, glass…, water)",
            "normal": _floats(port.normal), "distance": float(port.distance),
            "thicknesses": [float(v) for v in port.thicknesses],
            "indices": [float(v) for v in port.indices],
            "note": None if has_port else "an all-air scene: the port is index-matched "
                                          "(all indices 1) and bends no ray"}
    return port_entry


def cameras_json_view_port(port) -> dict:
    """The ``port`` entry of one camera in a ``cameras.json`` of N cameras: its own flat port's
    interfaces (reference frame), its dome, or ``{"present": False}`` for a camera in air."""
    if port is None or not port_refracts(port):
        return {"present": False}
    if isinstance(port, DomePort):
        return {"present": True, "model": "dome", "center": _floats(port.center),
                "radius": port.radius, "thickness": port.thickness,
                "indices": [float(v) for v in port.indices]}
    return {"present": True, "model": "flat", **_flat_entry(port)}


def _flat_entry(port: FlatPort) -> dict:
    return {"normal": _floats(port.normal), "distance": float(port.distance),
            "thicknesses": [float(v) for v in port.thicknesses],
            "indices": [float(v) for v in port.indices]}


def _write_flat_node(fs, name: str, port: FlatPort, present=None) -> None:
    fs.startWriteStruct(name, cv2.FileNode_MAP)
    if present is not None:
        fs.write("present", int(present))
    fs.write("normal", port.normal.reshape(3, 1))
    fs.write("distance", float(port.distance))
    for key, values in (("thicknesses", port.thicknesses), ("indices", port.indices)):
        fs.startWriteStruct(key, cv2.FileNode_SEQ)
        for v in values:
            fs.write("", float(v))
        fs.endWriteStruct()
    fs.endWriteStruct()


def write_calib_port(fs, port: FlatPort | FlatPair | DomePair, has_port: bool = True) -> None:
    """The port's node of a dataset's ``calib.yaml`` (:func:`synth.products.dataset.write_calib`)
    into the ``cv2.FileStorage`` ``fs``: ``port`` (present, normal, distance, thicknesses,
    indices), ``ports`` (two housings: ``left`` and ``right`` maps of normal, distance,
    thicknesses, indices, reference frame) or ``dome`` (per camera: center, radius, thickness,
    indices)."""
    if isinstance(port, FlatPair):
        fs.startWriteStruct("ports", cv2.FileNode_MAP)
        _write_flat_node(fs, "left", port.left)
        _write_flat_node(fs, "right", port.right)
        fs.endWriteStruct()
    elif isinstance(port, DomePair):
        fs.startWriteStruct("dome", cv2.FileNode_MAP)
        for name, dome in (("left", port.left), ("right", port.right)):
            fs.startWriteStruct(name, cv2.FileNode_MAP)
            fs.write("center", dome.center.reshape(3, 1))
            fs.write("radius", float(dome.radius))
            fs.write("thickness", float(dome.thickness))
            fs.startWriteStruct("indices", cv2.FileNode_SEQ)
            for v in dome.indices:
                fs.write("", float(v))
            fs.endWriteStruct()
            fs.endWriteStruct()
        fs.endWriteStruct()
    else:
        _write_flat_node(fs, "port", port, has_port)


def write_view_port(fs, port: FlatPort | DomePort) -> None:
    """One camera's port into its one-camera ``camera.yaml`` (``eval calibrate PHOTOS
    --intrinsics``): a flat port as :func:`write_calib_port`'s ``port`` node; a dome as a
    ``dome`` map of ``center`` (3x1, mm), ``radius``, ``thickness`` and ``indices``."""
    if not isinstance(port, DomePort):
        write_calib_port(fs, port)
        return
    fs.startWriteStruct("dome", cv2.FileNode_MAP)
    fs.write("center", port.center.reshape(3, 1))
    fs.write("radius", float(port.radius))
    fs.write("thickness", float(port.thickness))
    fs.startWriteStruct("indices", cv2.FileNode_SEQ)
    for v in port.indices:
        fs.write("", float(v))
    fs.endWriteStruct()
    fs.endWriteStruct()


def port_text_files(port, cameras: dict) -> dict:
    """``{file name: text}`` of the port beside a calibration: ``flatport.txt``
    (:func:`flatport_text`) for a flat port or a port per camera; nothing for domes, whose
    DOMEPORT lines live in
    the COLMAP ``cameras.txt`` (:func:`housing_params`)."""
    if isinstance(port, DomePair):
        return {}
    return {"flatport.txt": flatport_text(port, cameras)}
