"""The cameras and the port of ``python -m synth scene`` (:mod:`synth.commands.scene`): from
``--rig FILE`` (a calibration file's cameras and port(s)), or from the rig options (a row or a
ring of cameras) and the port options — one flat port, a flat port per camera, a dome per camera
(units mm, the left camera's frame)."""

from __future__ import annotations

import sys

from synth.infra.cli import CLIError


def cameras_from_options(args, size, focal: float, baseline: float, toe_in: float) -> list:
    """The cameras of ``--cameras N`` (``--arrangement row`` or ``ring``) of image ``size`` px,
    focal length ``focal`` px, ``--dist``, ``baseline`` mm apart (a ring's radius) and each
    turned ``toe_in`` degrees more (:mod:`synth.scene.rig`)."""
    from synth.scene import rig as rigs

    if args.arrangement == "ring":
        if args.cameras < 3:
            raise CLIError(f"--arrangement ring needs --cameras 3 or more (a centre camera "
                           f"and two or more round it), got {args.cameras}")
        return rigs.ring_cameras(args.cameras, size, focal, args.dist, baseline, toe_in)
    return rigs.row_cameras(args.cameras, size, focal, args.dist, baseline, toe_in)


def port_from_options(args, cameras) -> tuple:
    """``(port, comment)`` of the port options for ``cameras``: ``--port paper`` one flat port
    (:func:`flat_port`), ``per-camera`` a flat port each (:func:`own_ports`; its numbers are the
    comment), ``dome`` a dome each (:func:`dome_port`: a DomePair of two cameras, a list of N
    domes of more), ``none`` None; the comment is empty but
    for ``per-camera``."""
    if args.ports is not None and args.port != "mixed":
        raise CLIError(f"--ports {args.ports} needs --port mixed (a port of its kind for "
                       f"each camera)")
    if args.port == "paper":
        return flat_port(args), ""
    if args.port == "per-camera":
        return own_ports(args, cameras)
    if args.port == "dome":
        return dome_port(args, cameras), ""
    if args.port == "mixed":
        return mixed_ports(args, cameras), ""
    return None, ""


def flat_port(args):
    """The FlatPort of ``--port paper``: ``--port-tilt`` (degrees about x and y from the left
    optical axis), ``--port-distance`` mm, the glass of ``--glass-thickness`` mm or the layers of
    ``--layer``, the indices of :func:`port_indices`."""
    import numpy as np

    from measure import FlatPort

    from synth.scene import rig as rigs

    n = port_indices(args)
    port_tilt = [one_value(v, "--port-tilt") for v in args.port_tilt]
    tilt = np.radians(port_tilt)
    if np.any(np.abs(tilt) >= np.radians(30)):
        raise CLIError(f"--port-tilt must stay below 30 degrees, got {port_tilt}")
    normal = rigs.tilted_port_normal(*port_tilt)
    distance = one_value(args.port_distance, "--port-distance")
    distance = distance if distance is not None else rigs.PAPER_PORT_DISTANCE_MM
    if args.layer:
        thicknesses = tuple(t for _, t in args.layer)
        n = [n[0], *(index for index, _ in args.layer), n[2]]
    else:
        thickness = one_value(args.glass_thickness, "--glass-thickness")
        thicknesses = (thickness if thickness is not None else rigs.PAPER_GLASS_THICKNESS_MM,)
    return FlatPort(normal, distance, thicknesses, tuple(n))


#: The options that describe the rig, which ``--rig FILE`` gives instead (refused with it).
RIG_OPTIONS = ("cameras", "arrangement", "baseline", "toe_in", "size", "focal", "dist", "port",
               "dome_radius", "dome_thickness", "dome_offset", "n_water", "n_glass", "port_distance",
               "glass_thickness", "layer", "port_tilt", "ports")


def rig_from_file(args):
    """``(cameras, port)`` of ``--rig FILE`` (:func:`synth.products.rig_file.read_rig_file`),
    with ``args.port`` and ``args.cameras`` set to what the file holds (the kind of port
    decides which layout options apply). CLIError (one line naming the file) for a file that is
    not a calibration, or a rig of more than two cameras with a port of each its own."""
    from synth.infra.cli import given
    from synth.products.dataset import DatasetError
    from synth.products.rig_file import read_rig_file
    from synth.scene.mixed import is_mixed

    taken = [f"--{d.replace('_', '-')}" for d in RIG_OPTIONS if given(args, d)]
    if taken:
        raise CLIError(f"{taken[0]} does not apply with --rig {args.rig}: the file gives the "
                       f"cameras and the port")
    try:
        rig = read_rig_file(args.rig)
    except DatasetError as exc:
        raise CLIError(f"--rig {exc}") from None
    for name, camera in zip(rig.names, rig.cameras):
        fx, fy, skew = camera.K[0, 0], camera.K[1, 1], camera.K[0, 1]
        if abs(fx - fy) > 1e-9 * fx or skew != 0:
            raise CLIError(f"--rig {args.rig}: {name} has fx = {fx:.6g}, fy = {fy:.6g} px"
                           f"{f', skew {skew:g}' if skew else ''}; Mitsuba's perspective sensor "
                           f"renders square pixels only (fx = fy, no skew), so this rig cannot "
                           f"be rendered exactly")
    stereo = rig.stereo()
    if stereo is not None:
        port = stereo.port if stereo.port is not None and stereo.port.refracts else None
        kind = {"flat": "paper", "flat pair": "per-camera", "dome": "dome"}.get(
            port.kind if port is not None else "", "none")
    elif all(p is None for p in rig.ports) or not rig.refracts:
        port, kind = None, "none"
    elif all(p == rig.ports[0] for p in rig.ports):
        port, kind = rig.ports[0], "paper"
    elif is_mixed(rig.ports):
        if len(rig.cameras) == 2:
            raise CLIError(f"--rig {args.rig}: a pair whose cameras have different kinds of "
                           f"port ({MIXED_PAIR})")
        port, kind = _mixed_from_file(args, rig), "mixed"
    else:  # a port per camera: a dome each, or a window each (then each port must be flat)
        port, kind = list(rig.ports), _own_ports_kind(args, rig)
    args.port, args.cameras = kind, len(rig.cameras)
    return list(rig.cameras), port



def _mixed_from_file(args, rig):
    """The :class:`synth.scene.mixed.MixedPorts` of a rig file whose cameras have different
    kinds of port, with ``args.ports`` set to their kinds (a flat port two cameras share
    ``paper``); CLIError for glass that does not fit."""
    from synth.scene.mixed import MixedPorts, check_mixed, glass_of_rig

    def kind(port) -> str:
        if port is None:
            return "none"
        if port.kind == "dome":
            return "dome"
        return "paper" if sum(p == port for p in rig.ports) > 1 else "per-camera"

    try:
        check_mixed(rig, glass_of_rig(rig))
    except ValueError as exc:
        raise CLIError(f"--rig {args.rig}: {exc}") from None
    args.ports = ",".join(kind(p) for p in rig.ports)
    return MixedPorts(rig.ports)


def _own_ports_kind(args, rig) -> str:
    """``dome`` for a rig file of N cameras each inside its own dome, ``per-camera`` for one
    of N cameras each behind its own flat port; CLIError for a field of view that does not
    fit, or ports that are neither all domes nor all flat."""
    from measure.geometry.port import require_flat_port

    from synth.scene.dome import check_field_of_view
    from synth.scene.windows import check_windows, fit_windows

    domes = {getattr(p, "kind", None) for p in rig.ports} == {"dome"}
    try:
        if domes:
            check_field_of_view(rig)
            return "dome"
        for name, each in zip(rig.names, rig.ports):
            require_flat_port(each, f"{len(rig.cameras)} cameras with ports of their own, "
                                    f"{name}'s not flat; a scene of more than two cameras has "
                                    f"them behind one flat port, a flat port each, a dome each "
                                    f"or none")
        check_windows(rig, fit_windows(rig))
    except ValueError as exc:
        raise CLIError(f"--rig {args.rig}: {exc}") from None
    return "per-camera"


def dome_port(args, cameras):
    """The domes of ``--port dome``: ``--dome-radius``, ``--dome-thickness``, ``--dome-offset``
    (in each camera's frame), the glass index ``--n-glass`` and the water's ``--n-water``; a
    DomePair of two cameras, a list of one DomePort per camera of more. CLIError for a camera
    outside its dome or a field of view that does not fit through the domes."""
    from measure import StereoRig
    from measure.stereo.rig import Rig

    from synth.infra.cli import option_number
    from synth.scene.dome import (DEFAULT_DOME_RADIUS_MM, DEFAULT_DOME_THICKNESS_MM,
                                  camera_domes, check_dome_size, check_field_of_view, dome_pair)

    n = port_indices(args)
    radius = args.dome_radius if args.dome_radius is not None else DEFAULT_DOME_RADIUS_MM
    thickness = (args.dome_thickness if args.dome_thickness is not None
                 else DEFAULT_DOME_THICKNESS_MM)
    offset = tuple(args.dome_offset) if args.dome_offset is not None else (0.0, 0.0, 0.0)
    try:
        check_dome_size(radius, thickness)
    except ValueError as exc:
        raise CLIError(f"--dome-radius {option_number(radius)} --dome-thickness "
                       f"{option_number(thickness)}: {exc}") from None
    try:
        if len(cameras) == 2:
            port = dome_pair(cameras, radius, thickness, offset, tuple(n))
        else:
            port = camera_domes(cameras, radius, thickness, offset, tuple(n))
    except ValueError as exc:
        raise CLIError(f"--dome-offset {' '.join(f'{v:g}' for v in offset)}: {exc}") from None
    try:
        check_field_of_view(StereoRig(*cameras, port) if len(cameras) == 2
                            else Rig(cameras, port))
    except ValueError as exc:
        raise CLIError(f"--dome-radius {radius:g} --dome-thickness {thickness:g}: {exc}") from None
    return port


#: Why a pair of two kinds of port is refused (its commands take one port, two windows or two
#: domes).
MIXED_PAIR = ("not measured as a pair yet: eval run, synth dataset and eval calibrate take a "
              "pair behind one port, a window each or a dome each, --port paper, per-camera or "
              "dome")


def mixed_ports(args, cameras):
    """The ports of ``--port mixed --ports K0,K1,…`` (one kind per camera, in camera order):
    ``paper`` the one flat port those cameras share (:func:`flat_port`: ``--port-distance``,
    ``--glass-thickness``, ``--port-tilt``, ``--layer``), ``per-camera`` the camera's own flat
    window (its optical axis the normal, the defaults of ``--port per-camera``), ``dome`` its own
    dome (:func:`dome_port`'s options), ``none`` in air; a
    :class:`synth.scene.mixed.MixedPorts`. CLIError (one line naming ``--ports``) for a bad
    list, options no camera's port takes, or glass that does not fit
    (:func:`synth.scene.mixed.check_mixed`)."""
    from measure.stereo.rig import Rig

    from synth.scene.dome import DEFAULT_DOME_RADIUS_MM, DEFAULT_DOME_THICKNESS_MM, camera_domes
    from synth.scene.mixed import MIXED_KINDS, MixedPorts, check_mixed, glass_of_rig
    from synth.scene.windows import (DEFAULT_PAIR_DISTANCE_MM, DEFAULT_PAIR_THICKNESS_MM,
                                     flat_ports)

    kinds, what = (args.ports or "").split(","), f"--ports {args.ports}"
    if len(cameras) == 2:
        raise CLIError(f"--port mixed: a pair of two kinds of port ({MIXED_PAIR}); give "
                       f"--cameras 3 or more")
    if set(kinds) == {"none"}:
        raise CLIError(f"{what}: every camera in air: that is --port none")
    bad = [k for k in kinds if k not in MIXED_KINDS]
    if args.ports is None or bad or len(kinds) != len(cameras):
        why = ("not given" if args.ports is None else f"{bad[0]!r} is not a kind of port"
               if bad else f"{len(kinds)} kinds for {len(cameras)} cameras")
        raise CLIError(f"{what if args.ports else '--ports'}: {why}; "
                       f"--port mixed needs one kind per camera, each "
                       f"{', '.join(MIXED_KINDS)} (e.g. --ports "
                       f"{','.join((['paper', 'dome', 'per-camera', 'none'] * 9)[:len(cameras)])})")
    _refuse_unused(args, kinds, what)
    n = tuple(port_indices(args))
    ports = [None] * len(cameras)
    shared = flat_port(args) if "paper" in kinds else None
    own = [k for k, kind in enumerate(kinds) if kind == "per-camera"]
    domed = [k for k, kind in enumerate(kinds) if kind == "dome"]
    radius = args.dome_radius if args.dome_radius is not None else DEFAULT_DOME_RADIUS_MM
    thickness = args.dome_thickness if args.dome_thickness is not None \
        else DEFAULT_DOME_THICKNESS_MM
    offset = tuple(args.dome_offset) if args.dome_offset is not None else (0.0, 0.0, 0.0)
    try:
        windows = flat_ports([cameras[k] for k in own], [DEFAULT_PAIR_DISTANCE_MM] * len(own),
                             [(0.0, 0.0)] * len(own), [DEFAULT_PAIR_THICKNESS_MM] * len(own), n)
        domes = camera_domes([cameras[k] for k in domed], radius, thickness, offset, n) \
            if domed else []
        for k, port in [*zip(own, windows), *zip(domed, domes)]:
            ports[k] = port
        for k, kind in enumerate(kinds):
            ports[k] = shared if kind == "paper" else ports[k]
        rig = Rig(cameras, ports)
        check_mixed(rig, glass_of_rig(rig))
    except ValueError as exc:
        raise CLIError(f"--port mixed {what}: {exc}") from None
    return MixedPorts(ports)


def _refuse_unused(args, kinds, what: str) -> None:
    """CLIError for a port option that no camera's kind of port in ``kinds`` takes."""
    from synth.infra.cli import refuse_given

    if "dome" not in kinds:
        refuse_given(args, ["dome_radius", "dome_thickness", "dome_offset"],
                     f"to {what} (no dome)")
    if "paper" not in kinds:
        refuse_given(args, ["port_distance", "glass_thickness", "port_tilt", "layer"],
                     f"to {what} (no shared flat port: the cameras' own windows take the "
                     f"defaults of --port per-camera)")
    if args.layout == "surface" or args.water != "clear" or args.lighting == "lit" \
            or args.aperture_radius is not None:
        raise CLIError("--port mixed holds LED disk targets seen by pinhole cameras in clear "
                       "water (no --layout surface, --water, --lighting lit or thin lens)")


def one_value(values, option: str):
    """The single value of a ``LEFT,RIGHT`` option where there is one port (None: not given)."""
    if values is None or len(values) == 1:
        return None if values is None else values[0]
    raise CLIError(f"{option} {','.join(f'{v:g}' for v in values)}: {len(values)} values are for "
                   f"--port per-camera (a port per camera); this port is one: give one value")


def each_value(values, option: str, default: float, count: int) -> tuple:
    """One value per camera of a ``LEFT,RIGHT`` (``V0,V1,…``) option of ``--port per-camera``;
    any other count — one value too — is refused (a port per camera needs a value per
    camera)."""
    if values is None:
        return (default,) * count
    if len(values) != count:
        each = ",".join([f"{values[0]:g}"] * count)
        example = f"{option} {each} {each}" if option == "--port-tilt" else f"{option} {each}"
        which = "LEFT,RIGHT" if count == 2 else f"{count} values, V0,…,V{count - 1}"
        raise CLIError(f"{option} {','.join(f'{v:g}' for v in values)}: --port per-camera needs "
                       f"one value per camera, {which} (e.g. {example})")
    return tuple(values)


def own_ports(args, cameras) -> tuple:
    """The ports of ``--port per-camera``: per camera ``--port-distance``,
    ``--glass-thickness`` and ``--port-tilt`` (each ``LEFT,RIGHT``, or one per camera of N; the
    tilt from that camera's own optical axis, in its frame), the glass index ``--n-glass`` and
    the water's ``--n-water``; a FlatPair of two cameras, a list of N flat ports of more.
    CLIError for a camera in another's glass, or windows that cannot keep the fields of view
    apart (:func:`synth.scene.windows.check_windows`). Returns ``(port, comment)``."""
    import numpy as np

    from measure import StereoRig
    from measure.stereo.rig import Rig

    from synth.infra.cli import given
    from synth.scene.windows import (DEFAULT_PAIR_DISTANCE_MM, DEFAULT_PAIR_THICKNESS_MM,
                                     check_windows, fit_windows, flat_pair, flat_ports)

    count = len(cameras)
    distances = each_value(args.port_distance, "--port-distance", DEFAULT_PAIR_DISTANCE_MM, count)
    thicknesses = each_value(args.glass_thickness, "--glass-thickness", DEFAULT_PAIR_THICKNESS_MM,
                        count)
    if given(args, "port_tilt"):
        tilt_x, tilt_y = (each_value(v, "--port-tilt", 0.0, count) for v in args.port_tilt)
    else:
        tilt_x = tilt_y = (0.0,) * count
    if np.any(np.abs([tilt_x, tilt_y]) >= 30):
        raise CLIError(f"--port-tilt must stay below 30 degrees, got {comma_text(tilt_x)} "
                       f"{comma_text(tilt_y)}")
    what = f"--port per-camera --port-distance {comma_text(distances)}"
    indices = tuple(port_indices(args))
    try:
        if count == 2:
            port = flat_pair(cameras, distances, list(zip(tilt_x, tilt_y)), thicknesses, indices)
            rig = StereoRig(cameras[0], cameras[1], port)
        else:
            port = flat_ports(cameras, distances, list(zip(tilt_x, tilt_y)), thicknesses,
                              indices)
            rig = Rig(cameras, port)
        check_windows(rig, fit_windows(rig))
    except ValueError as exc:
        raise CLIError(f"{what}: {exc}") from None
    comment = (f" distances {comma_text(distances)} mm, glass {comma_text(thicknesses)} mm, tilts "
               f"{comma_text(tilt_x)} {comma_text(tilt_y)} deg about x and y (each port from its own camera)")
    return port, comment


def comma_text(values) -> str:
    return ",".join(f"{v:g}" for v in values)


def dome_comment(port, left) -> str:
    """The dome's numbers for the scene file's first comment (the offset in the left camera's
    frame): ``port`` a DomePair or a list of one DomePort per camera (the first is
    ``left``'s)."""
    dome = port[0]
    offset = left.R.T @ (dome.center - left.center)
    return (f" radius {dome.radius:g} mm thickness {dome.thickness:g} mm offset "
            f"{offset[0]:g} {offset[1]:g} {offset[2]:g} mm")



def port_indices(args) -> list:
    """``[n_air, n_glass, n_water]``: the paper's, with ``--n-glass`` and ``--n-water`` applied
    (a water index from temperature and salinity prints how it was computed)."""
    from synth.scene import rig as rigs

    n = list(rigs.PAPER_INDICES)
    if args.n_glass is not None:
        n[1] = args.n_glass
    if args.n_water is not None:
        n[2] = float(args.n_water)
        if getattr(args.n_water, "note", None):
            print(args.n_water.note, file=sys.stderr)
    return n
