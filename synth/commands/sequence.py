"""``python -m synth sequence SCENE --approach FROM,TO --frames N --out DIR [--yaw DEG]
[--size-mm 1000] [--marker-radius-mm 10] [--fps 10] [--spp N] [--seed S]``: a docking frame
approaching the scene's rig, rendered frame by frame with its true pose
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
    p.add_argument("--approach", type=approach, required=True, metavar="FROM,TO",
                   help="the frame's distance (mm, along the port normal from the left camera) "
                        "in the first and the last frame")
    p.add_argument("--frames", type=positive_int, required=True, help="number of frames")
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
            progress=not args.no_progress, adaptive=not args.full_film)
    except ValueError as exc:
        raise CLIError(f"{args.scene}: {exc}") from None
    w, h = manifest["image_size"]
    print(f"wrote {args.out}: {manifest['frames']} frames of a docking frame "
          f"({manifest['object']['size_mm']:g} mm) from {args.approach[0]:g} to "
          f"{args.approach[1]:g} mm, {w}x{h} px, {manifest['spp']} spp with "
          f"{manifest['variant']}: render {manifest['seconds']['render']:.1f} s, total "
          f"{manifest['seconds']['total']:.1f} s; true poses in poses.csv and poses_tum.txt")
    return 0
