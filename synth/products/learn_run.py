"""Running a learning set (:mod:`synth.products.learn_set`) on Dask: what ``python -m synth learn``
and a suite spec with ``render = "learn"`` (``python -m synth suite SPEC.toml``) both do.

:func:`run_learn` checks ``DIR`` (new, empty, or an earlier set of the same options: more seeds
may be added), renders the scenes without a whole folder on the cluster of
:func:`synth.infra.cluster.connect` (a local one of single-threaded workers, or a scheduler's;
the workers write straight into ``DIR`` and must see it), then rebuilds ``learn.json``,
``index.csv``, the lists, the KITTI tree and the README, and prints one summary line. Resumable
like a suite: a killed run keeps every scene it finished.

A learning suite spec (:func:`read_learn_spec`; ``suites/learn_sea.toml``) holds the options of
``synth learn`` as TOML keys: ``render = "learn"``, ``seed`` (the first scene's), ``scenes``,
``size = [W, H]``, ``spp``, ``ports``, ``water``, ``light`` (lists of names),
``distance_mm = [NEAR, FAR]``, ``pitch_deg = [LOW, HIGH]``, ``split = [TRAIN, VAL, TEST]``,
``objects`` (mesh files relative to the spec), and ``name``, ``description``; nothing else (an
unknown key is refused, naming it).
"""

from __future__ import annotations

import json
import os
import sys
import time
import uuid
from dataclasses import dataclass

from synth.infra import interrupt
from synth.infra.cli import CLIError
from synth.scene.sea_draw import LIGHTS, PORT_KINDS, WATERS, SeaRanges
from synth.scene.sea_write import DEFAULT_LEARN_SPP


@dataclass(frozen=True)
class LearnRequest:
    """A learning set to write: ``out`` the directory, the scenes' ``seeds``, their ``ranges``,
    ``spp`` and the split's ``fractions`` (train, val, test)."""

    out: str
    seeds: tuple
    ranges: SeaRanges
    spp: int
    fractions: tuple


def _claim(out: str, options: dict) -> dict | None:
    """The earlier ``learn.json`` of ``out`` (None for a new or empty directory); CLIError for
    a directory that is not an earlier output of synth learn with the same options."""
    from synth.products.learn_set import LEARN_JSON, options_hash

    if os.path.lexists(out) and not os.path.isdir(out):
        raise CLIError(f"--out {out} exists and is not a directory")
    if not os.path.isdir(out) or not os.listdir(out):
        return None
    try:
        with open(os.path.join(out, LEARN_JSON), encoding="utf-8") as handle:
            previous = json.load(handle)
    except (OSError, ValueError):
        raise CLIError(f"--out {out} exists and holds files synth learn did not write") from None
    fixed = {k: v for k, v in options.items() if k != "seeds"}
    if previous.get("options_hash_without_seeds") != options_hash(fixed):
        raise CLIError(f"--out {out} holds a learning set of other options (ranges, spp or "
                       f"split); write into another directory")
    return previous


def run_learn(request: LearnRequest, scheduler, workers, connect_timeout, progress) -> int:
    """Write the learning set of ``request`` (module docs); returns the exit code (1 when a
    scene failed or missed a check's bound)."""
    from synth.products.learn_set import options_of, scene_done

    started = time.perf_counter()
    options = options_of(request.seeds, request.ranges, request.spp, request.fractions)
    previous = _claim(request.out, options)
    os.makedirs(request.out, exist_ok=True)
    if previous is None:  # claimed before the first scene: a killed first run is resumed too
        _write_learn_json(request.out, options, {}, [])
    todo = [s for s in request.seeds
            if not scene_done(request.out, s, request.ranges, request.spp)]
    if progress:
        print(f"learn: {len(request.seeds)} scenes, {len(todo)} to render now "
              f"({len(request.seeds) - len(todo)} done before)", file=sys.stderr, flush=True)
    results, where, compute = _render(request, todo, scheduler, workers, connect_timeout,
                                      progress)
    return _finish(request, options, previous, todo, results, where, compute, started)


def _render(request, todo, scheduler, workers, timeout, progress) -> tuple[dict, str, float]:
    """Render the scenes of ``todo`` on the cluster: ``({seed: result}, where, seconds)``."""
    if not todo:
        return {}, "nothing to render", 0.0
    from distributed import as_completed
    from tqdm import tqdm

    from synth.infra.cluster import connect
    from synth.products.learn_set import probe, render_scene_task, scene_folder

    client, cluster, where = connect(scheduler, workers, timeout, probe, "learn scenes")
    started, results, run = time.perf_counter(), {}, uuid.uuid4().hex[:8]
    try:
        futures = {}
        for seed in todo:
            task = {"seed": seed, "spp": request.spp, "ranges": request.ranges.describe(),
                    "out": os.path.abspath(os.path.join(request.out, scene_folder(seed)))}
            futures[client.submit(render_scene_task, task, pure=False,
                                  key=f"learn-{run}-{seed}")] = seed
        bar = tqdm(total=len(todo), unit="scene", desc="learn", file=sys.stderr,
                   disable=True if not progress else None)
        for future in as_completed(futures, loop=client.loop):
            interrupt.check()
            seed = futures.pop(future)
            try:
                results[seed] = future.result()
            except Exception as exc:  # a worker died
                results[seed] = {"seed": seed, "status": "failed",
                                 "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"}
            bar.update(1)
        bar.close()
    finally:
        with interrupt.deferred():
            client.close()
            if cluster is not None:
                cluster.close()
    return results, where, time.perf_counter() - started


def _finish(request, options, previous, todo, results, where, compute, started) -> int:
    """Rebuild ``learn.json``, ``index.csv``, the lists and the README; print the summary."""
    from synth.infra.fileio import atomic_write_text
    from synth.products.learn_set import (read_manifests, readme_text, split_of, write_index,
                                          write_lists)

    interrupt.check()
    out, seeds, fractions = request.out, request.seeds, request.fractions
    manifests = read_manifests(out, seeds)
    rows = write_index(out, manifests, fractions)
    counts = write_lists(out, manifests, fractions)
    atomic_write_text(os.path.join(out, "README.md"), readme_text(options, counts, rows))
    failed = {s: r for s, r in results.items() if r.get("status") != "ok"}
    missed = [r["seed"] for r in rows if not r["passed"]]
    runs = list((previous or {}).get("runs", []))
    runs.append({"run_id": uuid.uuid4().hex[:12], "where": where, "scenes_rendered": len(todo),
                 "compute_seconds": compute, "seconds": time.perf_counter() - started})
    _write_learn_json(out, options, {
        str(s): {"split": split_of(s, fractions), "status": "ok" if s in manifests else "missing",
                 "manifest_sha256": _manifest_digest(out, s),
                 "error": failed.get(s, {}).get("error")} for s in seeds}, runs)
    rate = f" ({3600 * len(todo) / compute:.0f} pairs/hour)" if todo and compute > 0 else ""
    print(f"learn: {len(seeds)} scenes ({', '.join(f'{counts[k]} {k}' for k in counts)}): "
          f"{len(seeds) - len(todo)} done before, {len(todo) - len(failed)} rendered now on "
          f"{where} in {compute:.1f} s{rate}; {len(failed)} failed, {len(missed)} outside the "
          f"checks' bounds; wrote {out}/index.csv, learn.json, lists/, kitti/, README.md")
    if rows:
        worst_trip = max(r["round_trip_max_px"] for r in rows)
        worst_rect = max((r["rectified_vs_flow_max_px"] or 0.0) for r in rows)
        worst_exact = max((r["exact_rectified_vs_flow_max_px"] or 0.0) for r in rows)
        exact = sum(r["exact_pixels_compared"] for r in rows)
        print(f"  checks: Fermat round trip max {worst_trip:.2e} px, rectified disparity vs "
              f"correspondence truth max {worst_rect:.2e} px ({worst_exact:.2e} px over the "
              f"{exact} sampled pixels where the warp is exact)")
    for seed, result in list(failed.items())[:5]:
        print(f"  seed {seed}: {result['error']}", file=sys.stderr)
    return 1 if failed or missed else 0


def _write_learn_json(out: str, options: dict, scenes: dict, runs: list) -> None:
    """``learn.json``: the options, their hash without the seeds (what a rerun must match),
    each scene's split and status, the runs."""
    from synth.infra.fileio import atomic_write_json
    from synth.products.learn_set import LEARN_JSON, options_hash

    fixed = {k: v for k, v in options.items() if k != "seeds"}
    atomic_write_json(os.path.join(out, LEARN_JSON), {
        "command": "synth learn", "options": options,
        "options_hash_without_seeds": options_hash(fixed), "scenes": scenes, "runs": runs})


def _manifest_digest(out: str, seed: int) -> str | None:
    """The SHA-256 of a scene's ``manifest.json`` (None when there is none)."""
    import hashlib

    from synth.products.learn_set import scene_folder

    path = os.path.join(out, scene_folder(seed), "manifest.json")
    if not os.path.isfile(path):
        return None
    with open(path, "rb") as handle:
        return hashlib.sha256(handle.read()).hexdigest()


# ---------------------------------------------------------------------------------------------
# a suite spec of render = "learn"
# ---------------------------------------------------------------------------------------------
SPEC_KEYS = ("name", "description", "render", "seed", "scenes", "size", "spp", "ports", "water",
             "light", "distance_mm", "pitch_deg", "split", "objects")


def checked_objects(paths) -> tuple:
    """The object files as absolute paths, each read once here (ValueError naming the file for
    one that is not a usable mesh: before anything is written)."""
    from synth.scene.sea_objects import read_object

    for path in paths:
        read_object(path)
    return tuple(os.path.abspath(p) for p in paths)


def is_learn_spec(data: dict) -> bool:
    return isinstance(data, dict) and data.get("render") == "learn"


def _names(data, key, known, label) -> tuple:
    from synth.infra.grid import need

    value = data.get(key, list(known))
    need(isinstance(value, list) and value and all(v in known for v in value), label,
         f"{key} must be a list of {', '.join(known)}, got {value!r}")
    return tuple(dict.fromkeys(value))


def _numbers(data, key, count, default, label, low, high) -> tuple:
    from synth.infra.grid import need

    value = data.get(key, list(default))
    ok = (isinstance(value, list) and len(value) == count
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
          and all(low <= v <= high for v in value))
    need(ok, label, f"{key} must be {count} numbers in [{low:g}, {high:g}], got {value!r}")
    return tuple(float(v) for v in value)


def read_learn_spec(data: dict, label: str, out: str) -> LearnRequest:
    """The :class:`LearnRequest` of a learning suite spec (module docs); SpecError naming the
    file and the key for anything wrong."""
    from synth.infra.grid import check_top_keys, integer, need

    check_top_keys(data, SPEC_KEYS, label)
    seed = integer(data, "seed", 0, 0, label)
    scenes = integer(data, "scenes", 10, 1, label)
    spp = integer(data, "spp", DEFAULT_LEARN_SPP, 1, label)
    w, h = _numbers(data, "size", 2, (960, 768), label, 64, 8192)
    need(w.is_integer() and h.is_integer(), label, f"size must be whole pixels, got {[w, h]}")
    distance = _numbers(data, "distance_mm", 2, (800.0, 2500.0), label, 100.0, 20000.0)
    pitch = _numbers(data, "pitch_deg", 2, (50.0, 90.0), label, 30.0, 90.0)
    split = _numbers(data, "split", 3, (0.8, 0.1, 0.1), label, 0.0, 1e9)
    need(distance[0] <= distance[1] and pitch[0] <= pitch[1] and sum(split) > 0, label,
         "distance_mm and pitch_deg must be [low, high], split not all 0")
    objects = data.get("objects", [])
    need(isinstance(objects, list) and all(isinstance(o, str) for o in objects), label,
         f"objects must be a list of mesh files (relative to the spec), got {objects!r}")
    base = os.path.dirname(os.path.abspath(label))
    ranges = SeaRanges(size=(int(w), int(h)), ports=_names(data, "ports", PORT_KINDS, label),
                       waters=_names(data, "water", WATERS, label),
                       lights=_names(data, "light", LIGHTS, label), distance_mm=distance,
                       pitch_deg=pitch,
                       objects=checked_objects(os.path.join(base, o) for o in objects))
    return LearnRequest(out, tuple(range(seed, seed + scenes)), ranges, spp, split)


__all__ = ["LearnRequest", "SPEC_KEYS", "checked_objects", "is_learn_spec", "read_learn_spec",
           "run_learn"]
