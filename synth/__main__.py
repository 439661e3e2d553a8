"""``python -m synth`` -- write scenes, render them, write and check benchmark datasets.

Subcommands::

    python -m synth scene   --layout paper --z 1000 --out scenes/paper_plane.xml [options]
    python -m synth render  SCENE --out DIR [--spp N] [--variant V] [--exr] [-D name=value ...]
    python -m synth dataset SCENE --out DIR [--spp N] [--variant V] [--exr] [-D name=value ...]
    python -m synth check   DIR [--rms PX] [--max PX] [--json]

Bad input (missing or malformed scene, wrong structure, unknown ``-D``, bad option) prints one
line ``python -m synth <cmd>: error: ...`` and exits with code 2; ``check`` exits with 1 when the
dataset is outside the bounds.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

PROG = "python -m synth"


class _Fail(Exception):
    """A user error: printed as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line instead of usage + error
        raise _Fail(f"{self.prog}: error: {message}")


def _add_render_options(p):
    p.add_argument("scene", help="Mitsuba 3 scene file written by `python -m synth scene`")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--spp", type=int, help="samples per pixel (default: the scene's spp)")
    p.add_argument("--seed", type=int, help="sampler seed (default: the scene's seed)")
    p.add_argument("--variant", help="Mitsuba variant (default: cuda_ad_rgb > llvm_ad_rgb > "
                                     "scalar_rgb, whichever works here)")
    p.add_argument("--exr", action="store_true", help="also write float32 linear EXR images")
    p.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="override a <default> of the scene (repeatable)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=PROG, description="Mitsuba scenes and datasets of a stereo rig "
                                            "behind a flat port (units mm).")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("scene", help="write a Mitsuba scene of the rig, the port and targets")
    p.add_argument("--out", required=True, help="scene file to write (.xml)")
    p.add_argument("--layout", choices=("paper", "grid", "random"), default="paper",
                   help="paper: 496 targets on concentric circles; grid; random volume")
    p.add_argument("--z", type=float, default=1000.0, help="target plane Z, mm (paper, grid)")
    p.add_argument("--spacing", type=float, default=50.0, help="grid spacing, mm")
    p.add_argument("--half-width", type=float, default=500.0, help="grid half width, mm")
    p.add_argument("--n", type=int, default=200, help="number of random targets")
    p.add_argument("--z-range", type=float, nargs=2, default=(600.0, 2000.0),
                   metavar=("ZMIN", "ZMAX"), help="random targets' depth range, mm")
    p.add_argument("--layout-seed", type=int, default=0, help="seed of the random layout")
    p.add_argument("--port", choices=("paper", "none"), default="paper",
                   help="the paper's air-glass-water port, or none (all air)")
    p.add_argument("--n-water", type=float, help="water index (default 1.33)")
    p.add_argument("--n-glass", type=float, help="glass index (default 1.54)")
    p.add_argument("--port-distance", type=float, help="D, mm (default 100)")
    p.add_argument("--glass-thickness", type=float, help="d, mm (default 5)")
    p.add_argument("--size", type=int, nargs=2, metavar=("W", "H"),
                   help="image size, px (default 2448 2048); the focal length scales with W")
    p.add_argument("--focal", type=float, help="focal length, px (default 1100·W/2448)")
    p.add_argument("--dist", type=float, nargs="+", metavar="K",
                   help="OpenCV distortion coefficients of both cameras (4, 5 or 8)")
    p.add_argument("--target-radius", type=float, help="target disk radius, mm (default 2.5)")
    p.add_argument("--spp", type=int, help="default samples per pixel written into the scene")
    p.add_argument("--seed", type=int, default=0, help="default sampler seed of the scene")

    p = sub.add_parser("render", help="render both views to 16-bit linear PNGs (+ previews)")
    _add_render_options(p)
    p = sub.add_parser("dataset", help="render and write a benchmark dataset, atomically")
    _add_render_options(p)

    p = sub.add_parser("check", help="detect targets in a dataset and compare with pixels.csv")
    p.add_argument("dir", help="dataset directory")
    p.add_argument("--rms", type=float, default=None, help="RMS bound, px (default 0.05)")
    p.add_argument("--max", type=float, default=None, help="max bound, px (default 0.15)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    return parser


# ---------------------------------------------------------------------------------------------
def _cmd_scene(args) -> int:
    from measure import FlatPort

    from . import layouts, rig as rigs
    from .scene import DEFAULT_SPP, DEFAULT_TARGET_RADIUS_MM, write_scene

    size = tuple(args.size) if args.size else rigs.PAPER_IMAGE_SIZE
    if min(size) <= 0:
        raise _Fail(f"{PROG} scene: error: --size must be positive")
    focal = args.focal if args.focal else rigs.PAPER_FOCAL_PX * size[0] / rigs.PAPER_IMAGE_SIZE[0]
    left, right = rigs.paper_cameras(size, focal, args.dist)
    port = None
    if args.port == "paper":
        n = list(rigs.PAPER_INDICES)
        if args.n_glass is not None:
            n[1] = args.n_glass
        if args.n_water is not None:
            n[2] = args.n_water
        port = FlatPort((0.0, 0.0, 1.0),
                        args.port_distance if args.port_distance is not None
                        else rigs.PAPER_PORT_DISTANCE_MM,
                        (args.glass_thickness if args.glass_thickness is not None
                         else rigs.PAPER_GLASS_THICKNESS_MM,), tuple(n))
    if args.layout == "paper":
        targets = layouts.paper_plane(args.z)
    elif args.layout == "grid":
        targets = layouts.grid_plane(args.z, args.half_width, args.spacing)
    else:
        targets = layouts.random_volume(args.n, args.layout_seed, tuple(args.z_range))
    radius = args.target_radius if args.target_radius else DEFAULT_TARGET_RADIUS_MM
    comment = (f"written by python -m synth scene: layout {args.layout}"
               + (f", z {args.z:g} mm" if args.layout != "random" else "")
               + f", port {args.port}, target radius {radius:g} mm")
    write_scene(args.out, (left, right), port, targets, radius,
                spp=args.spp if args.spp else DEFAULT_SPP, seed=args.seed, comment=comment)
    print(f"wrote {args.out}: {targets.shape[0]} targets of radius {radius:g} mm, "
          f"{'port' if port else 'no port'}, {size[0]}x{size[1]} px")
    return 0


def _spec(args):
    from .scene import load_scene, parse_defines

    return load_scene(args.scene, parse_defines(args.defines))


def _cmd_render(args) -> int:
    from .render import png16_scale, render_stereo, srgb_preview, to_png16, write_exr, write_png

    spec = _spec(args)
    t0 = time.perf_counter()
    left, right, info = render_stereo(spec, spp=args.spp, variant=args.variant,
                                      progress=not args.quiet, seed=args.seed)
    os.makedirs(args.out, exist_ok=True)
    scale = png16_scale(left, right)
    white = max(float(left.max()), float(right.max()))
    for name, img in (("left", left), ("right", right)):
        for suffix, data in (("", to_png16(img, scale)), ("_preview", srgb_preview(img, white))):
            final = os.path.join(args.out, f"{name}{suffix}.png")
            tmp = os.path.join(args.out, f".{name}{suffix}.tmp.png")
            write_png(tmp, data)
            os.replace(tmp, final)
        if args.exr:
            tmp = os.path.join(args.out, f".{name}.tmp.exr")
            write_exr(tmp, img, info["variant"])
            os.replace(tmp, os.path.join(args.out, f"{name}.exr"))
    print(f"rendered {spec.path} with {info['variant']}, {info['spp']} spp, "
          f"{info['size'][0]}x{info['size'][1]} px: left {info['seconds']['left']:.1f} s, "
          f"right {info['seconds']['right']:.1f} s, {info['samples_per_second'] / 1e6:.2f} M "
          f"samples/s, total {time.perf_counter() - t0:.1f} s; png_scale {scale:.6g} -> {args.out}")
    return 0


def _cmd_dataset(args) -> int:
    from .dataset import write_dataset
    from .scene import parse_defines

    manifest = write_dataset(args.scene, args.out, defines=parse_defines(args.defines), spp=args.spp, variant=args.variant, exr=args.exr,
                             progress=not args.quiet, seed=args.seed)
    if manifest.get("skipped"):
        print(f"{args.out}: up to date (same scene, parameters and options); nothing to do")
        return 0
    s = manifest["seconds"]
    stages = ", ".join(f"{k} {v:.2f} s" for k, v in s.items() if k != "total")
    print(f"wrote {args.out} with {manifest['variant']}, {manifest['spp']} spp: {stages}; "
          f"total {s['total']:.1f} s")
    return 0


def _cmd_check(args) -> int:
    from .dataset import CHECK_MAX_PX, CHECK_RMS_PX, check_dataset

    report = check_dataset(args.dir, rms_px=args.rms if args.rms is not None else CHECK_RMS_PX,
                           max_px=args.max if args.max is not None else CHECK_MAX_PX)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        for view in ("left", "right"):
            r = report[view]
            rej = ", ".join(f"{k} {v}" for k, v in r["rejected"].items() if v) or "none"
            print(f"{view:5s}: found {r['found']}/{r['in_image']} in-image targets "
                  f"({r['detected']} detections, {r['unmatched_detections']} unmatched; "
                  f"rejected {rej}); RMS {r['rms_px']:.4f} px, max {r['max_px']:.4f} px, "
                  f"mean offset ({r['mean_px'][0]:+.4f}, {r['mean_px'][1]:+.4f}) px"
                  + (f"; missed ids {r['missed'][:10]}" if r["missed"] else ""))
        b = report["bounds"]
        print(f"both : RMS {report['rms_px']:.4f} px (<= {b['rms_px']}), max "
              f"{report['max_px']:.4f} px (<= {b['max_px']}), all found: "
              f"{'yes' if report['all_found'] else 'no'} -> "
              f"{'PASS' if report['passed'] else 'FAIL'}")
    return 0 if report["passed"] else 1


COMMANDS = {"scene": _cmd_scene, "render": _cmd_render, "dataset": _cmd_dataset,
            "check": _cmd_check}


def main(argv=None) -> int:
    """Run the CLI; returns the exit code (2 on bad input, with one line on stderr)."""
    from .dataset import DatasetError
    from .scene import SceneError

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        return COMMANDS[args.command](args)
    except _Fail as exc:
        print(str(exc), file=sys.stderr)
        return 2
    except (SceneError, DatasetError, ValueError, OSError) as exc:
        command = (argv if argv is not None else sys.argv[1:] or ["?"])[0]
        message = " ".join(str(exc).split("\n")[0].split())
        print(f"{PROG} {command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
