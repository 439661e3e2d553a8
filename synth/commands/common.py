"""What several ``python -m synth`` commands share: the options of ``render`` and ``dataset``
and the scene they load (``-D`` and ``--seed`` applied)."""

from __future__ import annotations

from synth.cli import non_negative_int, positive_int


def add_render_options(p) -> None:
    """The arguments of ``render`` and ``dataset``: the scene, ``--out`` and the rendering
    options."""
    p.add_argument("scene", help="Mitsuba 3 scene file written by `python -m synth scene`")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--spp", type=positive_int, help="samples per pixel (default: the scene's spp)")
    p.add_argument("--seed", type=non_negative_int,
                   help="the scene's seed, same as -D seed=S (default: the scene's seed)")
    p.add_argument("--variant", help="Mitsuba variant (default: cuda_ad_rgb > llvm_ad_rgb > "
                                     "scalar_rgb, whichever works here)")
    p.add_argument("--exr", action="store_true", help="also write float32 linear EXR images")
    p.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="override a <default> of the scene (repeatable)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def scene_from_args(args):
    """The scene with ``-D`` and ``--seed`` applied (``--seed S`` is ``-D seed=S``)."""
    from synth.scene import apply_seed, load_scene, parse_defines

    return load_scene(args.scene, apply_seed(parse_defines(args.defines), args.seed))
