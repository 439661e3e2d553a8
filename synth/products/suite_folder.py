"""A benchmark suite's folder (:mod:`synth.products.suite` is its spec): the task a Dask worker
runs for one entry (:func:`render_task`), the folder updated in place (:class:`SuiteDir`), its
index, ``suite.json`` and ``README.md``."""

from __future__ import annotations

import json
import os
import re

from synth.products.suite import COMMAND, FOLDER, OUTPUT_COMMAND, TOP_LEVEL, SuiteSpec

_STAGING = re.compile(r"^\..+\.(staging|trash)-\d+-[A-Za-z0-9_]+$")


# ------------------------------------------------------------------------------------------------
# on a worker


def render_task(task: dict) -> dict:
    """Render one entry (on a Dask worker): its dataset written by
    :func:`synth.products.dataset.write_dataset` straight into ``task["out"]`` when this machine sees the
    suite's directory (its lock file holds ``task["token"]``), else into a temporary folder
    whose files come back as bytes. Never raises: a failure is ``status = "failed"``, and
    ``write_error`` when it was the output that could not be written (the suite then stops)."""
    import shutil
    import tempfile
    import time
    import traceback

    from synth.infra.cluster import scene_file, setup_worker

    started = time.perf_counter()
    tmp = None
    try:
        setup_worker()
        from synth.products.dataset import write_dataset
        from synth.rendering.sensor_model import sensor_from_spec
        from synth.scene import load_scene

        scene = scene_file(task["scene_sha"], task["scene_data"], task["scene_path"])
        params = task["params"]
        if task.get("render") == "boards":
            return _render_boards(task, scene, started)
        sensor = sensor_from_spec(params["sensor"]) if params.get("sensor") else None
        direct = _sees_suite(task["out"], task["token"])
        target = task["out"] if direct else os.path.join(
            tmp := tempfile.mkdtemp(prefix="refstereo-suite-"), "dataset")
        spec = load_scene(scene, task["defines"])
        manifest = write_dataset(spec, target, spp=params.get("spp"),
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
                "cameras": len(manifest.get("cameras") or (0, 0)),
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

    from measure.calibration.board import Board

    from synth.products.boards import DEFAULT_POSES, DEFAULT_SPP, write_boards
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
            "cameras": len(manifest.get("cameras") or (0, 0)),
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
    import synth.products.dataset  # noqa: F401

    return True


# ------------------------------------------------------------------------------------------------
# the directory


class SuiteDir:
    """``DIR`` of a suite: the output rule of :mod:`synth.infra.fileio` for a directory updated in place
    (only what a suite writes: its files, ``entries/``, dataset folders, their staging folders)."""

    def __init__(self, path):
        from synth.infra.fileio import OutputError

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
        from synth.infra.fileio import MARKER_NAME, TEMPORARY_FILE, directory_problem, read_marker

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
            # a suite stopped before its first suite.json: the marker names its spec
            return {k: marker[k] for k in ("spec_hash", "spec_path") if k in marker}

    def open(self, spec: SuiteSpec, previous: dict | None, token: str) -> None:
        """Create or reuse ``DIR`` for ``spec`` (another spec's suite is refused), lock it and
        write the marker and ``spec.toml``."""
        from synth.infra.fileio import (MARKER_NAME, MARKER_SCHEMA, PROJECT_NAME, atomic_write_json,
                                  claim_in_place)

        if previous and previous.get("spec_hash") not in (None, spec.spec_hash()):
            self._refuse(f"holds a suite of another spec ({previous.get('spec_path', '?')}); "
                         f"write this one elsewhere")
        os.makedirs(self.path, exist_ok=True)
        marker = os.path.join(self.path, MARKER_NAME)
        # the spec's hash in the marker: a suite stopped before its first suite.json is still
        # known to be this spec's (another spec on the same DIR is refused, not mixed in)
        which = {"spec_hash": spec.spec_hash(), "spec_path": spec.path}
        if not os.path.exists(marker):  # first, so that a suite killed now is still ours
            atomic_write_json(marker, {"project": PROJECT_NAME, "schema": MARKER_SCHEMA,
                                       "command": COMMAND, "files": sorted(TOP_LEVEL), **which})
        os.makedirs(self.entries, exist_ok=True)
        self._lock = claim_in_place(
            self.path, ".suite.lock", self._refuse, (self.path, self.entries),
            {"command": COMMAND, "files": sorted(TOP_LEVEL),
             "note": "updated in place dataset by dataset (synth suite)", **which}, spec.text,
            token)

    def finished(self, spec: SuiteSpec) -> dict:
        """``{key: record}`` of the entries whose record says ok and whose dataset folder is
        whole (every file its marker lists, with its size and SHA-256); failed records too (they
        are not run again unless asked)."""
        from synth.infra.fileio import OutputDir

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
        """The scenes generated from options (:mod:`synth.products.suite_scenes`), each written
        atomically into ``DIR/scenes/<name>_<hash>/`` unless already there whole."""
        from synth.products.suite_scenes import write_generated

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
        from synth.infra.fileio import OutputDir

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
    from synth.products.suite_scenes import SCENE_FILE

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
        deviated = (entry.design or {}).get("error", {})
        # D.* are the spec's values: a water index that error.n_water moved is not one
        row.update({f"D.{k}": v for k, v in entry.defines.items()
                    if f"D.{k}" not in entry.params and not (k == "n_water"
                                                             and "n_water" in deviated)})
        row.update({"width": (record.get("image_size") or [None, None])[0],
                    "height": (record.get("image_size") or [None, None])[1],
                    "cameras": record.get("cameras"),
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
    last = ["width", "height", "cameras", "n_targets", "poses", "variant", "status", "error",
            "render_seconds"]
    middle = sorted({k for row in rows for k in row} - set(first) - set(last))
    return first + middle + last


def write_index(directory: str, spec: SuiteSpec, records: dict) -> list:
    from synth.infra.tables import write_table

    rows = index_rows(spec, records)
    write_table(directory, "index", rows, index_columns(rows))
    return rows


def write_suite_json(directory: str, spec: SuiteSpec, records: dict, runs: list) -> None:
    from synth.infra.fileio import atomic_write_json
    from synth.infra.provenance import package_versions

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

{_design_text(spec)}## Scoring against it

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


def _design_text(spec: SuiteSpec) -> str:
    """The README's paragraphs on generated scenes and on port deviations (empty without)."""
    out = ""
    if spec.generated:
        out += ("## Generated scenes\n\nThe scenes were generated from `python -m synth scene` "
                "options (`spec.toml`) into `scenes/<name>_<hash>/scene.xml`; the index's "
                "`scene_file` column names each dataset's.\n\n")
    if any(e.design for e in spec.entries):
        out += ("## Truth and design\n\nThe port of some datasets deviates from its design "
                "(the index's `error.*` columns, truth − design: `port_distance` mm, "
                "`port_tilt_x` / `port_tilt_y` degrees, `glass_thickness` mm, `n_glass`, "
                "`n_water`). `calib.yaml`, `cameras.json` and `colmap/` are the TRUTH that was "
                "rendered (and scored against); `calib_design.yaml` and `cameras_design.json` "
                "(same formats) hold the DESIGN port a user would believe: calibrate or measure "
                "with those to see what the deviation costs.\n\n")
    return out


def write_readme(directory: str, spec: SuiteSpec, rows: list) -> None:
    from synth.infra.fileio import atomic_write_text

    atomic_write_text(os.path.join(directory, "README.md"), readme_text(spec, rows))


__all__ = ["SuiteDir", "index_columns", "index_rows", "probe", "readme_text", "render_task",
           "write_index", "write_readme", "write_suite_json"]
