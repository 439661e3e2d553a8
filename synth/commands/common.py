"""What several ``python -m synth`` commands share: the options of ``render`` and ``dataset``
and the scene they load (``-D`` and ``--seed`` applied)."""

from __future__ import annotations

from synth.infra.cli import (add_define_option, add_full_film_option, add_out_option,
                       add_progress_option, add_scene_argument, positive_int, scene_seed)


def add_render_options(p, command: str) -> None:
    """The arguments of ``render`` and ``dataset`` (``command``, for the ``--out`` rule): the
    scene, ``--out`` and the rendering options."""
    add_scene_argument(p)
    add_out_option(p, command)
    p.add_argument("--spp", type=positive_int, help="samples per pixel (default: the scene's spp)")
    p.add_argument("--seed", type=scene_seed,
                   help="the scene's seed, same as -D seed=S (default: the scene's seed)")
    p.add_argument("--variant", help="Mitsuba variant (default: cuda_ad_rgb > llvm_ad_rgb > "
                                     "scalar_rgb, whichever works here)")
    p.add_argument("--exr", action="store_true", help="also write float32 linear EXR images")
    add_full_film_option(p)
    add_define_option(p)
    add_progress_option(p)


def scene_from_args(args):
    """The scene with ``-D``, ``--seed`` and ``--spp`` applied (``--seed S`` is ``-D seed=S``,
    ``--spp N`` is ``-D spp=N``: a ``-D`` with another value is refused). A scene of N
    cameras has :attr:`synth.scene.model.SceneSpec.extra_cameras`: each command writes every
    view (``render``, ``dataset``)."""
    from synth.scene import apply_seed, apply_spp, load_scene, parse_defines

    defines = apply_spp(apply_seed(parse_defines(args.defines), args.seed), args.spp)
    return load_scene(args.scene, defines).rendered_with(spp=args.spp)
