"""Benchmark suites: ``python -m synth suite SPEC.toml --out DIR`` renders one dataset per entry
of a spec on Dask workers into ``DIR/<folder>/`` and indexes them.

The spec uses the grammar of :mod:`synth.grid` (the one ``eval sweep`` uses)::

    name = "smoke"
    description = "what the suite is for"     # copied into DIR/README.md
    seed = 0                  # every dataset's seed derives from it and the entry's key
    repeats = 1               # datasets per combination (the seed differs)
    scenes = ["../scenes/small_grid.xml"]     # relative to the spec; each combination on each
    render = "targets"        # what the entries render: "targets", "surface" (the scenes must
                              # be target or surface scenes: python -m synth scene) or "boards"
                              # (a calibration board sequence through the scene's cameras and
                              # port: synth boards; parameters poses, air, squares, square_mm)
    render_width = 320        # width of the images (height keeps the aspect); "scene": as is

    [fixed]
    spp = 16                  # parameters: spp, sensor ("" none, or a preset of --sensor),
    exr = false               # exr, full_film (true: --full-film, no adaptive rendering), and
                              # D.<name> (any <default> of the scenes, -D name=value)

    [grid]
    "D.target_z" = [600, 1000, 1500]

    [zip] / [random]          # as in eval sweep

An entry is keyed by the hash of its scene's bytes, its parameters, ``-D`` values, repeat,
random sample and the suite's seed (:func:`entry_key`); its folder is
``<index>_<scene stem>_<key[:8]>`` and its seed is derived from the suite seed and the key.

Output (``DIR`` updated in place, dataset by dataset, like ``eval sweep``'s): each dataset is a
``synth dataset`` output, written atomically by :func:`synth.dataset.write_dataset` (on the
worker, straight into ``DIR`` when the worker sees the same ``DIR``; otherwise its files travel
back and the client writes them through :class:`synth.fileio.OutputDir`); ``entries/<key>.json``
records a finished entry; ``index.parquet`` / ``index.csv`` (one row per dataset), ``suite.json``
(the spec, versions, what was rendered, the runs) and ``README.md`` are rebuilt at the end.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import dataclass, field

from synth.grid import (Scene, SpecError, canonical_json, check_defines, check_scene_parameter,
                        check_scene_value, check_top_keys, combinations, d_text, entry_key,
                        entry_seed, integer, need, number, parse_sections, read_scene, read_toml,
                        scene_defines, swept)

COMMAND = "synth suite"
TOP_KEYS = ("name", "description", "seed", "repeats", "scenes", "render", "render_width",
            "fixed", "grid", "zip", "random")
PLAIN_PARAMETERS = ("spp", "sensor", "exr", "full_film")
#: Parameters of board sequences (``render = "boards"``) only.
BOARD_PARAMETERS = ("poses", "air", "squares", "square_mm")
RENDERS = ("targets", "surface", "boards")
#: The command whose output each kind of entry is.
OUTPUT_COMMAND = {"targets": "synth dataset", "surface": "synth dataset", "boards": "synth boards"}
DEFAULT_RENDER_WIDTH = 320
#: What a suite writes at the top of its directory besides the dataset folders.
TOP_LEVEL = ("suite.json", "spec.toml", "README.md", "index.parquet", "index.csv", "entries",
             "scenes", ".suite.lock")
#: Prefix of the parameters that vary a generated scene's options (:mod:`synth.suite_scenes`).
SCENE_PREFIX = "scene."
#: Prefix of the port deviations, truth − design (:mod:`synth.design`).
ERROR_PREFIX = "error."
#: Columns of the index that differ from run to run of the same entry.
TIMING_COLUMNS = ("render_seconds",)
FOLDER = re.compile(r"^\d{3,}_[A-Za-z0-9_.-]+_[0-9a-f]{8}$")
_STAGING = re.compile(r"^\..+\.(staging|trash)-\d+-[A-Za-z0-9_]+$")


@dataclass(frozen=True)
class Entry:
    """One dataset of a suite."""

    key: str
    folder: str
    scene: str
    render: str
    params: dict
    defines: dict
    repeat: int
    seed: int
    sample: int | None = None
    #: The concrete scene's key in :attr:`SuiteSpec.scene_files` (its SHA-256, or a generated
    #: scene's digest over all its files).
    scene_id: str = ""
    #: The design port the dataset states besides the truth (:mod:`synth.design`), or None.
    design: dict | None = None


@dataclass
class SuiteSpec:
    path: str
    name: str
    description: str
    seed: int
    repeats: int
    scenes: dict
    render: str
    render_width: int | None
    fixed: dict
    grid: dict
    zip: dict
    random: dict
    random_samples: int
    random_seed: int
    text: str = ""
    entries: list = field(default_factory=list)
    #: ``{scene_id: Scene}`` of every entry's concrete scene (files and generated ones).
    scene_files: dict = field(default_factory=dict)
    #: ``{scene_id: GeneratedScene}`` of the scenes generated from options
    #: (:mod:`synth.suite_scenes`), written into ``DIR/scenes/`` when the suite runs.
    generated: dict = field(default_factory=dict)

    @property
    def swept(self) -> list:
        names = list(self.grid) + list(self.zip) + list(self.random)
        out = swept(names, self.entries, lambda e, n: e.params.get(n))
        if len(self.scenes) > 1:
            out.insert(0, "scene")
        return out

    def canonical(self) -> dict:
        return {"seed": self.seed, "repeats": self.repeats, "render": self.render,
                "scenes": {label: s.sha256 if isinstance(s, Scene) else {"generate": s}
                           for label, s in self.scenes.items()},
                "render_width": self.render_width, "fixed": self.fixed, "grid": self.grid,
                "zip": self.zip, "random": self.random, "random_samples": self.random_samples,
                "random_seed": self.random_seed}

    def spec_hash(self) -> str:
        return hashlib.sha256(canonical_json(self.canonical()).encode()).hexdigest()


def load_suite_spec(path) -> SuiteSpec:
    """Read, check and expand the suite spec at ``path``; :class:`SpecError` for anything wrong
    (one line naming the file and the key)."""
    data, text, label = read_toml(path)
    spec = parse_suite_spec(data, os.path.dirname(os.path.abspath(os.fspath(path))), label)
    spec.path, spec.text = os.path.abspath(os.fspath(path)), text
    return spec


def _is_surface(scene) -> bool:
    return b'id="surface"' in scene.data


def _read_sources(data: dict, base_dir: str, label: str) -> dict:
    """``{label: Scene or options}`` of the spec's ``scenes`` list: a scene file (a string,
    relative to the spec) or a table of ``synth scene`` options (:mod:`synth.suite_scenes`;
    ``name`` labels it, default its layout and surface)."""
    items = data.get("scenes")
    need(isinstance(items, list) and items and all(isinstance(s, (str, dict)) for s in items),
         label, "scenes must be a non-empty list of scene files or tables of python -m synth "
                "scene options")
    sources = {}
    for k, item in enumerate(items):
        if isinstance(item, str):
            need(item not in sources, label, f"scene {item} is listed twice")
            sources[item] = read_scene(item, base_dir, label)
            continue
        options = dict(item)
        name = options.pop("name", None)
        if name is None:
            name = str(options.get("layout", "paper"))
            if name == "surface":
                name += f"_{options.get('surface', 'plane')}"
        need(isinstance(name, str) and name, label, f"scenes[{k}]: name must be a string")
        need(name not in sources, label, f"scenes[{k}]: two scenes are called {name!r} (give "
                                         f"each table its own name = \"…\")")
        sources[name] = options
    return sources


def parse_suite_spec(data: dict, base_dir: str, label: str) -> SuiteSpec:
    from synth.design import ERRORS
    from synth.suite_scenes import generate, option_names

    check_top_keys(data, TOP_KEYS, label)
    seed = integer(data, "seed", 0, 0, label)
    repeats = integer(data, "repeats", 1, 1, label)
    name = str(data.get("name", os.path.splitext(os.path.basename(label))[0]))
    description = data.get("description", "")
    need(isinstance(description, str), label, "description must be a string")
    render = data.get("render", "targets")
    need(render in RENDERS, label, f"render must be one of {', '.join(RENDERS)} (what each "
                                   f"dataset holds), got {render!r}")
    sources = _read_sources(data, base_dir, label)
    files = {k: v for k, v in sources.items() if isinstance(v, Scene)}
    made = {k: v for k, v in sources.items() if not isinstance(v, Scene)}
    known_options = option_names() if made else ()
    for scene in files.values():
        _check_render(scene, render, label)
    width = data.get("render_width", DEFAULT_RENDER_WIDTH)
    if width == "scene":
        width = None
    else:
        need(isinstance(width, int) and not isinstance(width, bool) and width >= 16, label,
             f'render_width must be an integer >= 16 or "scene", got {width!r}')

    def check_name(key, section):
        if render == "boards" and key in ("sensor", "exr"):
            raise SpecError(f"{label}: [{section}] {key}: board sequences have no {key}")
        if key in PLAIN_PARAMETERS:
            return
        if key in BOARD_PARAMETERS:
            need(render == "boards", label, f"[{section}] {key}: a parameter of board sequences "
                                            f"(render = \"boards\")")
            return
        if key.startswith(SCENE_PREFIX):
            option = key[len(SCENE_PREFIX):]
            need(made and not files, label,
                 f"[{section}] {key}: varies the options of generated scenes (tables in "
                 f"scenes), and the spec lists the scene file(s) "
                 f"{', '.join(files) or '(none generated)'}")
            need(option in known_options, label,
                 f"[{section}] unknown parameter {key!r} (scene.<option> takes the options of "
                 f"python -m synth scene, with _ for -: {', '.join(known_options)})")
            return
        if key.startswith(ERROR_PREFIX):
            error = key[len(ERROR_PREFIX):]
            need(error in ERRORS, label,
                 f"[{section}] unknown parameter {key!r} (port deviations, truth - design: "
                 f"{', '.join(ERROR_PREFIX + e for e in ERRORS)})")
            need(render != "boards", label, f"[{section}] {key}: board sequences state no "
                                            f"design port")
            need(error == "n_water" or not files, label,
                 f"[{section}] {key}: the port of a scene file is drawn in its geometry; this "
                 f"deviation needs generated scenes (tables in scenes), and the spec lists "
                 f"{', '.join(files)}")
            return
        if key.startswith("D.") and len(key) > 2:
            if render == "boards":
                from synth.commands.boards import NOT_RENDERED

                need(key[2:] not in NOT_RENDERED, label,
                     f"[{section}] {key} does not apply to board sequences (no targets, water "
                     f"medium, lights or thin lens are rendered)")
            check_scene_parameter(key, files, label, section)
            return
        raise SpecError(f"{label}: [{section}] unknown parameter {key!r} (a suite's "
                        f"parameters: {', '.join(PLAIN_PARAMETERS)}, D.<scene default>, "
                        f"scene.<synth scene option> of generated scenes, error.<port "
                        f"deviation>; board sequences also {', '.join(BOARD_PARAMETERS)})")

    sections = parse_sections(data, seed, label, check_name)
    spec = SuiteSpec(path=label, name=name, description=description, seed=seed, repeats=repeats,
                     scenes=sources, render=render, render_width=width, fixed=sections.fixed,
                     grid=sections.grid, zip=sections.zip, random=sections.random,
                     random_samples=sections.random_samples, random_seed=sections.random_seed)
    combos = combinations(sections, label, len(sources) * repeats)
    checked, entries, cache = {}, [], {}
    for source_label, source in sources.items():
        stem = re.sub(r"[^A-Za-z0-9_.-]", "_",
                      os.path.splitext(os.path.basename(source_label))[0])
        for sample, values in combos:
            params = dict(sorted((k, _check_value(k, v, label)) for k, v in values.items()))
            errors = {k[len(ERROR_PREFIX):]: v for k, v in params.items()
                      if k.startswith(ERROR_PREFIX)}
            if isinstance(source, Scene):
                scene, scene_id, design_port = source, source.sha256, {}
            else:
                options = {**source, **{k[len(SCENE_PREFIX):]: v for k, v in params.items()
                                        if k.startswith(SCENE_PREFIX)}}
                truth_options, design_port = _deviate(options, errors, source_label, label)
                signature = canonical_json([source_label, truth_options])
                if signature not in cache:
                    cache[signature] = generate(source_label, truth_options, base_dir, label)
                made_scene = cache[signature]
                scene, scene_id = made_scene.scene, made_scene.digest
                spec.generated[scene_id] = made_scene
                _check_render(scene, render, label)
                for key in params:
                    need(not key.startswith("D.") or key[2:] in scene.defaults, label,
                         f"unknown parameter {key}: scene {source_label!r} has no default "
                         f"{key[2:]!r} (its defaults: {', '.join(sorted(scene.defaults))})")
            spec.scene_files[scene_id] = scene
            defines = scene_defines(params, scene, width)
            if "n_water" in errors:
                need("n_water" in scene.defaults, label,
                     f"error.n_water: scene {source_label} has no port (no water index)")
                base = float(defines.get("n_water", scene.defaults["n_water"]))
                defines["n_water"] = d_text(base + errors["n_water"])
                design_port["n_water"] = base
            check_defines(scene, defines, label, checked)
            design = ({"error": errors, "port": design_port} if errors else None)
            for repeat in range(repeats):
                payload = {"render": render, "scene": scene_id, "params": params,
                           "defines": defines, "repeat": repeat, "suite_seed": seed}
                if sample is not None:
                    payload["sample"] = sample
                if design is not None:
                    payload["design"] = design
                key = entry_key(payload)
                folder = f"{len(entries):03d}_{stem}_{key[:8]}"
                entries.append(Entry(key, folder, source_label, render, params, defines, repeat,
                                     entry_seed(seed, key), sample, scene_id, design))
    need(len({e.key for e in entries}) == len(entries), label,
         "two entries of the spec are the same (a value is listed twice?)")
    spec.entries = entries
    return spec


def _check_render(scene, render: str, label: str) -> None:
    need(_is_surface(scene) == (render == "surface") or render == "boards" and
         not _is_surface(scene), label,
         f"render = {render!r} but scene {scene.label} is a "
         f"{'surface' if _is_surface(scene) else 'target'} scene")


def _deviate(options: dict, errors: dict, name: str, label: str) -> tuple[dict, dict]:
    """``(the options of the true scene, the design port's values)`` of a generated scene's
    ``options`` (the design) with the port deviations ``errors`` (truth − design;
    :mod:`synth.design`) applied, ``n_water`` aside (a ``-D`` value, see the caller)."""
    from synth import rig

    geometric = {k: v for k, v in errors.items() if k != "n_water"}
    if not geometric:
        return options, {}
    need(options.get("port", "paper") != "none", label,
         f"scene {name!r}: port deviations need a port (the scene has port = \"none\")")
    truth, design = dict(options), {}
    for error in ("glass_thickness", "n_glass"):
        need(error not in geometric or "layer" not in options, label,
             f"error.{error}: scene {name!r} gives its port as layers (layer = …); deviate "
             f"the layers themselves")
    defaults = {"port_distance": rig.PAPER_PORT_DISTANCE_MM,
                "glass_thickness": rig.PAPER_GLASS_THICKNESS_MM, "n_glass": rig.PAPER_INDICES[1]}
    for error, default in defaults.items():
        if error in geometric:
            value = options.get(error, default)
            need(number(value), label, f"scene {name!r}: {error} = {value!r}: expected a number "
                                       f"to deviate from")
            design[error] = float(value)
            truth[error] = float(value) + geometric[error]
    if "port_tilt_x" in geometric or "port_tilt_y" in geometric:
        tilt = options.get("port_tilt", [0.0, 0.0])
        need(isinstance(tilt, list) and len(tilt) == 2 and all(number(t) for t in tilt), label,
             f"scene {name!r}: port_tilt = {tilt!r}: expected [about_x, about_y] degrees")
        design["port_normal"] = rig.tilted_port_normal(*tilt).tolist()
        truth["port_tilt"] = [float(tilt[0]) + geometric.get("port_tilt_x", 0.0),
                              float(tilt[1]) + geometric.get("port_tilt_y", 0.0)]
    return truth, design


def _check_value(key: str, value, label: str):
    def bad(expected):
        raise SpecError(f"{label}: {key} = {value!r}: expected {expected}")

    if key == "spp":
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
            bad("an integer >= 1")
        return value
    if key == "poses":
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
            bad("an integer >= 1")
        return value
    if key == "square_mm":
        if not (isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0):
            bad("a number > 0 (mm)")
        return value
    if key == "squares":
        from measure.board import Board, BoardError

        try:
            cols, rows = (int(v) for v in str(value).lower().split("x"))
            Board("chessboard", (cols, rows), 40.0)
        except (ValueError, BoardError) as exc:
            bad(f'"COLSxROWS" such as "11x8" ({exc})')
        return value
    if key.startswith(SCENE_PREFIX):  # checked by python -m synth scene's code
        if isinstance(value, bool) or not (number(value) or isinstance(value, str) or (
                isinstance(value, list) and all(number(v) or isinstance(v, list)
                                                for v in value))):
            bad("a number, a string or a list of numbers (an option of python -m synth scene)")
        return value
    if key.startswith(ERROR_PREFIX):
        if not number(value):
            bad("a number (truth - design)")
        return value
    if key in ("exr", "air", "full_film"):
        if not isinstance(value, bool):
            bad("true or false")
        return value
    if key == "sensor":
        if not isinstance(value, str):
            bad('"" (no sensor) or a preset such as "imx174[,name=value…]"')
        if value:
            from synth.sensor_model import SensorError, sensor_from_spec

            try:
                sensor_from_spec(value)
            except SensorError as exc:
                raise SpecError(f"{label}: {key} = {value!r}: {exc}") from None
        return value
    return check_scene_value(key, value, label)


# ------------------------------------------------------------------------------------------------
# on a worker


def render_task(task: dict) -> dict:
    """Render one entry (on a Dask worker): its dataset written by
    :func:`synth.dataset.write_dataset` straight into ``task["out"]`` when this machine sees the
    suite's directory (its lock file holds ``task["token"]``), else into a temporary folder
    whose files come back as bytes. Never raises: a failure is ``status = "failed"``, and
    ``write_error`` when it was the output that could not be written (the suite then stops)."""
    import shutil
    import tempfile
    import time
    import traceback

    from synth.cluster import scene_file, setup_worker

    started = time.perf_counter()
    tmp = None
    try:
        setup_worker()
        from synth.dataset import write_dataset
        from synth.sensor_model import sensor_from_spec

        scene = scene_file(task["scene_sha"], task["scene_data"], task["scene_path"])
        params = task["params"]
        if task.get("render") == "boards":
            return _render_boards(task, scene, started)
        sensor = sensor_from_spec(params["sensor"]) if params.get("sensor") else None
        direct = _sees_suite(task["out"], task["token"])
        target = task["out"] if direct else os.path.join(
            tmp := tempfile.mkdtemp(prefix="refstereo-suite-"), "dataset")
        manifest = write_dataset(scene, target, spp=params.get("spp"), defines=task["defines"],
                                 exr=bool(params.get("exr", False)), progress=False,
                                 seed=task["seed"], sensor=sensor,
                                 adaptive=not params.get("full_film", False),
                                 design=task.get("design"))
        files = None if direct else _read_files(target)
        return {"key": task["key"], "status": "ok", "error": None, "files": files,
                "request_key": manifest["request_key"],
                "render_seconds": manifest["seconds"]["total"],
                "task_seconds": time.perf_counter() - started,
                "variant": manifest["variant"], "spp": manifest["spp"],
                "n_targets": manifest["scene"]["n_targets"],
                "image_size": manifest["image_size"], "skipped": bool(manifest.get("skipped"))}
    except OSError as exc:  # the output cannot be written (a full disk): the suite stops
        return {"key": task["key"], "status": "failed", "write_error": True, "files": None,
                "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}",
                "task_seconds": time.perf_counter() - started}
    except Exception as exc:  # recorded, never raised: the suite goes on
        message = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
        if os.environ.get("REFSTEREO_TRACEBACK"):
            message += "\n" + traceback.format_exc()
        return {"key": task["key"], "status": "failed", "error": message, "files": None,
                "task_seconds": time.perf_counter() - started}
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def _render_boards(task: dict, scene: str, started: float) -> dict:
    """A board sequence (``synth boards``) of one entry: see :func:`render_task`."""
    import shutil
    import tempfile
    import time

    from measure.board import Board

    from synth.boards import DEFAULT_POSES, DEFAULT_SPP, write_boards
    from synth.scene import load_scene

    params = task["params"]
    cols, rows = (int(v) for v in str(params.get("squares", "11x8")).lower().split("x"))
    board = Board("chessboard", (cols, rows), float(params.get("square_mm", 40.0)))
    spp = int(params.get("spp", DEFAULT_SPP))
    spec = load_scene(scene, task["defines"]).rendered_with(spp=spp, seed=task["seed"])
    direct = _sees_suite(task["out"], task["token"])
    tmp = None if direct else tempfile.mkdtemp(prefix="refstereo-suite-")
    target = task["out"] if direct else os.path.join(tmp, "boards")
    try:
        manifest = write_boards(spec, target, board, n_poses=int(params.get("poses",
                                                                             DEFAULT_POSES)),
                                spp=spp, seed=task["seed"], air=bool(params.get("air", False)),
                                progress=False, adaptive=not params.get("full_film", False))
        files = None if direct else _read_files(target)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return {"key": task["key"], "status": "ok", "error": None, "files": files,
            "request_key": manifest["request_key"],
            "render_seconds": manifest["seconds"]["total"],
            "task_seconds": time.perf_counter() - started, "variant": manifest["variant"],
            "spp": manifest["spp"], "n_targets": None, "poses": manifest["poses"],
            "image_size": manifest["image_size"], "skipped": bool(manifest.get("skipped"))}


def _read_files(target: str) -> dict:
    files = {}
    for root, _, names in os.walk(target):
        for name in names:
            path = os.path.join(root, name)
            rel = os.path.relpath(path, target)
            if not rel.startswith("."):
                with open(path, "rb") as handle:
                    files[rel] = handle.read()
    return files


def _sees_suite(out: str, token: str) -> bool:
    try:
        with open(os.path.join(os.path.dirname(out), ".suite.lock"), encoding="utf-8") as handle:
            return handle.read().strip() == token
    except OSError:
        return False


def probe() -> bool:
    """What a worker must import to render entries (``--scheduler``'s check)."""
    import synth.dataset  # noqa: F401

    return True


# ------------------------------------------------------------------------------------------------
# the directory


class SuiteDir:
    """``DIR`` of a suite: the output rule of :mod:`synth.fileio` for a directory updated in place
    (only what a suite writes: its files, ``entries/``, dataset folders, their staging folders)."""

    def __init__(self, path):
        from synth.fileio import OutputError

        self.display = os.fspath(path)
        self.path = os.path.abspath(self.display)
        self.entries = os.path.join(self.path, "entries")
        self._lock = None
        self._error = OutputError

    def _refuse(self, why: str):
        raise self._error(f"--out {self.display} {why}")

    def check(self) -> dict | None:
        """The rule (no writes): the earlier suite's ``suite.json`` (``{}`` if unreadable) or
        None when ``DIR`` is new or empty."""
        from synth.fileio import MARKER_NAME, TEMPORARY_FILE, directory_problem, read_marker

        problem = directory_problem(self.path)
        if problem:
            self._refuse(problem)
        if not os.path.isdir(self.path) or not os.listdir(self.path):
            return None
        if not os.access(self.path, os.W_OK | os.X_OK):
            self._refuse(f"cannot be written: {self.path} is not writable")
        marker = read_marker(self.path)
        if marker is None or marker.get("command") != COMMAND:
            self._refuse("exists and holds files this command did not write")
        for name in sorted(os.listdir(self.path)):
            full = os.path.join(self.path, name)
            ours = (name in TOP_LEVEL or name == MARKER_NAME or TEMPORARY_FILE.match(name)
                    or _STAGING.match(name) or (FOLDER.match(name) and os.path.isdir(full)))
            if name == "entries" and os.path.isdir(full):
                ours = all(re.fullmatch(r"[0-9a-f]{20}\.json", n) or TEMPORARY_FILE.match(n)
                           for n in os.listdir(full))
            if name == "scenes" and os.path.isdir(full):
                ours = all(re.fullmatch(r"[A-Za-z0-9_.-]+_[0-9a-f]{12}", n) or _STAGING.match(n)
                           for n in os.listdir(full))
            if not ours:
                self._refuse(f"exists and holds files this command did not write ({name})")
        try:
            with open(os.path.join(self.path, "suite.json"), encoding="utf-8") as handle:
                return json.load(handle)
        except (OSError, ValueError):
            return {}

    def open(self, spec: SuiteSpec, previous: dict | None, token: str) -> None:
        """Create or reuse ``DIR`` for ``spec`` (another spec's suite is refused), lock it and
        write the marker and ``spec.toml``."""
        from synth.fileio import (MARKER_NAME, MARKER_SCHEMA, PROJECT_NAME, atomic_write_json,
                                  claim_in_place)

        if previous and previous.get("spec_hash") not in (None, spec.spec_hash()):
            self._refuse(f"holds a suite of another spec ({previous.get('spec_path', '?')}); "
                         f"write this one elsewhere")
        os.makedirs(self.path, exist_ok=True)
        marker = os.path.join(self.path, MARKER_NAME)
        if not os.path.exists(marker):  # first, so that a suite killed now is still ours
            atomic_write_json(marker, {"project": PROJECT_NAME, "schema": MARKER_SCHEMA,
                                       "command": COMMAND, "files": sorted(TOP_LEVEL)})
        os.makedirs(self.entries, exist_ok=True)
        self._lock = claim_in_place(
            self.path, ".suite.lock", self._refuse, (self.path, self.entries),
            {"command": COMMAND, "files": sorted(TOP_LEVEL),
             "note": "updated in place dataset by dataset (synth suite)"}, spec.text, token)

    def finished(self, spec: SuiteSpec) -> dict:
        """``{key: record}`` of the entries whose record says ok and whose dataset folder is
        whole (every file its marker lists, with its size and SHA-256); failed records too (they
        are not run again unless asked)."""
        from synth.fileio import OutputDir

        out = {}
        for entry in spec.entries:
            try:
                with open(os.path.join(self.entries, f"{entry.key}.json"),
                          encoding="utf-8") as handle:
                    record = json.load(handle)
            except (OSError, ValueError):
                continue
            if record.get("key") != entry.key:
                continue
            if record.get("status") == "ok":
                folder = OutputDir(os.path.join(self.path, entry.folder),
                                   OUTPUT_COMMAND[entry.render])
                if not folder.exists_as_output() or folder.damage() is not None:
                    continue
            out[entry.key] = record
        return out

    def write_scenes(self, spec: SuiteSpec) -> None:
        """The scenes generated from options (:mod:`synth.suite_scenes`), each written
        atomically into ``DIR/scenes/<name>_<hash>/`` unless already there whole."""
        from synth.suite_scenes import write_generated

        for made in spec.generated.values():
            write_generated(self.path, made)

    def write_record(self, record: dict) -> None:
        text = json.dumps(record, allow_nan=False, separators=(",", ":"), sort_keys=True)
        path = os.path.join(self.entries, f"{record['key']}.json")
        tmp = os.path.join(self.entries, f".{record['key']}.json.{os.getpid()}.tmp")
        with open(tmp, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)

    def write_dataset_files(self, folder: str, files: dict, request_key: str,
                            render: str = "targets") -> None:
        """A dataset (or board sequence) that came back as bytes, written atomically as the
        output of ``synth dataset`` (``synth boards``)."""
        from synth.fileio import OutputDir

        output = OutputDir(os.path.join(self.path, folder), OUTPUT_COMMAND[render])
        output.claim()
        with output.staged(extra={"request_key": request_key}) as tmp:
            for rel, data in files.items():
                path = os.path.join(tmp, rel)
                os.makedirs(os.path.dirname(path), exist_ok=True)
                with open(path, "wb") as handle:
                    handle.write(data)


# ------------------------------------------------------------------------------------------------
# index, suite.json, README


def index_rows(spec: SuiteSpec, records: dict) -> list:
    """One row per entry of the spec that has a record, in the spec's order."""
    from synth.suite_scenes import SCENE_FILE

    rows = []
    for entry in spec.entries:
        record = records.get(entry.key)
        if record is None:
            continue
        row = {"folder": entry.folder, "key": entry.key, "render": entry.render,
               "scene": entry.scene, "repeat": entry.repeat, "sample": entry.sample,
               "seed": entry.seed}
        made = spec.generated.get(entry.scene_id)
        if made is not None:  # where the scene lies in DIR (python -m eval run SCENE --from …)
            row["scene_file"] = f"{made.folder}/{SCENE_FILE}"
        row.update(entry.params)
        row.update({f"D.{k}": v for k, v in entry.defines.items()
                    if f"D.{k}" not in entry.params})
        row.update({"width": (record.get("image_size") or [None, None])[0],
                    "height": (record.get("image_size") or [None, None])[1],
                    "n_targets": record.get("n_targets"), "poses": record.get("poses"),
                    "variant": record.get("variant"),
                    "status": record["status"], "error": record.get("error"),
                    "render_seconds": record.get("render_seconds")})
        rows.append(row)
    return rows


def index_columns(rows: list) -> list:
    first = ["folder", "key", "render", "scene", "repeat", "sample", "seed"]
    if any("scene_file" in row for row in rows):
        first.insert(4, "scene_file")
    last = ["width", "height", "n_targets", "poses", "variant", "status", "error",
            "render_seconds"]
    middle = sorted({k for row in rows for k in row} - set(first) - set(last))
    return first + middle + last


def write_index(directory: str, spec: SuiteSpec, records: dict) -> list:
    from synth.tables import write_table

    rows = index_rows(spec, records)
    write_table(directory, "index", rows, index_columns(rows))
    return rows


def write_suite_json(directory: str, spec: SuiteSpec, records: dict, runs: list) -> None:
    from synth.fileio import atomic_write_json
    from synth.provenance import package_versions

    rendered = [{"folder": e.folder, "key": e.key, "scene": e.scene, "render": e.render,
                 "params": e.params, "defines": e.defines, "repeat": e.repeat,
                 "sample": e.sample, "seed": e.seed,
                 "status": records.get(e.key, {}).get("status", "missing")}
                for e in spec.entries]
    atomic_write_json(os.path.join(directory, "suite.json"), {
        "name": spec.name, "description": spec.description, "spec_path": spec.path,
        "spec_hash": spec.spec_hash(), "spec": spec.canonical(), "spec_text": spec.text,
        "swept": spec.swept, "versions": package_versions(), "datasets": rendered,
        "runs": runs})


def readme_text(spec: SuiteSpec, rows: list) -> str:
    ok = sum(1 for r in rows if r["status"] == "ok")
    swept_lines = []
    for name in spec.swept:
        if name == "scene":
            values = list(spec.scenes)
        else:
            distinct = {json.dumps(e.params.get(name)): e.params.get(name) for e in spec.entries}
            values = [json.dumps(v) for v in sorted(
                distinct.values(), key=lambda v: (not isinstance(v, (int, float)), v
                                                  if isinstance(v, (int, float)) else str(v)))]
        swept_lines.append(f"- `{name}`: {', '.join(str(v) for v in values)}")
    fixed = ", ".join(f"`{k}` = {json.dumps(v)}" for k, v in spec.fixed.items()) or "none"
    what = ("stereo images of circular targets, their true 3D centres (`targets.ply`) and the "
            "simulator's pixels of every target (`pixels.csv`)" if spec.render == "targets" else
            "a sequence of stereo pairs of a calibration chessboard at random poses "
            "(`left_PP.png`, `right_PP.png`, `poses.csv`, `corners.csv`, `calib.yaml`; "
            "`python -m eval calibrate` reads it)"
            if spec.render == "boards" else
            "stereo images of a speckled surface, its mesh (`surface.ply`) and per-pixel truth: "
            "depth along the camera's z (`*_truth_zdepth.pfm`, `*_truth_zdepth.png` 16-bit with "
            "the scale in `manifest.json`), the left→right correspondence "
            "(`left_truth_flow.flo`, NaN where none) and masks (`*_truth_*.png`)")
    return f"""# Benchmark suite `{spec.name}`

{spec.description.strip() or "A benchmark suite of refractive stereo datasets."}

Written by `python -m synth suite` (refractive-stereo): **{len(spec.entries)} datasets**
({ok} rendered), each {what}, of a stereo camera pair behind a flat glass port in water.
Units: millimetres; the reference frame is the left camera's (OpenCV axes: x right, y down, z
forward into the water); pixels: OpenCV's (the centre of the top-left pixel is (0, 0)).

## What varies

{chr(10).join(swept_lines) or "- nothing (one combination)"}

Fixed: {fixed}. Every dataset's parameters, seed and render time: `index.csv` /
`index.parquet` (one row per dataset, `folder` names its folder); the spec: `spec.toml`,
`suite.json` (spec, software versions, what was rendered).

## One dataset folder

- `left.png`, `right.png`: 16-bit **linear** images (`linear = (png − png_offset) / png_scale`,
  both in `manifest.json`); `*_preview.png` 8-bit sRGB for looking at.
- `calib.yaml` (OpenCV FileStorage: K1, D1, K2, D2, stereo R, T, the port) and `cameras.json`
  (plain JSON, the same rig with units and both pose conventions named).
- `colmap/`: a text model (`cameras.txt` with the refractive COLMAP fork's FLATPORT in metres,
  `images.txt`, `points3D.txt`); pixels there are COLMAP's (top-left pixel centre at
  (0.5, 0.5)). Upstream COLMAP ignores the port.
- The truth, as above; `manifest.json` lists every file with its SHA-256.

## Scoring against it

Put your pipeline's output per dataset in a folder `SUB/<folder>/`: `points.ply` (3D points in
mm, left-camera frame) or `pairs.csv` (matched pixels `u_left,v_left,u_right,v_right`); for
surface datasets `depth.pfm` / `depth.npy` (depth along the left camera's z, mm, the left image's
pixel grid) or a point cloud `points.ply` (mm, left-camera frame). Then

```sh
python -m eval score SUITE_DIR --submission SUB --out scores      # SUITE_DIR: this folder
```

scores every dataset (a missing or unreadable one counts as a failure) and writes
`summary.md`, `summary.csv`, `summary.parquet` and figures of the error against each swept
parameter. One dataset alone: `python -m eval score SUITE_DIR/<folder> --points points.ply`.
"""


def write_readme(directory: str, spec: SuiteSpec, rows: list) -> None:
    from synth.fileio import atomic_write_text

    atomic_write_text(os.path.join(directory, "README.md"), readme_text(spec, rows))


__all__ = ["COMMAND", "Entry", "SuiteDir", "SuiteSpec", "TIMING_COLUMNS", "index_columns",
           "index_rows", "load_suite_spec", "parse_suite_spec", "probe", "readme_text",
           "render_task", "write_index", "write_readme", "write_suite_json"]
