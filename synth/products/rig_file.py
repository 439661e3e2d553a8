"""``calib.yaml`` of a rig of N cameras (:class:`measure.stereo.rig.Rig`).

A rig of two cameras of today's kinds (one flat port, a flat port per camera, a dome per camera,
all air) is written as the two-camera ``calib.yaml`` of :func:`synth.formats.calib_yaml.write_calib`
— unchanged — and any two-camera file (or calibmar / COLMAP calibration that
:func:`synth.formats.calib_yaml.read_calib` reads) reads as a rig of two. Any other rig is an
OpenCV FileStorage of (units mm, reference frame = the first camera's, OpenCV axes):

* ``units``: ``mm``;
* ``cameras``: a sequence, one map per camera: ``name``, ``image_width``, ``image_height``,
  ``K`` (3x3), ``D`` (1x5 or 1x8 OpenCV distortion), ``R`` (3x3) and ``t`` (3x1 mm): the pose
  camera-to-reference, ``X_ref = R · X_cam + t`` (not OpenCV's stereo convention);
* ``port`` (when cameras share it): one flat port {``normal`` (3x1), ``distance``,
  ``thicknesses`` (sequence), ``indices`` (sequence)};
* ``ports``: a sequence with one entry per camera, in the order of ``cameras``: ``shared``
  (the ``port`` map), ``none`` (in air), or a map with ``kind``: ``flat`` (``normal``,
  ``distance``, ``thicknesses``, ``indices``: that camera's own flat port) or ``dome``
  (``center`` 3x1, ``radius``, ``thickness``, ``indices``). Without ``ports`` every camera
  looks through ``port``.

Anything unreadable or inconsistent raises :class:`synth.formats.calib_yaml.DatasetError` with
one line naming the file and the camera: cameras that overlap, a camera inside another
camera's port glass, ``ports`` given as one value where one per camera is needed.
"""

from __future__ import annotations

import os

import cv2
import numpy as np

from measure import Camera, FlatPort
from measure.geometry.dome import DomePort
from measure.stereo.rig import Rig
from synth.formats.calib_formats import (CalibFormatError, calib_format, colmap_cameras,
                                         read_colmap_rig)
from synth.formats.calib_yaml import DatasetError, not_a_file, read_calib, write_calib

#: The entries of ``ports`` that are not maps.
SHARED, NONE = "shared", "none"


def _seq(node) -> list[float]:
    if node.isSeq():
        return [node.at(i).real() for i in range(node.size())]
    mat = node.mat()
    return [] if mat is None else [float(v) for v in mat.ravel()]


def _write_seq(fs, name, values) -> None:
    fs.startWriteStruct(name, cv2.FileNode_SEQ)
    for v in values:
        fs.write("", float(v))
    fs.endWriteStruct()


def _write_flat(fs, name, port: FlatPort, kind: bool) -> None:
    fs.startWriteStruct(name, cv2.FileNode_MAP)
    if kind:
        fs.write("kind", "flat")
    fs.write("normal", port.normal.reshape(3, 1))
    fs.write("distance", float(port.distance))
    _write_seq(fs, "thicknesses", port.thicknesses)
    _write_seq(fs, "indices", port.indices)
    fs.endWriteStruct()


def _write_dome(fs, name, dome: DomePort) -> None:
    fs.startWriteStruct(name, cv2.FileNode_MAP)
    fs.write("kind", "dome")
    fs.write("center", dome.center.reshape(3, 1))
    fs.write("radius", float(dome.radius))
    fs.write("thickness", float(dome.thickness))
    _write_seq(fs, "indices", dome.indices)
    fs.endWriteStruct()


#: How each kind of camera port is written into ``ports`` (by the class's name: the file's
#: vocabulary, like the scene writer's table).
PORT_WRITERS = {"FlatPort": lambda fs, port: _write_flat(fs, "", port, True),
                "DomePort": lambda fs, port: _write_dome(fs, "", port)}


def shared_port(rig: Rig):
    """The port that two or more cameras share (the first such), or None."""
    for k, port in enumerate(rig.ports):
        if port is not None and any(port == other for other in rig.ports[k + 1:]):
            return port
    return None


def write_rig_file(path, rig: Rig, covariance=None) -> None:
    """Write ``calib.yaml`` (module docs): today's two-camera file for a rig that is one.
    ``covariance`` ``(names, matrix)`` (a rig of more than two cameras): the calibration's
    covariance of the named parameters (px, mm, rad), as the map ``uncertainty`` {``names``
    (sequence of strings), ``covariance`` (P x P)} that :func:`read_rig_covariance` reads."""
    stereo = rig.stereo()
    if stereo is not None:
        if covariance is not None:
            raise ValueError("a two-camera calib.yaml carries its covariance as "
                             "synth.formats.calib_yaml.write_calib writes it")
        write_calib(path, stereo, has_port=rig.refracts)
        return
    shared = shared_port(rig)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        fs.write("units", "mm")
        fs.startWriteStruct("cameras", cv2.FileNode_SEQ)
        for name, camera in zip(rig.names, rig.cameras):
            fs.startWriteStruct("", cv2.FileNode_MAP)
            fs.write("name", name)
            fs.write("image_width", int(camera.size[0]))
            fs.write("image_height", int(camera.size[1]))
            fs.write("K", camera.K)
            dist = np.zeros(5) if camera.dist is None else camera.dist
            fs.write("D", np.asarray(dist, dtype=np.float64).reshape(1, -1))
            fs.write("R", camera.R)
            fs.write("t", camera.t.reshape(3, 1))
            fs.endWriteStruct()
        fs.endWriteStruct()
        if shared is not None:
            _write_flat(fs, "port", shared, False)
        if shared is None or any(p != shared for p in rig.ports):
            fs.startWriteStruct("ports", cv2.FileNode_SEQ)
            for port in rig.ports:
                if port is None:
                    fs.write("", NONE)
                elif shared is not None and port == shared:
                    fs.write("", SHARED)
                else:
                    PORT_WRITERS[type(port).__name__](fs, port)
            fs.endWriteStruct()
        if covariance is not None:
            names, matrix = covariance
            fs.startWriteStruct("uncertainty", cv2.FileNode_MAP)
            fs.startWriteStruct("names", cv2.FileNode_SEQ)
            for name in names:
                fs.write("", str(name))
            fs.endWriteStruct()
            fs.write("covariance", np.asarray(matrix, dtype=np.float64))
            fs.endWriteStruct()
    finally:
        fs.release()


def read_rig_covariance(path):
    """``(names, matrix)`` of a ``calib.yaml`` of N cameras' ``uncertainty`` map
    (:func:`write_rig_file`), or None when it has none. :class:`DatasetError` for a map that
    does not hold one name per row of a square matrix."""
    fs = cv2.FileStorage(os.fspath(path), cv2.FILE_STORAGE_READ)
    try:
        node = fs.getNode("uncertainty")
        if node.empty():
            return None
        names_node = node.getNode("names")
        names = tuple(names_node.at(i).string() for i in range(names_node.size()))
        matrix = node.getNode("covariance").mat()
    finally:
        fs.release()
    if matrix is None or matrix.shape != (len(names), len(names)) or not names:
        raise DatasetError(f"{path}: uncertainty: expected one name per row of a square "
                           f"covariance, got {len(names)} names")
    return names, np.asarray(matrix, dtype=np.float64)


def _is_rig_file(path) -> bool:
    """Whether ``path`` is an OpenCV FileStorage with a ``cameras`` sequence."""
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):
        return False
    try:
        return fs.isOpened() and not fs.getNode("cameras").empty()
    finally:
        fs.release()


def _is_one_camera_file(path) -> bool:
    """Whether ``path`` is one camera's ``camera.yaml`` (a ``camera_matrix``, no ``K1``)."""
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):
        return False
    try:
        return (fs.isOpened() and not fs.getNode("camera_matrix").empty()
                and fs.getNode("K1").empty())
    finally:
        fs.release()


def read_rig_file(path) -> Rig:
    """A rig of N cameras from ``calib.yaml`` (module docs), or from any two-camera calibration
    :func:`synth.formats.calib_yaml.read_calib` reads (as a rig of two: ``left``, ``right``).
    :class:`DatasetError` (one line naming the file) for anything unusable."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DatasetError(not_a_file(path))
    if _is_one_camera_file(path):
        raise DatasetError(f"{path}: a calibration of one camera (camera_matrix: eval calibrate "
                           f"of one camera's folder), not of a rig: give the rig's calib.yaml")
    if calib_format(path) == "colmap" and colmap_cameras(path) != 2:
        try:  # the COLMAP fork's cameras.txt of N cameras, rig_config.json beside it
            return read_colmap_rig(path)
        except CalibFormatError as exc:
            raise DatasetError(str(exc)) from None
    if not _is_rig_file(path):
        calib = read_calib(path)
        return Rig.from_stereo(calib["rig"])
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
    try:
        units = fs.getNode("units")
        if not units.empty() and not (units.isString() and units.string().strip() == "mm"):
            raise DatasetError(f"{path}: units: only mm is read (every length in millimetres)")
        node = fs.getNode("cameras")
        if not node.isSeq():
            raise DatasetError(f"{path}: cameras: a sequence of one map per camera")
        cameras, names = [], []
        for k in range(node.size()):
            sub = node.at(k)
            name = sub.getNode("name").string() if sub.getNode("name").isString() else f"cam{k}"
            names.append(name)
            cameras.append(_read_camera(path, sub, name))
        shared = None
        pnode = fs.getNode("port")
        if not pnode.empty():
            shared = _read_flat(path, pnode, "port")
        ports = _read_ports(path, fs.getNode("ports"), shared, names)
    finally:
        fs.release()
    try:
        return Rig(cameras, ports, names)
    except ValueError as exc:
        raise DatasetError(f"{path}: {exc}") from None


def _read_camera(path, node, name) -> Camera:
    mats = {}
    for key in ("K", "D", "R", "t"):
        mat = node.getNode(key).mat()
        if mat is None:
            raise DatasetError(f"{path}: {name}: no matrix {key}")
        mats[key] = np.asarray(mat, dtype=np.float64)
    size = tuple(node.getNode(key).real() for key in ("image_width", "image_height"))
    try:
        return Camera(mats["K"], size, dist=mats["D"].ravel(), R=mats["R"], t=mats["t"].ravel())
    except ValueError as exc:
        raise DatasetError(f"{path}: {name}: {exc}") from None


def _read_flat(path, node, what) -> FlatPort:
    normal = node.getNode("normal").mat() if node.isMap() else None
    if normal is None or node.getNode("distance").empty():
        raise DatasetError(f"{path}: {what}: a flat port map needs normal, distance, "
                           f"thicknesses and indices")
    try:
        return FlatPort(normal.ravel(), node.getNode("distance").real(),
                        tuple(_seq(node.getNode("thicknesses"))),
                        tuple(_seq(node.getNode("indices"))))
    except ValueError as exc:
        raise DatasetError(f"{path}: {what}: {exc}") from None


def _read_dome(path, node, what) -> DomePort:
    centre = node.getNode("center").mat()
    if centre is None:
        raise DatasetError(f"{path}: {what}: a dome needs center, radius, thickness, indices")
    try:
        return DomePort(centre.ravel(), node.getNode("radius").real(),
                        node.getNode("thickness").real(), tuple(_seq(node.getNode("indices"))))
    except ValueError as exc:
        raise DatasetError(f"{path}: {what}: {exc}") from None


#: How each ``kind`` of a ``ports`` map is read.
PORT_READERS = {"flat": _read_flat, "dome": _read_dome}


def _read_ports(path, node, shared, names) -> list:
    n = len(names)
    if node.empty():
        if shared is None:
            raise DatasetError(f"{path}: neither a port map (one flat port the cameras share) "
                               f"nor ports (one entry per camera: {', '.join(names)})")
        return [shared] * n
    if not node.isSeq():
        raise DatasetError(f"{path}: ports: one value where {n} are needed (one entry per "
                           f"camera: {', '.join(names)})")
    if node.size() != n:
        which = (f"no entry for {names[node.size()]}" if node.size() < n
                 else f"{node.size() - n} more than the cameras")
        raise DatasetError(f"{path}: ports: {node.size()} entries for {n} cameras ({which})")
    ports = []
    for name, k in zip(names, range(n)):
        entry = node.at(k)
        what = f"ports: {name}"
        if entry.isString():
            word = entry.string().strip()
            if word == SHARED:
                if shared is None:
                    raise DatasetError(f"{path}: {what}: shared, but there is no port map")
                ports.append(shared)
            elif word == NONE:
                ports.append(None)
            else:
                raise DatasetError(f"{path}: {what}: {word!r}: shared, none or a map")
            continue
        kind = entry.getNode("kind").string() if entry.isMap() else ""
        if kind not in PORT_READERS:
            raise DatasetError(f"{path}: {what}: a map with kind flat or dome, shared or none")
        ports.append(PORT_READERS[kind](path, entry, what))
    return ports


__all__ = ["NONE", "SHARED", "read_rig_covariance", "read_rig_file", "shared_port", "write_rig_file"]
