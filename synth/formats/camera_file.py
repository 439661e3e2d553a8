"""One camera's calibration files: calibmar's one-camera YAML, a one-line COLMAP ``cameras.txt``
and OpenCV's FileStorage ``camera.yaml`` (K, distortion, the lens model, an optional port and
covariance), written and read (:mod:`synth.formats.calib_formats` has the shared conventions)."""

from __future__ import annotations

import os

import numpy as np

from measure import Camera
from measure.geometry.camera import BROWN_CONRADY, FISHEYE
from measure.geometry.flatport_format import housing_params

from synth.infra.fileio import atomic_write_text
from synth.formats.calib_common import (CALIBMAR_NAME, COLMAP_CAMERAS_NAME, PYCOLMAP_WARNING,
                                        CalibFormatError, calib_format, colmap_camera,
                                        distortion_model_of, opencv_camera)
from synth.formats.calibmar_file import calibmar_text, parse_calibmar
from synth.formats.colmap_files import parse_cameras_txt


def write_single_camera(directory, camera: Camera, port=None) -> list[str]:
    """One camera as calibmar's one-camera file (:data:`CALIBMAR_NAME`) and a one-line COLMAP
    ``cameras.txt``, into ``directory``, atomically: in air (``port`` None: ``non_svp_model:
    NONE``, no housing) or behind ``port``, a rig port whose view 0 is the camera's (a flat
    port, or a :class:`measure.geometry.dome.DomePair` whose left dome is the camera's): its
    FLATPORT or DOMEPORT. Returns the paths."""
    directory = os.fspath(directory)
    housing, params = "NONE", None
    if port is not None:
        housing, params, _ = housing_params(port, camera, camera, CalibFormatError)
    calibmar = os.path.join(directory, CALIBMAR_NAME)
    atomic_write_text(calibmar, calibmar_text(camera, params, camera.size,
                                               (np.eye(3), np.zeros(3)), None, housing))
    name, values = colmap_camera(camera)
    line = ["1", name, str(int(camera.size[0])), str(int(camera.size[1]))]
    line += [repr(v) for v in values]
    header = ["# Camera list with one line of data per camera:",
              "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"
              + ("" if params is None else " REFRAC_MODEL REFRAC_PARAMS[]"),
              "# Number of cameras: 1"]
    if params is None:
        header.append("# Written by refractive-stereo: one camera in air. Pixels: COLMAP's, the "
                      "centre of the top-left pixel is (0.5, 0.5) (cx, cy = OpenCV's + 0.5).")
    else:
        line += [housing] + [repr(float(v)) for v in params]
        header += ["# Written by refractive-stereo for the refractive COLMAP fork (MDSKiel/"
                   "colmap_underwater): one camera behind its own port. Pixels: COLMAP's, the "
                   "centre of the top-left pixel is (0.5, 0.5) (cx, cy = OpenCV's + 0.5).",
                   "# FLATPORT: Nx Ny Nz (unit normal in the camera's frame) int_dist int_thick "
                   "(metres) na ng nw.",
                   "# DOMEPORT: Cx Cy Cz (dome centre in the camera's frame) int_radius "
                   "int_thick (metres) na ng nw.",
                   f"# WARNING: {PYCOLMAP_WARNING}."]
    cameras = os.path.join(directory, COLMAP_CAMERAS_NAME)
    atomic_write_text(cameras, "\n".join(header + [" ".join(line)]) + "\n")
    return [calibmar, cameras]


#: The nodes of an OpenCV camera file (OpenCV's calibration sample, ``eval calibrate PHOTOS
#: --air``'s ``camera.yaml``) that :func:`read_single_camera` reads.
CAMERA_FILE_NODES = ("image_width", "image_height", "camera_matrix", "distortion_coefficients")


def read_single_camera(path) -> dict:
    """One camera's in-air calibration: ``camera`` (:class:`measure.Camera` at the reference
    origin), ``size``, ``rms_px`` (or None), ``lens_model`` (or None), ``covariance`` (a
    :class:`measure.stereo.rig_covariance.RigCovariance` of ``left.fx`` … or None),
    ``covariance_photos`` (the same intrinsics' photo-to-photo spread, or None) and
    ``format``. The file is an OpenCV ``camera.yaml`` (:data:`CAMERA_FILE_NODES`; ``eval
    calibrate PHOTOS --air`` writes it, with ``rms_px``, ``lens_model`` and a ``covariance``
    node), calibmar's one-camera YAML (``non_svp_model: NONE``) or a COLMAP ``cameras.txt`` of
    one camera with no housing, told apart by content. CalibFormatError names the file and
    what is wrong (a stereo calibration, a file that already holds a housing)."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise CalibFormatError(f"{path}: no such file")
    kind = calib_format(path)
    out = {"rms_px": None, "lens_model": None, "covariance": None, "covariance_photos": None,
           "format": kind}
    if kind == "calibmar":
        K, D, size, model = _calibmar_camera(path)
    elif kind == "colmap":
        K, D, size, model = _colmap_camera(path)
    else:
        K, D, size, model = _opencv_camera(path, out)
    dist = np.asarray(D, dtype=np.float64).ravel()
    try:
        out["camera"] = Camera(np.asarray(K, dtype=np.float64), size,
                               dist=dist if np.any(dist) or model == FISHEYE else None,
                               distortion_model=model)
    except ValueError as exc:
        raise CalibFormatError(f"{path}: {exc}") from None
    out["size"] = tuple(size)
    return out


def _calibmar_camera(path):
    """``(K, D, size, model)`` of calibmar's one-camera YAML in air (``non_svp_model: NONE``,
    not the second camera of a stereo pair)."""
    values = parse_calibmar(path)
    if str(values["non_svp_model"]) != "NONE":
        raise CalibFormatError(f"{path}: non_svp_model {values['non_svp_model']}: already "
                               f"a housing calibration; give the camera's in-air "
                               f"calibration (non_svp_model: NONE)")
    if values.get("cam_to_world_translation") and np.any(values["cam_to_world_translation"]):
        raise CalibFormatError(f"{path}: the second camera of a calibmar stereo "
                               f"calibration; give one camera's file")
    K, D = opencv_camera(str(values["model"]), values["parameters"], path)
    return K, D, values["size"], distortion_model_of(str(values["model"]))


def _colmap_camera(path):
    """``(K, D, size, model)`` of a COLMAP ``cameras.txt`` of one camera with no housing."""
    cameras = parse_cameras_txt(path)
    if len(cameras) != 1:
        raise CalibFormatError(f"{path}: {len(cameras)} cameras; one camera's housing is "
                               f"calibrated from a cameras.txt of one camera")
    (only,) = cameras.values()
    if only["housing"] is not None:
        raise CalibFormatError(f"{path}: the camera has a {only['housing']}: already a "
                               f"housing calibration; give the camera's in-air calibration")
    return only["K"], only["D"], only["size"], only["model"]


def _opencv_camera(path, out):
    """``(K, D, size, model)`` of an OpenCV ``camera.yaml`` (:data:`CAMERA_FILE_NODES`); its
    ``rms_px``, ``lens_model`` and covariances go into ``out``."""
    import cv2

    try:
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):
        raise CalibFormatError(f"{path}: not a valid OpenCV FileStorage, calibmar or COLMAP "
                               f"camera file") from None
    if not fs.isOpened():
        raise CalibFormatError(f"{path}: cannot open as OpenCV FileStorage")
    try:
        if not fs.getNode("K1").empty():
            raise CalibFormatError(f"{path}: a stereo calibration (K1, K2); give one "
                                   f"camera's in-air calibration (camera.yaml of eval "
                                   f"calibrate PHOTOS --air)")
        if not (fs.getNode("port").empty() and fs.getNode("dome").empty()):
            raise CalibFormatError(f"{path}: already a housing calibration (a port or dome "
                                   f"node); give the camera's in-air calibration")
        missing = [n for n in CAMERA_FILE_NODES if fs.getNode(n).empty()]
        if missing:
            raise CalibFormatError(f"{path}: no {', '.join(missing)} (expected an OpenCV "
                                   f"camera file: {', '.join(CAMERA_FILE_NODES)})")
        K = fs.getNode("camera_matrix").mat()
        D = fs.getNode("distortion_coefficients").mat()
        size = (int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real()))
        node = fs.getNode("rms_px")
        out["rms_px"] = None if node.empty() else float(node.real())
        node = fs.getNode("lens_model")
        out["lens_model"] = None if node.empty() else node.string()
        node = fs.getNode("distortion_model")
        model = BROWN_CONRADY if node.empty() else node.string()
        out["covariance"] = read_covariance_node(path, fs.getNode("covariance"))
        out["covariance_photos"] = read_covariance_node(path, fs.getNode("covariance_photos"))
    finally:
        fs.release()
    if K is None or np.shape(K) != (3, 3) or D is None or not np.all(np.isfinite(K)):
        raise CalibFormatError(f"{path}: camera_matrix must be 3x3 and "
                               f"distortion_coefficients a row of numbers")
    return K, D, size, model


def read_covariance_node(path, node, error=CalibFormatError):
    """A calibration file's ``covariance`` node (``names``, ``matrix``, ``normal_axes`` where
    given) as a :class:`measure.stereo.rig_covariance.RigCovariance`, or None when the file has
    none; ``error`` (naming ``path``) when it is malformed, singular or not positive
    definite."""
    from measure.stereo.rig_covariance import CovarianceError, RigCovariance

    if node.empty():
        return None
    names_node = node.getNode("names")
    names = ([names_node.at(i).string() for i in range(names_node.size())]
             if names_node.isSeq() else [])
    matrix = node.getNode("matrix").mat()
    axes = node.getNode("normal_axes").mat()
    try:
        return RigCovariance(names, np.zeros((0, 0)) if matrix is None else matrix, axes)
    except CovarianceError as exc:
        raise error(f"{path}: covariance: {exc}") from None
