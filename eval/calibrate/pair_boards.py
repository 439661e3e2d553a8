"""``eval calibrate BOARDS`` of a pair's ``synth boards`` folder, every estimate beside the
folder's truth: in air OpenCV calibrates both cameras and the stereo pose
(:func:`measure.calibration.air.calibrate_in_air`); underwater the housing is estimated by
refractive bundle adjustment with the in-air intrinsics of ``--intrinsics`` held
(:func:`measure.calibration.housing.calibrate_housing`). The truth says which housing: one flat
port, a flat port per camera (two housings, ``--port-distance``) or a dome per camera; the
design options and the default free parameters differ by kind.

The stages of :func:`calibrate_pair_boards`: the kind of housing and the options it refuses, the
design checked before any work, the detection, the calibration in air or of the housing, then
the files, the report and the printed summary. Lengths mm, pixels px, times s.
"""

from __future__ import annotations

import os
import time

from eval.calibrate.causes import FIT_ERRORS, housing_failure
from eval.calibrate.design import (DOME_DESIGN_OPTIONS, FLAT_DESIGN_OPTIONS, design_domes,
                                   design_pair, design_port, pair_glass, parse_free)
from eval.calibrate.intrinsics import read_in_air, refuse_calibration_folder
from eval.calibrate.options import HOUSING_OPTIONS, LENS_UNDERWATER, refuse_for_boards_folder
from eval.calibrate.outputs import failed, print_written, write_calibrations
from eval.cli import CLIError
from synth.infra.cli import given, refuse_given


def calibrate_pair_boards(args, output, log, start, boards) -> int:
    """Calibrate a pair's boards folder (``boards``: :func:`synth.products.boards.read_boards`)
    in air or its housing underwater, write into ``output`` and print the summary; the exit
    code (module docs)."""
    from eval.calibrate import report as report_lib

    truth = boards.calib["rig"]
    dome, pair, free = _housing_kind(args, boards, truth)
    _refuse_for_boards(args, boards)
    _refuse_bad_design(args, boards, dome, pair)
    detections, report, timings = _detect(boards, log)
    air = housing = start_rig = None
    if boards.air:
        air = _calibrate_in_air(args, boards, detections, truth, report, timings, log)
        rig, air_covariance = air.rig, air.covariance
    else:
        start_rig, housing, air_covariance = _calibrate_housing(
            args, boards, detections, truth, dome, pair, free, report, timings, log)
        rig = housing.rig
    report["timings_s"] = timings
    log("write the calibration, report and figures …")
    with output.staged() as tmp:
        write_calibrations(tmp, rig, housing, report, None if boards.air else start_rig,
                           air_covariance)
        report_lib.figures(tmp, boards, detections, housing, rig)
        report = report_lib.write_report(tmp, report, report_lib.markdown, start)
    code = print_written(output, report_lib.summary_lines(report), args, housing is not None)
    if boards.air:  # a stereo fit the cameras' own fits contradict (e.g. --lens rational)
        from eval.calibrate import photos as trust

        return failed(args.dir, trust.stereo_rms_failure(
            air.rms_px, air.stereo_rms_px, "boards (with this lens model)"), output.path) or code
    return code


def _housing_kind(args, boards, truth):
    """``(dome, pair, free)``: whether the truth's housing is a dome per camera or a flat port
    per camera, and the parameters to free (the domes' default their decentring); the design
    options of another kind refused."""
    from measure.calibration.housing import HOUSINGS
    from measure.geometry.dome import DomePair

    if not boards.air and truth.port.kind not in HOUSINGS:  # a kind without a housing problem
        raise CLIError(f"{args.dir}: boards behind {truth.port.description}: no housing "
                       f"calibration of {truth.port.rig_name} yet")
    dome = not boards.air and isinstance(truth.port, DomePair)
    pair = not boards.air and truth.port.kind == "flat pair"  # two housings: --port-distance
    if not pair and not boards.air:
        refuse_given(args, ("port_distance",), f"to {args.dir}: its boards are not behind two "
                                               f"housings (the design distance is "
                                               f"--start-distance)")
    if dome:
        from measure.calibration.housing import DEFAULT_DOME_FREE

        refuse_given(args, FLAT_DESIGN_OPTIONS, f"to boards behind domes ({args.dir}): the "
                                                f"design is --dome-radius, --dome-thickness, "
                                                f"--n-glass, --n-water")
        free = parse_free(args.free if given(args, "free") else ",".join(DEFAULT_DOME_FREE),
                          True)
    else:
        refuse_given(args, DOME_DESIGN_OPTIONS, f"to {args.dir}: its boards are not behind "
                                                f"domes")
        free = parse_free(args.free)
    return dome, pair, free


def _refuse_for_boards(args, boards) -> None:
    """The options a boards folder refuses: its images' encoding and board (the folder says
    them), ``--air`` for underwater boards, the housing's options in air, ``--lens`` under
    water, and ``--intrinsics`` where it does not apply or is missing."""
    refuse_given(args, ("encoding",), f"to a boards folder ({args.dir}): its images are "
                                      f"16-bit linear renders")
    refuse_for_boards_folder(args, boards)
    if boards.air:
        refuse_given(args, HOUSING_OPTIONS, f"to in-air boards ({args.dir}): they calibrate the "
                                            f"cameras, no housing")
    else:
        refuse_given(args, ("lens",), LENS_UNDERWATER)
    if boards.air and args.intrinsics:
        raise CLIError(f"{args.dir}: in-air boards calibrate the intrinsics themselves; "
                       f"--intrinsics is for underwater boards")
    if not boards.air and not args.intrinsics:
        raise CLIError(f"{args.dir}: underwater boards need --intrinsics (an --air boards "
                       f"folder or a calib.yaml)")


def _refuse_bad_design(args, boards, dome, pair) -> None:
    """A bad design, or a wrong ``--intrinsics`` file, refused before any detection."""
    if pair:
        pair_glass(args)  # a bad design is refused before any work
    elif not boards.air and not dome:
        design_port(args, (0.0, 0.0, 1.0))  # a bad --design-port is refused before any work
    if not boards.air and not os.path.isdir(args.intrinsics):  # a wrong file, before detection
        read_in_air(args.intrinsics, lambda text: None)


def _detect(boards, log):
    """``(detections, report, timings)``: the board detected in every pose, the report begun
    with what was found and how accurately (against the rendered corners)."""
    from measure.calibration.air import detect_boards

    from eval.calibrate import report as report_lib

    log(f"detect the boards in {boards.path} ({len(boards.images)} poses) …")
    t = time.perf_counter()
    detections = detect_boards(boards.board, boards.images)
    timings = {"detect": time.perf_counter() - t}
    report = {"boards": os.path.abspath(boards.path), "air": boards.air,
              "board": boards.board.to_dict(), "poses": len(boards.images),
              "found": {"left": len(detections.found(0)), "right": len(detections.found(1))},
              "detection": report_lib.detection_accuracy(boards, detections)}
    return detections, report, timings


def _calibrate_in_air(args, boards, detections, truth, report, timings, log):
    """OpenCV's calibration of both cameras and the stereo pose (``--lens``), its summary
    against the truth into ``report``."""
    from measure.calibration.air import DEFAULT_LENS_MODEL, calibrate_in_air

    from eval.calibrate import report as report_lib

    log("calibrate in air (OpenCV calibrateCamera, stereoCalibrate) …")
    t = time.perf_counter()
    air = calibrate_in_air(boards.board, detections, boards.calib["size"],
                           args.lens or DEFAULT_LENS_MODEL)
    timings["calibrate"] = time.perf_counter() - t
    report["in_air"] = report_lib.air_summary(air, truth)
    return air


def _calibrate_housing(args, boards, detections, truth, dome, pair, free, report, timings, log):
    """``(start rig, housing, in-air covariance)``: the in-air calibration of ``--intrinsics``,
    the design the adjustment starts from, and the refractive bundle adjustment; its summary
    against the truth into ``report``. CLIError when the boards do not determine the housing."""
    from measure.calibration.housing import calibrate_housing

    from eval.calibrate import report as report_lib

    t = time.perf_counter()
    refuse_calibration_folder(args.intrinsics)
    air_rig, air, air_boards, air_covariance = read_in_air(args.intrinsics, log)
    timings["calibrate_in_air"] = time.perf_counter() - t
    if tuple(air_rig.left.size) != tuple(boards.calib["size"]):
        raise CLIError(f"--intrinsics {args.intrinsics}: image size "
                       f"{air_rig.left.size[0]}x{air_rig.left.size[1]} px, but the boards "
                       f"are {boards.calib['size'][0]}x{boards.calib['size'][1]} px")
    if air is not None:
        report["in_air"] = report_lib.air_summary(air, air_boards.calib["rig"])
    start_rig = _start_rig(args, truth, air_rig, dome, pair)
    log(f"refractive bundle adjustment of {', '.join(free)} over "
        f"{len(detections.found(0))} + {len(detections.found(1))} board views …")
    t = time.perf_counter()
    try:
        housing = calibrate_housing(start_rig, boards.board, detections, free,
                                    air_covariance, args.air_uncertainty)
    except FIT_ERRORS as exc:
        raise housing_failure(args.dir, exc, args, "render") from None
    timings["bundle_adjustment"] = time.perf_counter() - t
    if not housing.identifiable:
        raise housing_failure(args.dir, housing.reason, args, "render")
    report["dome"] = dome
    report["housing"] = (report_lib.dome_summary if dome else report_lib.housing_summary)(
        housing, truth, start_rig)
    return start_rig, housing, air_covariance


def _start_rig(args, truth, air_rig, dome, pair):
    """The in-air cameras behind the design housing the adjustment starts from: domes, a flat
    port per camera or one flat port (each of one glass layer, as the truth must be)."""
    from measure import StereoRig

    if dome:
        return design_domes(args, air_rig)
    if pair:
        if any(len(truth.view_port(v).thicknesses) != 1 for v in (0, 1)):
            raise CLIError(f"{args.dir}: the housing calibration models one glass layer "
                           f"per port")
        return design_pair(args, air_rig)
    if len(truth.port.thicknesses) != 1:
        raise CLIError(f"{args.dir}: the housing calibration models one glass layer; "
                       f"the truth has {len(truth.port.thicknesses)}")
    design = design_port(args, air_rig.left.R[:, 2])
    return StereoRig(air_rig.left, air_rig.right, design)
