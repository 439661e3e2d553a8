"""``python -m eval calibrate DIR``: calibrate from rendered board images, and say what it cost.

``DIR`` is a folder of ``python -m synth boards``. In air (``--air`` boards): OpenCV calibrates
both cameras and the stereo pose (:func:`measure.calibration.calibrate_in_air`). Underwater:
the housing is estimated by refractive bundle adjustment with the in-air intrinsics fixed
(:func:`measure.calibration.calibrate_housing`); ``--intrinsics`` gives them, as an in-air boards
folder (calibrated here first) or a ``calib.yaml``.

Writes to ``--out``: ``calib.yaml`` (the dataset format, with an ``uncertainty`` map),
``calib_in_air_only.yaml`` (underwater: the in-air calibration with the design port — what a
team that skips the housing calibration measures with), ``flatport.txt`` (the port as the
refractive COLMAP fork and calibmar write it), ``report.json``, ``report.md`` (every estimate
beside the truth with its error in σ) and figures ``residuals.png`` (reprojection residual
vectors per pose and view) and ``poses.png`` (the board poses in 3D).
"""

from __future__ import annotations

import os
import sys
import time

from eval.cli import CLIError, positive_float
from synth.cli import add_out_option, add_progress_option, refuse_given

COMMAND = "eval calibrate"
#: Options of the housing calibration (underwater boards): refused with in-air boards.
HOUSING_OPTIONS = ("free", "start_distance", "glass_thickness", "n_glass", "n_water")


def add_parser(subparsers):
    from measure.calibration import DEFAULT_FREE, HOUSING_PARAMETERS
    from synth.rig import PAPER_GLASS_THICKNESS_MM, PAPER_INDICES, PAPER_PORT_DISTANCE_MM

    p = subparsers.add_parser(
        "calibrate", help="calibrate from rendered boards (in air, or the housing underwater)",
        description="Calibrate from a folder of python -m synth boards and compare every "
                    "estimate with the rendered truth.")
    p.add_argument("dir", help="boards folder (python -m synth boards)")
    p.add_argument("--intrinsics", metavar="AIR_DIR_or_calib.yaml",
                   help="underwater boards: the in-air calibration, as an --air boards folder "
                        "(calibrated here with OpenCV) or a calib.yaml")
    p.add_argument("--free", default=",".join(DEFAULT_FREE),
                   help=f"housing parameters to estimate, comma list of "
                        f"{', '.join(HOUSING_PARAMETERS)} (default {','.join(DEFAULT_FREE)})")
    p.add_argument("--start-distance", type=positive_float, default=PAPER_PORT_DISTANCE_MM,
                   help=f"starting port distance D, mm (the design value; default "
                        f"{PAPER_PORT_DISTANCE_MM:g})")
    p.add_argument("--glass-thickness", type=positive_float, default=PAPER_GLASS_THICKNESS_MM,
                   help=f"design glass thickness, mm (default {PAPER_GLASS_THICKNESS_MM:g}; "
                        f"the start when --free thickness)")
    p.add_argument("--n-glass", type=positive_float, default=PAPER_INDICES[1],
                   help=f"design glass index (default {PAPER_INDICES[1]:g})")
    p.add_argument("--n-water", type=positive_float, default=PAPER_INDICES[2],
                   help=f"design water index (default {PAPER_INDICES[2]:g}; the start when "
                        f"--free n_water)")
    add_out_option(p, COMMAND)
    add_progress_option(p)


def _parse_free(text: str) -> tuple:
    from measure.calibration import HOUSING_PARAMETERS

    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    unknown = [n for n in names if n not in HOUSING_PARAMETERS]
    if not names or unknown:
        raise CLIError(f"--free {text!r}: unknown parameter {', '.join(unknown) or '(none)'} "
                       f"(choose from {', '.join(HOUSING_PARAMETERS)})")
    return names


def _in_air(path, log):
    """``(rig, air_summary or None)`` from ``--intrinsics``: a boards folder or a calib.yaml."""
    from measure.calibration import calibrate_in_air, detect_boards
    from synth.boards import read_boards
    from synth.dataset import read_calib

    if os.path.isdir(path):
        boards = read_boards(path)
        if not boards.air:
            raise CLIError(f"--intrinsics {path}: these boards were rendered underwater; the "
                           f"in-air calibration needs --air boards")
        log(f"detect the boards in {path} and calibrate in air (OpenCV) …")
        detections = detect_boards(boards.board, boards.images)
        air = calibrate_in_air(boards.board, detections, boards.calib["size"])
        return air.rig, air, boards
    return read_calib(path)["rig"], None, None


def main(args) -> int:

    from measure import FlatPort, StereoRig
    from measure.calibration import calibrate_housing, calibrate_in_air, detect_boards
    from synth.boards import read_boards
    from synth.fileio import OutputDir, atomic_write_json, atomic_write_text, jsonable

    from eval.calibrate import report as report_lib

    log = (lambda text: None) if args.no_progress else (
        lambda text: print(text, file=sys.stderr, flush=True))
    free = _parse_free(args.free)
    output = OutputDir(args.out, COMMAND).claim()
    start = time.perf_counter()
    boards = read_boards(args.dir)
    truth = boards.calib["rig"]
    if boards.air:
        refuse_given(args, HOUSING_OPTIONS, f"to in-air boards ({args.dir}): they calibrate the "
                                            f"cameras, no housing")
    if boards.air and args.intrinsics:
        raise CLIError(f"{args.dir}: in-air boards calibrate the intrinsics themselves; "
                       f"--intrinsics is for underwater boards")
    if not boards.air and not args.intrinsics:
        raise CLIError(f"{args.dir}: underwater boards need --intrinsics (an --air boards "
                       f"folder or a calib.yaml)")
    log(f"detect the boards in {boards.path} ({len(boards.images)} poses) …")
    t = time.perf_counter()
    detections = detect_boards(boards.board, boards.images)
    timings = {"detect": time.perf_counter() - t}
    report = {"boards": os.path.abspath(boards.path), "air": boards.air,
              "board": boards.board.to_dict(), "poses": len(boards.images),
              "found": {"left": len(detections.found(0)), "right": len(detections.found(1))},
              "detection": report_lib.detection_accuracy(boards, detections)}
    if boards.air:
        log("calibrate in air (OpenCV calibrateCamera, stereoCalibrate) …")
        t = time.perf_counter()
        air = calibrate_in_air(boards.board, detections, boards.calib["size"])
        timings["calibrate"] = time.perf_counter() - t
        rig = air.rig
        report["in_air"] = report_lib.air_summary(air, truth)
        housing = None
    else:
        t = time.perf_counter()
        air_rig, air, air_boards = _in_air(args.intrinsics, log)
        timings["calibrate_in_air"] = time.perf_counter() - t
        if tuple(air_rig.left.size) != tuple(boards.calib["size"]):
            raise CLIError(f"--intrinsics {args.intrinsics}: image size "
                           f"{air_rig.left.size[0]}x{air_rig.left.size[1]} px, but the boards "
                           f"are {boards.calib['size'][0]}x{boards.calib['size'][1]} px")
        if air is not None:
            report["in_air"] = report_lib.air_summary(air, air_boards.calib["rig"])
        if len(truth.port.thicknesses) != 1:
            raise CLIError(f"{args.dir}: the housing calibration models one glass layer; the "
                           f"truth has {len(truth.port.thicknesses)}")
        design = FlatPort(air_rig.left.R[:, 2], args.start_distance, (args.glass_thickness,),
                          (1.0, args.n_glass, args.n_water))
        start_rig = StereoRig(air_rig.left, air_rig.right, design)
        log(f"refractive bundle adjustment of {', '.join(free)} over "
            f"{len(detections.found(0))} + {len(detections.found(1))} board views …")
        t = time.perf_counter()
        housing = calibrate_housing(start_rig, boards.board, detections, free)
        timings["bundle_adjustment"] = time.perf_counter() - t
        if not housing.identifiable:
            raise CLIError(f"{args.dir}: {housing.reason}; nothing written (free fewer "
                           f"parameters with --free, or render more varied poses)")
        rig = housing.rig
        report["housing"] = report_lib.housing_summary(housing, truth, start_rig)
    report["timings_s"] = timings
    log("write the calibration, report and figures …")
    with output.staged() as tmp:
        report_lib.write_calibration(tmp, rig, not boards.air, housing, report)
        if housing is not None:
            report_lib.write_calibration(os.path.join(tmp, "calib_in_air_only.yaml"),
                                         start_rig, True, None, None, single=True)
        report_lib.figures(tmp, boards, detections, housing, rig)
        report["timings_s"]["total"] = time.perf_counter() - start
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), report_lib.markdown(report))
    print(report_lib.summary_lines(report))
    print(f"wrote {output.path}")
    return 0
