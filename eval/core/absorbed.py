"""The absorbed baseline: the underwater cameras calibrated as ordinary pinhole cameras with
distortion (OpenCV ``calibrateCamera`` + ``stereoCalibrate`` on underwater board photos), the
focal lengths and distortion "absorbing" the port — what most people who measure under water do
today, and what the paper's introduction calls approximate.

Its rig has no port (an index-matched one: every ray is a pinhole ray) and its frame is a
virtual one: the calibration puts the cameras where pinhole cameras would best explain the
refracted corners, not at their centres. Its points are therefore scored three ways beside every
other method's (raw dP, dP after the best rigid alignment, the length error of target pairs:
:func:`eval.core.cloud_metrics.length_errors`).

Where the calibration comes from: ``--absorbed-calib FILE`` (a calibration without a port, as
``eval calibrate --model absorbed`` or ``--air`` writes it), or — without a file — the scene's own
boards projected through the scene's true port by the analytic forward model (the poses, board
and seed that ``synth boards SCENE`` renders with its defaults), without pixel noise: the
absorbed model's error is then its model error alone.

Units: millimetres and pixels; frames as docs/architecture.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from measure.calibration.air import (LENS_MODEL_GAIN, LENS_MODEL_ORDER, CalibrationError,
                                     Detections, calibrate_in_air)
from measure.calibration.board import Board
from synth.products.boards import (DEFAULT_DISTANCE_RANGE_MM, DEFAULT_MAX_TILT_DEG, DEFAULT_POSES,
                                   corner_pixels, sample_poses)
from synth.infra.cli import DEFAULT_BOARD

#: The method's name in ``--methods`` and the reports.
ABSORBED = "absorbed"
#: The lens model of the absorbed calibration: ``auto`` fits the stereo pair with each model of
#: :data:`measure.calibration.air.LENS_MODEL_ORDER` and keeps a richer one only when it lowers
#: the *stereo* RMS by :data:`measure.calibration.air.LENS_MODEL_GAIN` or more — under water a
#: richer model fits each camera better and can still make ``stereoCalibrate`` diverge (the
#: rational model did on the paper's rig: stereo RMS 3e10 px).
ABSORBED_LENS_MODEL = "auto"


@dataclass(frozen=True)
class AbsorbedCalibration:
    """``rig`` (pinhole cameras, no port) and ``summary`` (where it came from, its lens models,
    RMS and stereo RMS in px, the poses and distance range: the report's ``absorbed``)."""

    rig: object
    summary: dict


def default_board() -> Board:
    """The board ``synth boards`` renders by default."""
    cols, rows = (int(v) for v in DEFAULT_BOARD["squares"].split("x"))
    return Board(DEFAULT_BOARD["board"], (cols, rows), float(DEFAULT_BOARD["square_mm"]))


def board_corner_detections(rig, board: Board, poses) -> Detections:
    """Every corner of ``board`` at each of ``poses`` (:class:`synth.products.boards.BoardPose`)
    projected through ``rig``'s port into both cameras (the Fermat forward model, px)."""
    views = corner_pixels(rig, board, poses)
    return Detections([[np.arange(len(world))] * 2 for world, _ in views],
                      [list(pixels) for _, pixels in views])


def analytic_absorbed_calibration(rig, seed: int = 0, board: Board | None = None,
                                  n_poses: int = DEFAULT_POSES,
                                  distance_range=DEFAULT_DISTANCE_RANGE_MM,
                                  lens_model: str = ABSORBED_LENS_MODEL) -> AbsorbedCalibration:
    """The absorbed calibration of the cameras behind ``rig``'s port from board corners projected
    analytically (module docs); ValueError (its message says why) when the poses or the fit
    cannot be had."""
    board = default_board() if board is None else board
    poses = sample_poses(rig, board, n_poses, seed, True, distance_range, DEFAULT_MAX_TILT_DEG)
    detections = board_corner_detections(rig, board, poses)
    air, stereo_rms = calibrate_absorbed(board, detections, rig.left.size, lens_model)
    return AbsorbedCalibration(air.rig, {
        "source": (f"the scene's boards projected through its port (analytic, no noise): "
                   f"{n_poses} poses at {distance_range[0]:g}-{distance_range[1]:g} mm, "
                   f"{board.squares[0]}x{board.squares[1]} squares of {board.square_mm:g} mm, "
                   f"seed {seed}"),
        "distance_range_mm": [float(v) for v in distance_range],
        "lens_model": air.lens_models["left"]["model"],
        "stereo_rms_px_by_lens_model": stereo_rms,
        "rms_px": air.rms_px, "stereo_rms_px": air.stereo_rms_px,
        "poses": air.poses_used, "stereo_left_out": list(air.stereo_left_out)})


def calibrate_absorbed(board: Board, detections: Detections, size,
                       lens_model: str = ABSORBED_LENS_MODEL, stereo_intrinsics: str = "fixed"):
    """The absorbed calibration of underwater board ``detections``: both cameras with one lens
    model (``auto``: :data:`ABSORBED_LENS_MODEL`) and the stereo pose (``stereo_intrinsics``:
    :data:`measure.calibration.air.STEREO_INTRINSICS`). Returns ``(AirCalibration, {model:
    stereo RMS px or None where the fit failed})``; raises
    :class:`measure.calibration.air.CalibrationError` when no model gives a stereo fit."""
    order = LENS_MODEL_ORDER if lens_model == "auto" else (lens_model,)
    best, stereo_rms, failures = None, {}, []
    for model in order:
        try:
            air = calibrate_in_air(board, detections, size, lens_model=model,
                                   stereo_intrinsics=stereo_intrinsics)
        except CalibrationError as exc:
            stereo_rms[model] = None
            failures.append(f"{model}: {exc}")
            continue
        stereo_rms[model] = air.stereo_rms_px
        if not np.isfinite(air.stereo_rms_px):
            continue
        if best is None or air.stereo_rms_px < (1 - LENS_MODEL_GAIN) * best.stereo_rms_px:
            best = air
    if best is None:
        raise CalibrationError("no lens model gave a stereo fit (" + "; ".join(failures) + ")")
    return best, stereo_rms


def read_absorbed_calibration(path: str, size) -> AbsorbedCalibration:
    """An absorbed calibration from a calibration file without a port (ValueError naming the
    file when it has one, or another image size)."""
    from synth.products.dataset import DatasetError, read_calib

    try:
        calib = read_calib(path)
    except DatasetError as exc:
        raise ValueError(f"--absorbed-calib {exc} (expected a stereo calib.yaml without a port: "
                         f"eval calibrate DIR --model absorbed)") from None
    rig = calib["rig"]
    if rig.port.refracts:
        raise ValueError(f"--absorbed-calib {path}: the file calibrates "
                         f"{rig.port.description}; the absorbed baseline is a calibration "
                         f"without a port (eval calibrate --model absorbed)")
    if tuple(calib["size"]) != tuple(size):
        raise ValueError(f"--absorbed-calib {path}: image size {calib['size'][0]}x"
                         f"{calib['size'][1]} px, but the scene renders {size[0]}x{size[1]} px")
    return AbsorbedCalibration(rig, {"source": f"--absorbed-calib {path}"})


__all__ = ["ABSORBED", "AbsorbedCalibration", "analytic_absorbed_calibration",
           "board_corner_detections", "default_board", "read_absorbed_calibration"]
