"""The in-air calibration that ``eval calibrate --intrinsics`` gives an underwater calibration: an
``--air`` boards folder (calibrated here with OpenCV) or a calibration file (``calib.yaml``,
calibmar's YAML, the COLMAP fork's ``cameras.txt``) with its covariance when it has one
(:func:`read_in_air`); an underwater calibration's port is said and not used
(:func:`underwater_note`); a photo folder or a calibration's output folder is refused with what
to give instead."""

from __future__ import annotations

import os

from eval.cli import CLIError


def is_photo_folder(path) -> bool:
    """Whether ``path`` is a photo folder (it holds ``left/`` and ``right/``)."""
    return all(os.path.isdir(os.path.join(path, sub)) for sub in ("left", "right"))


def underwater_note(path, calib) -> str | None:
    """The line that says an ``--intrinsics`` calibration is an underwater one (``calib``:
    :func:`synth.formats.calib_yaml.read_calib` of ``path``) whose port is not used; None for an
    in-air one."""
    if not calib["has_port"]:
        return None
    housing = getattr(calib["port"], "housing", "port")
    return (f"note: --intrinsics {path} is an underwater calibration (it holds a {housing}): its "
            f"cameras' intrinsics and stereo pose are used, its {housing} and the {housing}'s "
            f"part of its covariance are not (the housing is estimated here, from the design "
            f"options)")


def read_in_air(path, log):
    """``(rig, air calibration or None, boards or None, covariance or None)`` from
    ``--intrinsics``: a boards folder (calibrated here) or a calibration file (its covariance
    node, when it has one)."""
    from measure.calibration.air import calibrate_in_air, detect_boards
    from synth.products.boards import read_boards
    from synth.products.dataset import DatasetError, read_calib

    if os.path.isdir(path):
        boards = read_boards(path)
        if not boards.air:
            raise CLIError(f"--intrinsics {path}: these boards were rendered underwater; the "
                           f"in-air calibration needs --air boards")
        log(f"detect the boards in {path} and calibrate in air (OpenCV) …")
        detections = detect_boards(boards.board, boards.images)
        air = calibrate_in_air(boards.board, detections, boards.calib["size"])
        return air.rig, air, boards, air.covariance
    try:
        calib = read_calib(path)
    except DatasetError as exc:
        raise CLIError(f"--intrinsics {path}: {str(exc).removeprefix(f'{path}: ')}") from None
    covariance = calib.get("covariance")
    if calib["has_port"]:  # said, not silently ignored: only its cameras are used
        log(underwater_note(path, calib))
        if covariance is not None:  # the cameras' part of it: the port's is not a prior here
            covariance = _cameras_covariance(covariance)
    return calib["rig"], None, None, covariance


def _cameras_covariance(covariance):
    """The cameras' part of an underwater calibration's covariance (its port's and domes'
    parameters dropped), or None when nothing else is left."""
    import numpy as np

    from measure.stereo.rig_covariance import RigCovariance

    keep = [i for i, n in enumerate(covariance.names) if not n.startswith("port.")
            and ".dome_center" not in n]
    return (RigCovariance([covariance.names[i] for i in keep],
                          covariance.matrix[np.ix_(keep, keep)]) if keep else None)


def intrinsics_for_photos(path, log):
    """The in-air rig of ``--intrinsics`` for underwater photos and its covariance (or None): a
    calib.yaml, or an in-air boards folder (calibrated here)."""
    if os.path.isdir(path) and is_photo_folder(path):
        raise CLIError(f"--intrinsics {path}: a photo folder; calibrate it first (python -m eval "
                       f"calibrate {path} --air …) and give its calib.yaml")
    refuse_calibration_folder(path)
    rig, _, _, covariance = read_in_air(path, log)
    return rig, covariance


def refuse_calibration_folder(path) -> None:
    """``--intrinsics OUT``, the folder of a calibration rather than its file: named, with the
    file to give (it read as 'not a boards folder (… manifest.json)')."""
    if (os.path.isdir(path) and not os.path.exists(os.path.join(path, "manifest.json"))
            and os.path.isfile(os.path.join(path, "calib.yaml"))):
        raise CLIError(f"--intrinsics {path}: a folder holding a calibration; give the file, "
                       f"--intrinsics {os.path.join(path, 'calib.yaml')}")
