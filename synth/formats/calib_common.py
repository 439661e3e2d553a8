"""What calibmar's YAML files, the COLMAP fork's ``cameras.txt`` and one camera's files share
(:mod:`synth.formats.calib_formats` describes the formats and their conventions): the file
names, the COLMAP camera models and pixel offset, the error, the rig ↔ cameras and port
conversions, the checks of a port's parameters and which format a file is. Lengths in mm
inside the project, metres in the files; poses ``X_world = R·X_cam + t``."""

from __future__ import annotations

import re

import numpy as np

from measure import Camera, FlatPort, Rig, StereoRig
from measure.geometry.camera import BROWN_CONRADY, FISHEYE
from measure.geometry.dome import DomePair
from measure.geometry.flat_pair import FlatPair
from measure.geometry.flatport_format import (DOMEPORT_NAMES, FLATPORT_NAMES, from_domeport,
                                              from_flatport, housing_params)


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
PARAMS_INFO = {"FLATPORT": "Nx, Ny, Nz, int_dist, int_thick, na, ng, nw (Note that [Nx, Ny, "
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
    """The dictionary :func:`synth.formats.calib_yaml.read_calib` returns: ``size``, ``K1``, ``D1``, ``K2``,
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


def relative_pose(rig: Rig):
    """The right camera's camera-to-left pose ``(R, t mm)`` of any rig."""
    left, right = rig.left, rig.right
    return left.R.T @ right.R, left.R.T @ (right.t - left.t)


def poses_from_relative(pose_left, pose_right):
    """``(R, T)`` in OpenCV's stereo convention from two camera-to-world poses ``(R, t)``."""
    left = Camera(np.eye(3), (1, 1), R=pose_left[0], t=pose_left[1])
    right = Camera(np.eye(3), (1, 1), R=pose_right[0], t=pose_right[1])
    R, T = stereo_extrinsics(left, right)
    return R, T.reshape(3, 1)


def air_flat_port() -> FlatPort:
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


def check_port_params(params, where: str, housing: str = "FLATPORT") -> list[float]:
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


def dome_pair_from_params(params_left, params_right, left: Camera, right: Camera) -> DomePair:
    """The two domes of two ``DOMEPORT`` parameter lists (each in its camera's frame, the
    cameras' poses in any common frame), in the left camera's frame (mm)."""
    domes = []
    for params, camera in ((params_left, left), (params_right, right)):
        dome = from_domeport(params, camera)
        domes.append(dome.replace(center=left.R.T @ (dome.center - left.t)))
    return DomePair(*domes)


def flat_ports_from_params(params_left, params_right, left: Camera, right: Camera) -> FlatPort | FlatPair:
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


def rig_port_params(rig: Rig) -> tuple[str, list, list]:
    """``(housing, left parameters, right parameters)``: FLATPORT or DOMEPORT (metres)."""
    return housing_params(rig.port, rig.left, rig.right, CalibFormatError)


def format_numbers(values) -> str:
    return ", ".join(repr(float(v)) for v in values)


# ---------------------------------------------------------------------------------------------
# calibmar
# ---------------------------------------------------------------------------------------------
def read_text_file(path) -> str:
    """The text of a calibration file; :class:`CalibFormatError` naming it when unreadable."""
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.read()
    except FileNotFoundError:
        raise CalibFormatError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibFormatError(f"{path}: cannot read ({exc})") from None


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
