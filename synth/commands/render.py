"""``python -m synth render SCENE --out DIR [--spp N] [--variant V] [--exr]
[-D name=value ...]``: every view (``left``, ``right``; ``cam0``, ``cam1``, … of a scene of N
cameras) as 16-bit linear PNGs (scale in the summary line) and sRGB
previews, optionally float32 EXR."""

from __future__ import annotations

import os
import time

from synth.commands.common import add_render_options, scene_from_args


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("render", help="render both views to 16-bit linear PNGs (+ previews)")
    add_render_options(p, "synth render")


def main(args) -> int:
    """Render every view of the scene into ``--out`` (``left``, ``right``; a scene of N
    cameras ``cam0``, ``cam1``, …)."""
    from synth.infra.fileio import OutputDir
    from synth.rendering.image_files import png16_scale, srgb_preview, to_png16, write_exr, write_png
    from synth.rendering.render import render_summary, render_views

    output = OutputDir(args.out, "synth render").claim()
    spec = scene_from_args(args)
    t0 = time.perf_counter()
    images, info = render_views(spec, spp=args.spp, variant=args.variant,
                                progress=not args.no_progress, adaptive=not args.full_film)
    names = spec.camera_names
    scale = png16_scale(*images)
    white = max(float(img.max()) for img in images)
    with output.staged() as tmp:
        for name, img in zip(names, images):
            write_png(os.path.join(tmp, f"{name}.png"), to_png16(img, scale))
            write_png(os.path.join(tmp, f"{name}_preview.png"), srgb_preview(img, white))
            if args.exr:
                write_exr(os.path.join(tmp, f"{name}.exr"), img, info["variant"])
    from synth.rendering.render import spp_text

    print(f"rendered {spec.path} with {info['variant']}, "
          f"{spp_text(info['spp'], info.get('spp_rendered'))}, "
          f"{info['size'][0]}x{info['size'][1]} px: "
          + ", ".join(f"{name} {info['seconds'][name]:.1f} s" for name in names)
          + f", {info['samples_per_second'] / 1e6:.2f} M "
          f"samples/s, total {time.perf_counter() - t0:.1f} s; png_scale {scale:.6g} -> {args.out}")
    for name in names:
        print(f"  {name}: {render_summary(info['render'][name])}")
    return 0
