"""The command line of ``python -m eval calibrate``: its parser, as named groups of options (what
to calibrate, the housing's design, the fit and its inputs), the option sets that one kind of
folder refuses, and the check that a photo folder's board is on the command line
(:func:`require_board`). Lengths in mm, image sizes in px.

Only light modules are imported here at module level: ``--help`` builds this parser
(``tests/test_cli_startup.py``)."""

from __future__ import annotations

from eval.calibrate.port_lengths import per_camera_lengths
from eval.cli import CLIError, positive_float
from eval.core.photos import add_encoding_option
from synth.infra.cli import (positive_int, WATER_INDEX_HELP, add_board_options, add_out_option,
                             add_progress_option, water_index_argument)

COMMAND = "eval calibrate"
#: Options of the housing calibration (underwater boards): refused with in-air boards.
HOUSING_OPTIONS = ("free", "design_port", "start_distance", "glass_thickness", "n_glass",
                   "n_water", "air_uncertainty", "port_distance")
#: Why ``--lens`` is refused under water.
LENS_UNDERWATER = ("underwater: the lens model is the in-air calibration's (--intrinsics); "
                   "give --lens to eval calibrate --air")


def add_calibrate_parser(subparsers) -> None:
    """The ``calibrate`` subparser of ``python -m eval``, its options in the order ``--help``
    lists them."""
    p = subparsers.add_parser(
        "calibrate", help="calibrate from board images (in air, or the housing underwater)",
        description="Calibrate from a folder of python -m synth boards (every estimate beside "
                    "the rendered truth; a pair or N cameras) or from your own photos: a "
                    "pair's DIR/left/ and DIR/right/, N cameras' DIR/cam0/ DIR/cam1/ …, paired "
                    "by name, or one camera's folder of photos (give the board, and --air or "
                    "--intrinsics).")
    _add_what_to_calibrate(p)
    _add_housing_design_options(p)
    _add_fit_options(p)
    add_out_option(p, COMMAND)
    add_encoding_option(p)
    add_progress_option(p)


def _add_what_to_calibrate(p) -> None:
    """``DIR``, ``--model``, ``--air``, ``--intrinsics`` and the board."""
    p.add_argument("dir", help="boards folder (python -m synth boards) or photo folder: "
                               "DIR/left/ and DIR/right/, DIR/cam0/ DIR/cam1/ … (N cameras), or "
                               "one camera's photos in DIR")
    p.add_argument("--model", choices=("port", "absorbed"), default="port",
                   help="port (default): the cameras in air, then the housing's port; absorbed: "
                        "underwater boards or photos calibrated as pinhole cameras, the port "
                        "absorbed by focal length and distortion (docs/absorbed.md)")
    p.add_argument("--air", action="store_true",
                   help="photos: taken in air (OpenCV calibrates both cameras and the stereo "
                        "pose); a boards folder says it itself")
    p.add_argument("--intrinsics", metavar="AIR_DIR_or_calib.yaml",
                   help="underwater boards or photos: the in-air calibration, as an --air "
                        "boards folder (calibrated here with OpenCV) or a file: calib.yaml, "
                        "calibmar's YAML or the COLMAP fork's cameras.txt; one camera's photos: "
                        "that camera's camera.yaml (eval calibrate PHOTOS --air), calibmar's "
                        "one-camera YAML or a one-camera cameras.txt")
    add_board_options(p, defaults=False, circles=True,
                      needed="photos: required; a boards folder's board.json defines it")


def _add_housing_design_options(p) -> None:
    """What the housing calibration frees (``--free``), how the in-air σ enters it, and the
    design it starts from: one flat port, a port per camera, or domes (mm, indices)."""
    from measure.calibration.dome import DOME_PARAMETERS
    from measure.calibration.flat import HOUSING_PARAMETERS
    from measure.calibration.housing import DEFAULT_DOME_FREE, DEFAULT_FREE, DEFAULT_UNCERTAINTY, UNCERTAINTY
    from synth.scene.rig import PAPER_GLASS_THICKNESS_MM, PAPER_INDICES, PAPER_PORT_DISTANCE_MM

    p.add_argument("--free", default=",".join(DEFAULT_FREE),
                   help=f"housing parameters to estimate, comma list of "
                        f"{', '.join(HOUSING_PARAMETERS)} (default {','.join(DEFAULT_FREE)}); "
                        f"behind domes: {', '.join(DOME_PARAMETERS)} (default "
                        f"{','.join(DEFAULT_DOME_FREE)}: each camera's decentring)")
    p.add_argument("--air-uncertainty", choices=UNCERTAINTY, default=DEFAULT_UNCERTAINTY,
                   help=f"how the in-air calibration's covariance (--intrinsics: its calib.yaml's "
                        f"covariance node) enters the housing's σ: propagate (intrinsics and "
                        f"stereo pose held, their covariance propagated) or prior (freed, the "
                        f"in-air result as a prior); default {DEFAULT_UNCERTAINTY} "
                        f"(docs/calibration.md says why)")
    p.add_argument("--start-distance", type=positive_float, default=PAPER_PORT_DISTANCE_MM,
                   help=f"starting port distance D, mm (the design value; default "
                        f"{PAPER_PORT_DISTANCE_MM:g})")
    p.add_argument("--glass-thickness", type=positive_float, default=PAPER_GLASS_THICKNESS_MM,
                   help=f"design glass thickness, mm (default {PAPER_GLASS_THICKNESS_MM:g}; "
                        f"the start when --free thickness)")
    p.add_argument("--n-glass", type=positive_float, default=PAPER_INDICES[1],
                   help=f"design glass index (default {PAPER_INDICES[1]:g})")
    p.add_argument("--n-water", type=water_index_argument, default=PAPER_INDICES[2],
                   help=f"design {WATER_INDEX_HELP}; default {PAPER_INDICES[2]:g}; the start "
                        f"when --free n_water")
    p.add_argument("--port-distance", type=per_camera_lengths, metavar="LEFT,RIGHT",
                   help="a port per camera (two housings; N cameras D0,D1,…): the design "
                        "distance of each port from its camera's centre along the camera's "
                        "optical axis, mm, as python -m synth scene --port per-camera gives it "
                        "(default 40 each; one number: every camera); the start of each port's "
                        "D and normal (each ⟂ its camera); photos: giving it says that the "
                        "photos were taken behind a housing per camera. --glass-thickness, --n-glass, "
                        "--n-water (or --design-port without distance=) give both ports' glass "
                        "and water")
    p.add_argument("--dome-radius", type=positive_float, default=50.0,
                   help="boards behind domes: the design inner radius of each dome, mm (default "
                        "50); the start is a dome centred on each camera. One camera's photos: "
                        "giving it (or --dome-thickness) says the camera is inside a dome")
    p.add_argument("--dome-thickness", type=positive_float, default=8.0,
                   help="boards behind domes: the design glass thickness of each dome, mm "
                        "(default 8)")
    p.add_argument("--design-port", metavar="KEY=VALUE,…",
                   help="the starting port in one option, from the housing's drawing: any of "
                        "distance=MM, thickness=MM, n_glass=N, n_water=N (e.g. "
                        "distance=120,thickness=8,n_glass=1.49); the keys not given keep the "
                        "defaults above")


def _add_fit_options(p) -> None:
    """The in-air lens model, the absorbed model's stereo fit, detections instead of photos and
    the thinning of many poses."""
    from measure.calibration.air import LENS_MODELS, STEREO_INTRINSICS

    from eval.calibrate.sources import add_detection_options

    p.add_argument("--lens", choices=("auto", *LENS_MODELS), default=None,
                   help="in air: the lens model OpenCV fits — standard (k1 k2 p1 p2), k3, "
                        "rational (k1…k6 p1 p2: wide and action-camera lenses), fisheye "
                        "(OpenCV's fisheye model, k1…k4 on the ray's angle) or auto "
                        "(default: the richer model only where it lowers the RMS by 2 %%; the "
                        "report lists each model's RMS)")
    p.add_argument("--stereo-intrinsics", choices=STEREO_INTRINSICS, default=None,
                   help="--model absorbed: fixed (default: each camera's own calibration held "
                        "in the stereo fit) or refined (the stereo fit refines both cameras' "
                        "intrinsics too, as MATLAB's stereo calibrator does)")
    add_detection_options(p)
    p.add_argument("--max-poses", type=positive_int, default=None, metavar="N",
                   help="photos or detections: more poses than N (default 150; the frames of a "
                        "calibration video) are thinned by pose diversity before the fit, the "
                        "choice reported")


def require_board(args, where) -> None:
    """CLIError when a photo folder's board is not on the command line (a circle grid's
    options are checked where it is made)."""
    if args.board in ("circles", "acircles"):
        return
    missing = [option for dest, option in (("squares", "--squares COLSxROWS (or "
                                                       "--inner-corners)"),
                                           ("square_mm", "--square-mm S"))
               if getattr(args, dest) is None
               and not (dest == "squares" and args.inner_corners is not None)]
    if missing:
        raise CLIError(f"{where}: a photo folder needs the board on the command line: "
                       f"{' and '.join(missing)} (and --board charuco for a ChArUco board)")


def require_air_or_intrinsics(args, where: str, underwater: str) -> None:
    """The medium of a photo folder of two or more cameras: ``--air`` (then the housing's
    options and ``--intrinsics`` are refused) or ``--intrinsics`` (``underwater``: what the
    message says that file is); CLIError naming ``where`` when neither is given."""
    from synth.infra.cli import refuse_given

    if args.air:
        refuse_given(args, HOUSING_OPTIONS, "to in-air photos (--air): they calibrate the "
                                            "cameras, no housing")
        if args.intrinsics:
            raise CLIError("--intrinsics does not apply with --air: in-air photos calibrate the "
                           "intrinsics themselves")
    elif not args.intrinsics:
        raise CLIError(f"{where}: say --air (photos taken in air) or --intrinsics calib.yaml "
                       f"(photos taken underwater, with {underwater})")


def refuse_for_boards_folder(args, boards, board_options: bool = True) -> None:
    """What a folder of rendered boards refuses: the board's options (``board_options``: the
    folder's board.json defines the board) and ``--air`` where its manifest says the boards were
    rendered underwater."""
    from synth.infra.cli import BOARD_OPTIONS, refuse_given

    if board_options:
        refuse_given(args, BOARD_OPTIONS, f"to a boards folder ({args.dir}): the folder's "
                                          f"board.json defines the board")
    if args.air and not boards.air:
        raise CLIError(f"--air: {args.dir} holds boards rendered underwater (its manifest says "
                       f"so; --air is for photos)")
