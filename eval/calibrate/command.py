"""``python -m eval calibrate DIR``: calibrate from board images, and say what it cost.

``DIR`` is a folder of ``python -m synth boards`` (compared with its truth) or a folder of a
user's own photos (``DIR/left/``, ``DIR/right/``, paired by name; the board on the command line,
``--air`` or ``--intrinsics``; the report says what can be trusted without truth:
:mod:`eval.calibrate.photos`), or ONE camera's photos (a folder holding them: in air
:mod:`eval.calibrate.single`, underwater with its ``camera.yaml`` the housing of that camera,
:mod:`eval.calibrate.single_housing`). In air (``--air`` boards): OpenCV calibrates
both cameras and the stereo pose (:func:`measure.calibration.air.calibrate_in_air`). Underwater:
the housing is estimated by refractive bundle adjustment with the in-air intrinsics fixed
(:func:`measure.calibration.housing.calibrate_housing`); ``--intrinsics`` gives them, as an in-air boards
folder (calibrated here first) or a ``calib.yaml``. Behind two housings (each camera its own
flat port: boards whose truth says so, or photos with ``--port-distance``) each camera's port is
estimated, starting ``--port-distance LEFT,RIGHT`` mm from its camera (:mod:`eval.calibrate.design`;
N cameras ``D0,D1,…``, :mod:`eval.calibrate.cameras`).

Writes to ``--out``: ``calib.yaml`` (the dataset format, with an ``uncertainty`` map),
``calib_in_air_only.yaml`` (underwater: the in-air calibration with the design port — what a
team that skips the housing calibration measures with), ``flatport.txt`` (the port as the
refractive COLMAP fork and calibmar write it), ``report.json``, ``report.md`` (every estimate
beside the truth with its error in σ) and figures ``residuals.png`` (reprojection residual
vectors per pose and view) and ``poses.png`` (the board poses in 3D).

This module routes a folder to its calibration; the parser is :mod:`eval.calibrate.options`, a
pair's boards :mod:`eval.calibrate.pair_boards`, a pair's photos or detections
:mod:`eval.calibrate.pair_photos`, ``--intrinsics`` :mod:`eval.calibrate.intrinsics`, and the
files and lines at the end :mod:`eval.calibrate.outputs`.
"""

from __future__ import annotations

import os
import sys
import time

from eval.calibrate.design import (DOME_DESIGN_OPTIONS, FLAT_DESIGN_OPTIONS, design_domes,
                                   design_port, pair_glass, parse_free)
from eval.calibrate.intrinsics import is_photo_folder
from eval.calibrate.options import (COMMAND, HOUSING_OPTIONS, LENS_UNDERWATER,
                                    add_calibrate_parser, require_air_or_intrinsics,
                                    require_board)
from eval.calibrate.outputs import COLMAP_NOTE, failed, print_n_water_note
from eval.calibrate.pair_boards import calibrate_pair_boards
from eval.calibrate.pair_photos import calibrate_pair_photos
from eval.calibrate.port_lengths import lengths_for
from eval.calibrate.single import single_camera_folder
from eval.cli import CLIError
from eval.core.photos import encoding_note
from synth.infra.cli import board_from_args, given, refuse_given


def add_parser(subparsers):
    """The ``calibrate`` subcommand's parser (:mod:`eval.calibrate.options`: its options by
    group)."""
    add_calibrate_parser(subparsers)


def main(args) -> int:
    """``eval calibrate DIR`` (module docs): the folder's kind says which calibration runs —
    ``--model absorbed``, detections, photos of N cameras, of a pair or of one camera, or a
    ``synth boards`` folder."""
    from synth.infra.fileio import OutputDir

    log = (lambda text: None) if args.no_progress else (
        lambda text: print(text, file=sys.stderr, flush=True))
    output = OutputDir(args.out, COMMAND).claim()
    start = time.perf_counter()
    _check_folder_and_model(args)
    if args.model == "absorbed":
        return _calibrate_absorbed(args, output, log, start)
    if args.detections:
        return _calibrate_detections(args, output, log, start, args.free)
    if not os.path.exists(os.path.join(args.dir, "manifest.json")):
        cameras = _camera_folders(args.dir)
        if cameras:
            return _calibrate_camera_photos(args, output, log, start, cameras)
    if is_photo_folder(args.dir) or (
            any(os.path.isdir(os.path.join(args.dir, sub)) for sub in ("left", "right"))
            and not os.path.exists(os.path.join(args.dir, "manifest.json"))):
        refuse_given(args, DOME_DESIGN_OPTIONS, f"to photos ({args.dir}): the housing "
                                                "calibration of photos models a flat port")
        return calibrate_pair_photos(args, output, log, parse_free(args.free), start)
    if not os.path.isfile(os.path.join(args.dir, "manifest.json")) and single_camera_folder(
            args.dir):
        return _calibrate_single(args, output, log, start)
    if not os.path.isfile(os.path.join(args.dir, "manifest.json")) and os.path.isdir(args.dir):
        raise CLIError(f"{args.dir}: not a boards folder (no manifest.json) nor a photo folder "
                       f"(no left/ and right/ folders, no photos)")
    return _calibrate_boards(args, output, log, start)


def _check_folder_and_model(args) -> None:
    """CLIError when ``DIR`` is no folder, a detection option is given without
    ``--detections`` (or wrongly), or ``--stereo-intrinsics`` without ``--model absorbed``."""
    from eval.calibrate.sources import check_detection_options

    if not os.path.isdir(args.dir):
        what = "a file, not a folder" if os.path.exists(args.dir) else "no such folder"
        raise CLIError(f"{args.dir}: {what} (give a photo folder, DIR/left/ and DIR/right/, or a "
                       f"synth boards folder)")
    check_detection_options(args)
    if args.model != "absorbed":
        refuse_given(args, ("stereo_intrinsics",), "without --model absorbed (the port model's "
                                                   "stereo fit holds the in-air intrinsics)")


def _calibrate_absorbed(args, output, log, start) -> int:
    """``--model absorbed`` (:mod:`eval.calibrate.absorbed`): the underwater photos calibrate
    the cameras themselves, so ``--air``, ``--intrinsics`` and the port's options are
    refused."""
    from eval.calibrate.absorbed import calibrate_absorbed_main

    if args.air or args.intrinsics:
        raise CLIError(f"--model absorbed: {'--air' if args.air else '--intrinsics'} does not "
                       f"apply: the underwater photos themselves calibrate the cameras")
    refuse_given(args, HOUSING_OPTIONS + DOME_DESIGN_OPTIONS,
                 "with --model absorbed: it has no port")
    return calibrate_absorbed_main(args, output, log, start)


def _camera_folders(path) -> list:
    """The camera folders (``cam0/``, ``cam1/``, …) of a photo folder of N cameras; empty for
    any other folder."""
    from eval.core.photos import PhotoError, camera_folder_names

    try:
        return camera_folder_names(path)
    except PhotoError as exc:
        raise CLIError(str(exc)) from None


def _calibrate_boards(args, output, log, start) -> int:
    """A ``synth boards`` folder: of N > 2 cameras (:mod:`eval.calibrate.cameras`) or of a pair
    (:mod:`eval.calibrate.pair_boards`)."""
    from synth.products.boards import read_boards

    boards = read_boards(args.dir)
    if "multirig" in boards.calib:  # a folder of N > 2 cameras
        from eval.calibrate.cameras import boards_source, calibrate_cameras_main

        if boards.air:
            refuse_given(args, HOUSING_OPTIONS, f"to in-air boards ({args.dir}): they calibrate "
                                                f"the cameras, no housing")
        source = boards_source(boards)
        design = None if boards.air else _n_camera_design(args, source.own_ports,
                                                            len(source.names))
        return calibrate_cameras_main(args, output, log, start, source, design)
    return calibrate_pair_boards(args, output, log, start, boards)


def _n_camera_design(args, own_ports: bool = False, cameras: int = 3):
    """The starting glass of N cameras under water: one shared port (:mod:`eval.calibrate.design`), or
    — ``--port-distance`` given, or boards whose truth has a port per camera (``own_ports``) —
    the glass and water each camera's own port has (:func:`pair_glass`: the shared distance
    options refused)."""
    if own_ports or given(args, "port_distance"):
        return pair_glass(args, cameras)
    return design_port(args, (0.0, 0.0, 1.0))


def _calibrate_camera_photos(args, output, log, start, cameras) -> int:
    """``eval calibrate`` of a user's photo folder of N > 2 cameras (``cam0/``, ``cam1/``, …:
    :mod:`eval.calibrate.cameras`)."""
    from eval.calibrate.cameras import calibrate_cameras_main, photos_source

    where = f"{args.dir} (photos of {len(cameras)} cameras)"
    if len(cameras) == 2:
        raise CLIError(f"{args.dir}: two camera folders (cam0/, cam1/); a stereo pair's photos "
                       f"are left/ and right/ (the two-camera calibration)")
    require_air_or_intrinsics(args, where, "the in-air calibration of these cameras")
    require_board(args, where)
    board = board_from_args(args)
    if board.symmetric:
        raise CLIError(f"{where}: a {board.squares[0]}x{board.squares[1]} chessboard looks the "
                       f"same turned by 180°; a rig of N cameras does not settle its turn yet "
                       f"(one camera and a pair do): use a board with one odd and one even "
                       f"number of squares")
    design = None if args.air else _n_camera_design(args, cameras=len(cameras))
    if design is not None and given(args, "port_distance"):
        lengths_for(args.port_distance, len(cameras))  # refused before any photo is read
    note = None
    first = os.path.join(args.dir, cameras[0])
    photos = sorted(f for f in os.listdir(first) if not f.startswith("."))
    if photos:
        note = encoding_note(os.path.join(first, photos[0]), args.encoding)
    log(f"read the photos of {', '.join(cameras)} from {args.dir} …")
    source = photos_source(args.dir, cameras, board, bool(args.air), args.encoding)
    if note:  # once the photos are read: a refused folder prints its error line only
        print(note, file=sys.stderr, flush=True)
    return calibrate_cameras_main(args, output, log, start, source, design)


def _calibrate_detections(args, output, log, start, free) -> int:
    """``--detections``: one camera's files, or a pair's in ``left/`` and ``right/``, through
    the paths of photos (:mod:`eval.calibrate.sources`)."""
    from eval.core.detections import DetectionError, detection_layout

    try:
        layout = detection_layout(args.dir)
    except DetectionError as exc:
        raise CLIError(str(exc)) from None
    if not layout:
        return _calibrate_single(args, output, log, start)
    refuse_given(args, DOME_DESIGN_OPTIONS, f"to a pair's detections ({args.dir}): the housing "
                                            "calibration of a pair's photos models flat ports")
    return calibrate_pair_photos(args, output, log, parse_free(free), start)


def _calibrate_single(args, output, log, start) -> int:
    """``eval calibrate`` of one camera's photo folder: in air (:mod:`eval.calibrate.single`)
    or, with ``--intrinsics``, its housing (:mod:`eval.calibrate.single_housing`)."""
    from eval.calibrate.single import calibrate_single

    where = f"{args.dir} (one camera's photos)"
    if not args.air and not args.intrinsics:
        raise CLIError(f"{where}: say --air (photos taken in air) or --intrinsics camera.yaml "
                       f"(photos taken underwater, with the camera's in-air calibration)")
    if not args.air:
        return _calibrate_single_housing(args, output, log, start, where)
    if args.intrinsics:
        raise CLIError("--intrinsics does not apply with --air: in-air photos calibrate the "
                       "intrinsics themselves")
    refuse_given(args, HOUSING_OPTIONS + DOME_DESIGN_OPTIONS + ("intrinsics",),
                 "to one camera's in-air photos (--air): they calibrate the camera, no housing")
    require_board(args, where)
    report, summary = calibrate_single(args, output, log, start, board_from_args(args))
    print(summary)
    print(f"wrote {output.path} (camera.yaml for OpenCV; calibmar.yaml; cameras.txt for COLMAP)")
    return failed(args.dir, report["failures"], output.path)


def _calibrate_single_housing(args, output, log, start, where) -> int:
    """One camera's underwater photos with its in-air calibration: the housing of that camera
    (:mod:`eval.calibrate.single_housing`). A dome when a dome design option is given, else a
    flat port (the stereo calibration's options)."""
    from measure import StereoRig
    from measure.calibration.housing import DEFAULT_DOME_FREE

    from eval.calibrate.single_housing import calibrate_single_housing, read_intrinsics

    refuse_given(args, ("lens",), LENS_UNDERWATER)
    refuse_given(args, ("port_distance",), f"to one camera's photos ({args.dir}): it is the "
                                           f"design of two housings (one camera's port: "
                                           f"--start-distance)")
    dome = any(given(args, dest) for dest in DOME_DESIGN_OPTIONS)
    if dome:
        refuse_given(args, FLAT_DESIGN_OPTIONS, "to a camera inside a dome (--dome-radius / "
                                                "--dome-thickness given): the design is "
                                                "--dome-radius, --dome-thickness, --n-glass, "
                                                "--n-water")
    free = parse_free(args.free if given(args, "free") or not dome
                      else ",".join(DEFAULT_DOME_FREE), dome)
    if "extrinsics" in free:
        raise CLIError(f"--free {args.free}: extrinsics is the stereo pose; {args.dir} holds one "
                       f"camera's photos")
    require_board(args, where)
    board = board_from_args(args)
    if not dome:
        design_port(args, (0.0, 0.0, 1.0))  # a bad --design-port is refused before any work
    intrinsics = read_intrinsics(args.intrinsics)
    camera = intrinsics["camera"]
    if dome:
        start_port = design_domes(args, StereoRig(camera, camera, None)).port
    else:
        start_port = design_port(args, camera.R[:, 2])
    report, summary = calibrate_single_housing(args, output, log, start, board, intrinsics,
                                               start_port, free, dome)
    print_n_water_note(args)
    print(summary)
    print(f"wrote {output.path} (camera.yaml for OpenCV; calibmar.yaml; cameras.txt for the "
          f"refractive COLMAP fork — {COLMAP_NOTE})")
    return failed(args.dir, report["failures"], output.path)


