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

The grammar (the file, the sections, the distributions, the expansion order, the scenes) is
:mod:`synth.infra.grid`, shared with ``python -m synth suite``; this module adds what a cell is.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field

from synth.infra.grid import (MAX_ENTRIES, Scene, SpecError, canonical_json, check_defines,
                        check_scene_parameter, check_scene_value, check_top_keys, combinations,
                        entry_key, entry_seed, integer, need, number, parse_sections, read_scenes,
                        read_toml, swept)
from synth.infra.grid import scene_defines as grid_scene_defines

KINDS = ("render", "analytic")
TOP_KEYS = ("name", "description", "seed", "repeats", "scenes", "methods", "render_width", "save",
            "cells_per_task", "fixed", "grid", "zip", "random")
PLAIN_PARAMETERS = ("kind", "noise_px", "spp", "self_calibrate", "gate_mm", "eccentricity",
                    "threshold_fraction", "max_elongation", "max_area_ratio", "median_filter")
#: Parameters that only render cells use.
RENDER_ONLY = ("spp", "eccentricity", "threshold_fraction", "max_elongation", "max_area_ratio",
               "median_filter")
SAVE_CHOICES = ("images", "ply", "figures")
DEFAULT_RENDER_WIDTH = 320
DEFAULT_METHODS = ("optical_path", "su", "regular")
#: Largest number of cells a spec may expand to.
MAX_CELLS = MAX_ENTRIES


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

        return swept(names, self.cells, value)

    def canonical(self) -> dict:
        """What the spec means (not how it is written): the sweep's identity."""
        return {"seed": self.seed, "repeats": self.repeats, "methods": list(self.methods),
                "scenes": {label: s.sha256 for label, s in self.scenes.items()},
                "render_width": self.render_width, "save": list(self.save),
                "fixed": self.fixed, "grid": self.grid, "zip": self.zip, "random": self.random,
                "random_samples": self.random_samples, "random_seed": self.random_seed}

    def spec_hash(self) -> str:
        return hashlib.sha256(canonical_json(self.canonical()).encode()).hexdigest()


def cell_key(kind: str, scene_sha: str, params: dict, methods, repeat: int, seed: int,
             sample: int | None = None) -> str:
    """The hash that names a cell: kind, scene content, parameters, methods, repeat, sweep seed
    (and the number of its random sample, when the spec draws any)."""
    payload = {"kind": kind, "scene": scene_sha, "params": params, "methods": list(methods),
               "repeat": repeat, "sweep_seed": seed}
    if sample is not None:
        payload["sample"] = sample
    return entry_key(payload)


def cell_seed(sweep_seed: int, key: str) -> int:
    """A cell's seed (0 … 2³¹−1): derived from the sweep seed and the cell key only."""
    return entry_seed(sweep_seed, key)


# ------------------------------------------------------------------------------------------------
# parsing


def load_spec(path) -> SweepSpec:
    """Read, check and expand the spec at ``path``; :class:`SpecError` for anything wrong."""
    data, text, label = read_toml(path)
    spec = parse_spec(data, os.path.dirname(os.path.abspath(os.fspath(path))), label)
    spec.path, spec.text = os.path.abspath(os.fspath(path)), text
    return spec


def parse_spec(data: dict, base_dir: str, label: str) -> SweepSpec:
    """Check a parsed TOML document (``base_dir``: where relative scene paths start)."""
    check_top_keys(data, TOP_KEYS, label)
    seed = integer(data, "seed", 0, 0, label)
    repeats = integer(data, "repeats", 1, 1, label)
    cells_per_task = integer(data, "cells_per_task", 0, 0, label)
    name = str(data.get("name", os.path.splitext(os.path.basename(label))[0]))
    scenes = read_scenes(data, base_dir, label)

    methods = data.get("methods", list(DEFAULT_METHODS))
    need(isinstance(methods, list) and methods and all(isinstance(m, str) for m in methods),
         label, "methods must be a non-empty list of method names")
    from measure import METHODS

    from eval.core.absorbed import ABSORBED

    known_methods = tuple(METHODS) + ("regular_in_air", ABSORBED)
    bad = [m for m in methods if m not in known_methods]
    need(not bad, label, f"unknown method {', '.join(bad)} (choose from "
                         f"{', '.join(known_methods)})")
    need(len(set(methods)) == len(methods), label, "a method is listed twice")

    width = data.get("render_width", DEFAULT_RENDER_WIDTH)
    if width == "scene":
        width = None
    else:
        need(isinstance(width, int) and not isinstance(width, bool) and width >= 16, label,
             f'render_width must be an integer >= 16 or "scene", got {width!r}')
    save = data.get("save", [])
    need(isinstance(save, list) and all(s in SAVE_CHOICES for s in save), label,
         f"save must be a list of {', '.join(SAVE_CHOICES)}, got {save!r}")

    sections = parse_sections(data, seed, label,
                              lambda key, section: _check_name(key, scenes, label, section))
    spec = SweepSpec(path=label, name=name, seed=seed, repeats=repeats, scenes=scenes,
                     methods=tuple(methods), render_width=width, save=tuple(save),
                     cells_per_task=cells_per_task, fixed=sections.fixed, grid=sections.grid,
                     zip=sections.zip, random=sections.random,
                     random_samples=sections.random_samples, random_seed=sections.random_seed)
    spec.cells = expand(spec, label, sections)
    return spec


def _check_name(key: str, scenes: dict, label: str, section: str) -> None:
    from eval.core.assumption import ASSUMABLE

    if key in PLAIN_PARAMETERS:
        return
    prefix, _, name = key.partition(".")
    if prefix == "D" and name:
        check_scene_parameter(key, scenes, label, section)
        return
    if prefix == "assume" and name:
        need(name in ASSUMABLE, label, f"[{section}] unknown parameter {key} (assume.<name> "
                                       f"with name one of {', '.join(ASSUMABLE)})")
        return
    raise SpecError(f"{label}: [{section}] unknown parameter {key!r} (parameters: "
                    f"{', '.join(PLAIN_PARAMETERS)}, D.<scene default>, assume.<name>)")


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
        if not (number(value) and value >= 0):
            bad("a finite number >= 0 (px)")
        return float(value)
    if key == "spp":
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
            bad("an integer >= 1")
        return value
    if key == "gate_mm":
        if not (number(value) and value > 0):
            bad("a finite number > 0 (mm)")
        return float(value)
    if key == "threshold_fraction":
        if not (number(value) and 0 < value < 1):
            bad("a number between 0 and 1 (exclusive)")
        return float(value)
    if key in ("max_elongation", "max_area_ratio"):
        if not (number(value) and value > 1):
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
        from measure.calibration.selfcal import PARAMETERS

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
        return check_scene_value(key, value, label)
    raise SpecError(f"{label}: unknown parameter {key!r}")  # pragma: no cover


def scene_defines(params: dict, scene: Scene, kind: str, render_width: int | None) -> dict:
    """The ``-D`` values of a cell: its ``D.*`` parameters, plus the small render size of render
    cells (``render_width``, the height keeping the scene's aspect) unless it sets them."""
    return grid_scene_defines(params, scene, render_width if kind == "render" else None)


def expand(spec: SweepSpec, label: str, sections=None) -> list:
    """The cells of the spec, in a fixed order: scene × grid × zip × random sample × repeat."""
    if sections is None:
        sections = parse_sections(canonical_sections(spec), spec.seed, label, lambda *_: None)
    combos = combinations(sections, label, len(spec.scenes) * spec.repeats)
    checked = {}  # (scene, D values) already checked
    cells = []
    for scene in spec.scenes.values():
        for number_, values in combos:
            params = {k: _check_value(k, v, label) for k, v in values.items()}
            kind = params.pop("kind", None)
            need(kind is not None, label, 'every cell needs a kind: set kind = "render" '
                                          'or "analytic" in [fixed] (or sweep it)')
            if kind == "render":
                need("regular_in_air" not in spec.methods, label,
                     "method regular_in_air (the all-air copy of the rig) exists in "
                     "analytic cells only")
            check_defines(scene, scene_defines(params, scene, kind, spec.render_width), label,
                          checked)
            params = dict(sorted(params.items()))
            for repeat in range(spec.repeats):
                key = cell_key(kind, scene.sha256, params, spec.methods, repeat, spec.seed,
                               number_)
                cells.append(Cell(key, kind, scene.label, params, repeat,
                                  cell_seed(spec.seed, key), spec.methods, number_))
    keys = {c.key for c in cells}
    need(len(keys) == len(cells), label, "two cells of the spec are the same (a value is "
                                         "listed twice?)")
    return cells


def canonical_sections(spec: SweepSpec) -> dict:
    """The spec's tables as a TOML document holds them (``[random]`` with samples and seed)."""
    random = dict(spec.random)
    if random:
        random.update(samples=spec.random_samples, seed=spec.random_seed)
    return {"fixed": spec.fixed, "grid": spec.grid, "zip": spec.zip, "random": random}


__all__ = ["Cell", "KINDS", "Scene", "SpecError", "SweepSpec", "cell_key", "cell_seed",
           "load_spec", "parse_spec", "scene_defines"]
