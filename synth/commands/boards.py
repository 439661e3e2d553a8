"""``python -m synth boards SCENE --out DIR [--poses 15] [--board chessboard|charuco]
[--squares 11x8] [--square-mm 40] [--seed S] [--air]``: stereo pairs of a calibration board at
random poses behind the scene's port (or in air), :mod:`synth.products.boards`."""

from __future__ import annotations

import argparse
import math

from synth.infra.cli import (CLIError, add_board_options, add_define_option, add_full_film_option,
                       add_out_option, add_progress_option, add_scene_argument, board_from_args,
                       non_negative_float, positive_float, positive_int, refuse_given,
                       scene_seed)


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("boards",
                              help="render stereo pairs of a calibration board at random poses")
    add_scene_argument(p)
    add_out_option(p, "synth boards")
    p.add_argument("--poses", type=positive_int, default=None, help="number of poses (default 15)")
    add_board_options(p)
    p.add_argument("--distance", type=positive_float, nargs=2, metavar=("NEAR", "FAR"),
                   default=None, help="board centre depth range along the port normal, mm "
                                      "(default 700 1400; with --air 350 800, so that the "
                                      "corners cover about half of each image)")
    p.add_argument("--max-tilt", type=non_negative_float, default=None,
                   help="largest tilt of the board, degrees (default 45)")
    p.add_argument("--spp", type=positive_int, default=None,
                   help="samples per pixel, same as -D spp=N (default 16)")
    p.add_argument("--seed", type=scene_seed, default=None,
                   help="seed of the poses and the renderer, same as -D seed=S (default 0)")
    p.add_argument("--air", action="store_true", help="the same cameras with no port (in air)")
    add_light_options(p)
    add_camera_options(p)
    p.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    add_full_film_option(p)
    add_define_option(p)
    add_progress_option(p)


def numbers(count: int, what: str):
    """An argparse type: ``count`` comma-separated finite numbers."""
    def parse(text: str) -> tuple:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) != count or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return values
    return parse


def add_light_options(p) -> None:
    """``--light`` and its lamp (:class:`synth.products.board_light.BoardLight`)."""
    from synth.products import board_light as bl

    water = ",".join(f"{v:g}" for v in bl.DEFAULT_LIGHT_POSITION_MM)
    air = ",".join(f"{v:g}" for v in bl.DEFAULT_AIR_LIGHT_POSITION_MM)
    p.add_argument("--light", choices=bl.LIGHT_KINDS, default=None,
                   help="the board printed on diffuse paper and lit by a lamp (a Mitsuba spot "
                        "or point light) instead of glowing evenly; the corners' truth is the "
                        "same")
    p.add_argument("--light-position", type=numbers(3, "X,Y,Z in mm"), default=None,
                   metavar="X,Y,Z", help=f"the lamp's position, mm in the left camera's frame "
                                         f"(default {water}: left of, above and ahead of the "
                                         f"camera, in the water; with --air {air}, behind it)")
    p.add_argument("--light-aim", type=numbers(3, "X,Y,Z in mm"), default=None, metavar="X,Y,Z",
                   help="the point the spot aims at, mm in the left camera's frame (default "
                        "the left optical axis at the middle of --distance)")
    p.add_argument("--light-intensity", type=positive_float, default=None,
                   help="the lamp's radiant intensity, linear units (default pi/0.8*1e6: white "
                        "paper at 1 m facing it is as bright as the luminous board's white)")
    p.add_argument("--light-angle", type=positive_float, default=None, metavar="DEG",
                   help=f"spot only: the cut-off half-angle, degrees (default "
                        f"{bl.DEFAULT_SPOT_CUTOFF_DEG:g}; full intensity within "
                        f"{bl.BEAM_FRACTION:g} of it)")
    p.add_argument("--print-reflectance", type=numbers(2, "BLACK,WHITE (two reflectances)"),
                   default=None, metavar="BLACK,WHITE",
                   help=f"the printed board's reflectances (default {bl.DEFAULT_PAPER_BLACK:g},"
                        f"{bl.DEFAULT_PAPER_WHITE:g})")


def light_from_args(args):
    """The :class:`synth.products.board_light.BoardLight` of ``--light`` and its options, or
    None; CLIError for a lamp option without ``--light`` or one that does not apply."""
    from synth.products.board_light import BoardLight

    lamp = ("light_position", "light_aim", "light_intensity", "light_angle", "print_reflectance")
    if args.light is None:
        refuse_given(args, lamp, "without --light (the board glows evenly; --light spot|point "
                                 "prints and lights it)")
        return None
    if args.light == "point":
        refuse_given(args, ("light_angle", "light_aim"), "to a point light (spot only)")
    defaults = BoardLight()
    black, white = args.print_reflectance or (defaults.black, defaults.white)
    try:
        return BoardLight(args.light, args.light_position,
                          args.light_aim, args.light_intensity or defaults.intensity,
                          args.light_angle or defaults.cutoff_deg, black, white)
    except ValueError as exc:
        raise CLIError(str(exc)) from None


def add_camera_options(p) -> None:
    """Vignetting, a thin lens and a rolling shutter
    (:class:`synth.products.board_camera.CameraEffects`), each off by default."""
    p.add_argument("--vignetting", action="store_true",
                   help="natural vignetting: each pixel times cos^4 of its ray's angle to the "
                        "optical axis")
    p.add_argument("--lens-falloff", type=non_negative_float, default=None, metavar="F",
                   help="lens (mechanical) vignetting: each pixel times 1 - F (r/r_corner)^2, "
                        "r from the principal point (0 <= F < 1)")
    p.add_argument("--aperture-radius", type=positive_float, default=None, metavar="MM",
                   help="defocus: thin-lens cameras of this aperture radius (mm)")
    p.add_argument("--focus-distance", type=positive_float, default=None, metavar="MM",
                   help="with --aperture-radius: the focus distance (mm; default where the "
                        "middle of --distance appears through the port, paraxially)")
    p.add_argument("--readout-ms", type=positive_float, default=None, metavar="MS",
                   help="rolling shutter: the time from the first row to the last (ms); needs "
                        "--board-velocity; the truth follows each corner's row")
    p.add_argument("--exposure-ms", type=positive_float, default=None, metavar="MS",
                   help="motion blur: a global shutter's exposure time (ms) during which the "
                        "board moves at --board-velocity; the truth is the board at "
                        "mid-exposure (not with --readout-ms)")
    p.add_argument("--board-velocity", type=numbers(3, "VX,VY,VZ in mm/s"), default=None,
                   metavar="VX,VY,VZ", help="with --readout-ms or --exposure-ms: the board's "
                                            "velocity while the image is taken, mm/s in the "
                                            "reference frame")


def effects_from_args(args):
    """The :class:`synth.products.board_camera.CameraEffects` of the camera options, or None
    when none is given; CLIError for an option without its partner."""
    from synth.products.board_camera import CameraEffects

    if args.aperture_radius is None:
        refuse_given(args, ("focus_distance",), "without --aperture-radius (a pinhole has no "
                                                "focus)")
    if args.readout_ms is not None and args.exposure_ms is not None:
        raise CLIError("--readout-ms and --exposure-ms are not rendered together here (a "
                       "rolling shutter, or motion blur in a global shutter): give one of them")
    timed = args.readout_ms is not None or args.exposure_ms is not None
    if timed != (args.board_velocity is not None):
        raise CLIError("--readout-ms or --exposure-ms and --board-velocity go together (a "
                       "rolling shutter or an exposure shows nothing on a still board, and a "
                       "moving board needs a readout or exposure time)")
    effects = CameraEffects(
        cos4=args.vignetting, lens_falloff=args.lens_falloff or 0.0,
        aperture_radius_mm=args.aperture_radius or 0.0,
        focus_distance_mm=args.focus_distance or 0.0,
        readout_s=(args.readout_ms or 0.0) / 1000.0,
        velocity_mm_s=args.board_velocity or (0.0, 0.0, 0.0),
        exposure_s=(args.exposure_ms or 0.0) / 1000.0)
    return None if effects == CameraEffects() else effects


#: Scene parameters of the port, which boards in air (``--air``) do not have.
PORT_PARAMETERS = ("n_water",)


def main(args) -> int:
    """Render stereo pairs of the board at random poses into ``--out`` (skipped when up to
    date)."""
    from synth.products import boards as b
    from synth.scene import apply_seed, apply_spp, load_scene, parse_defines

    board = board_from_args(args)
    light = light_from_args(args)
    try:
        effects = effects_from_args(args)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    cols, rows = board.squares
    if board.symmetric:
        raise CLIError(f"a {cols}x{rows} chessboard looks the same turned by 180°: its rendered "
                       f"corners could not be matched to their truth; render a board with one "
                       f"odd and one even number of squares (eval calibrate takes symmetric "
                       f"boards in real photos)")
    defines = apply_spp(apply_seed(parse_defines(args.defines), args.seed), args.spp)
    for name in defines:
        if name in b.NOT_RENDERED:
            raise CLIError(f"-D {name} does not apply to synth boards: its scene renders the "
                           f"scene's cameras and port with a board (no targets, water medium, "
                           f"lights or thin lens)")
        if args.air and name in PORT_PARAMETERS:
            raise CLIError(f"-D {name} does not apply with --air: the boards are seen in air, "
                           f"with no port")
    spec = load_scene(args.scene, defines)
    # -D spp / -D seed mean what they mean everywhere (the scene's defaults overridden); without
    # them the boards' own defaults hold
    spp = args.spp or (spec.spp if "spp" in defines else b.DEFAULT_SPP)
    seed = spec.seed if "seed" in defines else 0
    manifest = b.write_boards(
        spec.rendered_with(spp=spp, seed=seed), args.out, board,
        n_poses=args.poses or b.DEFAULT_POSES, spp=spp, seed=seed, air=args.air,
        distance_range=tuple(args.distance) if args.distance else None,
        max_tilt_deg=b.DEFAULT_MAX_TILT_DEG if args.max_tilt is None else args.max_tilt,
        variant=args.variant, progress=not args.no_progress, adaptive=not args.full_film,
        light=light, effects=effects)
    if manifest.get("skipped"):
        print(f"{args.out}: up to date (same scene, board and options); nothing to do")
        return 0
    if manifest.get("rendered_again"):
        print(f"{args.out}: {manifest['rendered_again']}; rendering it again")
    w, h = manifest["image_size"]
    views = (f"poses × {len(manifest['cameras'])} cameras" if manifest.get("cameras")
             else "stereo pairs")
    print(f"wrote {args.out}: {manifest['poses']} {views} of a {board.kind} "
          f"{cols}x{rows} ({board.square_mm:g} mm) "
          f"{'in air' if args.air else 'behind ' + _port_name(spec)}, "
          f"{w}x{h} px, {manifest['spp']} spp with {manifest['variant']}: render "
          f"{manifest['seconds']['render']:.1f} s ({manifest['samples_per_second'] / 1e6:.2f} M "
          f"samples/s), total {manifest['seconds']['total']:.1f} s")
    lit = [s["lit_fraction"] for pair in manifest["render"]["views"] for s in pair.values()
           if s.get("lit_fraction") is not None]
    modes = sorted({s["mode"] for pair in manifest["render"]["views"] for s in pair.values()})
    print(f"  render: {' and '.join(modes)}"
          + (f"; lit fraction {min(lit):.1%} to {max(lit):.1%} of the film" if lit else ""))
    return 0


def _port_name(spec) -> str:
    """The glass the boards were rendered behind, in the line ``wrote …``."""
    if spec.extra_ports:
        return f"each camera's own port ({len(spec.all_cameras)} ports)"
    return spec.rig.port.name
