"""The grammar of a spec of many runs, shared by ``python -m eval sweep`` (cells) and
``python -m synth suite`` (datasets): a TOML file whose ``[fixed]``, ``[grid]``, ``[zip]`` and
``[random]`` tables expand into parameter combinations, in a fixed order.

::

    seed = 0                       # the spec's seed: every entry's seed derives from it and its key
    scenes = ["../scenes/small_grid.xml"]   # relative to the spec file

    [fixed]                        # one value for every entry
    spp = 16

    [grid]                         # every combination of these values
    "D.target_z" = [1000, 2000]

    [zip]                          # lists of one length, varied together (one more grid axis)
    "D.n_water" = [1.33, 1.34]
    "D.target_radius" = [2.5, 2.0]

    [random]                       # seeded random samples, crossed with the grid
    samples = 8
    seed = 1                       # default: the spec's seed
    "D.n_water" = { uniform = [1.32, 1.34] }      # also loguniform, integers (inclusive), choice

What the names mean, and which values they take, is the command's business: it passes a
``check_name(key, section)`` callback to :func:`parse_sections` and checks each value itself.
Errors are :class:`SpecError` (a ``ValueError``), one line starting with the spec file.

This module holds only what both commands share (no Dask, no Mitsuba): reading the file, the
sections, the distributions, the expansion order (:func:`combinations`), the scenes of a spec
(:func:`read_scene`, :func:`scene_defines`), entry keys and seeds (:func:`entry_key`,
:func:`entry_seed`).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
from dataclasses import dataclass

DISTRIBUTIONS = ("uniform", "loguniform", "integers", "choice")
SECTIONS = ("fixed", "grid", "zip", "random")
#: Largest number of entries a spec may expand to.
MAX_ENTRIES = 2_000_000


class SpecError(ValueError):
    """A spec that cannot be used: one line naming the file and what is wrong."""


@dataclass(frozen=True)
class Scene:
    """A scene of a spec: its path as written (``label``), the file's absolute path, bytes
    (sent to the workers: a cluster needs no shared file system), SHA-256, declared defaults."""

    label: str
    path: str
    data: bytes
    sha256: str
    defaults: dict
    size: tuple


@dataclass(frozen=True)
class Sections:
    """The four tables of a spec, checked; ``random`` without its ``samples`` and ``seed``."""

    fixed: dict
    grid: dict
    zip: dict
    random: dict
    random_samples: int
    random_seed: int


def canonical_json(value) -> str:
    """JSON with sorted keys and no spaces (what a hash is taken of)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def entry_key(payload: dict, length: int = 20) -> str:
    """The hash that names an entry (a cell, a dataset): of its canonical JSON."""
    return hashlib.sha256(canonical_json(payload).encode()).hexdigest()[:length]


def entry_seed(spec_seed: int, key: str) -> int:
    """An entry's seed (0 … 2³¹−1): derived from the spec's seed and the entry's key only."""
    digest = hashlib.sha256(f"{spec_seed}:{key}".encode()).digest()
    return int.from_bytes(digest[:4], "big") & 0x7FFFFFFF


def need(condition, label, message) -> None:
    """:class:`SpecError` ``label: message`` unless ``condition``."""
    if not condition:
        raise SpecError(f"{label}: {message}")


def integer(data: dict, key: str, default, minimum: int, label: str) -> int:
    """``data[key]`` (or ``default``), an integer ≥ ``minimum``."""
    value = data.get(key, default)
    need(isinstance(value, int) and not isinstance(value, bool) and value >= minimum, label,
         f"{key} must be an integer >= {minimum}, got {value!r}")
    return value


def number(value) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def read_toml(path) -> tuple[dict, str, str]:
    """``(document, text, label)`` of the TOML file at ``path``; SpecError when it cannot be read
    or parsed."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    path = os.fspath(path)
    label = path
    if os.path.isdir(path):
        raise SpecError(f"{label}: is a directory, not a spec file")
    try:
        with open(path, "rb") as handle:
            raw = handle.read()
    except OSError as exc:
        raise SpecError(f"{label}: cannot read the spec ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8")
        data = tomllib.loads(text)
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SpecError(f"{label}: not a valid TOML file ({exc})") from None
    return data, text, label


def check_top_keys(data: dict, known, label: str) -> None:
    unknown = [k for k in data if k not in known]
    need(not unknown, label, f"unknown key {', '.join(map(repr, unknown))} (a spec knows "
                             f"{', '.join(known)})")


def parse_sections(data: dict, seed: int, label: str, check_name) -> Sections:
    """The ``[fixed]``, ``[grid]``, ``[zip]`` and ``[random]`` tables of ``data``, checked: each
    a table, each parameter in one section only and known (``check_name(key, section)`` raises
    SpecError otherwise), grid and zip lists non-empty, zip lists of one length, random draws
    well formed, fixed values single."""
    sections = {}
    for section in SECTIONS:
        value = data.get(section, {})
        need(isinstance(value, dict), label, f"[{section}] must be a table")
        sections[section] = dict(value)
    random = sections["random"]
    samples = random.pop("samples", 1 if random else 0)
    need(isinstance(samples, int) and not isinstance(samples, bool) and samples >= 1 or
         (not random and samples == 0), label,
         f"[random] samples must be an integer >= 1, got {samples!r}")
    random_seed = random.pop("seed", seed)
    need(isinstance(random_seed, int) and not isinstance(random_seed, bool) and random_seed >= 0,
         label, f"[random] seed must be an integer >= 0, got {random_seed!r}")

    seen = {}
    for section, table in sections.items():
        for key in table:
            need(key not in seen, label, f"parameter {key!r} is set in both [{seen.get(key)}] "
                                         f"and [{section}]")
            seen[key] = section
            check_name(key, section)
    for key, values in sections["grid"].items():
        need(isinstance(values, list), label, f"[grid] {key} must be a list of values")
        need(len(values) > 0, label, f"[grid] {key} is empty: a grid needs at least one value")
    zip_lengths = set()
    for key, values in sections["zip"].items():
        need(isinstance(values, list), label, f"[zip] {key} must be a list of values")
        need(len(values) > 0, label, f"[zip] {key} is empty: it needs at least one value")
        zip_lengths.add(len(values))
    need(len(zip_lengths) <= 1, label, f"[zip] lists must have one length, got "
                                       f"{sorted(zip_lengths)}")
    for key, dist in random.items():
        check_distribution(key, dist, label)
    for key, value in sections["fixed"].items():
        need(not isinstance(value, (list, dict)) or key.startswith(("assume.", "scene.")),
             label,
             f"[fixed] {key} must be one value (lists go into [grid] or [zip])")
    return Sections(sections["fixed"], sections["grid"], sections["zip"], random, samples,
                    random_seed)


def check_distribution(key, dist, label) -> None:
    need(isinstance(dist, dict) and len(dist) == 1 and next(iter(dist)) in DISTRIBUTIONS, label,
         f"[random] {key} must be one of {{ uniform = [a, b] }}, {{ loguniform = [a, b] }}, "
         f"{{ integers = [a, b] }}, {{ choice = [...] }}, got {dist!r}")
    kind, args = next(iter(dist.items()))
    need(isinstance(args, list) and len(args) > 0, label, f"[random] {key}: {kind} needs a "
                                                          f"non-empty list")
    if kind == "choice":
        return
    need(len(args) == 2 and all(number(a) for a in args) and args[0] <= args[1], label,
         f"[random] {key}: {kind} needs [low, high] with finite low <= high, got {args!r}")
    if kind == "loguniform":
        need(args[0] > 0, label, f"[random] {key}: loguniform needs low > 0, got {args[0]!r}")
    if kind == "integers":
        need(all(float(a).is_integer() for a in args), label,
             f"[random] {key}: integers needs integer bounds, got {args!r}")


def draw(dist: dict, rng):
    """One value of a ``[random]`` distribution from the numpy Generator ``rng``."""
    kind, args = next(iter(dist.items()))
    if kind == "uniform":
        return float(rng.uniform(args[0], args[1]))
    if kind == "loguniform":
        return float(math.exp(rng.uniform(math.log(args[0]), math.log(args[1]))))
    if kind == "integers":
        return int(rng.integers(int(args[0]), int(args[1]) + 1))
    return args[int(rng.integers(0, len(args)))]


def combinations(sections: Sections, label: str, factor: int = 1) -> list:
    """The parameter combinations of the sections, in a fixed order — grid × zip × random
    sample — as ``(sample number or None, {key: raw value})`` (fixed values first). The random
    samples are drawn once, in order, from ``random_seed``. ``factor`` (scenes × repeats) only
    counts towards :data:`MAX_ENTRIES`."""
    import numpy as np

    grid_keys = list(sections.grid)
    grid_points = (list(itertools.product(*(sections.grid[k] for k in grid_keys)))
                   if grid_keys else [()])
    zip_keys = list(sections.zip)
    zip_points = list(zip(*(sections.zip[k] for k in zip_keys))) if zip_keys else [()]
    rng = np.random.default_rng(sections.random_seed)
    samples = [{k: draw(d, rng) for k, d in sections.random.items()}
               for _ in range(sections.random_samples)] or [{}]
    total = factor * len(grid_points) * len(zip_points) * len(samples)
    need(total <= MAX_ENTRIES, label, f"the spec expands to {total} entries (at most "
                                      f"{MAX_ENTRIES})")
    out = []
    for gp in grid_points:
        for zp in zip_points:
            for index, sample in enumerate(samples):
                values = dict(sections.fixed)
                values.update(zip(grid_keys, gp))
                values.update(zip(zip_keys, zp))
                values.update(sample)
                out.append((index if sections.random else None, values))
    return out


def swept(names, entries, value) -> list:
    """The names that take more than one value over ``entries`` (``value(entry, name)``)."""
    return [n for n in names if len({json.dumps(value(e, n)) for e in entries}) > 1]


# ------------------------------------------------------------------------------------------------
# scenes


def read_scene(text: str, base_dir: str, label: str) -> Scene:
    """The scene file ``text`` (relative to ``base_dir``) of a spec: bytes, hash, defaults."""
    from synth.scene import SceneError, declared_defaults

    path = text if os.path.isabs(text) else os.path.join(base_dir, text)
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except OSError as exc:
        raise SpecError(f"{label}: scene {text}: cannot read it ({exc.strerror or exc})") from None
    try:
        defaults, _ = declared_defaults(data, text)
    except SceneError as exc:
        raise SpecError(f"{label}: {exc}") from None
    try:
        size = (int(defaults["width"]), int(defaults["height"]))
    except (KeyError, ValueError):
        raise SpecError(f"{label}: scene {text} declares no integer width and height defaults "
                        f"(write it with python -m synth scene)") from None
    return Scene(text, os.path.abspath(path), data, hashlib.sha256(data).hexdigest(), defaults,
                 size)


def read_scenes(data: dict, base_dir: str, label: str) -> dict:
    """``{label: Scene}`` of the spec's ``scenes`` list (required, non-empty, no repeats)."""
    scenes_in = data.get("scenes")
    need(isinstance(scenes_in, list) and scenes_in and all(isinstance(s, str) for s in scenes_in),
         label, "scenes must be a non-empty list of scene files")
    need(len(set(scenes_in)) == len(scenes_in), label, "a scene is listed twice")
    return {s: read_scene(s, base_dir, label) for s in scenes_in}


def check_scene_parameter(key: str, scenes: dict, label: str, section: str) -> None:
    """``D.<name>``: every scene of the spec declares the default ``name``; not ``D.seed``."""
    name = key[2:]
    need(name != "seed", label, f"[{section}] D.seed: every entry has its own seed, derived "
                                f"from the spec's seed (set seed = S at the top instead)")
    for scene in scenes.values():
        need(name in scene.defaults, label,
             f"[{section}] unknown parameter {key}: scene {scene.label} has no default "
             f"{name!r} (its defaults: {', '.join(sorted(scene.defaults))})")


def check_scene_value(key: str, value, label: str):
    """A ``D.<name>`` value: a number or a string."""
    if isinstance(value, bool) or not (number(value) or isinstance(value, str)):
        raise SpecError(f"{label}: {key} = {value!r}: expected a number or a string")
    return value


def d_text(value) -> str:
    """A ``-D`` value as text (``1000.0`` → ``1000``)."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return str(value)


def scene_defines(params: dict, scene: Scene, render_width: int | None) -> dict:
    """The ``-D`` values of an entry: its ``D.*`` parameters, plus the render size
    ``render_width`` (the height keeping the scene's aspect) unless it sets them (None: the
    scene's size)."""
    defines = {k[2:]: d_text(v) for k, v in params.items() if k.startswith("D.")}
    if render_width is not None and "width" not in defines:
        w, h = scene.size
        defines["width"] = str(render_width)
        if "height" not in defines:
            defines["height"] = str(max(1, round(h * render_width / w)))
    return defines


def check_defines(scene: Scene, defines: dict, label: str, checked: dict) -> None:
    """The scene's defaults with ``defines`` checked like ``-D`` is (once per distinct set:
    ``checked`` remembers)."""
    from synth.scene import SceneError, check_params

    signature = (scene.label, tuple(sorted(defines.items())))
    if signature in checked:
        return
    try:
        check_params({**scene.defaults, **defines}, scene.label)
    except SceneError as exc:
        raise SpecError(f"{label}: {exc}") from None
    checked[signature] = True


__all__ = ["DISTRIBUTIONS", "MAX_ENTRIES", "SECTIONS", "Scene", "Sections", "SpecError",
           "canonical_json", "check_defines", "check_distribution", "check_scene_parameter",
           "check_scene_value", "check_top_keys", "combinations", "d_text", "draw",
           "entry_key", "entry_seed", "integer", "need", "number", "parse_sections",
           "read_scene", "read_scenes", "read_toml", "scene_defines", "swept"]
