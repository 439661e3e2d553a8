"""``python -m synth learn --out DIR --scenes N [--seed S] [--size WxH] [--spp N]
[--ports …] [--water …] [--light …] [--distance NEAR,FAR] [--pitch LOW,HIGH]
[--split TRAIN,VAL,TEST] [--workers N | --scheduler tcp://HOST:PORT]``: generate sea scenes —
a sea floor seen through a housing's port, drawn from one seed each — render them and write the
truth and file layouts learned stereo and MVS tools read (:mod:`synth.products.learn_set`,
:mod:`synth.products.learn_scene`) on the Dask cluster ``synth suite`` uses.

Resumable: a rerun renders only the scenes without a whole folder; more scenes (a larger
``--scenes``) extend a set written with the same options. Exit 1 when a scene failed or missed
a check's bound."""

from __future__ import annotations

from synth.infra.cli import (CLIError, add_cluster_options, add_out_option, add_progress_option,
                             refuse_given)
from synth.scene.sea_write import DEFAULT_LEARN_SPP

#: What each choice option accepts.
CHOICES = {"ports": ("flat", "per-camera", "dome"),
           "water": ("clear", "clear_ocean", "coastal", "turbid_harbor"),
           "light": ("lamps", "sun")}


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "learn", help="generate sea scenes through real ports: training and test data for "
                      "learned stereo and MVS",
        description="Draw N sea scenes (a sea floor with slopes, ripples and rocks, textured "
                    "sand, gravel and rock; a stereo rig behind a flat port, two housings or "
                    "domes from the ranges of real rigs; clear to turbid water; lamps or sun), "
                    "one seed each, render both views and write per view and pair the truth "
                    "of the exact forward model (depth, range, points, normals, flow and "
                    "occlusion; a rectified pair with disparity and the warp's residual), "
                    "KITTI and SceneFlow files, COLMAP models, a manifest of SHA-256, and a "
                    "train/val/test split by seed. On Dask; resumable.")
    add_out_option(p, "synth learn", rule="updated in place scene by scene, so that a killed "
                   "run keeps what it finished; an existing one is used only if it is an "
                   "earlier output of synth learn with the same options (more scenes may be "
                   "added)")
    p.add_argument("--scenes", type=_count, default=10, metavar="N",
                   help="number of scenes (default 10): seeds S, S+1, …, S+N-1")
    p.add_argument("--seed", type=_count0, default=0, metavar="S",
                   help="seed of the first scene (default 0)")
    p.add_argument("--size", type=_size, default=(960, 768), metavar="WxH",
                   help="image size in px (default 960x768)")
    p.add_argument("--spp", type=_count, default=DEFAULT_LEARN_SPP, metavar="N",
                   help=f"samples per pixel (default {DEFAULT_LEARN_SPP}; the render is most "
                        f"of the time a scene takes, in proportion)")
    for name, what in (("ports", "kinds of port"), ("water", "waters"), ("light", "lights")):
        p.add_argument(f"--{name}", type=_choices(name), default=CHOICES[name],
                       metavar=",".join(CHOICES[name]),
                       help=f"the {what} a scene is drawn from, comma-separated (default: all)")
    p.add_argument("--distance", type=_pair("--distance", 100.0, 20000.0),
                   default=(800.0, 2500.0), metavar="NEAR,FAR",
                   help="range of the rig's distance to the sea floor along its axis, mm "
                        "(default 800,2500)")
    p.add_argument("--pitch", type=_pair("--pitch", 30.0, 90.0), default=(50.0, 90.0),
                   metavar="LOW,HIGH",
                   help="range of the rig's pitch below the horizontal, degrees (default "
                        "50,90; 90 looks straight down)")
    p.add_argument("--object", dest="objects", action="append", default=[], metavar="FILE",
                   help="an object mesh (PLY or OBJ, mm, z up: a rock, a pipe) to set on the "
                        "floors, 0-3 per scene at drawn places and headings; repeatable")
    p.add_argument("--split", type=_fractions, default=(0.8, 0.1, 0.1), metavar="TRAIN,VAL,TEST",
                   help="shares of the train, val and test splits (default 0.8,0.1,0.1); a "
                        "scene's split is a function of its seed")
    add_cluster_options(p)
    add_progress_option(p)


def _count(text: str) -> int:
    return _integer(text, 1)


def _count0(text: str) -> int:
    return _integer(text, 0)


def _integer(text: str, minimum: int) -> int:
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
    return value


def _size(text: str) -> tuple:
    import argparse

    parts = text.lower().split("x")
    try:
        w, h = (int(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not WxH: {text!r}") from None
    if min(w, h) < 64 or max(w, h) > 8192:
        raise argparse.ArgumentTypeError(f"each side must be 64-8192 px, got {w}x{h}")
    return (w, h)


def _choices(name: str):
    def parse(text: str) -> tuple:
        import argparse

        items = tuple(dict.fromkeys(t.strip() for t in text.split(",") if t.strip()))
        bad = [t for t in items if t not in CHOICES[name]]
        if not items or bad:
            raise argparse.ArgumentTypeError(
                f"{', '.join(bad) or 'nothing'} is not one of {', '.join(CHOICES[name])}")
        return items
    return parse


def _pair(option: str, low: float, high: float):
    def parse(text: str) -> tuple:
        import argparse
        import math

        try:
            a, b = (float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"not two numbers A,B: {text!r}") from None
        if not (math.isfinite(a) and math.isfinite(b) and low <= a <= b <= high):
            raise argparse.ArgumentTypeError(f"needs {low:g} <= A <= B <= {high:g}, got {text}")
        return (a, b)
    return parse


def _fractions(text: str) -> tuple:
    import argparse

    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not three numbers: {text!r}") from None
    if len(values) != 3 or min(values) < 0 or sum(values) <= 0:
        raise argparse.ArgumentTypeError(f"needs three shares >= 0, not all 0, got {text}")
    return values


def main(args) -> int:
    from synth.infra.cluster import check_address
    from synth.products.learn_run import LearnRequest, checked_objects, run_learn
    from synth.scene.sea_draw import SeaRanges

    if args.scheduler is None:
        refuse_given(args, ["connect_timeout"], "without --scheduler (the local cluster is "
                                                "started here, nothing is connected to)")
    else:
        check_address(args.scheduler)
        if args.workers is not None:
            raise CLIError("--workers sets the size of the local cluster; with --scheduler the "
                           "cluster's workers render the scenes")
    ranges = SeaRanges(size=tuple(args.size), ports=args.ports, waters=args.water,
                       lights=args.light, distance_mm=tuple(args.distance),
                       pitch_deg=tuple(args.pitch), objects=checked_objects(args.objects))
    request = LearnRequest(args.out, tuple(range(args.seed, args.seed + args.scenes)), ranges,
                           args.spp, tuple(args.split))
    return run_learn(request, args.scheduler, args.workers, args.connect_timeout,
                     not args.no_progress)


__all__ = ["add_parser", "main"]
