"""``eval calibrate DIR --model absorbed``: underwater boards or photos calibrated as ordinary
pinhole cameras — the port absorbed by focal length and distortion, what most practitioners do
(docs/absorbed.md).

DIR is a ``synth boards`` folder rendered behind the port or a photo folder (``left/``,
``right/``, taken underwater; the board from ``--squares``/``--square-mm``). OpenCV calibrates
both cameras and the stereo pose with each lens model and keeps the one the *stereo* fit favours
(:func:`eval.core.absorbed.calibrate_absorbed`: under water a richer model can fit each camera
better and still make ``stereoCalibrate`` diverge). Writes ``calib.yaml`` without a port (its
``model`` node says ``absorbed``; ``eval run --absorbed-calib``, ``eval score --absorbed-calib``
and ``eval measure --calib`` read it), ``report.json`` and ``report.md``: each camera's RMS, the
stereo RMS of every lens model, and — for a boards folder — the housing model's RMS on the same
corners with the rendered truth (the port model's own fit, for comparison).
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from eval.cli import CLIError

#: ``calib.yaml``'s ``model`` node of an absorbed calibration.
MODEL = "absorbed"
#: A stereo RMS above this (px) is a stereo fit that diverged.
DIVERGED_PX = 1e3


def _boards_or_photos(args, log):
    """``(board, detections, size, source, truth rig or None, names)``: the board detected in
    a boards folder's or a photo folder's pairs, or a pair's ``--detections`` read."""
    from measure.calibration.air import detect_boards
    from synth.products.boards import read_boards
    from synth.infra.cli import BOARD_OPTIONS, board_from_args, refuse_given

    from eval.calibrate.sources import read_detection_views
    from eval.core.photos import PhotoError, photo_folder, read_pairs

    if args.detections:
        board = board_from_args(args)
        names, detections, size = read_detection_views(args, board, 2)
        return board, detections, size, "detections", None, names
    if os.path.isfile(os.path.join(args.dir, "manifest.json")):
        refuse_given(args, BOARD_OPTIONS + ("encoding",),
                     f"to a boards folder ({args.dir}): its board.json defines the board and "
                     f"its images are 16-bit linear renders")
        boards = read_boards(args.dir)
        if boards.air:
            raise CLIError(f"--model absorbed: {args.dir} holds boards rendered in air; the "
                           f"absorbed calibration is of boards seen through the port")
        if "rig" not in boards.calib:
            raise CLIError(f"--model absorbed: {args.dir} holds boards of "
                           f"{len(boards.calib['names'])} cameras; the absorbed calibration is "
                           f"of a pair (a rig of N cameras is calibrated with its port)")
        log(f"detect the board in {len(boards.images)} pairs …")
        return (boards.board, detect_boards(boards.board, boards.images),
                tuple(boards.calib["size"]), "boards", boards.calib["rig"],
                [f"{k:02d}" for k in range(len(boards.images))])
    if args.board not in ("circles", "acircles") and (args.squares is None and args.inner_corners
                                                       is None or args.square_mm is None):
        raise CLIError(f"{args.dir} (photos): give the board: --squares COLSxROWS (or "
                       f"--inner-corners) and --square-mm")
    _refuse_other_photo_folders(args.dir)
    board = board_from_args(args)
    try:
        pairs = photo_folder(args.dir)
        log(f"read {len(pairs.names)} photo pairs from {args.dir} …")
        images, size = read_pairs(pairs, args.encoding)
    except PhotoError as exc:
        raise CLIError(str(exc)) from None
    log(f"detect the board in {len(images)} pairs …")
    return board, detect_boards(board, images), tuple(size), "photos", None, list(pairs.names)


def _refuse_other_photo_folders(path) -> None:
    """A photo folder that is not a pair's, named for what it is: photos of N cameras
    (``cam0/``, …) or one camera's photos (it said "no left and no right folder")."""
    from eval.calibrate.single import single_camera_folder
    from eval.core.photos import PhotoError, camera_folder_names

    if any(os.path.isdir(os.path.join(path, sub)) for sub in ("left", "right")):
        return
    try:
        cameras = camera_folder_names(path)
    except PhotoError:
        cameras = ()
    if cameras:
        raise CLIError(f"--model absorbed: {path} holds photos of {len(cameras)} cameras "
                       f"({', '.join(c + '/' for c in cameras)}); the absorbed calibration is of "
                       f"a pair, left/ and right/ (a rig of N cameras is calibrated with its "
                       f"port: --intrinsics)")
    if single_camera_folder(path):
        raise CLIError(f"--model absorbed: {path} holds one camera's photos; the absorbed "
                       f"calibration is of a pair, left/ and right/ (one camera's underwater "
                       f"photos as a pinhole camera that absorbs the port: eval calibrate "
                       f"{path} --air …; its housing: --intrinsics camera.yaml)")


def calibrate_absorbed_main(args, output, log, start) -> int:
    """The command (module docs); returns the exit code."""
    from measure.calibration.air import CalibrationError
    from synth.infra.fileio import atomic_write_json, atomic_write_text, jsonable
    from synth.products.dataset import write_calib

    from eval.calibrate.sources import repeat_lines, repeated_views, without_repeats
    from eval.core.absorbed import calibrate_absorbed

    board, detections, size, source, truth, names = _boards_or_photos(args, log)
    repeats = repeated_views(detections)
    detections = without_repeats(detections, repeats)
    log("calibrate as pinhole cameras (OpenCV calibrateCamera, stereoCalibrate; each lens "
        "model) …")
    try:
        air, stereo_rms = calibrate_absorbed(board, detections, size, args.lens or "auto",
                                             args.stereo_intrinsics or "fixed")
    except CalibrationError as exc:
        raise CLIError(f"{args.dir}: {exc}") from None
    model = air.lens_models["left"]["model"]
    right = air.rig.right
    baseline = float(np.linalg.norm(right.t))
    angle = float(np.degrees(np.arccos(np.clip((np.trace(right.R) - 1) / 2, -1, 1))))
    report = {"source": source, "dir": os.path.abspath(args.dir), "model": MODEL,
              "board": board.to_dict(), "pairs": len(names), "lens_model": model,
              "stereo_rms_px_by_lens_model": stereo_rms, "rms_px": air.rms_px,
              "stereo_rms_px": air.stereo_rms_px, "poses": air.poses_used,
              "baseline_mm": baseline, "rotation_deg": angle,
              "repeats": repeat_lines(repeats, names),
              "stereo_left_out": [names[k] for k in air.stereo_left_out]}
    if truth is not None:
        report["housing"] = _housing_rms(truth, board, detections, log)
    with output.staged() as tmp:
        write_calib(os.path.join(tmp, "calib.yaml"), air.rig, has_port=False,
                    extra={"model": MODEL, "lens_model": model})
        report["timings_s"] = {"total": time.perf_counter() - start}
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), _markdown(report))
    diverged = [m for m, rms in stereo_rms.items() if rms is None or rms > DIVERGED_PX]
    line = (f"absorbed calibration ({model} model): RMS left {air.rms_px['left']:.4f} px, right "
            f"{air.rms_px['right']:.4f} px, stereo {air.stereo_rms_px:.4f} px; baseline "
            f"{baseline:.2f} mm, the cameras turned {angle:.2f}° from each other")
    if diverged:
        line += f"; the stereo fit failed or diverged with {', '.join(diverged)}"
    if "housing" in report and report["housing"].get("rms_px") is not None:
        line += f"; the port model on the same corners: {report['housing']['rms_px']:.4f} px"
    print(line)
    for repeat in report["repeats"]:
        print(f"warning: {repeat}: left out (a photo given twice is one pose)")
    print(f"wrote {output.path} (calib.yaml without a port: eval run --absorbed-calib)")
    if not np.isfinite(air.stereo_rms_px) or air.stereo_rms_px > DIVERGED_PX:
        from synth.infra.cli import EXIT_CHECK_FAILED

        print(f"failed: {args.dir}: the stereo fit with the {model} model diverged (stereo RMS "
              f"{air.stereo_rms_px:.3g} px): choose another --lens (report in {output.path})",
              file=sys.stderr)
        return EXIT_CHECK_FAILED
    return 0


def _housing_rms(truth, board, detections, log) -> dict:
    """The port model's RMS on the same corners: the housing fit started from the rendered
    truth (``measure.calibration.housing.calibrate_housing``), for the comparison."""
    from measure.calibration.air import CalibrationError
    from measure.calibration.housing import calibrate_housing

    log("the port model on the same corners (housing fit from the rendered truth) …")
    try:
        fit = calibrate_housing(truth, board, detections)
    except (CalibrationError, ValueError) as exc:
        return {"rms_px": None, "note": str(exc)}
    return {"rms_px": float(fit.rms_px), "note": "the housing fit (the port model) started "
                                                 "from the rendered rig"}


def _markdown(report: dict) -> str:
    models = ", ".join(f"{m} {('failed' if v is None else f'{v:.4g} px')}"
                       for m, v in report["stereo_rms_px_by_lens_model"].items())
    lines = ["# Absorbed calibration", "",
             f"{report['pairs']} pairs from `{report['dir']}` ({report['source']}), calibrated as "
             f"pinhole cameras with distortion: the port absorbed (docs/absorbed.md).", "",
             f"Lens model: **{report['lens_model']}** (stereo RMS of each model: {models}).", "",
             f"RMS: left {report['rms_px']['left']:.4f} px, right "
             f"{report['rms_px']['right']:.4f} px, stereo {report['stereo_rms_px']:.4f} px."]
    housing = report.get("housing")
    if housing and housing.get("rms_px") is not None:
        lines += ["", f"The port model on the same corners: RMS {housing['rms_px']:.4f} px "
                      f"({housing['note']})."]
    return "\n".join(lines) + "\n"
