"""The design a housing calibration starts from (``eval calibrate`` under water): the starting
flat port of the single options and ``--design-port`` (:func:`design_port`), two housings' or N
cameras' ports (:func:`design_pair`, :func:`pair_glass`), the domes (:func:`design_domes`), and
the free parameters (:func:`parse_free`). Lengths in mm, indices unitless; the starting port's
normal along the first camera's optical axis unless given."""

from __future__ import annotations

import math

from eval.calibrate.port_lengths import lengths_for
from eval.cli import CLIError
from synth.infra.cli import given, refuse_given

#: ``--design-port`` keys and the single option each one stands for.
DESIGN_KEYS = {"distance": "start_distance", "thickness": "glass_thickness", "n_glass": "n_glass",
               "n_water": "n_water"}


def design_port(args, normal):
    """The starting port (:class:`measure.FlatPort`, normal ``normal``): the single options, with
    ``--design-port`` keys over them (a key and its single option both given are refused)."""
    from measure import FlatPort

    values = {dest: getattr(args, dest) for dest in DESIGN_KEYS.values()}
    seen = set()
    items = (args.design_port or "").split(",")
    if args.design_port is not None and not all(item.strip() for item in items):
        raise CLIError(f"--design-port {args.design_port!r}: an empty item; expected KEY=VALUE "
                       f"items separated by commas, KEY one of {', '.join(DESIGN_KEYS)}")
    for item in filter(None, items):
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or key not in DESIGN_KEYS:
            hint = (" (the water of a temperature and salinity: --n-water T=…,S=…)"
                    if key in ("S", "wavelength") else "")
            raise CLIError(f"--design-port {args.design_port!r}: expected KEY=VALUE items with KEY "
                           f"one of {', '.join(DESIGN_KEYS)}, got {item!r}{hint}")
        if key in seen:
            raise CLIError(f"--design-port {args.design_port!r}: {key} is given twice")
        seen.add(key)
        option = given(args, DESIGN_KEYS[key])
        if option:
            raise CLIError(f"--design-port {key}= and {option} both give the design {key}; "
                           f"give one")
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        index = key.startswith("n_")
        if not (math.isfinite(value) and (value >= 1.0 if index else value > 0.0)):
            hint = (" (the water of a temperature and salinity: --n-water T=…,S=…)"
                    if key == "n_water" and "=" in text else "")
            raise CLIError(f"--design-port {key}={text}: expected "
                           f"{'an index >= 1' if index else 'a positive length, mm'}{hint}")
        values[DESIGN_KEYS[key]] = value
    return FlatPort(normal, values["start_distance"], (values["glass_thickness"],),
                    (1.0, values["n_glass"], values["n_water"]))


def design_pair(args, rig):
    """The starting rig of a two-housing calibration: ``rig``'s cameras, each behind its own
    flat port ⟂ its optical axis, ``--port-distance`` from its centre
    (:func:`synth.scene.windows.flat_pair`), the glass and water of :func:`design_port`
    (``--design-port distance=`` and ``--start-distance`` are refused: the distances are per
    camera)."""
    from measure import StereoRig
    from synth.scene.windows import DEFAULT_PAIR_DISTANCE_MM, flat_pair

    shared = pair_glass(args)
    distances = lengths_for(args.port_distance or (DEFAULT_PAIR_DISTANCE_MM,), 2)
    try:
        pair = flat_pair(rig.cameras, distances, [(0.0, 0.0)] * 2, shared.thicknesses * 2,
                         shared.indices)
    except ValueError as exc:
        raise CLIError(f"--port-distance {','.join(f'{d:g}' for d in distances)}: {exc}") from None
    return StereoRig(rig.left, rig.right, pair)


def pair_glass(args, cameras: int = 2):
    """The glass and water every port of a housing per camera shares (a :func:`design_port`);
    the options that give one port's distance are refused (the distances are per camera; two
    housings, or ``cameras`` > 2)."""
    what = "two housings" if cameras == 2 else f"a port per camera ({cameras} cameras)"
    each = ("LEFT,RIGHT" if cameras == 2
            else ",".join(f"D{k}" for k in range(cameras)))
    refuse_given(args, ("start_distance",), f"to {what}: give each port's distance with "
                                            f"--port-distance {each}")
    if any(item.partition("=")[0].strip() == "distance"
           for item in (args.design_port or "").split(",")):
        raise CLIError(f"--design-port distance= does not apply to {what}: give each "
                       f"port's distance with --port-distance {each}")
    return design_port(args, (0.0, 0.0, 1.0))


def parse_free(text: str, dome: bool = False) -> tuple:
    from measure.calibration.dome import DOME_PARAMETERS
    from measure.calibration.flat import HOUSING_PARAMETERS

    table = DOME_PARAMETERS if dome else HOUSING_PARAMETERS
    listed = [n.strip() for n in text.split(",")]
    twice = sorted({n for n in listed if n and listed.count(n) > 1})
    if twice or (text.strip() and not all(listed)):
        what = f"{', '.join(twice)} given twice" if twice else "an empty item"
        raise CLIError(f"--free {text!r}: {what}; give each parameter once, separated by "
                       f"commas (from {', '.join(table)})")
    names = tuple(dict.fromkeys(n for n in listed if n))
    unknown = [n for n in names if n not in table]
    if not names or unknown:
        kind = " of a dome rig" if dome else ""
        raise CLIError(f"--free {text!r}: unknown parameter{kind} "
                       f"{', '.join(unknown) or '(none)'} (choose from {', '.join(table)})")
    return names


#: Options of a flat port's design, refused for dome boards; the dome's own, refused otherwise.
FLAT_DESIGN_OPTIONS = ("start_distance", "glass_thickness", "design_port")
DOME_DESIGN_OPTIONS = ("dome_radius", "dome_thickness")


def design_domes(args, rig):
    """The starting rig of a dome housing calibration: ``rig``'s cameras, each inside a dome
    centred on it (no decentring) of ``--dome-radius`` and ``--dome-thickness``, indices
    ``(1, --n-glass, --n-water)``."""
    from measure import StereoRig
    from synth.scene.dome import dome_pair

    try:
        pair = dome_pair(rig.cameras, args.dome_radius, args.dome_thickness, (0.0, 0.0, 0.0),
                         (1.0, args.n_glass, float(args.n_water)))
    except ValueError as exc:
        raise CLIError(f"--dome-radius / --dome-thickness: {exc}") from None
    return StereoRig(rig.left, rig.right, pair)
