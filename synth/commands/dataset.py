"""``python -m synth dataset SCENE --out DIR [--spp N] [--variant V] [--exr] [--sensor PRESET]
[-D name=value ...]``: render and write a benchmark dataset, atomically (:mod:`synth.products.dataset`;
a scene of more than two cameras: one folder per camera, :mod:`synth.products.dataset_layout`)."""

from __future__ import annotations

from synth.infra.cli import CLIError
from synth.commands.common import add_render_options, scene_from_args


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("dataset", help="render and write a benchmark dataset, atomically")
    add_render_options(p, "synth dataset")
    p.add_argument("--sensor", metavar="PRESET[,name=value…]",
                   help="store the images as a camera sensor's raw codes (exposure, shot and "
                        "read noise, dark level, gain, bit depth; seeded): preset imx174; "
                        "overrides full_well_e, read_noise_e, bit_depth, dark_level_dn, exposure")


def main(args) -> int:
    """Render the scene and write the benchmark dataset ``--out`` (skipped when up to date)."""
    from synth.products.dataset import write_dataset
    from synth.rendering.sensor_model import SensorError, sensor_from_spec

    try:
        sensor = None if args.sensor is None else sensor_from_spec(args.sensor)
    except SensorError as exc:
        raise CLIError(f"--sensor {args.sensor}: {exc}") from None
    spec = scene_from_args(args)
    if spec.extra_cameras and spec.surface is not None:
        raise CLIError(f"{args.scene}: a surface scene of {len(spec.all_cameras)} cameras; synth "
                       f"dataset writes a surface's truth maps for two cameras")
    manifest = write_dataset(spec, args.out, spp=args.spp, variant=args.variant, exr=args.exr,
                             progress=not args.no_progress, sensor=sensor,
                             adaptive=not args.full_film)
    if manifest.get("skipped"):
        print(f"{args.out}: up to date (same scene, parameters and options); nothing to do")
        return 0
    if manifest.get("rendered_again"):
        print(f"{args.out}: {manifest['rendered_again']}; rendering it again")
    s = manifest["seconds"]
    stages = ", ".join(f"{k} {v:.2f} s" for k, v in s.items() if k != "total")
    from synth.rendering.render import spp_text

    print(f"wrote {args.out} with {manifest['variant']}, "
          f"{spp_text(manifest['spp'], manifest.get('spp_rendered'))}: {stages}; "
          f"total {s['total']:.1f} s")
    from synth.rendering.render import render_summary

    for name in manifest.get("cameras") or ("left", "right"):
        print(f"  {name}: {render_summary(manifest['render'][name])}")
    return 0

