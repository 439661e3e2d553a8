"""``python -m synth scene --layout paper --z 1000 --out scenes/paper_plane.xml [options]``:
write a Mitsuba scene of the paper's rig, a port (or none) and targets or a speckled surface
(units mm, the left camera's frame; :mod:`synth.scene`, :mod:`synth.scene.surface_scene`)."""

from __future__ import annotations

import os

from synth.commands.scene_rig import (cameras_from_options, dome_comment, port_from_options,
                                     rig_from_file)
from synth.infra.cli import (WATER_INDEX_HELP, CLIError, add_out_option, any_float,
                       non_negative_float, non_negative_int, positive_float, positive_int,
                       refuse_given, scene_seed, water_index_argument)

#: The first comment of every scene file ``python -m synth scene`` writes.
SCENE_COMMENT_PREFIX = "written by python -m synth scene"


def _coverage(text: str) -> float:
    import argparse

    value = positive_float(text)
    if not value < 1:
        raise argparse.ArgumentTypeError(f"expected a fraction in (0, 1), got {text!r}")
    return value


def _per_camera(base):
    """An argparse type: one number (``base``), or one per camera separated by commas —
    ``LEFT,RIGHT``, or ``V0,V1,…`` for N cameras (``--port per-camera``); a tuple. Whether the
    count fits the cameras is checked where the cameras are known
    (:func:`synth.commands.scene_rig.each_value`)."""

    def parse(text: str) -> tuple:
        return tuple(base(part) for part in str(text).split(","))

    return parse


def _camera_count(text: str) -> int:
    import argparse

    value = positive_int(text)
    if value < 2:
        raise argparse.ArgumentTypeError(f"a rig has at least two cameras, got {text!r}")
    return value


def add_parser(subparsers) -> None:
    """The ``scene`` subparser: ``--out`` and the named groups of options, in ``--help`` order."""
    p = subparsers.add_parser("scene",
                              help="write a Mitsuba scene of the rig, the port and targets")
    add_out_option(p, "synth scene", what="file",
                   rule="the scene (.xml; --layout surface also writes its mesh and speckle "
                        "texture beside it); an existing file is replaced only if python -m synth "
                        "scene wrote it")
    _add_layout_options(p)
    _add_target_options(p)
    _add_port_options(p)
    _add_rig_options(p)
    _add_look_options(p)


def _add_layout_options(p) -> None:
    """What the scene holds: ``--layout`` (targets or a speckled surface) and the
    surface's shape and speckle."""
    p.add_argument("--layout", choices=("paper", "grid", "random", "tilted", "cylinder", "sphere",
                                        "surface"),
                   default="paper",
                   help="paper: 496 targets on concentric circles; grid; random volume; tilted: "
                        "the paper's targets on a tilted plane; cylinder, sphere: targets on a "
                        "convex surface facing the cameras; surface: a speckled surface (mesh) "
                        "for dense matching, see --surface")
    p.add_argument("--surface", choices=("plane", "tilted", "cylinder", "sphere", "wavy", "mesh"),
                   default="plane",
                   help="layout surface: plane facing the cameras at --z; tilted (--tilt); "
                        "cylinder, sphere (--surface-radius, --half-angle); wavy "
                        "(--wave-amplitude, --wavelength); mesh (--mesh FILE)")
    p.add_argument("--mesh", help="layout surface, --surface mesh: a PLY or OBJ file, mm, in the "
                                  "left camera's frame")
    p.add_argument("--speckle-size", type=positive_float, default=2.5,
                   help="layout surface: speckle dot diameter, mm (default 2.5)")
    p.add_argument("--speckle-coverage", type=_coverage, default=0.5,
                   help="layout surface: dark fraction of the speckle pattern (default 0.5)")
    p.add_argument("--speckle-seed", type=non_negative_int, default=0,
                   help="layout surface: seed of the speckle pattern (default 0)")
    p.add_argument("--wave-amplitude", type=positive_float, default=20.0,
                   help="--surface wavy: amplitude, mm (default 20)")
    p.add_argument("--wavelength", type=positive_float, default=300.0,
                   help="--surface wavy: wavelength, mm (default 300)")


def _add_target_options(p) -> None:
    """Where the targets are: the plane's depth, the grid, the tilt, the convex
    surface, the random volume (mm, degrees)."""
    p.add_argument("--z", type=positive_float, default=1000.0,
                   help="target plane Z, mm (paper, grid; tilted: its centre; cylinder, "
                        "sphere: the nearest point of the surface)")
    p.add_argument("--spacing", type=positive_float, default=50.0,
                   help="target spacing, mm (grid; cylinder and sphere: along the surface)")
    p.add_argument("--tilt", type=any_float, nargs=2, metavar=("ABOUT_X", "ABOUT_Y"),
                   default=(0.0, 30.0), help="tilt of the target plane, degrees (layout tilted; "
                                             "default 0 30)")
    p.add_argument("--surface-radius", type=positive_float, default=400.0,
                   help="radius of the cylinder or sphere, mm (default 400)")
    p.add_argument("--half-angle", type=positive_float, default=60.0,
                   help="targets up to this angle from the line or point facing the cameras, "
                        "degrees (cylinder, sphere; default 60)")
    p.add_argument("--half-width", type=non_negative_float, default=500.0, help="grid half width, mm")
    p.add_argument("--n", type=positive_int, default=200, help="number of random targets")
    p.add_argument("--z-range", type=positive_float, nargs=2, default=(600.0, 2000.0),
                   metavar=("ZMIN", "ZMAX"), help="random targets' depth range, mm")
    p.add_argument("--layout-seed", type=non_negative_int, default=0, help="seed of the random layout")


def _add_port_options(p) -> None:
    """The port: one flat port, a flat port per camera, a dome per camera or none,
    and its numbers (indices, distances, thicknesses, layers, tilt)."""
    p.add_argument("--port", choices=("paper", "per-camera", "dome", "mixed", "none"),
                   default="paper",
                   help="the paper's air-glass-water port; per-camera: a housing per camera, "
                        "each camera behind its own flat port (a finite window; --port-distance, "
                        "--port-tilt, --glass-thickness take LEFT,RIGHT values — N cameras: "
                        "V0,V1,… —, each port relative to its own camera); dome: each camera inside its own "
                        "glass dome (two concentric spheres, --dome-radius, --dome-thickness, "
                        "--dome-offset); mixed: the kind of --ports for each camera; or none "
                        "(all air)")
    p.add_argument("--ports", metavar="K0,K1,…",
                   help="--port mixed: each camera's kind of port, in camera order: paper (the "
                        "one flat port they share; --port-distance, --glass-thickness, "
                        "--port-tilt, --layer), per-camera (its own flat window, the defaults), "
                        "dome (its own dome; the --dome-* options) or none (in air); e.g. "
                        "paper,paper,dome,dome")
    p.add_argument("--dome-radius", type=positive_float,
                   help="--port dome: inner radius of each dome, mm (default 50)")
    p.add_argument("--dome-thickness", type=positive_float,
                   help="--port dome: glass thickness of each dome, mm (default 8)")
    p.add_argument("--dome-offset", type=any_float, nargs=3, metavar=("X", "Y", "Z"),
                   help="--port dome: the dome centre relative to each camera's centre, mm, in "
                        "that camera's frame (the same for every camera; default 0 0 0: centred)")
    p.add_argument("--n-water", type=water_index_argument,
                   help=f"{WATER_INDEX_HELP}; default 1.33")
    p.add_argument("--n-glass", type=positive_float, help="glass index (default 1.54)")
    p.add_argument("--port-distance", type=_per_camera(positive_float),
                   help="D, mm (default 100); --port per-camera: LEFT,RIGHT (N cameras D0,D1,…), "
                        "each from its camera's centre along its port's normal (default 40 "
                        "each)")
    p.add_argument("--glass-thickness", type=_per_camera(positive_float),
                   help="d, mm (default 5); --port per-camera: LEFT,RIGHT or d0,d1,… (default 5 "
                        "each)")
    p.add_argument("--layer", type=positive_float, nargs=2, action="append",
                   metavar=("INDEX", "THICKNESS"),
                   help="one layer of the port, camera side first: refractive index and "
                        "thickness in mm (repeatable; replaces the glass of --n-glass and "
                        "--glass-thickness; e.g. --layer 1.49 10 --layer 1.54 5)")
    p.add_argument("--port-tilt", type=_per_camera(any_float), nargs=2,
                   metavar=("ABOUT_X", "ABOUT_Y"), default=((0.0,), (0.0,)),
                   help="tilt of the port normal from the left optical axis, degrees about x "
                        "and about y (default 0 0); --port per-camera: each LEFT,RIGHT (N cameras "
                        "one value per camera), each port's from its own camera's optical axis "
                        "(e.g. 0,0 0,2)")


def _add_rig_options(p) -> None:
    """The cameras: ``--rig FILE``, or how many, their arrangement, baseline,
    toe-in, image size, focal length and distortion."""
    p.add_argument("--rig", metavar="FILE",
                   help="render exactly the rig of a calibration file — calib.yaml of two or N "
                        "cameras, calibmar's stereo YAML or the COLMAP fork's cameras.txt: its "
                        "cameras (size, K, distortion, poses) and its port(s) replace the rig "
                        "options (--cameras, --baseline, --toe-in, --size, --focal, --dist, "
                        "--port and the port's options, which are refused with it)")
    p.add_argument("--cameras", type=_camera_count, default=2, metavar="N",
                   help="how many cameras (default 2: left, right): a row of N, --baseline "
                        "apart along x, camera k turned k × --toe-in about y towards the "
                        "targets, all behind the one flat port (--port paper), each behind its own "
                        "(--port per-camera), each inside its own dome (--port dome) or none; "
                        "their sensors are cam0, cam1, …")
    p.add_argument("--arrangement", choices=("row", "ring"), default=None,
                   help="--cameras N: row (default: a row along x, --baseline apart) or ring "
                        "(cam0 in the centre, the others evenly on a circle of radius "
                        "--baseline round its optical axis, each turned --toe-in degrees "
                        "towards that axis; N ≥ 3)")
    p.add_argument("--baseline", type=positive_float, default=None,
                   help="distance between neighbouring cameras, mm (default 200); --arrangement "
                        "ring: the ring's radius")
    p.add_argument("--toe-in", type=any_float, default=None, metavar="DEG",
                   help="each camera turned this much more than its neighbour about y, "
                        "towards the first (default 5 degrees)")
    p.add_argument("--size", type=positive_int, nargs=2, metavar=("W", "H"),
                   help="image size, px (default 2448 2048); the focal length scales with W")
    p.add_argument("--focal", type=positive_float, help="focal length, px (default 1100·W/2448)")
    p.add_argument("--dist", type=any_float, nargs="+", metavar="K",
                   help="OpenCV distortion coefficients of both cameras (4, 5 or 8)")


def _add_look_options(p) -> None:
    """How the scene looks and renders: target radius, samples and seed, the
    water, the lighting, a thin lens."""
    p.add_argument("--target-radius", type=positive_float, help="target disk radius, mm (default 2.5)")
    p.add_argument("--spp", type=positive_int, help="default samples per pixel written into the scene")
    p.add_argument("--seed", type=scene_seed, default=0, help="default sampler seed of the scene")
    p.add_argument("--water", choices=("clear", "clear_ocean", "coastal", "turbid_harbor"),
                   default="clear", help="water that absorbs and scatters (Petzold's "
                                         "measurements; default clear: no medium)")
    p.add_argument("--lighting", choices=("led", "lit"), default=None,
                   help="led: self-luminous targets (default for targets); lit: white diffuse "
                        "targets lit by two spot lights beside the housing (backscatter in "
                        "scattering water; default for --layout surface, whose speckle is then "
                        "the reflectance; led makes the speckle self-luminous)")
    p.add_argument("--aperture-radius", type=positive_float,
                   help="thin lens: aperture radius, mm (Mitsuba thinlens; default: pinhole)")
    p.add_argument("--focus-distance", type=positive_float,
                   help="thin lens: focus distance of the lens in air, mm (default: where the "
                        "targets' mean depth appears through the port, paraxially)")


def _is_our_scene(path: str) -> bool:
    """Whether ``path`` is a scene file that ``python -m synth scene`` wrote (may be replaced)."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(400).decode("utf-8", "replace")
    except OSError:
        return False
    return f"<!-- {SCENE_COMMENT_PREFIX}" in head

def main(args) -> int:
    """Write the scene file ``--out`` (a disk-target or a surface layout)."""
    from synth.scene import DEFAULT_TARGET_RADIUS_MM

    _check_out(args)
    from_file = rig_from_file(args) if args.rig else None
    _refuse_inapplicable(args)
    _check_layout_options(args)
    size, focal, baseline, toe_in = _rig_numbers(args)
    if from_file is not None:
        cameras, port = from_file
        size = tuple(cameras[0].size)
    else:
        cameras, port = cameras_from_options(args, size, focal, baseline, toe_in), None
    left = cameras[0]
    _check_port_options(args)
    pair_comment = ""
    if from_file is None:
        port, pair_comment = port_from_options(args, cameras)
    if args.layout == "surface":
        return _surface_scene(args, left, cameras[1], port)
    targets, normals = _targets(args)
    radius = args.target_radius if args.target_radius else DEFAULT_TARGET_RADIUS_MM
    _check_targets_seen(args, cameras, port, targets, radius)
    thin_lens = _thin_lens(args, port, targets)
    comment = _targets_comment(args, port, left, pair_comment, (baseline, toe_in), radius,
                               thin_lens)
    _write_targets_scene(args, cameras, port, targets, normals, radius, thin_lens, comment)
    print(f"wrote {args.out}: {targets.shape[0]} targets of radius {radius:g} mm, "
          f"{_port_words(args.port, len(cameras))}, "
          + (f"{args.cameras} cameras, " if args.cameras != 2 else "")
          + f"{size[0]}x{size[1]} px")
    return 0


def _check_out(args) -> None:
    """CLIError unless ``--out`` may be written: a new file, or one this command wrote and
    nobody edited since (its seal still matches)."""
    from synth.infra.fileio import check_file_output
    from synth.scene.write import scene_edited

    check_file_output(args.out, "--out", may_replace=_is_our_scene)
    if scene_edited(args.out):
        raise CLIError(f"--out {args.out} was edited since synth scene wrote it (its content "
                       f"no longer matches the seal on its last line): move it away or give "
                       f"another --out, so that your changes are not lost")


def _check_layout_options(args) -> None:
    """CLIError for layout options that do not fit together (and ``--lighting`` set to its
    default: lit for a surface, led for targets)."""
    if args.lighting is None and args.layout == "surface" and args.port == "none":
        raise CLIError("--port none: a surface in air needs --lighting led (the default, lit, "
                       "puts the spot lights in the water)")
    if args.lighting is None:
        args.lighting = "lit" if args.layout == "surface" else "led"
    if args.mesh and (args.layout != "surface" or args.surface != "mesh"):
        raise CLIError("--mesh needs --layout surface --surface mesh")
    if args.layout == "random" and not args.z_range[0] < args.z_range[1]:
        raise CLIError(f"--z-range must be ZMIN < ZMAX, got {args.z_range[0]:g} {args.z_range[1]:g}")
    _check_target_count(args)
    if args.aperture_radius is not None and args.dist and any(args.dist):
        raise CLIError("--aperture-radius (a thin lens) is rendered without lens distortion: "
                       "drop --dist or the thin lens")
    if args.layout == "grid" and args.half_width / args.spacing > 1000:
        raise CLIError(f"--half-width / --spacing gives more than 2001 x 2001 grid targets "
                       f"({args.half_width:g} / {args.spacing:g})")


def _rig_numbers(args) -> tuple:
    """``(image size px, focal length px, baseline mm, toe-in degrees)`` of the rig options, the
    paper's where not given (the focal length scales with the width)."""
    from synth.scene import rig as rigs

    size = tuple(args.size) if args.size else rigs.PAPER_IMAGE_SIZE
    focal = args.focal if args.focal else rigs.PAPER_FOCAL_PX * size[0] / rigs.PAPER_IMAGE_SIZE[0]
    baseline = rigs.PAPER_BASELINE_MM if args.baseline is None else args.baseline
    toe_in = rigs.PAPER_TOE_IN_DEG if args.toe_in is None else args.toe_in
    if not abs(toe_in) < 45:
        raise CLIError(f"--toe-in must stay below 45 degrees, got {toe_in:g}")
    return size, focal, baseline, toe_in


def _check_port_options(args) -> None:
    """CLIError for port options that do not fit together (layers, thin lens, no port)."""
    if args.layer and (args.n_glass is not None or args.glass_thickness is not None):
        raise CLIError("--layer replaces --n-glass and --glass-thickness; give one or the other")
    if args.layer and any(index < 1 for index, _ in args.layer):
        raise CLIError(f"--layer: refractive indices must be >= 1, got "
                       f"{[index for index, _ in args.layer]}")
    if args.focus_distance is not None and args.aperture_radius is None:
        raise CLIError("--focus-distance needs --aperture-radius (the thin lens)")
    if args.port == "none" and (args.layer or args.lighting == "lit"):
        raise CLIError(f"{'--layer' if args.layer else '--lighting lit'} needs a port (--port paper)")


def _targets(args) -> tuple:
    """``(targets (N, 3) mm, their normals (N, 3) or None: facing the cameras)`` of the
    disk-target layout (:mod:`synth.scene.layouts`)."""
    import numpy as np

    from synth.scene import layouts

    if args.layout == "paper":
        return layouts.paper_plane(args.z), None
    if args.layout == "grid":
        return layouts.grid_plane(args.z, args.half_width, args.spacing), None
    if args.layout == "random":
        return layouts.random_volume(args.n, args.layout_seed, tuple(args.z_range)), None
    try:
        if args.layout == "tilted":
            ax, ay = np.radians(args.tilt)
            combined = np.degrees(np.arccos(np.clip(np.cos(ax) * np.cos(ay), -1.0, 1.0)))
            if np.any(np.abs(args.tilt) >= 80) or combined >= 80:
                raise ValueError(f"--tilt must keep the plane within 80 degrees of facing the "
                                 f"cameras, got {args.tilt[0]:g} {args.tilt[1]:g} "
                                 f"({combined:.1f} degrees in all)")
            return layouts.tilted_plane(args.z, args.tilt)
        if args.layout == "cylinder":
            return layouts.cylinder(args.z, args.surface_radius, args.half_angle,
                                    2 * args.surface_radius, args.spacing)
        return layouts.sphere_cap(args.z, args.surface_radius, args.half_angle, args.spacing)
    except ValueError as exc:
        raise CLIError(str(exc).replace("half_angle_deg", "--half-angle")) from None


def _check_targets_seen(args, cameras, port, targets, radius: float) -> None:
    """CLIError for targets inside a dome, or none seen wholly by two cameras."""
    if args.port == "dome":
        from synth.scene.dome import check_targets

        try:
            check_targets(port, targets, radius)
        except ValueError as exc:
            raise CLIError(f"--layout {args.layout}: {exc}") from None
    _check_visible(cameras, port, targets, radius, args.layout)


def _thin_lens(args, port, targets):
    """``(aperture radius mm, focus distance mm)`` of ``--aperture-radius`` (focused where the
    targets' mean depth appears through the port unless ``--focus-distance``), or None."""
    import numpy as np

    if args.aperture_radius is None:
        return None
    focus = (args.focus_distance if args.focus_distance is not None
             else _apparent_distance(port, float(np.mean(targets[:, 2]))))
    return (args.aperture_radius, focus)


def _targets_comment(args, port, left, pair_comment: str, row: tuple, radius: float,
                     thin_lens) -> str:
    """The first comment of a disk-target scene: its options in words (``row``: the cameras'
    baseline mm and toe-in degrees)."""
    baseline, toe_in = row
    return (f"{SCENE_COMMENT_PREFIX}: layout {args.layout}"
            + (f", z {args.z:g} mm" if args.layout != "random" else "")
            + (f", tilt {args.tilt[0]:g} {args.tilt[1]:g} deg" if args.layout == "tilted" else "")
            + (f", surface radius {args.surface_radius:g} mm"
               if args.layout in ("cylinder", "sphere") else "")
            + f", port {args.port}"
            + (f", the rig of {os.path.basename(args.rig)}" if args.rig else "")
            + (dome_comment(port, left) if args.port == "dome" else "")
            + (pair_comment if args.port == "per-camera" else "")
            + (f" {args.ports}" if args.port == "mixed" else "")
            + (f" tilted {args.port_tilt[0][0]:g} deg about x, {args.port_tilt[1][0]:g} deg "
               f"about y" if args.port == "paper" and any(sum(args.port_tilt, ())) else "")
            + (f" of {len(args.layer)} layers" if args.layer else "")
            + (f", {args.cameras} cameras {baseline:g} mm apart, each turned {toe_in:g} deg "
               f"more" if args.cameras != 2 and not args.rig and args.arrangement != "ring"
               else "")
            + (f", {args.cameras} cameras: cam0 in the centre, {args.cameras - 1} on a ring "
               f"of radius {baseline:g} mm, each turned {toe_in:g} deg towards its axis"
               if args.arrangement == "ring" else "")
            + f", target radius {radius:g} mm"
            + (", lit targets" if args.lighting == "lit" else "")
            + (f", thin lens aperture {thin_lens[0]:g} mm focus {thin_lens[1]:.6g} mm"
               if thin_lens else ""))


def _write_targets_scene(args, cameras, port, targets, normals, radius: float, thin_lens,
                         comment: str) -> None:
    """Write the disk-target scene ``--out`` in the water of ``--water`` (its haze rendered on
    the full film: more samples by default); CLIError for what the writer refuses."""
    from synth.rendering.water import PRESETS as WATERS
    from synth.scene import DEFAULT_FULL_FILM_SPP, DEFAULT_SPP, write_scene

    water = WATERS.get(args.water)
    if water is not None and port is None:
        raise CLIError(f"--water {args.water} needs a port (--port paper): the water is behind it")
    if water is not None:
        comment += f", water {args.water}"
    try:
        default_spp = DEFAULT_SPP if water is None else DEFAULT_FULL_FILM_SPP  # haze: full film
        write_scene(args.out, cameras, port, targets, radius,
                    spp=args.spp if args.spp else default_spp, seed=args.seed, comment=comment,
                    water=water, target_normals=normals, lighting=args.lighting,
                    thin_lens=thin_lens)
    except ValueError as exc:
        raise CLIError(str(exc)) from None


def _surface_scene(args, left, right, port) -> int:
    """``--layout surface``: see :mod:`synth.scene.surface_scene`."""
    from synth.scene import DEFAULT_FULL_FILM_SPP
    from synth.scene.surface_scene import write_surface_scene
    from synth.rendering.water import PRESETS as WATERS

    if args.lighting == "lit" and port is None:
        raise CLIError("--lighting lit needs a port (the lights are in the water); use "
                       "--lighting led for a self-luminous surface in air")
    if args.aperture_radius is not None:
        raise CLIError("--layout surface is rendered with pinhole cameras: drop --aperture-radius")
    water = WATERS.get(args.water)
    if water is not None and port is None:
        raise CLIError(f"--water {args.water} needs a port (--port paper): the water is behind it")
    comment = (f"{SCENE_COMMENT_PREFIX}: layout surface {args.surface}, z {args.z:g} mm"
               + (f", tilt {args.tilt[0]:g} {args.tilt[1]:g} deg" if args.surface == "tilted" else "")
               + (f", surface radius {args.surface_radius:g} mm, half angle {args.half_angle:g} deg"
                  if args.surface in ("cylinder", "sphere") else "")
               + (f", amplitude {args.wave_amplitude:g} mm, wavelength {args.wavelength:g} mm"
                  if args.surface == "wavy" else "")
               + (f", mesh {os.path.basename(args.mesh)}" if args.surface == "mesh" and args.mesh
                  else "")
               + f", speckle {args.speckle_size:g} mm coverage {args.speckle_coverage:g} seed "
                 f"{args.speckle_seed}, port {args.port}, "
               + ("lit by two spot lights" if args.lighting == "lit" else "self-luminous")
               + (f", water {args.water}" if water is not None else ""))
    try:
        print(write_surface_scene(args.out, args, left, right, port,
                                  spp=args.spp if args.spp else DEFAULT_FULL_FILM_SPP,
                                  seed=args.seed,
                                  comment=comment, water=water, lighting=args.lighting))
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    return 0


def _refuse_inapplicable(args) -> None:
    """CLIError for a given option that the layout (or ``--port none``) does not use: refused,
    never ignored."""
    layout, surface = args.layout, args.surface if args.layout == "surface" else None
    shape = surface or layout  # what the options describe: the layout, or the surface's shape
    applies = {
        "z": layout != "random" and surface != "mesh",
        "spacing": layout in ("grid", "cylinder", "sphere"),
        "half_width": layout == "grid",
        "tilt": shape == "tilted",
        "surface_radius": shape in ("cylinder", "sphere"),
        "half_angle": shape in ("cylinder", "sphere"),
        "n": layout == "random", "z_range": layout == "random", "layout_seed": layout == "random",
        "target_radius": layout != "surface",
        "surface": layout == "surface",
        "speckle_size": layout == "surface", "speckle_coverage": layout == "surface",
        "speckle_seed": layout == "surface",
        "wave_amplitude": surface == "wavy", "wavelength": surface == "wavy",
    }
    where = f"--layout {layout}" + (f" --surface {surface}" if surface else "")
    refuse_given(args, [dest for dest, ok in applies.items() if not ok], f"to {where}")
    if args.port == "none":
        refuse_given(args, ["n_water", "n_glass", "port_distance", "glass_thickness",
                            "port_tilt"], "to --port none (no port: all air)")
    if args.port == "per-camera":
        refuse_given(args, ["layer", "aperture_radius", "focus_distance"],
                     "to --port per-camera (a housing per camera: pinhole cameras, each behind "
                     "one glass layer)")
        if layout == "surface":
            raise CLIError("--layout surface does not apply to --port per-camera (scenes of a "
                           "housing per camera hold disk targets)")
        if args.water != "clear":
            raise CLIError(f"--water {args.water} does not apply to --port per-camera (scenes of "
                           f"a housing per camera are in clear water)")
        if args.lighting == "lit":
            raise CLIError("--lighting lit does not apply to --port per-camera (scenes of a "
                           "housing per camera hold LED targets)")
    if args.cameras != 2:
        if layout == "surface":
            raise CLIError(f"--layout surface does not apply to --cameras {args.cameras} "
                           f"(scenes of more cameras hold disk targets)")
        refuse_given(args, ["aperture_radius", "focus_distance"],
                     f"to --cameras {args.cameras} (pinhole cameras)")
    if args.port != "dome":
        refuse_given(args, ["dome_radius", "dome_thickness", "dome_offset"],
                     f"to --port {args.port} (only to --port dome)")
    else:
        refuse_given(args, ["port_distance", "glass_thickness", "layer", "port_tilt",
                            "aperture_radius", "focus_distance"],
                     "to --port dome (a dome scene: pinhole cameras, each inside its dome)")
        if layout == "surface":
            raise CLIError("--layout surface does not apply to --port dome (dome scenes hold "
                           "disk targets)")
        if args.water != "clear":
            raise CLIError(f"--water {args.water} does not apply to --port dome (dome scenes "
                           f"are in clear water)")
        if args.lighting == "lit":
            raise CLIError("--lighting lit does not apply to --port dome (dome scenes hold LED "
                           "targets)")


#: How the line ``wrote …`` names each ``--port``.
PORT_WORDS = {"paper": "port", "per-camera": "two ports", "dome": "two domes", "none": "no port",
              "mixed": "mixed ports"}


def _port_words(kind: str, cameras: int) -> str:
    """:data:`PORT_WORDS` for a rig of ``cameras`` (``4 ports`` for four housings, ``4 domes``
    for four cameras in domes)."""
    if cameras != 2 and kind in ("per-camera", "dome"):
        return f"{cameras} {'ports' if kind == 'per-camera' else 'domes'}"
    return PORT_WORDS[kind]
#: Most targets a scene may hold (its XML grows by ~400 bytes per target).
MAX_TARGETS = 100_000


def _check_target_count(args) -> None:
    """CLIError naming the options when a layout would hold more than :data:`MAX_TARGETS`."""
    import math

    if args.layout == "random":
        count, names = args.n, "--n"
    elif args.layout in ("cylinder", "sphere"):
        arc = math.radians(min(args.half_angle, 90.0)) * args.surface_radius / args.spacing
        if args.layout == "cylinder":
            count = (2 * math.floor(arc) + 1) * (2 * math.floor(args.surface_radius / args.spacing) + 1)
        else:  # rings of at most 2πR / spacing targets each
            count = 1 + math.floor(arc) * 2 * math.pi * args.surface_radius / args.spacing
        names = "--surface-radius / --spacing"
    else:
        return
    if count > MAX_TARGETS:
        raise CLIError(f"{names}: the {args.layout} layout would hold about {count:.3g} targets, "
                       f"more than {MAX_TARGETS}")


def _check_visible(cameras, port, targets, radius: float, layout: str) -> None:
    """CLIError unless some target lies wholly inside two images (in front of the cameras;
    of two cameras, both)."""
    import numpy as np

    from measure.geometry.projection import project

    from synth.products.crosscheck import wholly_in_image

    seen = np.zeros(len(targets), dtype=int)
    for view, camera in enumerate(cameras):
        through = (None if port is None else port[view] if isinstance(port, (list, tuple))
                   else port.view(min(view, 1)))
        uv = project(camera, through, targets)
        seen += wholly_in_image(camera, uv, targets, radius)
    if not (seen >= 2).any():
        raise CLIError(f"--layout {layout}: none of the {len(targets)} targets is visible in both "
                       f"views (move them with --z or make the layout smaller)")


def _apparent_distance(port, depth_mm: float) -> float:
    """The focus distance of a lens in air that images a point ``depth_mm`` along the axis
    sharply: :meth:`measure.FlatPort.apparent_depth`, or ``depth_mm`` itself without a port."""
    return depth_mm if port is None else port.apparent_depth(depth_mm)
