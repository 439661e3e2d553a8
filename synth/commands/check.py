"""``python -m synth check DIR [--rms PX] [--max PX] [--json]``: detect the targets of a dataset
and compare them with its pixels.csv (:mod:`synth.products.crosscheck`), or check a surface dataset's truth
maps (:mod:`synth.products.truth_maps`); exit code 1 when the dataset is outside the bounds."""

from __future__ import annotations

import json

import sys

from synth.infra.cli import add_json_option, positive_float, refuse_given


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("check",
                              help="detect targets in a dataset and compare with pixels.csv")
    p.add_argument("dir", help="dataset directory")
    p.add_argument("--rms", type=positive_float, default=None, help="RMS bound, px (default 0.05)")
    p.add_argument("--max", type=positive_float, default=None, help="max bound, px (default 0.15)")
    add_json_option(p)


def main(args) -> int:
    """Check the dataset ``dir``; 0 when it passes, 1 when it does not."""
    from synth.products.crosscheck import CHECK_MAX_PX, CHECK_RMS_PX, check_dataset
    from synth.products.dataset import read_dataset

    data = read_dataset(args.dir)
    if data.is_surface:
        refuse_given(args, ["rms", "max"], f"to the surface dataset {args.dir}: its truth maps "
                                           f"are checked, no detection")
        return _check_surface(args, data)

    report = check_dataset(args.dir, rms_px=args.rms if args.rms is not None else CHECK_RMS_PX,
                           max_px=args.max if args.max is not None else CHECK_MAX_PX)
    stream = sys.stderr if args.json else sys.stdout
    width = max(len(view) for view in report["views"])
    for view in report["views"]:
        r = report[view]
        rej = ", ".join(f"{k} {v}" for k, v in r["rejected"].items() if v) or "none"
        print(f"{view:{width}s}: found {r['found']}/{r['in_image']} in-image targets "
                  f"({r['detected']} detections, {r['unmatched_detections']} unmatched; "
              f"rejected {rej}); RMS {r['rms_px']:.4f} px, max {r['max_px']:.4f} px, "
              f"mean offset ({r['mean_px'][0]:+.4f}, {r['mean_px'][1]:+.4f}) px"
              + (f"; missed ids {r['missed'][:10]}" if r["missed"] else ""), file=stream)
    b = report["bounds"]
    label = "both" if len(report["views"]) == 2 else "all"
    print(f"{label:{width}s}: RMS {report['rms_px']:.4f} px (<= {b['rms_px']}), max "
          f"{report['max_px']:.4f} px (<= {b['max_px']}), all found: "
          f"{'yes' if report['all_found'] else 'no'} -> "
          f"{'PASS' if report['passed'] else 'FAIL'}", file=stream)
    _print_json(args, report)
    return 0 if report["passed"] else 1


def _print_json(args, report) -> None:
    """With ``--json``, the report as JSON on stdout."""
    if args.json:
        from synth.infra.fileio import jsonable

        print(json.dumps(jsonable(report), indent=2))


def _check_surface(args, data) -> int:
    """``check`` of a surface dataset: the truth maps (see synth.products.truth_maps.check_truth_maps)."""
    from synth.products.truth_maps import check_truth_maps

    report = check_truth_maps(data)
    stream = sys.stderr if args.json else sys.stdout
    for view in ("left", "right"):
        r = report[view]
        print(f"{view:5s}: {r['valid_pixels']} pixels see the surface, {r['overlap_pixels']} of "
              f"them seen by the other camera too; truth points' Fermat projection to their "
              f"pixel centres: max {r['round_trip_max_px']:.2e} px; renderer lit "
              f"{r['lit_outside_surface']} pixels off the surface, left "
              f"{r['black_on_surface']} on it black", file=stream)
    print(f"truth maps: max round trip <= {report['bound_px']:g} px -> "
          f"{'PASS' if report['passed'] else 'FAIL'}", file=stream)
    _print_json(args, report)
    return 0 if report["passed"] else 1
