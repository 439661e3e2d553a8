"""Stereo calibrations in the files users already have: calibmar's YAML and the refractive
COLMAP fork's ``cameras.txt`` — written from and read into this project's rig, exactly.

Both come from Kiel's refractive tools (docs/formats.md has the sources, file and line):

* **calibmar** (github MDSKiel/calibmar) saves a stereo calibration as *two* files:
  ``<name>.yaml`` for the first camera and ``<name>_stereo.yaml`` for the second
  (``src/app/ui/main_window.cpp``), each ``model``, ``parameters`` (a COLMAP camera model),
  ``non_svp_model`` (``FLATPORT``, ``DOMEPORT``, or ``NONE`` in air), ``non_svp_parameters``
  ``[Nx, Ny, Nz, int_dist, int_thick, na, ng, nw]`` (``DOMEPORT``: ``[Cx, Cy, Cz, int_radius,
  int_thick, na, ng, nw]``, the dome centre in that camera's frame), ``width``, ``height`` and the stereo pose
  ``cam_to_world_rotation_rowmajor`` (9 numbers) and ``cam_to_world_translation`` (3):
  ``X_world = R·X_cam + t``, the world being the first camera (identity in its file)
  (``src/calibmar/core/report.cpp`` lines 91–152, ``stereo_calibrator.cpp`` lines 93–96).
* **COLMAP fork** (github MDSKiel/colmap_underwater): ``cameras.txt`` lines
  ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS… [FLATPORT Nx Ny Nz int_dist int_thick na ng nw]`` or
  ``… [DOMEPORT Cx Cy Cz int_radius int_thick na ng nw]``
  (``src/colmap/scene/reconstruction.cc`` lines 1854–1893). A ``cameras.txt`` holds no relative
  pose; the fork's rig bundle adjuster reads it from a rig configuration JSON
  (``src/colmap/exe/sfm.cc`` lines 540–583): ``[{"ref_camera_id": 1, "cameras": [{"camera_id",
  "image_prefix", "cam_from_rig_rotation": [w, x, y, z], "cam_from_rig_translation"}…]}]``.
  So this project writes ``cameras.txt`` and, beside it, ``rig_config.json``; reading a
  ``cameras.txt`` needs that file beside it (the left camera is ``ref_camera_id``).

Conventions of both: COLMAP pixels — the centre of the top-left pixel is (0.5, 0.5), so
``cx, cy`` are OpenCV's + 0.5 (calibmar adds 0.5 to OpenCV's corners:
``src/calibmar/extractors/chessboard_extractor.cpp`` lines 61–63); the port normal in each
camera's own frame and its distance from that camera (:mod:`measure.geometry.flatport_format`); lengths
in metres (calibmar: the unit of the target, "expected in meters"). Two FLATPORTs that agree
(:data:`PORT_TOLERANCE`) are one flat port both cameras look through
(:class:`measure.FlatPort`); two that differ are two housings, each camera behind its own port
(:class:`measure.geometry.flat_pair.FlatPair`, written back the same way); a
rig of two domes (:class:`measure.geometry.dome.DomePair`) is one DOMEPORT per camera, each camera's
own (:func:`measure.geometry.flatport_format.to_domeport`); both cameras must have the same
housing; a rig with a skewed K, zero or several port layers cannot be written and raises
:class:`CalibFormatError`.
Camera models read: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV (their
distortion is OpenCV's Brown–Conrady model) and OPENCV_FISHEYE (OpenCV's fisheye model, k1…k4);
written: OPENCV, or FULL_OPENCV when k3 (or k4–k6) is not zero; OPENCV_FISHEYE for a fisheye
camera.
"""

from __future__ import annotations

import json
import os
import re

import numpy as np
from scipy.spatial.transform import Rotation

from measure import Camera, FlatPort, StereoRig
from measure.geometry.camera import BROWN_CONRADY, FISHEYE
from measure.geometry.dome import DomePair
from measure.geometry.flat_pair import FlatPair
from measure.geometry.flatport_format import (DOMEPORT_NAMES, FLATPORT_NAMES, METRES_PER_MM,
                                     from_domeport, from_flatport, housing_params)

from synth.infra.fileio import atomic_write_text

#: COLMAP puts the centre of the top-left pixel at (0.5, 0.5), OpenCV at (0, 0).
COLMAP_PIXEL_OFFSET = 0.5
#: ``{model: parameter names}`` of the COLMAP camera models this module reads.
COLMAP_MODELS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}
#: Two cameras' FLATPORTs that agree this well are one port (normal in rad, lengths in mm,
#: indices): calibmar writes 10 significant digits, a rig with two housings differs far more;
#: beyond it each camera has its own port (a FlatPair).
PORT_TOLERANCE = {"normal_rad": 1e-6, "mm": 1e-3, "index": 1e-9}
#: File names :func:`write_calibration_formats` writes.
CALIBMAR_NAME = "calibmar.yaml"
COLMAP_CAMERAS_NAME = "cameras.txt"
COLMAP_RIG_NAME = "rig_config.json"
#: Image folders the rig configuration names (the layout of a photo folder: left/, right/).
IMAGE_PREFIXES = ("left/", "right/")
PYCOLMAP_WARNING = ("upstream COLMAP and pycolmap (4.2.1 tried) read this file without an error "
                    "and silently DROP the FLATPORT part: use the refractive fork")
#: The housings (the fork's refractive models) this module writes and reads, their parameters.
HOUSINGS = {"FLATPORT": FLATPORT_NAMES, "DOMEPORT": DOMEPORT_NAMES}
#: calibmar's comment line above ``non_svp_parameters`` (the fork's RefracParamsInfo, newline
#: replaced by a space: calibmar ``src/calibmar/core/report.cpp`` lines 113–119).
_PARAMS_INFO = {"FLATPORT": "Nx, Ny, Nz, int_dist, int_thick, na, ng, nw (Note that [Nx, Ny, "
                            "Nz] must be unit vector)",
                "DOMEPORT": "Cx, Cy, Cz, int_radius, int_thick, na, ng, nw"}


class CalibFormatError(ValueError):
    """A calibration file that cannot be read, or a rig that a format cannot hold exactly."""


# ---------------------------------------------------------------------------------------------
# the read_calib dictionary
# ---------------------------------------------------------------------------------------------
def stereo_extrinsics(left: Camera, right: Camera) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's stereo ``R, T`` (``X_right = R·X_left + T``) from two camera-to-reference poses."""
    R = right.R.T @ left.R
    T = right.R.T @ (left.t - right.t)
    return R, T


def calib_dict(size, K1, D1, K2, D2, R, T, port: FlatPort, has_port: bool,
               where: str = "calibration", models=(BROWN_CONRADY, BROWN_CONRADY)) -> dict:
    """The dictionary :func:`synth.products.dataset.read_calib` returns: ``size``, ``K1``, ``D1``, ``K2``,
    ``D2``, ``R``, ``T`` (OpenCV's stereo pose, 3x1), ``port``, ``has_port``, ``rig`` (the
    left camera at the reference origin), ``covariance`` (None here; ``calib.yaml`` may
    hold one) and ``models``, the two cameras' distortion models (``D1``, ``D2`` are theirs);
    ``where`` (the file) starts a CalibFormatError."""
    out = {"size": (int(size[0]), int(size[1])),
           "K1": np.asarray(K1, dtype=np.float64), "D1": np.asarray(D1, dtype=np.float64),
           "K2": np.asarray(K2, dtype=np.float64), "D2": np.asarray(D2, dtype=np.float64),
           "R": np.asarray(R, dtype=np.float64), "T": np.asarray(T, dtype=np.float64),
           "port": port, "has_port": bool(has_port), "covariance": None,
           "models": tuple(models)}
    if out["R"].shape != (3, 3) or out["T"].size != 3:
        raise CalibFormatError(f"{where}: R must be 3x3 and T 3x1")
    try:
        left = Camera(out["K1"], out["size"], dist=out["D1"].ravel(), distortion_model=models[0])
        R, T = out["R"], out["T"].ravel()
        right = Camera(out["K2"], out["size"], dist=out["D2"].ravel(), R=R.T, t=-R.T @ T,
                       distortion_model=models[1])
    except ValueError as exc:
        raise CalibFormatError(f"{where}: {exc}") from None
    centres = np.array([left.center, right.center])
    if not has_port and np.any(port.view(0).water_side(centres)):
        # in air the plane bends nothing and may lie anywhere (eval rectify's virtual cameras
        # keep the real port's plane, behind them): 1 mm beyond the cameras, as "no port" is
        from measure.geometry.port import index_matched_port

        port = index_matched_port(port.normal, centres)
        out["port"] = port
    out["rig"] = StereoRig(left, right, port)
    return out


def _relative(rig: StereoRig):
    """The right camera's camera-to-left pose ``(R, t mm)`` of any rig."""
    left, right = rig.left, rig.right
    return left.R.T @ right.R, left.R.T @ (right.t - left.t)


def _from_relative(pose_left, pose_right):
    """``(R, T)`` in OpenCV's stereo convention from two camera-to-world poses ``(R, t)``."""
    left = Camera(np.eye(3), (1, 1), R=pose_left[0], t=pose_left[1])
    right = Camera(np.eye(3), (1, 1), R=pose_right[0], t=pose_right[1])
    R, T = stereo_extrinsics(left, right)
    return R, T.reshape(3, 1)


def _air_port() -> FlatPort:
    from synth.scene.rig import air_port

    return air_port()


# ---------------------------------------------------------------------------------------------
# cameras as COLMAP models
# ---------------------------------------------------------------------------------------------
def distortion_model_of(colmap_model: str) -> str:
    """The :class:`Camera` distortion model of a COLMAP camera model."""
    return FISHEYE if colmap_model == "OPENCV_FISHEYE" else BROWN_CONRADY


def colmap_camera(camera: Camera, model: str | None = None) -> tuple[str, list[float]]:
    """``(model, params)`` of ``camera`` in COLMAP's pixels: OPENCV, or FULL_OPENCV when k3 or
    the rational k4–k6 are not zero (``model=None``); ``model="OPENCV"`` refuses those; a
    fisheye camera is OPENCV_FISHEYE (fx fy cx cy k1 k2 k3 k4)."""
    K = camera.K
    if K[0, 1] != 0:
        raise CalibFormatError(f"K has a skew of {K[0, 1]:g}: COLMAP's camera models have none")
    if camera.fisheye or model == "OPENCV_FISHEYE":
        if not camera.fisheye or model not in (None, "OPENCV_FISHEYE"):
            raise CalibFormatError(f"OPENCV_FISHEYE holds OpenCV's fisheye model only; this "
                                   f"camera's is {camera.distortion_model}, model {model}")
        return "OPENCV_FISHEYE", [float(v) for v in (
            K[0, 0], K[1, 1], K[0, 2] + COLMAP_PIXEL_OFFSET, K[1, 2] + COLMAP_PIXEL_OFFSET,
            *camera.dist)]
    dist = np.zeros(8) if camera.dist is None else np.pad(camera.dist, (0, 8 - camera.dist.size))
    needs_full = bool(np.any(dist[4:]))
    model = model or ("FULL_OPENCV" if needs_full else "OPENCV")
    if model == "OPENCV" and needs_full:
        raise CalibFormatError(f"OPENCV holds k1 k2 p1 p2 only; this camera has k3…k6 = "
                               f"{dist[4:].tolist()}: write FULL_OPENCV")
    if model not in ("OPENCV", "FULL_OPENCV"):
        raise CalibFormatError(f"write OPENCV or FULL_OPENCV, not {model}")
    params = [K[0, 0], K[1, 1], K[0, 2] + COLMAP_PIXEL_OFFSET, K[1, 2] + COLMAP_PIXEL_OFFSET,
              *dist[:4]]
    if model == "FULL_OPENCV":
        params += [*dist[4:]]
    return model, [float(v) for v in params]


def opencv_camera(model: str, params, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``(K, D)`` in OpenCV's pixels of a COLMAP model and its parameters; ``D`` is ``(1, 5)``
    (``(1, 8)`` with rational terms; ``(1, 4)``, k1…k4 of the fisheye model, for
    OPENCV_FISHEYE: :func:`distortion_model_of`). CalibFormatError names ``where`` and what is wrong."""
    if model not in COLMAP_MODELS:
        raise CalibFormatError(f"{where}: unknown or unsupported camera model {model!r} "
                               f"(read: {', '.join(COLMAP_MODELS)})")
    names = COLMAP_MODELS[model]
    values = np.asarray(params, dtype=np.float64)
    if values.size != len(names) or not np.all(np.isfinite(values)):
        raise CalibFormatError(f"{where}: {model} needs {len(names)} finite parameters "
                               f"({', '.join(names)}), got {_got(values, names)}")
    p = dict(zip(names, values))
    fx, fy = (p["f"], p["f"]) if "f" in p else (p["fx"], p["fy"])
    if not (fx > 0 and fy > 0):
        raise CalibFormatError(f"{where}: focal lengths must be positive, got {fx:g}, {fy:g}")
    K = np.array([[fx, 0.0, p["cx"] - COLMAP_PIXEL_OFFSET],
                  [0.0, fy, p["cy"] - COLMAP_PIXEL_OFFSET], [0.0, 0.0, 1.0]])
    if distortion_model_of(model) == FISHEYE:
        return K, np.array([[p["k1"], p["k2"], p["k3"], p["k4"]]])
    dist = np.zeros(8)
    dist[0] = p.get("k1", p.get("k", 0.0))
    dist[1] = p.get("k2", 0.0)
    for i, name in enumerate(("p1", "p2", "k3", "k4", "k5", "k6"), start=2):
        dist[i] = p.get(name, 0.0)
    D = dist if np.any(dist[5:]) else dist[:5]
    return K, D.reshape(1, -1)


def _got(values: np.ndarray, names) -> str:
    """What was found instead of ``len(names)`` finite numbers: their count, or (the count being
    right) which of them are not finite."""
    if values.size != len(names):
        return str(values.size)
    bad = [f"{n} = {v!r}" for n, v in zip(names, values.tolist()) if not np.isfinite(v)]
    return f"{', '.join(bad)}"


def _check_port(params, where: str, housing: str = "FLATPORT") -> list[float]:
    """The 8 numbers of a ``FLATPORT`` or ``DOMEPORT`` (metres), checked (CalibFormatError)."""
    names = HOUSINGS[housing]
    values = [float(v) for v in params]
    if len(values) != len(names) or not np.all(np.isfinite(values)):
        raise CalibFormatError(f"{where}: {housing} needs {len(names)} finite numbers "
                               f"({', '.join(names)}), got {_got(np.asarray(values), names)}")
    if housing == "DOMEPORT":
        for k in (3, 4):
            if not values[k] > 0:
                raise CalibFormatError(f"{where}: DOMEPORT {names[k]} must be > 0, got "
                                       f"{values[k]:g}")
        offset = float(np.linalg.norm(values[:3]))
        if not offset < values[3]:
            raise CalibFormatError(f"{where}: DOMEPORT: the camera centre lies outside its dome "
                                   f"(|Cx, Cy, Cz| = {offset:.6g} m >= int_radius "
                                   f"{values[3]:.6g} m)")
        if min(values[5:]) < 1.0:
            raise CalibFormatError(f"{where}: DOMEPORT indices na, ng, nw must be >= 1, got "
                                   f"{values[5:]}")
        return values
    length = float(np.linalg.norm(values[:3]))
    if abs(length - 1.0) > 1e-6:
        raise CalibFormatError(f"{where}: FLATPORT normal (Nx, Ny, Nz) must be a unit vector, "
                               f"got length {length:.9g}")
    if not values[3] > 0:
        raise CalibFormatError(f"{where}: FLATPORT int_dist must be > 0 (the camera in front "
                               f"of the port), got {values[3]:g}")
    if not values[4] > 0:
        raise CalibFormatError(f"{where}: FLATPORT int_thick must be > 0, got {values[4]:g}")
    if min(values[5:]) < 1.0:
        raise CalibFormatError(f"{where}: FLATPORT indices na, ng, nw must be >= 1, got "
                               f"{values[5:]}")
    return values


def _dome_pair(params_left, params_right, left: Camera, right: Camera) -> DomePair:
    """The two domes of two ``DOMEPORT`` parameter lists (each in its camera's frame, the
    cameras' poses in any common frame), in the left camera's frame (mm)."""
    domes = []
    for params, camera in ((params_left, left), (params_right, right)):
        dome = from_domeport(params, camera)
        domes.append(dome.replace(center=left.R.T @ (dome.center - left.t)))
    return DomePair(*domes)


def _flat_ports(params_left, params_right, left: Camera, right: Camera) -> FlatPort | FlatPair:
    """The port(s) of two ``FLATPORT`` parameter lists (each in its camera's frame, the cameras'
    poses in any common frame), in the left camera's frame (mm): one :class:`FlatPort` (the left
    camera's) when the two are the same port (:data:`PORT_TOLERANCE`), else a
    :class:`~measure.geometry.flat_pair.FlatPair` (two housings)."""
    ports = []
    for params, camera in ((params_left, left), (params_right, right)):
        port = from_flatport(params, camera)
        ports.append(FlatPort(left.R.T @ port.normal, port.distance - float(port.normal @ left.t),
                              port.thicknesses, port.indices))
    port, other = ports
    angle = float(np.arccos(np.clip(port.normal @ other.normal, -1.0, 1.0)))
    lengths = np.abs(np.array([port.distance - other.distance,
                               port.thicknesses[0] - other.thicknesses[0]]))
    indices = float(np.max(np.abs(np.subtract(port.indices, other.indices))))
    if (angle > PORT_TOLERANCE["normal_rad"] or np.max(lengths) > PORT_TOLERANCE["mm"]
            or indices > PORT_TOLERANCE["index"]):
        return FlatPair(port, other)
    return port


def _port_params(rig: StereoRig) -> tuple[str, list, list]:
    """``(housing, left parameters, right parameters)``: FLATPORT or DOMEPORT (metres)."""
    return housing_params(rig.port, rig.left, rig.right, CalibFormatError)


def _numbers(values) -> str:
    return ", ".join(repr(float(v)) for v in values)


# ---------------------------------------------------------------------------------------------
# calibmar
# ---------------------------------------------------------------------------------------------
def calibmar_partner(path) -> tuple[str, str]:
    """``(first, second)``: the two files of a calibmar stereo calibration, from either one
    (``NAME.yaml`` and ``NAME_stereo.yaml``)."""
    path = os.fspath(path)
    stem, ext = os.path.splitext(path)
    if stem.endswith("_stereo"):
        return stem[: -len("_stereo")] + ext, path
    return path, stem + "_stereo" + ext


def _calibmar_text(camera: Camera, port_params, size, pose, model,
                   housing: str = "FLATPORT") -> str:
    name, params = colmap_camera(camera, model)
    R, t = pose
    lines = [f"model: {name}", "# " + ", ".join(COLMAP_MODELS[name]),
             f"parameters: [{_numbers(params)}]"]
    if port_params is None:
        lines += ["non_svp_model: NONE", "non_svp_parameters: []"]
    else:
        lines += [f"non_svp_model: {housing}", "# " + _PARAMS_INFO[housing],
                  f"non_svp_parameters: [{_numbers(port_params)}]"]
    lines += [f"width: {int(size[0])}", f"height: {int(size[1])}",
              "# written by refractive-stereo: COLMAP pixels (the centre of the top-left pixel "
              "is 0.5, 0.5), lengths in metres", "",
              "# stereo pose (camera to world, camera 3D point X_C can be transformed to 3D "
              "world point X_W by X_W = cam_to_world_rotation * X_C + cam_to_world_translation)",
              f"cam_to_world_rotation_rowmajor: [{_numbers(np.asarray(R).ravel())}]",
              f"cam_to_world_translation: [{_numbers(np.asarray(t) * METRES_PER_MM)}]"]
    return "\n".join(lines) + "\n"


def write_calibmar(path, rig: StereoRig, has_port: bool = True,
                   model: str | None = None) -> tuple[str, str]:
    """Write ``rig`` as calibmar's stereo pair ``path`` (left) and ``<stem>_stereo.yaml``
    (right), atomically; ``has_port=False`` writes ``non_svp_model: NONE`` (in air). Returns the
    two paths. CalibFormatError for a rig the format cannot hold (module docs)."""
    first, second = calibmar_partner(path)
    if os.path.normpath(first) != os.path.normpath(os.fspath(path)):
        raise CalibFormatError(f"{path}: name the first camera's file; {first} and {second} "
                               f"are written")
    housing, *ports = _port_params(rig) if has_port else ("NONE", None, None)
    R_rel, t_rel = _relative(rig)
    texts = (_calibmar_text(rig.left, ports[0], rig.left.size, (np.eye(3), np.zeros(3)), model,
                            housing),
             _calibmar_text(rig.right, ports[1], rig.left.size, (R_rel, t_rel), model, housing))
    for target, text in zip((first, second), texts):
        atomic_write_text(target, text)
    return first, second


_LIST = re.compile(r"^\[(.*)\]$")


def _read_text(path) -> str:
    """The text of a calibration file; :class:`CalibFormatError` naming it when unreadable."""
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.read()
    except FileNotFoundError:
        raise CalibFormatError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibFormatError(f"{path}: cannot read ({exc})") from None


def _parse_calibmar(path) -> dict:
    text = _read_text(path)
    values = {}
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        key, sep, value = line.partition(":")
        key, value = key.strip(), value.strip()
        if not sep or not key:
            raise CalibFormatError(f"{path}: line {number} is not 'key: value': {line[:60]!r}")
        if key in values:
            raise CalibFormatError(f"{path}: {key} given twice (line {number})")
        match = _LIST.match(value)
        if match:
            try:
                value = [float(v) for v in match.group(1).split(",") if v.strip()]
            except ValueError:
                raise CalibFormatError(f"{path}: line {number}: {key} is not a list of "
                                       f"numbers") from None
        values[key] = value
    for key in ("model", "parameters", "width", "height", "non_svp_model"):
        if key not in values:
            raise CalibFormatError(f"{path}: no {key} (not a calibmar calibration.yaml)")
    try:
        values["size"] = (int(values["width"]), int(values["height"]))
    except (TypeError, ValueError):
        raise CalibFormatError(f"{path}: width and height must be whole numbers") from None
    for key, count in (("cam_to_world_rotation_rowmajor", 9), ("cam_to_world_translation", 3)):
        value = values.get(key)
        if value is not None and (not isinstance(value, list) or len(value) != count):
            raise CalibFormatError(f"{path}: {key} must hold {count} numbers")
    if not isinstance(values["parameters"], list):
        raise CalibFormatError(f"{path}: parameters must be a list [p1, p2, …]")
    return values


def _calibmar_pose(values, path, required: bool):
    R, t = values.get("cam_to_world_rotation_rowmajor"), values.get("cam_to_world_translation")
    if R is None or t is None:
        if required:
            raise CalibFormatError(f"{path}: no stereo pose (cam_to_world_rotation_rowmajor, "
                                   f"cam_to_world_translation): not the second camera of a "
                                   f"calibmar stereo calibration")
        return np.eye(3), np.zeros(3)
    R = np.array(R, dtype=np.float64).reshape(3, 3)
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-8) or np.linalg.det(R) < 0:
        raise CalibFormatError(f"{path}: cam_to_world_rotation_rowmajor is not a rotation")
    return R, np.array(t, dtype=np.float64) / METRES_PER_MM


def read_calibmar(path) -> dict:
    """A calibmar stereo calibration (``path`` either of its two files) as the dictionary of
    :func:`synth.products.dataset.read_calib`. ``non_svp_model: NONE`` in both files is an in-air
    calibration (``has_port`` False, the index-matched air port); CalibFormatError names the
    file and what is wrong."""
    first, second = calibmar_partner(path)
    for name in (first, second):
        if not os.path.isfile(name):
            raise CalibFormatError(f"{name}: no such file (a calibmar stereo calibration is two "
                                   f"files: {os.path.basename(first)} for the first camera and "
                                   f"{os.path.basename(second)} for the second)")
    files = {"left": (first, _parse_calibmar(first)), "right": (second, _parse_calibmar(second))}
    sizes = {view: values["size"] for view, (_, values) in files.items()}
    if sizes["left"] != sizes["right"]:
        raise CalibFormatError(f"{second}: image size {sizes['right']} differs from {first}'s "
                               f"{sizes['left']}; this project's calibration has one image size")
    cams, poses = {}, {}
    models = tuple(distortion_model_of(str(files[view][1]["model"])) for view in ("left", "right"))
    for view, (name, values) in files.items():
        K, D = opencv_camera(str(values["model"]), values["parameters"], name)
        cams[view] = (K, D)
        poses[view] = _calibmar_pose(values, name, required=view == "right")
    R, T = _from_relative(poses["left"], poses["right"])
    housings = {view: str(values["non_svp_model"]) for view, (_, values) in files.items()}
    if housings["left"] == housings["right"] == "NONE":
        return calib_dict(sizes["left"], *cams["left"], *cams["right"], R, T, _air_port(), False,
                          first, models)
    for view, (name, _) in files.items():
        if housings[view] not in HOUSINGS or housings[view] != housings["left"]:
            raise CalibFormatError(f"{name}: non_svp_model {housings[view]}; this project reads "
                                   f"FLATPORT or DOMEPORT (both files alike) or NONE (both, in "
                                   f"air)")
    housing = housings["left"]
    params = {view: _check_port(values.get("non_svp_parameters") or [], name, housing)
              for view, (name, values) in files.items()}
    left = Camera(cams["left"][0], sizes["left"], R=poses["left"][0], t=poses["left"][1])
    right = Camera(cams["right"][0], sizes["left"], R=poses["right"][0], t=poses["right"][1])
    if housing == "DOMEPORT":
        return calib_dict(sizes["left"], *cams["left"], *cams["right"], R, T,
                          _dome_pair(params["left"], params["right"], left, right), True, first,
                          models)
    port = _flat_ports(params["left"], params["right"], left, right)
    return calib_dict(sizes["left"], *cams["left"], *cams["right"], R, T, port, True, first,
                      models)


# ---------------------------------------------------------------------------------------------
# the COLMAP fork: cameras.txt and rig_config.json
# ---------------------------------------------------------------------------------------------
def _colmap_header(count: int, which: str, poses: str) -> list:
    """The comment lines that open a ``cameras.txt`` of ``count`` cameras (``which``: how they
    are numbered; ``poses``: "the stereo pose is" / "the poses are")."""
    return ["# Camera list with one line of data per camera:",
            "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[] OPTIONAL[REFRAC_MODEL REFRAC_PARAMS[]]",
            f"# Number of cameras: {count}",
            "# Written by refractive-stereo for the refractive COLMAP fork (MDSKiel/"
            f"colmap_underwater): {which};",
            f"# {poses} in {COLMAP_RIG_NAME} beside this file. Pixels: COLMAP's, the "
            "centre of the top-left pixel is (0.5, 0.5) (cx, cy = OpenCV's + 0.5).",
            "# FLATPORT: Nx Ny Nz (unit normal in that camera's frame) int_dist int_thick "
            "(metres) na ng nw.",
            "# DOMEPORT: Cx Cy Cz (dome centre in that camera's frame) int_radius int_thick "
            "(metres) na ng nw.",
            f"# WARNING: {PYCOLMAP_WARNING}."]


def write_colmap(path, rig: StereoRig, has_port: bool = True,
                 model: str | None = None) -> tuple[str, str]:
    """Write ``rig`` as the COLMAP fork's ``cameras.txt`` at ``path`` (camera 1 = left,
    2 = right, each with its FLATPORT unless ``has_port`` is False) and ``rig_config.json``
    beside it (the stereo pose), atomically. Returns both paths."""
    path = os.fspath(path)
    housing, *ports = _port_params(rig) if has_port else ("NONE", None, None)
    lines = _colmap_header(2, "camera 1 is the left (reference) camera, 2 the right",
                           "the stereo pose is")
    for camera_id, (camera, port) in enumerate(zip((rig.left, rig.right), ports), start=1):
        name, params = colmap_camera(camera, model)
        items = [str(camera_id), name, str(int(rig.left.size[0])), str(int(rig.left.size[1]))]
        items += [repr(v) for v in params]
        if port is not None:
            items += [housing] + [repr(float(v)) for v in port]
        lines.append(" ".join(items))  # single spaces: the fork's reader splits on ' '
    R_rel, t_rel = _relative(rig)
    R_cam = R_rel.T  # cam_from_rig of the right camera (the rig frame is the left camera's)
    t_cam = -R_cam @ t_rel * METRES_PER_MM
    x, y, z, w = Rotation.from_matrix(R_cam).as_quat()
    quat = [float(w), float(x), float(y), float(z)]
    if quat[0] < 0:
        quat = [-q for q in quat]
    config = [{"ref_camera_id": 1, "cameras": [
        {"camera_id": 1, "image_prefix": IMAGE_PREFIXES[0],
         "cam_from_rig_rotation": [1.0, 0.0, 0.0, 0.0], "cam_from_rig_translation": [0.0] * 3},
        {"camera_id": 2, "image_prefix": IMAGE_PREFIXES[1], "cam_from_rig_rotation": quat,
         "cam_from_rig_translation": [float(v) for v in t_cam]}]}]
    rig_path = os.path.join(os.path.dirname(path), COLMAP_RIG_NAME)
    atomic_write_text(path, "\n".join(lines) + "\n")
    atomic_write_text(rig_path, json.dumps(config, indent=2) + "\n")
    return path, rig_path


def write_colmap_rig(path, rig) -> tuple[str, str]:
    """Write a rig of N cameras (:class:`measure.stereo.multirig.MultiRig`) as the COLMAP
    fork's ``cameras.txt`` at ``path`` (camera k + 1 = the rig's camera k, each with its own
    FLATPORT or DOMEPORT in its frame, none for a camera in air) and ``rig_config.json`` beside
    it (every camera's ``cam_from_rig`` pose; the rig frame is the first camera's, the reference
    frame), atomically. A two-camera rig is written as :func:`write_colmap` writes it."""
    from measure.geometry.flatport_format import view_port_params

    path = os.fspath(path)
    size = rig.cameras[0].size
    lines = _colmap_header(len(rig.cameras), "camera k + 1 is the rig's camera k ("
                           + ", ".join(f"{k + 1} {name}" for k, name in enumerate(rig.names))
                           + ")", "the poses are")
    cameras = []
    for k, (camera, port) in enumerate(zip(rig.cameras, rig.ports)):
        try:
            housing, params = view_port_params(port, camera)
        except ValueError as exc:
            raise CalibFormatError(f"{rig.names[k]}: {exc}") from None
        name, values = colmap_camera(camera)
        items = [str(k + 1), name, str(int(size[0])), str(int(size[1]))]
        items += [repr(v) for v in values]
        if housing is not None:
            items += [housing] + [repr(float(v)) for v in params]
        lines.append(" ".join(items))
        R_cam = camera.R.T  # cam_from_rig: the rig frame is the reference frame
        t_cam = -R_cam @ camera.t * METRES_PER_MM
        x, y, z, w = Rotation.from_matrix(R_cam).as_quat()
        quat = [float(w), float(x), float(y), float(z)]
        if quat[0] < 0:
            quat = [-q for q in quat]
        cameras.append({"camera_id": k + 1, "image_prefix": f"{rig.names[k]}/",
                        "cam_from_rig_rotation": quat,
                        "cam_from_rig_translation": [float(v) for v in t_cam]})
    rig_path = os.path.join(os.path.dirname(path), COLMAP_RIG_NAME)
    atomic_write_text(path, "\n".join(lines) + "\n")
    atomic_write_text(rig_path, json.dumps([{"ref_camera_id": 1, "cameras": cameras}],
                                           indent=2) + "\n")
    return path, rig_path


def read_colmap_rig(path):
    """The rig of N cameras (:class:`measure.stereo.multirig.MultiRig`, the reference frame
    the rig configuration's reference camera's) of the COLMAP fork's ``cameras.txt`` and the
    ``rig_config.json`` beside it; CalibFormatError names the file and what is wrong."""
    from measure.geometry.flatport_format import one_port_per_plane, view_port_from_params
    from measure.stereo.multirig import MultiRig

    cameras = _parse_cameras_txt(path)
    ref, poses = _read_rig_config(os.path.join(os.path.dirname(os.fspath(path)),
                                               COLMAP_RIG_NAME), cameras)
    R_ref, t_ref = poses[ref]
    ids = [ref] + sorted(i for i in cameras if i != ref)
    built, ports = [], []
    for camera_id in ids:
        entry = cameras[camera_id]
        R, t = poses[camera_id]
        camera = Camera(entry["K"], entry["size"], dist=entry["D"],
                        R=R_ref.T @ R, t=R_ref.T @ (t - t_ref), distortion_model=entry["model"])
        try:
            ports.append(view_port_from_params(entry["housing"], entry["port"], camera))
        except ValueError as exc:
            raise CalibFormatError(f"{path}: camera {camera_id}: {exc}") from None
        built.append(camera)
    try:
        return MultiRig(built, one_port_per_plane(ports), [f"cam{k}" for k in range(len(built))])
    except ValueError as exc:
        raise CalibFormatError(f"{path}: {exc}") from None


def colmap_cameras(path) -> int | None:
    """How many cameras the COLMAP ``cameras.txt`` ``path`` lists (None: not readable as one)."""
    try:
        return len(_parse_cameras_txt(path))
    except (CalibFormatError, OSError, ValueError):
        return None


def _parse_cameras_txt(path) -> dict:
    text = _read_text(path)
    cameras = {}
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        where = f"{path}: line {number}"
        if len(parts) < 4 or not all(p.isdigit() for p in (parts[0], parts[2], parts[3])):
            raise CalibFormatError(f"{where}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS…")
        camera_id, model = int(parts[0]), parts[1]
        if model not in COLMAP_MODELS:
            raise CalibFormatError(f"{where}: unknown or unsupported camera model {model!r} "
                                   f"(read: {', '.join(COLMAP_MODELS)})")
        count = len(COLMAP_MODELS[model])
        rest = parts[4:]
        port = None
        housing = None
        if len(rest) > count:
            housing = rest[count]
            if housing not in HOUSINGS:
                raise CalibFormatError(f"{where}: {model} takes {count} parameters; then "
                                       f"FLATPORT and 8 numbers may follow (or DOMEPORT and "
                                       f"8), found {rest[count]!r}")
            port = rest[count + 1:]
        try:
            params = [float(v) for v in rest[:count]]
            port = None if port is None else [float(v) for v in port]
        except ValueError:
            raise CalibFormatError(f"{where}: parameters must be numbers") from None
        if len(params) != count:
            raise CalibFormatError(f"{where}: {model} needs {count} parameters "
                                   f"({', '.join(COLMAP_MODELS[model])}), got {len(params)}")
        if camera_id in cameras:
            raise CalibFormatError(f"{where}: camera {camera_id} given twice")
        K, D = opencv_camera(model, params, where)
        cameras[camera_id] = {"size": (int(parts[2]), int(parts[3])), "K": K, "D": D,
                              "model": distortion_model_of(model),
                              "housing": housing,
                              "port": None if port is None else _check_port(port, where,
                                                                            housing)}
    return cameras


def _read_rig_config(path, cameras) -> tuple[int, dict]:
    """``(ref_camera_id, {camera_id: camera-to-rig (R, t mm)})`` from ``rig_config.json``."""
    try:
        with open(path, encoding="utf-8") as fh:
            config = json.load(fh)
    except FileNotFoundError:
        raise CalibFormatError(f"{path}: no such file (a cameras.txt holds no stereo pose; "
                               f"this project reads it from the COLMAP fork's rig "
                               f"configuration beside it)") from None
    except (OSError, ValueError) as exc:
        raise CalibFormatError(f"{path}: not valid JSON ({exc})") from None
    try:
        if not isinstance(config, list) or len(config) != 1:
            raise CalibFormatError(f"{path}: expected a list of one rig")
        ref = int(config[0]["ref_camera_id"])
        poses = {}
        for entry in config[0]["cameras"]:
            camera_id = int(entry["camera_id"])
            if "cam_from_rig_rotation" not in entry or "cam_from_rig_translation" not in entry:
                raise CalibFormatError(f"{path}: camera {camera_id} has no cam_from_rig_rotation "
                                       f"and cam_from_rig_translation (the relative pose)")
            w, x, y, z = (float(v) for v in entry["cam_from_rig_rotation"])
            t = np.array([float(v) for v in entry["cam_from_rig_translation"]], dtype=np.float64)
            norm = float(np.linalg.norm([w, x, y, z]))
            if t.shape != (3,) or not np.all(np.isfinite(t)) or not abs(norm - 1.0) <= 1e-6:
                raise CalibFormatError(f"{path}: camera {camera_id}: the rotation must be a unit "
                                       f"quaternion (w, x, y, z) and the translation 3 numbers")
            R_cam = Rotation.from_quat([x, y, z, w]).as_matrix()
            poses[camera_id] = (R_cam.T, -R_cam.T @ t / METRES_PER_MM)
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, CalibFormatError):
            raise
        raise CalibFormatError(f"{path}: not a COLMAP rig configuration ({exc!r})") from None
    if set(poses) != set(cameras) or ref not in poses:
        raise CalibFormatError(f"{path}: names cameras {sorted(poses)} (reference {ref}), "
                               f"cameras.txt {sorted(cameras)}")
    return ref, poses


def read_colmap(path) -> dict:
    """The COLMAP fork's ``cameras.txt`` (two cameras) with ``rig_config.json`` beside it as the
    dictionary of :func:`synth.products.dataset.read_calib`; the reference camera is the left one.
    Cameras without FLATPORT are an in-air calibration. CalibFormatError names the file."""
    path = os.fspath(path)
    cameras = _parse_cameras_txt(path)
    if len(cameras) != 2:
        raise CalibFormatError(f"{path}: a rig of {len(cameras)} camera(s), not a stereo pair: "
                               f"this reads two cameras")
    ref, poses = _read_rig_config(os.path.join(os.path.dirname(path), COLMAP_RIG_NAME), cameras)
    other = next(c for c in cameras if c != ref)
    left, right = cameras[ref], cameras[other]
    if left["size"] != right["size"]:
        raise CalibFormatError(f"{path}: cameras {ref} and {other} have different image sizes "
                               f"{left['size']} and {right['size']}; this project's calibration "
                               f"has one image size")
    R, T = _from_relative(poses[ref], poses[other])
    models = (left["model"], right["model"])
    if left["port"] is None and right["port"] is None:
        return calib_dict(left["size"], left["K"], left["D"], right["K"], right["D"], R, T,
                          _air_port(), False, path, models)
    if left["port"] is None or right["port"] is None:
        raise CalibFormatError(f"{path}: one camera has a {left['housing'] or right['housing']} "
                               f"and the other none")
    if left["housing"] != right["housing"]:
        raise CalibFormatError(f"{path}: camera {ref} has a {left['housing']}, camera {other} a "
                               f"{right['housing']}; both cameras need the same housing")
    cam_left = Camera(left["K"], left["size"], R=poses[ref][0], t=poses[ref][1])
    cam_right = Camera(right["K"], left["size"], R=poses[other][0], t=poses[other][1])
    if left["housing"] == "DOMEPORT":
        return calib_dict(left["size"], left["K"], left["D"], right["K"], right["D"], R, T,
                          _dome_pair(left["port"], right["port"], cam_left, cam_right), True,
                          path, models)
    port = _flat_ports(left["port"], right["port"], cam_left, cam_right)
    return calib_dict(left["size"], left["K"], left["D"], right["K"], right["D"], R, T, port,
                      True, path, models)


# ---------------------------------------------------------------------------------------------
# by content; all formats at once
# ---------------------------------------------------------------------------------------------
_CALIBMAR_KEY = re.compile(r"^\s*(model|non_svp_model)\s*:", re.M)
_COLMAP_LINE = re.compile(r"^\d+\s+[A-Z][A-Z_]*\s+\d+\s+\d+(\s|$)")


def calib_format(path) -> str:
    """``"opencv"`` (this project's ``calib.yaml``, OpenCV FileStorage), ``"calibmar"`` or
    ``"colmap"`` (``cameras.txt``), by the file's content; ``"opencv"`` when unsure (OpenCV's
    reader then says what is wrong)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(65536).decode("utf-8", "replace")
    except OSError:
        return "opencv"
    stripped = head.lstrip()
    if stripped.startswith(("%YAML", "<?xml", "<opencv_storage", "{")):
        return "opencv"
    if _CALIBMAR_KEY.search(head):
        return "calibmar"
    for line in head.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            return "colmap" if _COLMAP_LINE.match(line) else "opencv"
    return "opencv"


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
    atomic_write_text(calibmar, _calibmar_text(camera, params, camera.size,
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
    import cv2

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise CalibFormatError(f"{path}: no such file")
    kind = calib_format(path)
    out = {"rms_px": None, "lens_model": None, "covariance": None, "covariance_photos": None,
           "format": kind}
    if kind == "calibmar":
        values = _parse_calibmar(path)
        if str(values["non_svp_model"]) != "NONE":
            raise CalibFormatError(f"{path}: non_svp_model {values['non_svp_model']}: already "
                                   f"a housing calibration; give the camera's in-air "
                                   f"calibration (non_svp_model: NONE)")
        if values.get("cam_to_world_translation") and np.any(values["cam_to_world_translation"]):
            raise CalibFormatError(f"{path}: the second camera of a calibmar stereo "
                                   f"calibration; give one camera's file")
        K, D = opencv_camera(str(values["model"]), values["parameters"], path)
        size = values["size"]
        model = distortion_model_of(str(values["model"]))
    elif kind == "colmap":
        cameras = _parse_cameras_txt(path)
        if len(cameras) != 1:
            raise CalibFormatError(f"{path}: {len(cameras)} cameras; one camera's housing is "
                                   f"calibrated from a cameras.txt of one camera")
        (only,) = cameras.values()
        if only["housing"] is not None:
            raise CalibFormatError(f"{path}: the camera has a {only['housing']}: already a "
                                   f"housing calibration; give the camera's in-air calibration")
        K, D, size, model = only["K"], only["D"], only["size"], only["model"]
    else:
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
            out["covariance_photos"] = read_covariance_node(path,
                                                            fs.getNode("covariance_photos"))
        finally:
            fs.release()
        if K is None or np.shape(K) != (3, 3) or D is None or not np.all(np.isfinite(K)):
            raise CalibFormatError(f"{path}: camera_matrix must be 3x3 and "
                                   f"distortion_coefficients a row of numbers")
    dist = np.asarray(D, dtype=np.float64).ravel()
    try:
        out["camera"] = Camera(np.asarray(K, dtype=np.float64), size,
                               dist=dist if np.any(dist) or model == FISHEYE else None,
                               distortion_model=model)
    except ValueError as exc:
        raise CalibFormatError(f"{path}: {exc}") from None
    out["size"] = tuple(size)
    return out


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


def write_calibration_formats(directory, rig: StereoRig, has_port: bool = True) -> list[str]:
    """Write ``rig`` beside a ``calib.yaml`` in ``directory`` as calibmar's stereo pair
    (:data:`CALIBMAR_NAME` and its ``_stereo`` partner) and the COLMAP fork's ``cameras.txt``
    with ``rig_config.json``; every file atomically. Returns the paths written (4)."""
    directory = os.fspath(directory)
    written = list(write_calibmar(os.path.join(directory, CALIBMAR_NAME), rig, has_port))
    written += write_colmap(os.path.join(directory, COLMAP_CAMERAS_NAME), rig, has_port)
    return written


__all__ = ["CALIBMAR_NAME", "COLMAP_CAMERAS_NAME", "COLMAP_MODELS", "COLMAP_PIXEL_OFFSET",
           "COLMAP_RIG_NAME", "CalibFormatError", "IMAGE_PREFIXES", "PORT_TOLERANCE",
           "PYCOLMAP_WARNING", "calib_dict", "calib_format", "calibmar_partner", "colmap_camera",
           "distortion_model_of",
           "opencv_camera", "read_calibmar", "read_colmap", "read_single_camera", "stereo_extrinsics",
           "colmap_cameras", "read_colmap_rig", "read_covariance_node", "write_calibmar",
           "write_calibration_formats", "write_colmap", "write_colmap_rig", "write_single_camera"]
