"""``python -m synth sequence SCENE (--approach FROM,TO --frames N [--yaw DEG] [--fps 10] |
--trajectory FILE) --out DIR [--size-mm 1000] [--marker-radius-mm 10] [--spp N] [--seed S]``: a
docking frame approaching the scene's rig, or along a TUM trajectory or ``poses.csv``, rendered
frame by frame with its true pose
(:mod:`synth.products.sequence`; ``python -m eval track`` follows it)."""

from __future__ import annotations

import argparse

from synth.infra.cli import (CLIError, add_define_option, add_full_film_option, add_out_option,
                             add_progress_option, add_scene_argument,
                             positive_float, positive_int, scene_seed)


def approach(text: str) -> tuple[float, float]:
    """An argparse type: ``FROM,TO`` two positive distances in mm."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 2 or not all(v > 0 and v < float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"expected FROM,TO (two positive distances in mm), "
                                         f"got {text!r}")
    return values


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("sequence", help="render a docking frame approaching the rig, "
                                               "frame by frame with its true pose")
    add_scene_argument(p)
    add_out_option(p, "synth sequence")
    p.add_argument("--approach", type=approach, default=None, metavar="FROM,TO",
                   help="the frame's distance (mm, along the port normal from the left camera) "
                        "in the first and the last frame (or --trajectory)")
    p.add_argument("--trajectory", default=None, metavar="FILE",
                   help="instead of --approach: the object's pose per frame, a TUM trajectory "
                        "(timestamp tx ty tz qx qy qz qw, metres; the reference frame = the left "
                        "camera's) or a poses.csv of synth sequence (mm); its time stamps are "
                        "the frames' (--frames, --yaw and --fps do not apply)")
    p.add_argument("--frames", type=positive_int, default=None,
                   help="number of frames (with --approach)")
    p.add_argument("--yaw", type=float, default=0.0, metavar="DEG",
                   help="the frame turns about y from 0 to this angle (degrees; default 0)")
    p.add_argument("--size-mm", type=positive_float, default=1000.0,
                   help="side of the docking frame's square (mm; default 1000)")
    p.add_argument("--marker-radius-mm", type=positive_float, default=None,
                   help="radius of the marker disks (mm; default 10)")
    p.add_argument("--fps", type=positive_float, default=None,
                   help="frames per second of the time stamps (default 10)")
    p.add_argument("--spp", type=positive_int, default=None,
                   help="samples per pixel (default: the scene's spp)")
    p.add_argument("--seed", type=scene_seed, default=None,
                   help="the renderer's seed, frame k renders with seed + 2k (default: the "
                        "scene's)")
    p.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    add_full_film_option(p)
    add_define_option(p)
    add_progress_option(p)


def main(args) -> int:
    """Render the sequence into ``--out``."""
    from synth.products import sequence as s
    from synth.scene import load_scene, parse_defines

    trajectory = None
    if (args.approach is None) == (args.trajectory is None):
        raise CLIError("give --approach FROM,TO with --frames N, or --trajectory FILE (one of "
                       "them)")
    if args.trajectory is not None:
        for option, value in (("--frames", args.frames), ("--fps", args.fps),
                              ("--yaw", args.yaw or None)):
            if value is not None:
                raise CLIError(f"{option} does not apply with --trajectory (the file gives "
                               f"every pose and its time)")
        try:
            trajectory = (args.trajectory, *s.read_trajectory(args.trajectory))
        except ValueError as exc:
            raise CLIError(f"--trajectory {exc}") from None
    elif args.frames is None:
        raise CLIError("--approach needs --frames N (the number of frames)")
    if abs(args.yaw) >= 60:
        raise CLIError(f"--yaw {args.yaw:g}: at most 60 degrees in magnitude (the markers "
                       f"face the cameras)")
    spec = load_scene(args.scene, parse_defines(args.defines)).require_two_cameras(
        "synth sequence")
    try:
        manifest = s.write_sequence(
            spec, args.out, args.approach, args.frames, yaw_deg=args.yaw,
            size_mm=args.size_mm,
            marker_radius_mm=args.marker_radius_mm or s.DEFAULT_MARKER_RADIUS_MM,
            fps=args.fps or s.DEFAULT_FPS, spp=args.spp, seed=args.seed, variant=args.variant,
            progress=not args.no_progress, adaptive=not args.full_film, trajectory=trajectory)
    except ValueError as exc:
        raise CLIError(f"{args.scene}: {exc}") from None
    w, h = manifest["image_size"]
    path = (f"from {args.approach[0]:g} to {args.approach[1]:g} mm" if trajectory is None
            else f"along {args.trajectory}")
    print(f"wrote {args.out}: {manifest['frames']} frames of a docking frame "
          f"({manifest['object']['size_mm']:g} mm) {path}, {w}x{h} px, {manifest['spp']} spp with "
          f"{manifest['variant']}: render {manifest['seconds']['render']:.1f} s, total "
          f"{manifest['seconds']['total']:.1f} s; true poses in poses.csv and poses_tum.txt")
    return 0
