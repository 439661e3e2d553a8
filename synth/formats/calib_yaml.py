"""A rig's ``calib.yaml`` (OpenCV FileStorage; :mod:`synth.products.dataset` documents its
nodes): written from a :class:`measure.Rig` of two and read back — a flat port, two housings or
two domes, an optional covariance — and, by their content, calibmar's and the COLMAP fork's
files read into the same dictionary (:mod:`synth.formats.calib_formats`). Units mm; the
reference frame is the left camera's; OpenCV's stereo convention ``X_right = R·X_left + T``."""

from __future__ import annotations

import os

import cv2
import numpy as np

from measure import Camera, FlatPort, Rig
from measure.geometry.camera import BROWN_CONRADY
from measure.geometry.dome import DomePair, DomePort
from measure.geometry.flat_pair import FlatPair
from measure.geometry.flatport_format import write_calib_port

from synth.formats.calib_formats import (CalibFormatError, calib_dict, calib_format, read_calibmar,
                                         read_colmap, stereo_extrinsics)


class DatasetError(ValueError):
    """A dataset directory (or its calibration file) that cannot be read or written."""


# ---------------------------------------------------------------------------------------------
# calibration in OpenCV's stereo convention
# ---------------------------------------------------------------------------------------------
def _dist5(camera: Camera) -> np.ndarray:
    return np.zeros(5) if camera.dist is None else camera.dist.copy()


def write_node(fs, name: str, value) -> None:
    """A number, string, list or map as the FileStorage node ``name`` (maps and lists nest)."""
    if isinstance(value, dict):
        fs.startWriteStruct(name, cv2.FileNode_MAP)
        for key, item in value.items():
            write_node(fs, str(key), item)
        fs.endWriteStruct()
    elif isinstance(value, (list, tuple)):
        fs.startWriteStruct(name, cv2.FileNode_SEQ)
        for item in value:
            write_node(fs, "", item)
        fs.endWriteStruct()
    elif isinstance(value, str):
        fs.write(name, value)
    else:
        fs.write(name, float(value))


def write_calib(path, rig: Rig, has_port: bool = True, extra: dict | None = None,
                covariance=None) -> None:
    """Write ``calib.yaml`` (see module docs) with ``cv2.FileStorage``; ``extra`` adds maps
    (e.g. ``uncertainty``) of numbers, strings, lists and maps after the standard nodes;
    ``covariance`` (:class:`measure.stereo.rig_covariance.RigCovariance`) a ``covariance`` node:
    ``names`` (a sequence of parameter names), ``matrix`` (P x P), ``normal_axes`` (2 x 3)."""
    left, right = rig.left, rig.right
    R, T = stereo_extrinsics(left, right)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        fs.write("image_width", int(left.size[0]))
        fs.write("image_height", int(left.size[1]))
        fs.write("units", "mm")
        fs.write("K1", left.K)
        fs.write("D1", _dist5(left).reshape(1, -1))
        fs.write("K2", right.K)
        fs.write("D2", _dist5(right).reshape(1, -1))
        for key, camera in (("D1_model", left), ("D2_model", right)):
            if camera.distortion_model != BROWN_CONRADY:  # absent: OpenCV's Brown–Conrady
                fs.write(key, camera.distortion_model)
        fs.write("R", R)
        fs.write("T", T.reshape(3, 1))
        write_calib_port(fs, rig.port, has_port)
        if covariance is not None:
            fs.startWriteStruct("covariance", cv2.FileNode_MAP)
            write_node(fs, "names", list(covariance.names))
            fs.write("matrix", covariance.matrix)
            if covariance.normal_axes is not None:
                fs.write("normal_axes", covariance.normal_axes)
            fs.endWriteStruct()
        for name, value in (extra or {}).items():
            write_node(fs, name, value)
    finally:
        fs.release()


def _seq(node) -> list[float]:
    if node.isSeq():
        return [node.at(i).real() for i in range(node.size())]
    mat = node.mat()
    return [] if mat is None else [float(v) for v in mat.ravel()]


def read_calib(path) -> dict:
    """Read a stereo calibration: a dict with ``size``, ``K1``, ``D1``, ``K2``, ``D2``, ``R``,
    ``T``, ``port`` (:class:`measure.FlatPort`, a FlatPair or a DomePair), ``has_port`` and ``rig``
    (:class:`measure.Rig` of two, the left camera at the reference origin). The file is this
    project's ``calib.yaml``, a calibmar stereo calibration (either of its two YAML files) or
    the COLMAP fork's ``cameras.txt`` with ``rig_config.json`` beside it, told apart by content
    (:mod:`synth.formats.calib_formats`). Anything unreadable or inconsistent raises
    :class:`DatasetError` naming the file."""
    kind = calib_format(path) if os.path.isfile(path) else "opencv"
    try:
        if kind == "calibmar":
            return read_calibmar(path)
        if kind == "colmap":
            return read_colmap(path)
        return _read_calib(path)
    except DatasetError:
        raise
    except CalibFormatError as exc:  # its message starts with the file
        raise DatasetError(str(exc)) from None
    except (cv2.error, SystemError):  # OpenCV's parser: not YAML/XML FileStorage
        raise DatasetError(f"{path}: not a valid OpenCV FileStorage calibration file") from None
    except (ValueError, TypeError, AttributeError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        raise DatasetError(f"{path}: not a valid calibration file ({message[:200]})") from None


def not_a_file(path) -> str:
    """What to say of a calibration ``path`` that is not a file: a folder (and the calibration
    file inside it, when there is one) or nothing at all."""
    if os.path.isdir(path):
        inside = [n for n in ("calib.yaml", "camera.yaml") if os.path.isfile(os.path.join(path, n))]
        return (f"{path}: a folder, not a calibration file"
                + (f" (give {os.path.join(path, inside[0])})" if inside else ""))
    return f"{path}: no such file"


def other_calibration(fs, path) -> str | None:
    """Why the OpenCV FileStorage ``fs`` of ``path`` is not a stereo pair's calibration when it
    is another one: one camera's ``camera.yaml`` (``camera_matrix``) or a rig of N cameras
    (``cameras``); None otherwise."""
    if fs.getNode("K1").empty() and not fs.getNode("camera_matrix").empty():
        return (f"{path}: a calibration of one camera (camera_matrix: eval calibrate of one "
                f"camera's folder), not of a stereo pair (K1, K2, R, T): give the rig's calib.yaml")
    cameras = fs.getNode("cameras")
    if fs.getNode("K1").empty() and cameras.isSeq():
        return (f"{path}: a calibration of {cameras.size()} cameras, not of a stereo pair "
                f"(K1, K2, R, T): this reads two cameras")
    return None


def _read_calib(path) -> dict:
    if not os.path.isfile(path):
        raise DatasetError(not_a_file(path))
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise DatasetError(f"{path}: cannot open as OpenCV FileStorage")
    try:
        other = other_calibration(fs, path)
        if other:
            raise DatasetError(other)
        units = fs.getNode("units")
        if not units.empty() and not (units.isString() and units.string().strip() == "mm"):
            said = units.string() if units.isString() else units.real()
            raise DatasetError(f"{path}: units: {said!r}: only mm is read (every length of "
                               f"calib.yaml in millimetres, units: mm)")
        out = {"size": (int(fs.getNode("image_width").real()),
                        int(fs.getNode("image_height").real()))}
        for name in ("K1", "D1", "K2", "D2", "R", "T"):
            mat = fs.getNode(name).mat()
            if mat is None:
                raise DatasetError(f"{path}: no matrix {name}")
            out[name] = np.asarray(mat, dtype=np.float64)
        pnode, dnode, pairnode = fs.getNode("port"), fs.getNode("dome"), fs.getNode("ports")
        given = [name for name, node in (("port", pnode), ("dome", dnode), ("ports", pairnode))
                 if not node.empty()]
        if len(given) > 1:
            raise DatasetError(f"{path}: holds both a {' and a '.join(given)} map; a calibration "
                               f"has one (port: one flat port, ports: a flat port per camera, "
                               f"dome: a dome per camera)")
        if not dnode.empty():
            out["port"], out["has_port"] = _read_domes(path, dnode), True
        elif not pairnode.empty():
            out["port"], out["has_port"] = _read_flat_pair(path, pairnode), True
        else:
            if pnode.empty() or pnode.getNode("normal").mat() is None:
                raise DatasetError(f"{path}: no port map (normal, distance, thicknesses, "
                                   f"indices) and no dome map")
            present = pnode.getNode("present")
            if not present.empty() and not (present.isInt() and present.real() in (0, 1)):
                said = present.string() if present.isString() else f"{present.real():g}"
                raise DatasetError(f"{path}: port: present: {said}: must be 0 (in air: the "
                                   f"port bends no ray) or 1 (the port refracts)")
            out["has_port"] = bool(present.real()) if not present.empty() else True
            indices = tuple(_seq(pnode.getNode("indices")))
            if not out["has_port"]:  # in air: what the rig measures through is index-matched
                indices = (1.0,) * len(indices)
            out["port"] = FlatPort(pnode.getNode("normal").mat().ravel(),
                                   pnode.getNode("distance").real(),
                                   tuple(_seq(pnode.getNode("thicknesses"))), indices)
        covariance = _read_covariance(path, fs.getNode("covariance"))
        models = []
        for key in ("D1_model", "D2_model"):
            node = fs.getNode(key)
            models.append(BROWN_CONRADY if node.empty() else node.string().strip())
    finally:
        fs.release()
    calib = calib_dict(out["size"], out["K1"], out["D1"], out["K2"], out["D2"], out["R"],
                       out["T"], out["port"], out["has_port"], str(path), tuple(models))
    calib["covariance"] = covariance
    return calib


def _read_flat_pair(path, node) -> FlatPair:
    """The ``ports`` map of ``calib.yaml`` (two housings): ``left`` and ``right`` maps of
    ``normal`` (3x1), ``distance``, ``thicknesses`` and ``indices`` (reference frame, mm), each
    the port that camera looks through."""
    ports = []
    for name in ("left", "right"):
        sub = node.getNode(name)
        normal = None if sub.empty() else sub.getNode("normal").mat()
        if normal is None:
            raise DatasetError(f"{path}: ports: no {name} map (normal, distance, thicknesses, "
                               f"indices): a port per camera needs both left and right")
        if sub.getNode("distance").empty():
            raise DatasetError(f"{path}: ports: {name}: no distance")
        try:
            ports.append(FlatPort(normal.ravel(), sub.getNode("distance").real(),
                                  tuple(_seq(sub.getNode("thicknesses"))),
                                  tuple(_seq(sub.getNode("indices")))))
        except ValueError as exc:
            raise DatasetError(f"{path}: ports: {name}: {exc}") from None
    return FlatPair(*ports)


def _read_domes(path, node) -> DomePair:
    """The ``dome`` map of ``calib.yaml``: ``left`` and ``right`` maps of ``center`` (3x1, mm,
    reference frame), ``radius``, ``thickness`` (mm) and ``indices`` (air, glass, water)."""
    domes = []
    for name in ("left", "right"):
        sub = node.getNode(name)
        centre = None if sub.empty() else sub.getNode("center").mat()
        if centre is None:
            raise DatasetError(f"{path}: dome map without a {name} dome (center, radius, "
                               f"thickness, indices)")
        try:
            from synth.scene.dome import check_dome_size

            check_dome_size(sub.getNode("radius").real(), sub.getNode("thickness").real())
            domes.append(DomePort(centre.ravel(), sub.getNode("radius").real(),
                                  sub.getNode("thickness").real(),
                                  tuple(_seq(sub.getNode("indices")))))
        except ValueError as exc:
            raise DatasetError(f"{path}: {name} dome: {exc}") from None
    return DomePair(*domes)


def _read_covariance(path, node):
    """The ``covariance`` node as a :class:`measure.stereo.rig_covariance.RigCovariance`, or None when
    the file has none; DatasetError naming the file when it is malformed, singular or not
    positive definite (:func:`synth.formats.calib_formats.read_covariance_node`)."""
    from synth.formats.calib_formats import read_covariance_node

    return read_covariance_node(path, node, DatasetError)


# ---------------------------------------------------------------------------------------------
# small writers
# ---------------------------------------------------------------------------------------------
