"""What the measurement believes, separately from the truth that was rendered.

The scene file (with ``-D``) is the truth. ``--calib FILE`` (a ``calib.yaml`` as datasets write
it) and ``--assume name=value`` (repeatable) set the rig the measurement uses for matching,
triangulation and the eccentricity correction; scoring compares with the true targets, and the
cross-check with the simulator uses the true rig. Names (units mm, pixels; vectors as
space-separated numbers):

``n_water`` (or the water's temperature and salinity: ``n_water=T=12,S=35[,wavelength=550]``,
Quan & Fry 1995), ``n_glass`` (the first layer's index), ``port_distance`` (D), ``glass_thickness``
(the first layer), ``port_normal`` (3 values, normalized), ``focal`` (fx = fy of both cameras),
``left_focal``, ``right_focal``, ``left_dist``, ``right_dist`` (4, 5 or 8 OpenCV coefficients).
A dome rig takes the indices (of both domes) and the cameras' names (:data:`DOME_ASSUMABLE`);
the flat port's ``port_distance``, ``glass_thickness`` and ``port_normal`` are refused.
"""

from __future__ import annotations

import numpy as np

from measure import Camera, Rig, StereoRig
from measure.geometry.dome import DomePair

ASSUMABLE = ("n_water", "n_glass", "port_distance", "glass_thickness", "port_normal", "focal",
             "left_focal", "right_focal", "left_dist", "right_dist")
_PORT_NAMES = ("n_water", "n_glass", "port_distance", "glass_thickness", "port_normal")
_CAMERA_NAMES = ("focal", "left_focal", "right_focal", "left_dist", "right_dist")
#: What ``--assume`` may change in a dome rig (the flat port's distance, glass thickness and
#: normal have no meaning there).
DOME_ASSUMABLE = DomePair.assumable + _CAMERA_NAMES


def _water_index(item, text: str):
    """``(array, note)`` of an ``n_water`` value given as ``T=…,S=…[,wavelength=…]``."""
    from measure.calibration.water_index import WaterIndexError, parse_water_index

    try:
        value, note = parse_water_index(text)
    except WaterIndexError as exc:
        raise ValueError(f"--assume {item!r}: {exc}") from None
    return np.array([value]), note


def parse_assumptions(items, notes: list | None = None) -> dict:
    """``["name=value", …]`` → ``{name: numpy array}``; ValueError naming a bad item.
    ``n_water`` also takes the water's temperature and salinity, ``n_water=T=12,S=35[,
    wavelength=550]`` (Quan & Fry 1995, :mod:`measure.calibration.water_index`); the sentence saying which
    index that gave is appended to ``notes`` (when given), to be shown to the user once."""
    out = {}
    for item in items or ():
        name, sep, text = str(item).partition("=")
        name = name.strip()
        if not sep or name not in ASSUMABLE:
            raise ValueError(f"--assume {item!r}: expected name=value with name one of "
                             f"{', '.join(ASSUMABLE)}")
        if name == "n_water" and "=" in text:
            out[name], note = _water_index(item, text)
            if notes is not None:
                notes.append(note)
            continue
        try:
            value = np.array([float(v) for v in text.replace(",", " ").split()], dtype=float)
        except ValueError:
            value = np.array([])
        expected = {"port_normal": (3,), "left_dist": (4, 5, 8), "right_dist": (4, 5, 8)}.get(
            name, (1,))
        if value.size not in expected or not np.all(np.isfinite(value)):
            raise ValueError(f"--assume {item!r}: expected {' or '.join(map(str, expected))} "
                             f"finite number(s)")
        out[name] = value
    return out


def _with_focal(camera: Camera, focal: float) -> Camera:
    if not focal > 0:
        raise ValueError(f"--assume: focal length must be positive, got {focal:g}")
    K = camera.K.copy()
    K[0, 0] = K[1, 1] = focal
    return Camera(K, camera.size, camera.dist, camera.R, camera.t, camera.distortion_model)


def assumed_rig(truth: Rig, has_port: bool, assumptions: dict,
                base: Rig | None = None) -> Rig:
    """The rig the measurement believes: ``base`` (default the truth; e.g. a ``--calib`` rig)
    with ``assumptions`` (:func:`parse_assumptions`) applied."""
    rig = truth if base is None else base
    if not assumptions:
        return rig
    if not has_port and any(name in assumptions for name in _PORT_NAMES):
        raise ValueError("--assume: the scene has no port (all air); port parameters cannot be "
                         "assumed")
    refused = [name for name in assumptions
               if name in _PORT_NAMES and name not in rig.port.assumable]
    if refused:
        raise ValueError(f"--assume {refused[0]} does not apply to {rig.port.rig_name} "
                         f"({rig.port.rig_detail}); {rig.port.rig_name} takes "
                         f"{', '.join(rig.port.assumable + _CAMERA_NAMES)}")
    left, right, port_values = rig.left, rig.right, {}
    for name, value in assumptions.items():
        v = float(value[0]) if value.size == 1 else value
        if name in _PORT_NAMES:
            try:
                rig.port.check_assumption(name)
            except ValueError as exc:
                raise ValueError(f"--assume {exc}") from None
            port_values[name] = v
        else:
            left, right = _assumed_cameras(name, v, left, right)
    try:
        return StereoRig(left, right, rig.port.assumed(port_values))
    except ValueError as exc:
        raise ValueError(f"--assume: {exc}") from None


def _assumed_cameras(name: str, value, left: Camera, right: Camera):
    """``(left, right)`` with a camera assumption of ``--assume`` applied (``focal``,
    ``left_focal``, ``right_focal``: px; ``left_dist``, ``right_dist``: OpenCV coefficients);
    other names leave both cameras as they are."""
    if name in ("focal", "left_focal"):
        left = _with_focal(left, value)
    if name in ("focal", "right_focal"):
        right = _with_focal(right, value)
    elif name == "left_dist":
        left = Camera(left.K, left.size, value, left.R, left.t, left.distortion_model)
    elif name == "right_dist":
        right = Camera(right.K, right.size, value, right.R, right.t, right.distortion_model)
    return left, right


def describe_rig(rig: Rig) -> dict:
    """The rig as plain numbers: per camera ``K``, ``dist``, ``R``, ``t_mm``; the port."""
    def camera(c: Camera):
        return {"K": c.K.tolist(), "dist": None if c.dist is None else c.dist.tolist(),
                "R": c.R.tolist(), "t_mm": c.t.tolist()}
    return {"left": camera(rig.left), "right": camera(rig.right), "port": rig.port.describe()}


#: Differences at or below this (mm, px, rad, index units) are round-off — e.g. of a pose
#: written to ``calib.yaml`` as OpenCV's stereo R, T and read back — and are not reported.
ROUND_OFF = 1e-9


def rig_difference(truth: Rig, assumed: Rig) -> dict:
    """Assumed − true for every quantity that differs by more than :data:`ROUND_OFF`."""
    diff = {}
    def differs(a, b) -> bool:
        return bool(np.max(np.abs(np.asarray(a, float) - np.asarray(b, float))) > ROUND_OFF)

    if type(assumed.port) is not type(truth.port):
        diff["port"] = {"truth": truth.port.kind, "assumed": assumed.port.kind}
    else:
        truth.port.difference(assumed.port, differs, diff)
    _camera_difference(truth, assumed, differs, diff)
    return diff


def _camera_difference(truth: Rig, assumed: Rig, differs, diff) -> None:
    """The cameras' entries of :func:`rig_difference` (assumed − true), into ``diff``."""
    for view in ("left", "right"):
        a, b = getattr(assumed, view), getattr(truth, view)
        if differs(a.K, b.K):
            diff[f"{view}_K"] = (a.K - b.K).tolist()
        dist_a = np.zeros(8) if a.dist is None else np.pad(a.dist, (0, 8 - a.dist.size))
        dist_b = np.zeros(8) if b.dist is None else np.pad(b.dist, (0, 8 - b.dist.size))
        if differs(dist_a, dist_b):
            diff[f"{view}_dist"] = {"truth": None if b.dist is None else b.dist.tolist(),
                                    "assumed": None if a.dist is None else a.dist.tolist()}
        if differs(a.R, b.R) or differs(a.t, b.t):
            diff[f"{view}_pose"] = {"t_mm": (a.t - b.t).tolist(), "rotation_deg": float(
                np.degrees(np.arccos(np.clip((np.trace(a.R.T @ b.R) - 1) / 2, -1, 1))))}


__all__ = ["ASSUMABLE", "DOME_ASSUMABLE", "assumed_rig", "describe_rig", "parse_assumptions",
           "rig_difference"]
