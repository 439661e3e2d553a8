"""What a worker of ``python -m eval sweep`` does with a batch of cells (imported on the workers).

* A **render cell** is ``eval run`` in-process: the cell's parameters become a
  :class:`eval.run.config.RunConfig` (:func:`run_config`), measured by
  :func:`eval.run.pipeline.measure_scene` — render, detect, match, triangulate, score. Its
  report is ``eval run``'s ``report.json`` (without versions and output files).
* An **analytic cell** is the forward model plus noise, like ``eval paper``'s Monte Carlo: the
  scene's targets projected through the true rig (:func:`eval.core.analytic.project_pair`), Gaussian
  pixel noise of σ ``noise_px`` drawn from the cell's seed (:func:`synth.rendering.noise.pixel_noise`),
  triangulated with the assumed rig (:func:`eval.core.analytic.triangulation_errors`, numpy over all
  targets at once) and summarized with :class:`eval.core.results.ErrorStats` (the schema of ``eval
  run``'s ``methods``) with the length errors of target pairs and the error after the best rigid
  alignment. ``regular_in_air`` triangulates the all-air copy of the rig (indices 1),
  as section 3.3 of the paper does; ``absorbed`` the pinhole calibration of the scene's boards
  seen through its true port (:func:`eval.core.absorbed.analytic_absorbed_calibration`, once per
  rig and worker).

Every cell returns a record (key, status, error, report, row) and never raises: a cell that
fails records its error. A worker process keeps Mitsuba imported, its JIT kernels, the parsed
scenes and the projections of their targets between cells (:data:`_CACHE`). The scene files
travel with the tasks (bytes), so a cluster needs no shared file system.
"""

from __future__ import annotations

import os
import tempfile
import time
import traceback

from synth.infra.cluster import scene_file, setup_worker

#: Per worker process: scene files written, scenes parsed, projections computed.
_CACHE: dict = {}


def value_text(value) -> str:
    """A spec value as the text ``--assume`` / ``-D`` take (lists space-separated, floats exact)."""
    if isinstance(value, list):
        return " ".join(repr(float(v)) if isinstance(v, float) else str(v) for v in value)
    if isinstance(value, float):
        return repr(value)
    return str(value)


def cell_assumptions(params: dict) -> dict:
    """The ``assume.*`` parameters of a cell as :func:`eval.core.assumption.parse_assumptions`
    gives them."""
    from eval.core.assumption import parse_assumptions

    return parse_assumptions([f"{k[7:]}={value_text(v)}" for k, v in params.items()
                              if k.startswith("assume.")])


def run_config(cell: dict, scene_path: str):
    """The :class:`eval.run.config.RunConfig` of a render cell: its scene, ``-D`` values, seed,
    methods and the run parameters of the spec (``noise_px``, ``spp``, ``gate_mm``,
    ``self_calibrate``, ``eccentricity``, ``threshold_fraction``, ``max_elongation``,
    ``max_area_ratio``, ``median_filter``, ``assume.*``); no progress output."""
    from eval.run.config import RunConfig, parse_self_calibration

    p = cell["params"]
    kinds = {"noise_px": float, "spp": int, "gate_mm": float, "threshold_fraction": float,
             "max_elongation": float, "max_area_ratio": float}
    optional = {name: kind(p[name]) for name, kind in kinds.items() if name in p}
    return RunConfig(scene=scene_path,
                     defines=tuple((name, str(value))
                                   for name, value in sorted(cell["defines"].items())),
                     seed=int(cell["seed"]), methods=tuple(cell["methods"]),
                     assumptions=cell_assumptions(p),
                     self_calibrate=parse_self_calibration(p.get("self_calibrate", "")),
                     eccentricity=(None if p.get("eccentricity") is None
                                   else bool(p["eccentricity"])),
                     median_filter=int(p.get("median_filter") or 0), progress=False, **optional)


def render_cell(cell: dict, scene_path: str, save: tuple):
    """``(report, files)``: ``eval run`` on the cell, in this process; ``files`` ``{name:
    bytes}`` holds what ``save`` asks for (``images``, ``ply``, ``figures``)."""
    from synth.infra.fileio import jsonable

    from eval.run.pipeline import measure_scene

    start = time.perf_counter()
    result = measure_scene(run_config(cell, scene_path), lambda text: None)
    files = _saved_files(result, save) if save else {}
    report = result.report
    report["scene"] = cell["scene"]
    report["timings_s"]["total"] = time.perf_counter() - start
    report.pop("versions", None)
    return jsonable(report), files


def _saved_files(result, save) -> dict:
    from synth.rendering.image_files import png16_scale, to_png16, write_png

    from eval.run.report import write_outputs

    files = {}
    inputs = result.inputs
    with tempfile.TemporaryDirectory(prefix="refstereo-cell-") as tmp:
        if "ply" in save or "figures" in save:
            write_outputs(tmp, result, figures="figures" in save)
        if "images" in save:
            scale = png16_scale(inputs.left, inputs.right)
            for view in ("left", "right"):
                write_png(os.path.join(tmp, f"{view}.png"), to_png16(getattr(inputs, view), scale))
        for name in sorted(os.listdir(tmp)):
            kind = ("ply" if name.endswith((".ply", ".csv")) else  # points, covariances
                    "images" if name in ("left.png", "right.png") else "figures")
            if kind in save:
                with open(os.path.join(tmp, name), "rb") as handle:
                    files[name] = handle.read()
    return files


# ------------------------------------------------------------------------------------------------
# analytic cells


def _scene_spec(scene_path: str, defines: dict):
    key = ("scene", scene_path, tuple(sorted(defines.items())))
    spec = _CACHE.get(key)
    if spec is None:
        from synth.scene import load_scene

        spec = _CACHE[key] = load_scene(scene_path, dict(defines)).require_two_cameras(
            "an analytic sweep cell")
    return spec


def _projections(scene_path: str, defines: dict, spec, in_air: bool):
    key = ("projection", scene_path, tuple(sorted(defines.items())), in_air)
    uv = _CACHE.get(key)
    if uv is None:
        from eval.core.analytic import air_copy, project_pair

        rig = air_copy(spec.rig) if in_air else spec.rig
        uv = _CACHE[key] = project_pair(rig, spec.targets)
    return uv


def _absorbed_rig(rig):
    """The absorbed calibration's rig for the cameras behind ``rig``'s port, once per worker."""
    import json

    from eval.core.absorbed import analytic_absorbed_calibration
    from eval.core.assumption import describe_rig

    key = ("absorbed", json.dumps(describe_rig(rig), sort_keys=True, default=str))
    absorbed = _CACHE.get(key)
    if absorbed is None:
        absorbed = _CACHE[key] = analytic_absorbed_calibration(rig).rig
    return absorbed


def analytic_cell(cell: dict, scene_path: str) -> dict:
    """The report of an analytic cell (see module docs)."""
    import numpy as np

    from eval.core.analytic import air_copy, triangulation_errors
    from eval.core.assumption import assumed_rig, rig_difference
    from eval.core.results import ErrorStats
    from synth.rendering.noise import pixel_noise

    start = time.perf_counter()
    p = cell["params"]
    spec = _scene_spec(scene_path, cell["defines"])
    assumptions = cell_assumptions(p)
    truth = spec.rig
    believed = assumed_rig(truth, spec.has_port, assumptions)
    targets = spec.targets
    n = targets.shape[0]
    sigma = float(p.get("noise_px", 0.0))
    rng = np.random.default_rng(cell["seed"])
    offset_left = pixel_noise((n, 2), sigma ** 2, rng)
    offset_right = pixel_noise((n, 2), sigma ** 2, rng)
    clean_left, clean_right = _projections(scene_path, cell["defines"], spec, False)
    uv_left, uv_right = clean_left + offset_left, clean_right + offset_right
    from eval.core.absorbed import ABSORBED
    from eval.core.cloud_metrics import length_errors, rigid_alignment

    methods = {}
    for method in cell["methods"]:
        if method == "regular_in_air":
            air_left, air_right = _projections(scene_path, cell["defines"], spec, True)
            errors = triangulation_errors(air_copy(believed), air_left + offset_left,
                                          air_right + offset_right, "regular", targets)[0]
        elif method == ABSORBED:
            errors = triangulation_errors(_absorbed_rig(truth), uv_left, uv_right,
                                          "optical_path", targets)[0]
        else:
            errors = triangulation_errors(believed, uv_left, uv_right, method, targets)[0]
        points = targets + errors
        ok = np.all(np.isfinite(points), axis=1)
        methods[method] = {**ErrorStats.of(errors).to_json(),
                           "rms_dp_aligned_mm": rigid_alignment(points[ok], targets[ok])[
                               "rms_dp_aligned_mm"],
                           **length_errors(points[ok], targets[ok])}
    calibration = None
    names = tuple(n for n in p.get("self_calibrate", "").split(",") if n)
    if names:
        calibration = _self_calibration(truth, believed, uv_left, uv_right, names, cell, targets)
    return {"scene": cell["scene"], "kind": "analytic", "targets": int(n), "noise_px": sigma,
            "seed": cell["seed"], "methods": methods, "self_calibration": calibration,
            "rigs": {"difference": rig_difference(truth, believed)},
            "timings_s": {"total": time.perf_counter() - start}}


def _self_calibration(truth, believed, uv_left, uv_right, names, cell, targets) -> dict:
    from measure.calibration.selfcal import self_calibrate

    from eval.core.analytic import triangulation_errors
    from eval.core.results import ErrorStats

    fit = self_calibrate(believed, uv_left, uv_right, names)
    true_values = {"n_water": truth.port.n_water, "port_distance": truth.port.distance,
                   "port_normal": truth.port.normal.tolist()}
    summary = {"parameters": list(names), "converged": fit.converged,
               "identifiable": fit.identifiable, "reason": fit.reason,
               "rms_px_before": fit.rms_px_before, "rms_px_after": fit.rms_px,
               "estimates": fit.estimates, "sigmas": fit.sigmas,
               "truth": {k: true_values[k] for k in names}, "methods": None}
    for name in ("n_water", "port_distance"):
        if name in fit.estimates:
            summary.setdefault("error", {})[name] = fit.estimates[name] - true_values[name]
    if fit.converged and fit.identifiable:
        summary["methods"] = {
            m: ErrorStats.of(triangulation_errors(fit.rig, uv_left, uv_right, m, targets)[0])
            .to_json() for m in cell["methods"] if m != "regular_in_air"}
    return summary


# ------------------------------------------------------------------------------------------------
# rows and batches

#: Parts of a report that are not one number per cell (left out of the table's row).
_NOT_IN_ROW = ("rigs", "versions", "inputs", "budget", "ply", "sensor", "plane")


def flatten(report: dict, prefix: str = "") -> dict:
    """The scalar leaves of a report as ``{"a.b.c": value}`` (lists and rigs left out)."""
    out = {}
    for key, value in report.items():
        if key in _NOT_IN_ROW:
            continue
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, f"{name}."))
        elif isinstance(value, (bool, int, float, str)) or value is None:
            out[name] = value
    return out


def run_cell(cell: dict, scenes: dict, save: tuple) -> dict:
    """One cell's record; a failure is recorded (``status`` ``failed``, ``error``), never
    raised."""
    scene_sha = cell["scene_sha"]
    start = time.perf_counter()
    files = {}
    try:
        path = scene_file(scene_sha, scenes[scene_sha], cell["scene_path"])
        if cell["kind"] == "render":
            report, files = render_cell(cell, path, save)
        else:
            from synth.infra.fileio import jsonable

            report = jsonable(analytic_cell(cell, path))
        status, error = "ok", None
    except Exception as exc:  # the cell failed: its row says why, the sweep goes on
        report, status = None, "failed"
        error = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
        if os.environ.get("REFSTEREO_TRACEBACK"):
            error += "\n" + traceback.format_exc()
    metrics = flatten({k: v for k, v in (report or {}).items()
                       if k not in ("scene", "seed", "kind", "noise_px")})
    return {"key": cell["key"], "status": status, "error": error, "report": report,
            "metrics": metrics, "seconds": time.perf_counter() - start, "files": files,
            "worker_pid": os.getpid()}


def run_batch(cells: list, scenes: dict, save: tuple = ()) -> list:
    """The Dask task: every cell of ``cells`` (dicts), in order; ``scenes`` ``{sha: bytes}``."""
    setup_worker()
    return [run_cell(cell, scenes, tuple(save)) for cell in cells]


def probe() -> dict:
    """What a worker reports before a sweep: its project files and Python (a check that the
    workers can import this module at all)."""
    import sys

    return {"module": __file__, "python": sys.version.split()[0]}


__all__ = ["analytic_cell", "cell_assumptions", "flatten", "probe", "render_cell", "run_batch",
           "run_cell", "run_config", "scene_file", "value_text"]
