"""The spec of ``python -m eval sweep``: a TOML file, parsed and checked, expanded into cells.

A spec (every key optional unless marked; paths relative to the spec file)::

    name = "smoke"                 # for people
    seed = 0                       # the sweep seed: every cell's seed derives from it and the cell
    repeats = 3                    # cells per parameter combination (repeat 0, 1, …)
    scenes = ["../scenes/small_grid.xml"]   # required: each combination runs on each scene
    methods = ["optical_path", "su", "regular"]   # analytic cells also know "regular_in_air"
    render_width = 320             # render cells: width (height keeps the aspect) unless D.width
    save = ["ply", "figures", "images"]     # render cells: also keep these files per cell
    cells_per_task = 0             # analytic cells per Dask task (0: automatic)

    [fixed]                        # one value for every cell
    kind = "render"                # "render" (eval run: render, measure, score) or "analytic"

    [grid]                         # every combination of these values
    noise_px = [0.0, 0.1]
    "assume.n_water" = [1.33, 1.332]

    [zip]                          # lists of one length, varied together (one more grid axis)
    "D.target_z" = [1000, 2000]
    "D.target_radius" = [2.5, 2.0]

    [random]                       # seeded random samples, crossed with the grid
    samples = 8
    seed = 1                       # default: the sweep seed
    "D.n_water" = { uniform = [1.32, 1.34] }      # also loguniform, integers (inclusive), choice
    self_calibrate = { choice = ["", "n_water"] }

Parameters (in ``fixed``, ``grid``, ``zip`` or ``random``; each in one section only):

* ``kind`` — ``render`` or ``analytic``;
* ``D.<name>`` — any ``<default>`` of the scenes (``-D name=value`` of ``eval run``), checked like
  ``eval run`` checks it; ``D.seed`` is not allowed (every cell has its own seed);
* ``assume.<name>`` — what the measurement believes (``--assume``; :mod:`eval.core.assumption`);
* ``noise_px`` (σ of the Gaussian noise added to the pixels, ≥ 0), ``spp`` (render cells),
  ``self_calibrate`` (``""`` off, ``true`` = ``"n_water"``, or a comma list of ``n_water``,
  ``port_distance``, ``port_normal``), ``gate_mm`` (> 0), ``eccentricity`` (bool, render cells),
  ``threshold_fraction`` (0 < F < 1, render cells), ``max_elongation`` and ``max_area_ratio``
  (> 1, render cells), ``median_filter`` (0, 3 or 5, render cells) — ``eval run``'s detection
  options of the same names.

A cell is keyed by the hash of its kind, scene (the file's SHA-256, not its path), parameters,
methods, repeat and the sweep seed (:func:`cell_key`); its seed is derived from the sweep seed
and that key (:func:`cell_seed`), so the same cell gives the same numbers wherever it runs.
Errors are one line (:class:`SpecError`, a ``ValueError``: the CLI exits with 2).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
from dataclasses import dataclass, field

KINDS = ("render", "analytic")
TOP_KEYS = ("name", "description", "seed", "repeats", "scenes", "methods", "render_width", "save",
            "cells_per_task", "fixed", "grid", "zip", "random")
PLAIN_PARAMETERS = ("kind", "noise_px", "spp", "self_calibrate", "gate_mm", "eccentricity",
                    "threshold_fraction", "max_elongation", "max_area_ratio", "median_filter")
#: Parameters that only render cells use.
RENDER_ONLY = ("spp", "eccentricity", "threshold_fraction", "max_elongation", "max_area_ratio",
               "median_filter")
SAVE_CHOICES = ("images", "ply", "figures")
DISTRIBUTIONS = ("uniform", "loguniform", "integers", "choice")
DEFAULT_RENDER_WIDTH = 320
DEFAULT_METHODS = ("optical_path", "su", "regular")
#: Largest number of cells a spec may expand to.
MAX_CELLS = 2_000_000


class SpecError(ValueError):
    """A spec that cannot be used: one line naming the file and what is wrong."""


@dataclass(frozen=True)
class Scene:
    """A scene of the spec: its path as written (``label``), the file's absolute path, bytes
    (sent to the workers: a cluster needs no shared file system), SHA-256, declared defaults."""

    label: str
    path: str
    data: bytes
    sha256: str
    defaults: dict
    size: tuple


@dataclass(frozen=True)
class Cell:
    """One unit of work: ``params`` (sorted, JSON values) on ``scene`` (a label of the spec's
    scenes), repeat ``repeat``; ``key`` its hash, ``seed`` its seed."""

    key: str
    kind: str
    scene: str
    params: dict
    repeat: int
    seed: int
    methods: tuple
    sample: int | None = None


@dataclass
class SweepSpec:
    path: str
    name: str
    seed: int
    repeats: int
    scenes: dict  # label -> Scene
    methods: tuple
    render_width: int | None
    save: tuple
    cells_per_task: int
    fixed: dict
    grid: dict
    zip: dict
    random: dict
    random_samples: int
    random_seed: int
    text: str = ""
    cells: list = field(default_factory=list)

    @property
    def swept(self) -> list:
        """Names of the parameters that take more than one value (in spec order)."""
        names = list(self.grid) + list(self.zip) + list(self.random)

        def value(cell, name):
            return cell.kind if name == "kind" else cell.params.get(name)

        return [n for n in names if len({json.dumps(value(c, n)) for c in self.cells}) > 1]

    def canonical(self) -> dict:
        """What the spec means (not how it is written): the sweep's identity."""
        return {"seed": self.seed, "repeats": self.repeats, "methods": list(self.methods),
                "scenes": {label: s.sha256 for label, s in self.scenes.items()},
                "render_width": self.render_width, "save": list(self.save),
                "fixed": self.fixed, "grid": self.grid, "zip": self.zip, "random": self.random,
                "random_samples": self.random_samples, "random_seed": self.random_seed}

    def spec_hash(self) -> str:
        return hashlib.sha256(_canonical_json(self.canonical()).encode()).hexdigest()


def _canonical_json(value) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def cell_key(kind: str, scene_sha: str, params: dict, methods, repeat: int, seed: int,
             sample: int | None = None) -> str:
    """The hash that names a cell: kind, scene content, parameters, methods, repeat, sweep seed
    (and the number of its random sample, when the spec draws any)."""
    payload = {"kind": kind, "scene": scene_sha, "params": params, "methods": list(methods),
               "repeat": repeat, "sweep_seed": seed}
    if sample is not None:
        payload["sample"] = sample
    text = _canonical_json(payload)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def cell_seed(sweep_seed: int, key: str) -> int:
    """A cell's seed (0 … 2³¹−1): derived from the sweep seed and the cell key only."""
    digest = hashlib.sha256(f"{sweep_seed}:{key}".encode()).digest()
    return int.from_bytes(digest[:4], "big") & 0x7FFFFFFF


# ------------------------------------------------------------------------------------------------
# parsing


def load_spec(path) -> SweepSpec:
    """Read, check and expand the spec at ``path``; :class:`SpecError` for anything wrong."""
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
    spec = parse_spec(data, os.path.dirname(os.path.abspath(path)), label)
    spec.path, spec.text = os.path.abspath(path), text
    return spec


def _need(condition, label, message):
    if not condition:
        raise SpecError(f"{label}: {message}")


def _int(data, key, default, minimum, label):
    value = data.get(key, default)
    _need(isinstance(value, int) and not isinstance(value, bool) and value >= minimum, label,
          f"{key} must be an integer >= {minimum}, got {value!r}")
    return value


def parse_spec(data: dict, base_dir: str, label: str) -> SweepSpec:
    """Check a parsed TOML document (``base_dir``: where relative scene paths start)."""
    unknown = [k for k in data if k not in TOP_KEYS]
    _need(not unknown, label, f"unknown key {', '.join(map(repr, unknown))} (a spec knows "
                              f"{', '.join(TOP_KEYS)})")
    seed = _int(data, "seed", 0, 0, label)
    repeats = _int(data, "repeats", 1, 1, label)
    cells_per_task = _int(data, "cells_per_task", 0, 0, label)
    name = str(data.get("name", os.path.splitext(os.path.basename(label))[0]))

    scenes_in = data.get("scenes")
    _need(isinstance(scenes_in, list) and scenes_in and all(isinstance(s, str) for s in scenes_in),
          label, "scenes must be a non-empty list of scene files")
    _need(len(set(scenes_in)) == len(scenes_in), label, "a scene is listed twice")
    scenes = {s: _read_scene(s, base_dir, label) for s in scenes_in}

    methods = data.get("methods", list(DEFAULT_METHODS))
    _need(isinstance(methods, list) and methods and all(isinstance(m, str) for m in methods),
          label, "methods must be a non-empty list of method names")
    from measure import METHODS

    known_methods = tuple(METHODS) + ("regular_in_air",)
    bad = [m for m in methods if m not in known_methods]
    _need(not bad, label, f"unknown method {', '.join(bad)} (choose from "
                          f"{', '.join(known_methods)})")
    _need(len(set(methods)) == len(methods), label, "a method is listed twice")

    width = data.get("render_width", DEFAULT_RENDER_WIDTH)
    if width == "scene":
        width = None
    else:
        _need(isinstance(width, int) and not isinstance(width, bool) and width >= 16, label,
              f'render_width must be an integer >= 16 or "scene", got {width!r}')
    save = data.get("save", [])
    _need(isinstance(save, list) and all(s in SAVE_CHOICES for s in save), label,
          f"save must be a list of {', '.join(SAVE_CHOICES)}, got {save!r}")

    sections = {}
    for section in ("fixed", "grid", "zip", "random"):
        value = data.get(section, {})
        _need(isinstance(value, dict), label, f"[{section}] must be a table")
        sections[section] = dict(value)
    random = sections["random"]
    samples = random.pop("samples", 1 if random else 0)
    _need(isinstance(samples, int) and not isinstance(samples, bool) and samples >= 1 or
          (not random and samples == 0), label,
          f"[random] samples must be an integer >= 1, got {samples!r}")
    random_seed = random.pop("seed", seed)
    _need(isinstance(random_seed, int) and not isinstance(random_seed, bool) and random_seed >= 0,
          label, f"[random] seed must be an integer >= 0, got {random_seed!r}")

    seen = {}
    for section, table in sections.items():
        for key in table:
            _need(key not in seen, label, f"parameter {key!r} is set in both [{seen.get(key)}] "
                                          f"and [{section}]")
            seen[key] = section
            _check_name(key, scenes, label, section)
    for key, values in sections["grid"].items():
        _need(isinstance(values, list), label, f"[grid] {key} must be a list of values")
        _need(len(values) > 0, label, f"[grid] {key} is empty: a grid needs at least one value")
    zip_lengths = set()
    for key, values in sections["zip"].items():
        _need(isinstance(values, list), label, f"[zip] {key} must be a list of values")
        _need(len(values) > 0, label, f"[zip] {key} is empty: it needs at least one value")
        zip_lengths.add(len(values))
    _need(len(zip_lengths) <= 1, label, f"[zip] lists must have one length, got "
                                        f"{sorted(zip_lengths)}")
    for key, dist in random.items():
        _check_distribution(key, dist, label)
    fixed = sections["fixed"]
    for key, value in fixed.items():
        _need(not isinstance(value, (list, dict)) or key.startswith("assume."), label,
              f"[fixed] {key} must be one value (lists go into [grid] or [zip])")

    spec = SweepSpec(path=label, name=name, seed=seed, repeats=repeats, scenes=scenes,
                     methods=tuple(methods), render_width=width, save=tuple(save),
                     cells_per_task=cells_per_task, fixed=fixed, grid=sections["grid"],
                     zip=sections["zip"], random=random, random_samples=samples,
                     random_seed=random_seed)
    spec.cells = expand(spec, label)
    return spec


def _read_scene(text: str, base_dir: str, label: str) -> Scene:
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


def _check_name(key: str, scenes: dict, label: str, section: str) -> None:
    from eval.core.assumption import ASSUMABLE

    if key in PLAIN_PARAMETERS:
        return
    prefix, _, name = key.partition(".")
    if prefix == "D" and name:
        _need(name != "seed", label, f"[{section}] D.seed: every cell has its own seed, derived "
                                     f"from the sweep seed (set seed = S at the top instead)")
        for scene in scenes.values():
            _need(name in scene.defaults, label,
                  f"[{section}] unknown parameter {key}: scene {scene.label} has no default "
                  f"{name!r} (its defaults: {', '.join(sorted(scene.defaults))})")
        return
    if prefix == "assume" and name:
        _need(name in ASSUMABLE, label, f"[{section}] unknown parameter {key} (assume.<name> "
                                        f"with name one of {', '.join(ASSUMABLE)})")
        return
    raise SpecError(f"{label}: [{section}] unknown parameter {key!r} (parameters: "
                    f"{', '.join(PLAIN_PARAMETERS)}, D.<scene default>, assume.<name>)")


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_distribution(key, dist, label) -> None:
    _need(isinstance(dist, dict) and len(dist) == 1 and next(iter(dist)) in DISTRIBUTIONS, label,
          f"[random] {key} must be one of {{ uniform = [a, b] }}, {{ loguniform = [a, b] }}, "
          f"{{ integers = [a, b] }}, {{ choice = [...] }}, got {dist!r}")
    kind, args = next(iter(dist.items()))
    _need(isinstance(args, list) and len(args) > 0, label, f"[random] {key}: {kind} needs a "
                                                           f"non-empty list")
    if kind == "choice":
        return
    _need(len(args) == 2 and all(_number(a) for a in args) and args[0] <= args[1], label,
          f"[random] {key}: {kind} needs [low, high] with finite low <= high, got {args!r}")
    if kind == "loguniform":
        _need(args[0] > 0, label, f"[random] {key}: loguniform needs low > 0, got {args[0]!r}")
    if kind == "integers":
        _need(all(float(a).is_integer() for a in args), label,
              f"[random] {key}: integers needs integer bounds, got {args!r}")


def _draw(dist: dict, rng):
    kind, args = next(iter(dist.items()))
    if kind == "uniform":
        return float(rng.uniform(args[0], args[1]))
    if kind == "loguniform":
        return float(math.exp(rng.uniform(math.log(args[0]), math.log(args[1]))))
    if kind == "integers":
        return int(rng.integers(int(args[0]), int(args[1]) + 1))
    return args[int(rng.integers(0, len(args)))]


# ------------------------------------------------------------------------------------------------
# values


def _check_value(key: str, value, label: str):
    """The value checked and normalized (JSON-ready); SpecError when out of range."""
    def bad(expected):
        raise SpecError(f"{label}: {key} = {value!r}: expected {expected}")

    if key == "kind":
        if value not in KINDS:
            bad(f"one of {', '.join(KINDS)}")
        return value
    if key == "noise_px":
        if not (_number(value) and value >= 0):
            bad("a finite number >= 0 (px)")
        return float(value)
    if key == "spp":
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
            bad("an integer >= 1")
        return value
    if key == "gate_mm":
        if not (_number(value) and value > 0):
            bad("a finite number > 0 (mm)")
        return float(value)
    if key == "threshold_fraction":
        if not (_number(value) and 0 < value < 1):
            bad("a number between 0 and 1 (exclusive)")
        return float(value)
    if key in ("max_elongation", "max_area_ratio"):
        if not (_number(value) and value > 1):
            bad("a finite number > 1")
        return float(value)
    if key == "median_filter":
        if value not in (0, 3, 5) or isinstance(value, bool):
            bad("0 (none), 3 or 5")
        return int(value)
    if key == "eccentricity":
        if not isinstance(value, bool):
            bad("true or false")
        return value
    if key == "self_calibrate":
        from measure.selfcal import PARAMETERS

        if value is True:
            return "n_water"
        if value is False:
            return ""
        if not isinstance(value, str):
            bad(f'true, false or a comma list of {", ".join(PARAMETERS)}')
        names = [n.strip() for n in value.split(",") if n.strip()]
        if any(n not in PARAMETERS for n in names):
            bad(f'"" or a comma list of {", ".join(PARAMETERS)}')
        return ",".join(dict.fromkeys(names))
    if key.startswith("assume."):
        from eval.core.assumption import parse_assumptions

        name = key.split(".", 1)[1]
        text = " ".join(map(str, value)) if isinstance(value, list) else str(value)
        if isinstance(value, bool):
            bad("a number (or a list of numbers)")
        try:
            parsed = parse_assumptions([f"{name}={text}"])[name]
        except ValueError as exc:
            raise SpecError(f"{label}: {key} = {value!r}: {exc}") from None
        if name in ("n_water", "n_glass") and not parsed[0] >= 1.0:
            bad("a refractive index >= 1")
        if name in ("port_distance", "glass_thickness", "focal", "left_focal",
                    "right_focal") and not parsed[0] > 0:
            bad("a number > 0")
        if name == "port_normal" and not parsed.any():
            bad("a non-zero vector")
        return [float(v) for v in parsed] if parsed.size > 1 else float(parsed[0])
    if key.startswith("D."):
        if isinstance(value, bool) or not (_number(value) or isinstance(value, str)):
            bad("a number or a string")
        return value
    raise SpecError(f"{label}: unknown parameter {key!r}")  # pragma: no cover


def _d_text(value) -> str:
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return str(value)


def scene_defines(params: dict, scene: Scene, kind: str, render_width: int | None) -> dict:
    """The ``-D`` values of a cell: its ``D.*`` parameters, plus the small render size of render
    cells (``render_width``, the height keeping the scene's aspect) unless it sets them."""
    defines = {k[2:]: _d_text(v) for k, v in params.items() if k.startswith("D.")}
    if kind == "render" and render_width is not None and "width" not in defines:
        w, h = scene.size
        defines["width"] = str(render_width)
        if "height" not in defines:
            defines["height"] = str(max(1, round(h * render_width / w)))
    return defines


def expand(spec: SweepSpec, label: str) -> list:
    """The cells of the spec, in a fixed order: scene × grid × zip × random sample × repeat."""
    import numpy as np

    from synth.scene import SceneError, check_params

    grid_keys = list(spec.grid)
    grid_points = list(itertools.product(*(spec.grid[k] for k in grid_keys))) if grid_keys else [()]
    zip_keys = list(spec.zip)
    zip_points = list(zip(*(spec.zip[k] for k in zip_keys))) if zip_keys else [()]
    rng = np.random.default_rng(spec.random_seed)
    samples = [{k: _draw(d, rng) for k, d in spec.random.items()}
               for _ in range(spec.random_samples)] or [{}]
    total = (len(spec.scenes) * len(grid_points) * len(zip_points) * len(samples) * spec.repeats)
    _need(total <= MAX_CELLS, label, f"the spec expands to {total} cells (at most {MAX_CELLS})")
    fixed = {k: _check_value(k, v, label) for k, v in spec.fixed.items()}
    checked = {}  # (scene, D values) already checked

    cells = []
    for scene in spec.scenes.values():
        for gp in grid_points:
            for zp in zip_points:
                for index, sample in enumerate(samples):
                    number = index if spec.random else None
                    params = dict(fixed)
                    params.update({k: _check_value(k, v, label) for k, v in zip(grid_keys, gp)})
                    params.update({k: _check_value(k, v, label) for k, v in zip(zip_keys, zp)})
                    params.update({k: _check_value(k, v, label) for k, v in sample.items()})
                    kind = params.pop("kind", None)
                    _need(kind is not None, label, 'every cell needs a kind: set kind = "render" '
                                                   'or "analytic" in [fixed] (or sweep it)')
                    if kind == "render":
                        _need("regular_in_air" not in spec.methods, label,
                              "method regular_in_air (the all-air copy of the rig) exists in "
                              "analytic cells only")
                    defines = scene_defines(params, scene, kind, spec.render_width)
                    signature = (scene.label, tuple(sorted(defines.items())))
                    if signature not in checked:
                        merged = {**scene.defaults, **defines}
                        try:
                            check_params(merged, scene.label)
                        except SceneError as exc:
                            raise SpecError(f"{label}: {exc}") from None
                        checked[signature] = True
                    params = dict(sorted(params.items()))
                    for repeat in range(spec.repeats):
                        key = cell_key(kind, scene.sha256, params, spec.methods, repeat,
                                       spec.seed, number)
                        cells.append(Cell(key, kind, scene.label, params, repeat,
                                          cell_seed(spec.seed, key), spec.methods, number))
    keys = {c.key for c in cells}
    _need(len(keys) == len(cells), label, "two cells of the spec are the same (a value is "
                                          "listed twice?)")
    return cells


__all__ = ["Cell", "KINDS", "Scene", "SpecError", "SweepSpec", "cell_key", "cell_seed",
           "load_spec", "parse_spec", "scene_defines"]
