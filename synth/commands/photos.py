"""``python -m synth photos SRC --out DIR [--format jpg|png] [--quality 90]``: a boards folder
or a dataset written as a camera would store it — 8-bit sRGB photos in ``DIR/left/`` and
``DIR/right/`` (``DIR/cam0/``, … for a dataset of more cameras), paired by name, with no
calibration or truth beside them (:mod:`synth.products.photos`)."""

from __future__ import annotations

from synth.infra.cli import CLIError, add_out_option, positive_int


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("photos", help="write rendered pairs as 8-bit sRGB photos "
                                             "(left/, right/; no truth)")
    p.add_argument("src", help="a synth boards folder or a synth dataset")
    add_out_option(p, "synth photos")
    p.add_argument("--format", choices=("jpg", "png"), default="jpg",
                   help="file format (default jpg)")
    p.add_argument("--quality", type=positive_int, default=None,
                   help="JPEG quality 1-100 (default 90)")


def main(args) -> int:
    """Write the photos of ``src`` into ``--out`` (whole or not at all)."""
    import os

    from synth.infra.fileio import OutputDir
    from synth.products.photos import export_views

    if args.quality is not None and args.format != "jpg":
        raise CLIError(f"--quality does not apply to --format {args.format} (lossless)")
    quality = 90 if args.quality is None else args.quality
    if not 1 <= quality <= 100:
        raise CLIError(f"--quality must be 1..100, got {quality}")
    if not os.path.isdir(args.src):
        raise CLIError(f"{args.src}: no such folder")
    output = OutputDir(args.out, "synth photos").claim()
    with output.staged() as tmp:
        views, count = export_views(args.src, tmp, args.format, quality)
    detail = f"JPEG quality {quality}" if args.format == "jpg" else "8-bit PNG"
    if len(views) == 2:
        print(f"wrote {args.out}: {count} pair(s) as {detail} in left/ and right/ (sRGB, no "
              f"truth)")
    else:
        print(f"wrote {args.out}: {count} photo(s) per camera as {detail} in "
              f"{', '.join(f'{v}/' for v in views)} (sRGB, no truth)")
    return 0
