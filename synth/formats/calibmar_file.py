"""calibmar's stereo calibration: two YAML files (``<name>.yaml``, ``<name>_stereo.yaml``),
written from a rig and read back into one exactly (:mod:`synth.formats.calib_formats` has the
format)."""

from __future__ import annotations

import os
import re

import numpy as np

from measure import Camera, Rig
from measure.geometry.flatport_format import METRES_PER_MM

from synth.infra.fileio import atomic_write_text
from synth.formats.calib_common import (COLMAP_MODELS, HOUSINGS, PARAMS_INFO, CalibFormatError,
                                        air_flat_port, calib_dict, check_port_params,
                                        colmap_camera, distortion_model_of, dome_pair_from_params,
                                        flat_ports_from_params, format_numbers, opencv_camera,
                                        poses_from_relative, read_text_file, relative_pose,
                                        rig_port_params)


def calibmar_partner(path) -> tuple[str, str]:
    """``(first, second)``: the two files of a calibmar stereo calibration, from either one
    (``NAME.yaml`` and ``NAME_stereo.yaml``)."""
    path = os.fspath(path)
    stem, ext = os.path.splitext(path)
    if stem.endswith("_stereo"):
        return stem[: -len("_stereo")] + ext, path
    return path, stem + "_stereo" + ext


def calibmar_text(camera: Camera, port_params, size, pose, model,
                   housing: str = "FLATPORT") -> str:
    name, params = colmap_camera(camera, model)
    R, t = pose
    lines = [f"model: {name}", "# " + ", ".join(COLMAP_MODELS[name]),
             f"parameters: [{format_numbers(params)}]"]
    if port_params is None:
        lines += ["non_svp_model: NONE", "non_svp_parameters: []"]
    else:
        lines += [f"non_svp_model: {housing}", "# " + PARAMS_INFO[housing],
                  f"non_svp_parameters: [{format_numbers(port_params)}]"]
    lines += [f"width: {int(size[0])}", f"height: {int(size[1])}",
              "# written by refractive-stereo: COLMAP pixels (the centre of the top-left pixel "
              "is 0.5, 0.5), lengths in metres", "",
              "# stereo pose (camera to world, camera 3D point X_C can be transformed to 3D "
              "world point X_W by X_W = cam_to_world_rotation * X_C + cam_to_world_translation)",
              f"cam_to_world_rotation_rowmajor: [{format_numbers(np.asarray(R).ravel())}]",
              f"cam_to_world_translation: [{format_numbers(np.asarray(t) * METRES_PER_MM)}]"]
    return "\n".join(lines) + "\n"


def write_calibmar(path, rig: Rig, has_port: bool = True,
                   model: str | None = None) -> tuple[str, str]:
    """Write ``rig`` as calibmar's stereo pair ``path`` (left) and ``<stem>_stereo.yaml``
    (right), atomically; ``has_port=False`` writes ``non_svp_model: NONE`` (in air). Returns the
    two paths. CalibFormatError for a rig the format cannot hold (module docs)."""
    first, second = calibmar_partner(path)
    if os.path.normpath(first) != os.path.normpath(os.fspath(path)):
        raise CalibFormatError(f"{path}: name the first camera's file; {first} and {second} "
                               f"are written")
    housing, *ports = rig_port_params(rig) if has_port else ("NONE", None, None)
    R_rel, t_rel = relative_pose(rig)
    texts = (calibmar_text(rig.left, ports[0], rig.left.size, (np.eye(3), np.zeros(3)), model,
                            housing),
             calibmar_text(rig.right, ports[1], rig.left.size, (R_rel, t_rel), model, housing))
    for target, text in zip((first, second), texts):
        atomic_write_text(target, text)
    return first, second


_LIST = re.compile(r"^\[(.*)\]$")


def parse_calibmar(path) -> dict:
    text = read_text_file(path)
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
    :func:`synth.formats.calib_yaml.read_calib`. ``non_svp_model: NONE`` in both files is an in-air
    calibration (``has_port`` False, the index-matched air port); CalibFormatError names the
    file and what is wrong."""
    first, second = calibmar_partner(path)
    for name in (first, second):
        if not os.path.isfile(name):
            raise CalibFormatError(f"{name}: no such file (a calibmar stereo calibration is two "
                                   f"files: {os.path.basename(first)} for the first camera and "
                                   f"{os.path.basename(second)} for the second)")
    files = {"left": (first, parse_calibmar(first)), "right": (second, parse_calibmar(second))}
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
    R, T = poses_from_relative(poses["left"], poses["right"])
    housings = {view: str(values["non_svp_model"]) for view, (_, values) in files.items()}
    if housings["left"] == housings["right"] == "NONE":
        return calib_dict(sizes["left"], *cams["left"], *cams["right"], R, T, air_flat_port(), False,
                          first, models)
    for view, (name, _) in files.items():
        if housings[view] not in HOUSINGS or housings[view] != housings["left"]:
            raise CalibFormatError(f"{name}: non_svp_model {housings[view]}; this project reads "
                                   f"FLATPORT or DOMEPORT (both files alike) or NONE (both, in "
                                   f"air)")
    housing = housings["left"]
    params = {view: check_port_params(values.get("non_svp_parameters") or [], name, housing)
              for view, (name, values) in files.items()}
    left = Camera(cams["left"][0], sizes["left"], R=poses["left"][0], t=poses["left"][1])
    right = Camera(cams["right"][0], sizes["left"], R=poses["right"][0], t=poses["right"][1])
    if housing == "DOMEPORT":
        return calib_dict(sizes["left"], *cams["left"], *cams["right"], R, T,
                          dome_pair_from_params(params["left"], params["right"], left, right), True, first,
                          models)
    port = flat_ports_from_params(params["left"], params["right"], left, right)
    return calib_dict(sizes["left"], *cams["left"], *cams["right"], R, T, port, True, first,
                      models)


# ---------------------------------------------------------------------------------------------
# the COLMAP fork: cameras.txt and rig_config.json
# ---------------------------------------------------------------------------------------------
