"""The refractive COLMAP fork's ``cameras.txt`` with ``rig_config.json`` beside it (the rig's
relative poses), written from a rig and read back into one exactly, for two cameras or N
(:mod:`synth.formats.calib_formats` has the format)."""

from __future__ import annotations

import json
import os

import numpy as np
from scipy.spatial.transform import Rotation

from measure import Camera, Rig
from measure.geometry.flatport_format import METRES_PER_MM

from synth.infra.fileio import atomic_write_text
from synth.formats.calib_common import (COLMAP_MODELS, COLMAP_RIG_NAME, HOUSINGS, IMAGE_PREFIXES,
                                        PYCOLMAP_WARNING, CalibFormatError, air_flat_port,
                                        calib_dict, check_port_params, colmap_camera,
                                        distortion_model_of, dome_pair_from_params,
                                        flat_ports_from_params, opencv_camera,
                                        poses_from_relative, read_text_file, relative_pose,
                                        rig_port_params)


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


def write_colmap(path, rig: Rig, has_port: bool = True,
                 model: str | None = None) -> tuple[str, str]:
    """Write ``rig`` as the COLMAP fork's ``cameras.txt`` at ``path`` (camera 1 = left,
    2 = right, each with its FLATPORT unless ``has_port`` is False) and ``rig_config.json``
    beside it (the stereo pose), atomically. Returns both paths."""
    path = os.fspath(path)
    housing, *ports = rig_port_params(rig) if has_port else ("NONE", None, None)
    lines = _colmap_header(2, "camera 1 is the left (reference) camera, 2 the right",
                           "the stereo pose is")
    for camera_id, (camera, port) in enumerate(zip((rig.left, rig.right), ports), start=1):
        name, params = colmap_camera(camera, model)
        items = [str(camera_id), name, str(int(rig.left.size[0])), str(int(rig.left.size[1]))]
        items += [repr(v) for v in params]
        if port is not None:
            items += [housing] + [repr(float(v)) for v in port]
        lines.append(" ".join(items))  # single spaces: the fork's reader splits on ' '
    R_rel, t_rel = relative_pose(rig)
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
    """Write a rig of N cameras (:class:`measure.stereo.rig.Rig`) as the COLMAP
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
    """The rig of N cameras (:class:`measure.stereo.rig.Rig`, the reference frame
    the rig configuration's reference camera's) of the COLMAP fork's ``cameras.txt`` and the
    ``rig_config.json`` beside it; CalibFormatError names the file and what is wrong."""
    from measure.geometry.flatport_format import one_port_per_plane, view_port_from_params
    from measure.stereo.rig import Rig

    cameras = parse_cameras_txt(path)
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
        return Rig(built, one_port_per_plane(ports), [f"cam{k}" for k in range(len(built))])
    except ValueError as exc:
        raise CalibFormatError(f"{path}: {exc}") from None


def colmap_cameras(path) -> int | None:
    """How many cameras the COLMAP ``cameras.txt`` ``path`` lists (None: not readable as one)."""
    try:
        return len(parse_cameras_txt(path))
    except (CalibFormatError, OSError, ValueError):
        return None


def parse_cameras_txt(path) -> dict:
    text = read_text_file(path)
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
                              "port": None if port is None else check_port_params(port, where,
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
    dictionary of :func:`synth.formats.calib_yaml.read_calib`; the reference camera is the left one.
    Cameras without FLATPORT are an in-air calibration. CalibFormatError names the file."""
    path = os.fspath(path)
    cameras = parse_cameras_txt(path)
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
    R, T = poses_from_relative(poses[ref], poses[other])
    models = (left["model"], right["model"])
    if left["port"] is None and right["port"] is None:
        return calib_dict(left["size"], left["K"], left["D"], right["K"], right["D"], R, T,
                          air_flat_port(), False, path, models)
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
                          dome_pair_from_params(left["port"], right["port"], cam_left, cam_right), True,
                          path, models)
    port = flat_ports_from_params(left["port"], right["port"], cam_left, cam_right)
    return calib_dict(left["size"], left["K"], left["D"], right["K"], right["D"], R, T, port,
                      True, path, models)


# ---------------------------------------------------------------------------------------------
# by content; all formats at once
# ---------------------------------------------------------------------------------------------
