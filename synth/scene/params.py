"""The ``<default>`` parameters of a scene and their ``-D name=value`` overrides.

The ``<default>`` parameters that users vary, overridable as ``-D name=value``: ``spp``, ``seed``,
``width``, ``height`` (the focal length in pixels scales with ``width``: the field of view is
fixed), ``n_water``, ``target_radius`` (mm), ``target_z`` (mm, plane layouts only),
``max_depth``, and ``left_dist`` / ``right_dist`` -- the OpenCV distortion coefficients of each
sensor (``"k1 k2 p1 p2 k3"``), which Mitsuba has no notion of and which it tolerates only as
defaults (an unknown property inside a plugin is an error in Mitsuba 3's loader). A scene
without a port declares ``<default name="port" value="none"/>``.

The ``<default>`` declarations are read here without interpreting the XML further (Mitsuba's
parser does the rest, :mod:`synth.scene.read`); :func:`check_params` refuses values Mitsuba would
reject or mis-render.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

from synth.scene.model import SceneError
from synth.infra.seeds import MAX_SEED, seed_range_text

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_SUBST = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


def parse_defines(items) -> dict:
    """``["name=value", ...]`` (the ``-D`` arguments) to a dict; SceneError on a malformed one."""
    defines = {}
    for item in items or ():
        name, sep, value = str(item).partition("=")
        name = name.strip()
        if not sep or not _NAME.fullmatch(name):
            raise SceneError(f"malformed -D {item!r}: expected name=value")
        defines[name] = value.strip()
    return defines


def apply_option(defines: dict, name: str, value) -> dict:
    """An option that sets the scene parameter ``name`` (``--seed S`` is ``-D seed=S``,
    ``--spp N`` is ``-D spp=N``): put ``value`` into ``defines`` (returned; None leaves them as
    they are); a ``-D name`` with another value is an error naming both."""
    if value is None:
        return defines
    if name in defines:
        try:
            same = float(defines[name]) == float(value)
        except ValueError:
            same = False
        if not same:
            raise SceneError(f"--{name} {value} conflicts with -D {name}={defines[name]}")
    defines[name] = str(value)
    return defines


def apply_seed(defines: dict, seed: int | None) -> dict:
    """``--seed S`` is ``-D seed=S`` (:func:`apply_option`)."""
    return apply_option(defines, "seed", seed)


def apply_spp(defines: dict, spp: int | None) -> dict:
    """``--spp N`` and ``-D spp=M`` mean the same, the scene's spp default overridden: a
    ``-D spp`` with another value is an error naming both (:func:`apply_option`). Returned
    unchanged otherwise: the render takes ``--spp`` itself (a scene need not declare ``spp``),
    and :meth:`synth.scene.SceneSpec.rendered_with` records it in the scene's parameters."""
    if spp is not None and "spp" in defines:
        apply_option(defines, "spp", spp)
    return defines


def declared_defaults(data: bytes, label: str):
    """The ``<default name value>`` declarations of the scene's root (in order) and the names
    the file references as ``$name`` — read, not interpreted: Mitsuba's parser does the rest."""
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise SceneError(f"{label}: malformed XML ({exc})") from None
    if root.tag != "scene":
        raise SceneError(f"{label}: root element is <{root.tag}>, expected <scene>")
    params = {}
    for d in root.findall("default"):
        name, value = d.get("name"), d.get("value")
        if not name or value is None:
            raise SceneError(f"{label}: <default> needs name and value")
        params[name] = value
    referenced = frozenset(name for elem in root.iter() for value in elem.attrib.values()
                           for name in _SUBST.findall(value))
    return params, referenced


def override_defaults(params: dict, defines: dict | None, label: str) -> None:
    """Apply ``defines`` (``-D`` values, as strings or numbers) to ``params`` (a scene's
    ``<default>`` values, changed in place); a name with no ``<default>`` is an error."""
    for name, value in (defines or {}).items():
        if name not in params:
            known = ", ".join(sorted(params)) or "none"
            raise SceneError(f"{label}: unknown parameter -D {name} (the scene's defaults: {known})")
        params[name] = str(value)


#: Scene parameters that must be numbers, with their bounds: (kind, lower bound, strict).
_NUMERIC_PARAMS = {"spp": ("int", 1, False), "seed": ("int", 0, False),
                   "width": ("int", 1, False), "height": ("int", 1, False),
                   "max_depth": ("int", 0, False), "n_water": ("float", 1.0, False),
                   "target_radius": ("float", 0.0, True), "target_z": ("float", 0.0, True),
                   "water_c": ("float", 0.0, False), "water_albedo": ("float", 0.0, False),
                   "water_g": ("float", -1.0, True), "target_albedo": ("float", 0.0, False),
                   "light_intensity": ("float", 0.0, False),
                   "aperture_radius": ("float", 0.0, True), "focus_distance": ("float", 0.0, True)}
#: Upper bounds (inclusive unless marked strict) of the water's parameters.
_UPPER_BOUNDS = {"water_albedo": (1.0, False), "water_g": (1.0, True),
                 "target_albedo": (1.0, False)}


def check_params(params: dict, label: str) -> None:
    """One-line errors for parameter values Mitsuba would reject or mis-render."""
    for name, (kind, lower, strict) in _NUMERIC_PARAMS.items():
        if name not in params:
            continue
        text = str(params[name]).strip()
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        ok = math.isfinite(value) and (value > lower if strict else value >= lower)
        if kind == "int":
            ok = ok and value == int(value)
        if not ok:
            bound = f"> {lower:g}" if strict else f">= {lower:g}"
            raise SceneError(f"{label}: parameter {name}={text!r} must be a finite "
                             f"{'integer' if kind == 'int' else 'number'} {bound}")
        if name == "seed" and value > MAX_SEED:
            raise SceneError(f"{label}: parameter seed={text!r} is too large: expected an integer "
                             f"from {seed_range_text()}")
        if name in _UPPER_BOUNDS:
            upper, strict_upper = _UPPER_BOUNDS[name]
            if not (value < upper if strict_upper else value <= upper):
                raise SceneError(f"{label}: parameter {name}={text!r} must be "
                                 f"{'<' if strict_upper else '<='} {upper:g}")
        if kind == "int":
            params[name] = str(int(value))
