"""``python -m eval run SCENE`` on a surface scene (``python -m synth scene --layout surface``):
dense matching through the port, one point per left pixel, scored against the mesh.

Per method: ``optical_path`` matches along the refractive epipolar curves
(:func:`measure.dense.match.match_dense`, model ``"refractive"``) and triangulates with the paper's
optical-path model; ``regular`` is the baseline that ignores refraction — the same plane sweep
and refinement with straight rays (model ``"pinhole"``) and pinhole triangulation — what a user
gets who folds nothing for the port. Scores (:mod:`eval.core.surface_metrics`): point-to-mesh
distance, precision/recall/F at 0.5, 1 and 5 mm, Chamfer, per-pixel depth error against the
truth maps, the fraction of overlap pixels measured, flatness of planes.

Options that apply: ``--from``, ``--spp`` and ``--variant`` (without ``--from``), ``--seed``,
``-D``, ``--depth-range``,
``--assume`` / ``--calib`` (what the measurement believes), ``--sensor`` and ``--median-filter``
(the images the matcher sees), ``--methods`` (``optical_path``, ``regular``), ``--pixel-sigma``
(the matching σ, below), ``--json``, ``--no-figures``; the target-only options are refused with one ``error:``
line.

Uncertainty (``optical_path`` only; ``regular`` ignores the port and gets none, like the
sparse runs): every matched pixel's 3 × 3 covariance (:func:`dense_covariances`) from its
matching σ — the right pixel's σ along the epipolar curve, from the window's registration bound
and the image noise σ_n estimated from the matched windows (:mod:`measure.dense.match`), or
``--pixel-sigma PX`` stated for every pixel — and the ``--calib`` file's covariance when it
has one; the report gives the σ summary and, against the truth maps, the coverage.

Writes ``report.json``, ``report.md``, ``views.png`` (both images), per method
``depth_error_<method>.png`` and ``points_<method>.ply`` (coloured by point-to-mesh distance),
and ``distances.png`` (histograms); for ``optical_path`` also ``sigma_z_optical_path.npy``
(``(H, W)`` float32 mm, NaN unmatched) and ``sigma_z_optical_path.png``. ``--no-figures``:
none of the PNG files.
"""

from __future__ import annotations

import io
import os
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import fields

import numpy as np

from eval.cli import CLIError
from eval.core.formatting import format_number as fmt
from eval.run.config import COMMAND, RunConfig
from eval.run.report import verdict_exit_code, verdict_lines

#: Dense methods: name -> (matching model, triangulation method).
DENSE_METHODS = {"optical_path": ("refractive", "optical_path"), "regular": ("pinhole", "regular")}
#: Default search range: the surface's depth extent in the overlap, widened by this fraction of
#: its mean depth on each side.
DEPTH_MARGIN = 0.05
#: The pinhole baseline's search range starts this fraction nearer than the paraxial apparent
#: depth of the near end (see :func:`pinhole_depth_range`).
PINHOLE_NEAR_MARGIN = 0.2
#: Fields of :class:`eval.run.config.RunConfig` (options of ``eval run``) that apply to target
#: scenes only; a surface run refuses any of them that differs from its default.
TARGET_ONLY_OPTIONS = ("noise_px", "gate_mm", "self_calibrate", "eccentricity",
                       "threshold_fraction", "max_elongation", "max_area_ratio", "compare_calib")
#: The dense methods whose points get a covariance (the refractive model's; ``regular`` ignores
#: the port).
COVARIANCE_METHODS = ("optical_path",)
#: Points per chunk of :func:`dense_covariances` (bounded memory: ~1 kB per point and parameter).
COVARIANCE_CHUNK = 1 << 16


def is_surface_scene(path: str) -> bool:
    """Whether the scene file holds a surface (the ``ply`` shape of ``synth scene --layout
    surface``) — read with ElementTree, no Mitsuba; False for anything unreadable (the normal
    scene loader then says what is wrong)."""
    from synth.scene import SURFACE_ID

    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return False
    return any(shape.get("id") == SURFACE_ID for shape in root.iter("shape"))


def dense_methods(config: RunConfig) -> tuple:
    """The dense methods of the run (default: both); CLIError names an option of ``config``
    that does not apply to a surface scene."""
    defaults = {f.name: f.default for f in fields(RunConfig)}
    for name in TARGET_ONLY_OPTIONS:
        if getattr(config, name) != defaults[name]:
            raise CLIError(f"--{name.replace('_', '-')} applies to target scenes, not to the "
                           f"surface scene {config.scene}")
    if config.methods is None:
        return tuple(DENSE_METHODS)
    unknown = [m for m in config.methods if m not in DENSE_METHODS]
    if unknown or not config.methods:
        raise CLIError(f"--methods: a surface scene is measured with "
                       f"{' and '.join(DENSE_METHODS)}, got {','.join(config.methods)!r}")
    return config.methods


def develop(config: RunConfig, left, right, seed):
    """The images the matcher sees: through the ``--sensor`` model (seeded) and the
    ``--median-filter``, if given; returns ``(left, right, sensor report or None)``."""
    import cv2

    from eval.run.inputs import expose_views

    left, right, sensor_info = expose_views(left, right, config.sensor, seed)
    if config.median_filter:
        left, right = (cv2.medianBlur(np.asarray(image, dtype=np.float32), int(config.median_filter))
                       for image in (left, right))
    return left, right, sensor_info


def surface_inputs(config: RunConfig, log):
    """``(spec, measured rig, its covariance or None, left, right, truth maps of the left view,
    provenance)``."""
    from synth.products.truth_maps import MeshTracer, read_truth_maps, truth_maps

    from eval.run.inputs import load_run_scene, measurement_calibration, read_run_dataset

    spec = load_run_scene(config)
    if spec.extra_cameras:  # never the first two of them silently
        raise CLIError(f"{config.scene}: a surface scene of {len(spec.all_cameras)} cameras; "
                       f"dense matching is a method of two views (keep two sensors; scenes of "
                       f"more cameras are measured on disk targets)")
    rig, rig_covariance = measurement_calibration(config, spec)
    if config.from_dir:
        data = read_run_dataset(config, spec)
        try:
            truth = read_truth_maps(config.from_dir, "left", spec.size)
        except ValueError as exc:
            raise CLIError(f"--from {config.from_dir}: {exc}") from None
        log(f"reusing the images and truth maps of {config.from_dir}")
        return spec, rig, rig_covariance, data.left, data.right, truth, {
            "from": os.path.abspath(config.from_dir), "variant": data.manifest.get("variant"),
            "spp": data.manifest.get("spp"), "timings": {}}
    from synth.rendering.render import render_stereo

    log(f"render both views ({spec.size[0]}x{spec.size[1]} px, {config.spp or spec.spp} spp) …")
    left, right, info = render_stereo(spec, spp=config.spp, variant=config.variant,
                                      progress=config.progress, adaptive=not config.full_film)
    t = time.perf_counter()
    tracer = MeshTracer(spec.surface.mesh_path, spec.surface.vertices, spec.surface.triangles)
    truth = truth_maps(tracer, spec.rig.left, spec.rig.right, spec.rig.port)
    return spec, rig, rig_covariance, left, right, truth, {
        "variant": info["variant"], "spp": info["spp"], "render": info["render"],
        "timings": {"render_left": info["seconds"]["left"], "render_right": info["seconds"]["right"],
                    "truth_maps": time.perf_counter() - t}}


def pinhole_depth_range(rig, depth_range) -> tuple[float, float]:
    """The search range of the pinhole baseline: where the refractive range ``depth_range``
    *appears* to it, its near end lowered by :data:`PINHOLE_NEAR_MARGIN` — so the baseline finds
    the surface where the pinhole model sees it and is scored on what it then measures. Behind a
    flat port the paraxial apparent depths (the port's closed form,
    :meth:`measure.geometry.port.RigPort.apparent_depths`; off-axis points appear nearer still,
    hence the margin). Behind each camera's own port (domes, two housings), measured from the
    rig (:func:`_apparent_depths_traced`): exactly the range through centred domes, nearer
    through decentred ones (domes 2.5–4.6 mm off centre show a plane at 900 mm as near as
    624 mm).
    The near end stays beyond the glass (:func:`measure.dense.match.glass_depth`, + 1 mm), where the
    matcher's depth planes must lie."""
    from measure.dense.match import glass_depth

    closed_form = rig.port.apparent_depths(depth_range)
    near, far = (closed_form if closed_form is not None
                 else _apparent_depths_traced(rig, depth_range))
    return float(max(near * (1 - PINHOLE_NEAR_MARGIN), glass_depth(rig) + 1.0)), float(far)


def _apparent_depths_traced(rig, depth_range, grid: int = 9) -> tuple[float, float]:
    """``(nearest, farthest)`` depth (mm along :attr:`measure.Rig.depth_axis` from the
    left camera's centre) at which the pinhole model triangulates the points that lie at the
    two ends of ``depth_range`` on the water rays of a ``grid`` × ``grid`` lattice of left
    pixels, each projected through the right camera's own port (a dome, a housing). The
    nearest is at most ``depth_range``'s near end (a near end the right camera does not see at
    all would otherwise leave only the far end's points); ``depth_range`` itself where the
    right camera sees none of them."""
    from measure.geometry.projection import project
    from measure.stereo.triangulate import triangulate

    width, height = rig.left.size
    u, v = np.meshgrid(np.linspace(0.0, width - 1.0, grid), np.linspace(0.0, height - 1.0, grid))
    uv_left = np.column_stack([u.ravel(), v.ravel()])
    rays = rig.trace(0, rig.left.rays(uv_left))
    axis, center = rig.depth_axis, rig.left.center
    along = rays.directions @ axis
    seen = []
    for depth in depth_range:
        with np.errstate(divide="ignore", invalid="ignore"):
            step = (depth - (rays.origins - center) @ axis) / along
        points = rays.origins + step[:, None] * rays.directions
        uv_right = project(rig.right, rig.port.view(1), points)
        ok = (np.isfinite(step) & (step > 0) & np.all(np.isfinite(uv_right), axis=1)
              & rig.right.in_image(np.nan_to_num(uv_right, nan=-1.0)))
        if ok.any():
            pinhole = triangulate(rig, uv_left[ok], uv_right[ok], "regular").points
            seen.append((pinhole - center) @ axis)
    depths = np.concatenate(seen) if seen else np.empty(0)
    depths = depths[np.isfinite(depths)]
    if depths.size == 0:
        return float(depth_range[0]), float(depth_range[1])
    return min(float(depths.min()), float(depth_range[0])), float(depths.max())


def default_depth_range(truth) -> tuple[float, float]:
    """The search range when none is given (see :data:`DEPTH_MARGIN`), mm."""
    depth = truth.depth[truth.overlap]
    if depth.size == 0:
        raise CLIError("the surface is not seen by both cameras (no overlap pixel)")
    margin = DEPTH_MARGIN * float(depth.mean())
    return float(depth.min()) - margin, float(depth.max()) + margin


def dense_covariances(rig, matches, points, pixel_sigma, rig_covariance=None):
    """``(PointCovariance, info)``: the covariance of every dense match's point ``(N, 3)``
    (:func:`measure.stereo.uncertainty.dense_point_covariances`: the left pixel exact, the right one σ
    along its epipolar curve) and the rig's covariance (None: the rig taken as exact).
    ``pixel_sigma``: ``"auto"`` (the matcher's σ per pixel) or px (stated for every pixel)."""
    from eval.core.uncertainty import AUTO
    from measure.stereo.uncertainty import PointCovariance, dense_point_covariances

    n = points.shape[0]
    if pixel_sigma == AUTO:
        sigma = np.asarray(matches.sigma_px, dtype=np.float64)
        info = {"source": f"matching σ per pixel (image noise {matches.noise_source} from the "
                          f"matched windows' residuals)",
                "noise_sigma": matches.noise_sigma}
        if matches.noise_levels is not None:
            info["noise_levels"] = {"intensity": matches.noise_levels[0],
                                    "sigma": matches.noise_levels[1]}
    else:
        sigma = np.full(n, float(pixel_sigma))
        info = {"source": "stated (--pixel-sigma), along the epipolar curve",
                "stated_px": float(pixel_sigma)}
    finite = sigma[np.isfinite(sigma)]
    info.update({"median_px": float(np.median(finite)) if finite.size else None,
                 "p95_px": float(np.percentile(finite, 95)) if finite.size else None,
                 "max_px": float(finite.max()) if finite.size else None,
                 "infinite": int(n - finite.size)})
    parts = [dense_point_covariances(rig, points[k:k + COVARIANCE_CHUNK],
                                     sigma[k:k + COVARIANCE_CHUNK],
                                     matches.curve_direction[k:k + COVARIANCE_CHUNK],
                                     rig_covariance)
             for k in range(0, n, COVARIANCE_CHUNK)]
    if not parts:
        empty = np.zeros((0, 3, 3))
        return PointCovariance(empty, empty, empty), info
    return PointCovariance(*(np.concatenate([getattr(p, name) for p in parts])
                             for name in ("total", "pixel", "rig"))), info


def measure_surface(config: RunConfig, methods, log):
    """Match, triangulate and score every method; returns ``(report, arrays)``."""
    spec, rig, rig_covariance, left, right, truth, provenance = surface_inputs(config, log)
    left, right, sensor_info = develop(config, left, right,
                                       spec.seed if config.seed is None else config.seed)
    depth_range = _depth_range(config, rig, truth)
    h, w = truth.valid.shape
    report = {"scene": config.scene, "kind": "surface", "variant": provenance.get("variant"),
              "spp": provenance.get("spp"), "image_size": [w, h],
              "depth_range_mm": list(depth_range),
              "truth": {"valid_pixels": int(truth.valid.sum()),
                        "overlap_pixels": int(truth.overlap.sum())},
              "sensor": sensor_info, "median_filter": int(config.median_filter or 0),
              "methods": {}, "matching": {}, "uncertainty": {},
              "timings_s": dict(provenance["timings"]),
              "inputs": {k: v for k, v in provenance.items() if k in ("from", "render")}}
    arrays = {"left": left, "right": right, "per_method": {}}
    for method in methods:
        _measure_method(config, method, spec, rig, rig_covariance, left, right, truth,
                        depth_range, report, arrays, log)
    return report, arrays


def _depth_range(config, rig, truth) -> tuple:
    """The depths (mm) to search: ``--depth-range`` checked against the glass and the surface's
    own depths, else the range the truth spans (:func:`default_depth_range`)."""
    from measure.dense.match import glass_depth

    depth_range = config.depth_range_mm
    if depth_range is None:
        return default_depth_range(truth)
    if depth_range[0] <= glass_depth(rig):
        raise CLIError(f"--depth-range {depth_range[0]:g},{depth_range[1]:g}: NEAR must lie beyond "
                       f"the port (the water starts at {glass_depth(rig):g} mm)")
    seen = truth.depth[truth.overlap]
    if seen.size and (depth_range[1] < seen.min() or depth_range[0] > seen.max()):
        raise CLIError(f"--depth-range {depth_range[0]:g},{depth_range[1]:g} mm excludes the "
                       f"surface (its depths where both cameras see it: {seen.min():.1f}-"
                       f"{seen.max():.1f} mm)")
    return depth_range


def _measure_method(config, method, spec, rig, rig_covariance, left, right, truth, depth_range,
                    report, arrays, log) -> None:
    """One method matched, triangulated and scored against the truth; its entries go into
    ``report`` and its maps into ``arrays["per_method"]``."""
    from measure.dense.match import match_dense
    from measure.stereo.triangulate import triangulate

    from eval.core.surface_metrics import SurfaceCase, score_surface, surface_arrays

    h, w = truth.valid.shape
    model, triangulation = DENSE_METHODS[method]
    search = depth_range if model == "refractive" else pinhole_depth_range(rig, depth_range)
    log(f"{method}: dense matching ({model} model, depth {search[0]:.0f}-"
        f"{search[1]:.0f} mm) …")
    t = time.perf_counter()
    try:
        matches = match_dense(rig, left, right, search, model=model,
                              progress=_progress(config, method))
    except ValueError as exc:
        raise CLIError(f"--depth-range ({method}, searched {search[0]:.0f}-{search[1]:.0f} "
                       f"mm): {exc}") from None
    match_seconds = time.perf_counter() - t
    t = time.perf_counter()
    result = triangulate(rig, matches.uv_left, matches.uv_right, triangulation)
    measured = np.full((h, w, 3), np.nan)
    cols, rows = matches.uv_left[:, 0].astype(int), matches.uv_left[:, 1].astype(int)
    measured[rows, cols] = result.points
    triangulate_seconds = time.perf_counter() - t
    t = time.perf_counter()
    case = SurfaceCase(spec.surface.vertices, spec.surface.triangles, measured, truth.points,
                       truth.overlap, spec.rig.port.normal)
    method_arrays = surface_arrays(case)
    report["methods"][method] = score_surface(case, arrays=method_arrays)
    report["matching"][method] = {
        "model": model, "triangulation": triangulation, "matched_pixels": int(rows.size),
        "depth_range_mm": list(search),
        "planes": int(matches.n_planes), "median_score": float(np.median(matches.score))
        if matches.score.size else float("nan"),
        "timings_s": {**matches.timings, "total": match_seconds}}
    report["timings_s"][f"match_{method}"] = match_seconds
    report["timings_s"][f"triangulate_{method}"] = triangulate_seconds
    report["timings_s"][f"score_{method}"] = time.perf_counter() - t
    if method in COVARIANCE_METHODS:
        t = time.perf_counter()
        method_arrays["sigma_z"], report["uncertainty"][method] = _method_uncertainty(
            config, rig, rig_covariance, matches, result, truth, rows, cols)
        report["timings_s"][f"covariance_{method}"] = time.perf_counter() - t
    arrays["per_method"][method] = method_arrays
    log(f"{method}: {rows.size} pixels matched in {match_seconds:.1f} s")


def _method_uncertainty(config, rig, rig_covariance, matches, result, truth, rows, cols):
    """``(sigma_z (H, W) float32 mm, report entry)``: each matched pixel's point covariance
    (:func:`dense_covariances`) and its coverage of the errors against the truth."""
    from eval.core.uncertainty import rig_covariance_note, uncertainty_summary

    h, w = truth.valid.shape
    covariance, info = dense_covariances(rig, matches, result.points, config.pixel_sigma,
                                         rig_covariance)
    errors = result.points - truth.points[rows, cols]
    errors[~truth.overlap[rows, cols]] = np.nan
    sigma_z = np.full((h, w), np.nan, np.float32)
    sigma_z[rows, cols] = np.sqrt(covariance.total[:, 2, 2])
    # the truth point of a pixel lies on its left ray, like the measured one: with an
    # exact rig the error has one dimension (the covariance's 1 % across is padding)
    summary = uncertainty_summary(covariance.total, errors,
                                  dof=1 if rig_covariance is None else 3)
    if summary["coverage"].get("verdict"):
        summary["coverage"]["verdict"] = dense_verdict(summary["coverage"])
    rig_source = f"--calib {config.calib}" if config.calib else None
    return sigma_z, {"matching_sigma": info,
                     "rig": rig_covariance_note(rig_covariance, rig_source), **summary}


def dense_verdict(coverage: dict) -> str:
    """The report's sentence when a dense run's ``coverage_95`` is outside
    :data:`eval.core.uncertainty.HONEST_COVERAGE` (what the matching σ does not hold)."""
    from eval.core.uncertainty import HONEST_COVERAGE

    fraction = coverage["coverage_95"]
    if fraction < HONEST_COVERAGE[0]:
        return (f"σ understates the errors: {fraction:.3f} of the pixels inside their 95 % "
                f"interval (< {HONEST_COVERAGE[0]:.2f}); the matching σ holds the images' "
                f"noise, not the renderer's texture filtering nor the depth a window spans on "
                f"a slanted surface")
    return (f"σ overstates the errors: {fraction:.3f} of the pixels inside their 95 % interval "
            f"(> {HONEST_COVERAGE[1]:.2f}); with a calibration's covariance one calibration is "
            f"one draw of the rig error, shared by every pixel")


def _progress(config: RunConfig, method):
    """A ``(done, total)`` callback drawing a tqdm bar over the sweep planes (None if quiet)."""
    if not config.progress:
        return None
    from tqdm import tqdm

    bar = {}

    def update(done, total):
        if "bar" not in bar:
            bar["bar"] = tqdm(total=total, desc=f"{method} sweep", unit="plane", leave=False,
                              file=sys.stderr)
        bar["bar"].update(done - bar["bar"].n)
        if done >= total:
            bar["bar"].close()

    return update


def write_outputs(tmp: str, report: dict, arrays: dict, figures: bool = True) -> None:
    """Figures and coloured point clouds of a surface run into ``tmp`` (entries in the report:
    ``files``, and ``figures``, the PNG files written); ``figures=False``: the point clouds
    and ``sigma_z_*.npy`` only."""
    from synth.infra.fileio import atomic_write_bytes

    from eval.run import dense_figures
    from eval.run.figures import views_pair

    drawn = []

    def draw(function, name, *args):
        if figures:
            function(os.path.join(tmp, name), *args)
            drawn.append(name)

    draw(views_pair, "views.png", arrays["left"], arrays["right"])
    distances = {}
    report["files"] = {}
    for method, data in arrays["per_method"].items():
        draw(dense_figures.write_error_map, f"depth_error_{method}.png", data["depth_error"],
             f"{method}: measured − true depth [mm]")
        if "sigma_z" in data:
            buffer = io.BytesIO()
            np.save(buffer, data["sigma_z"], allow_pickle=False)
            atomic_write_bytes(os.path.join(tmp, f"sigma_z_{method}.npy"), buffer.getvalue())
            draw(dense_figures.write_sigma_map, f"sigma_z_{method}.png", data["sigma_z"],
                 f"{method}: σ_z of each point [mm]")
        vmax = float(np.nanpercentile(data["distance"], 99)) if data["distance"].size else 1.0
        report["files"][method] = dense_figures.write_colored_cloud(
            os.path.join(tmp, f"points_{method}.ply"), data["measured"], data["distance"],
            max(vmax, 1e-6))
        distances[method] = data["distance"]
    draw(dense_figures.write_distance_histogram, "distances.png", distances)
    report["figures"] = drawn


def report_markdown(report: dict) -> str:
    from eval.core.surface_metrics import surface_table

    t = report["timings_s"]
    lines = [f"# Dense run report: `{report['scene']}`", "",
             f"Surface scene, {report['image_size'][0]}x{report['image_size'][1]} px; Mitsuba "
             f"variant `{report['variant']}`, {report['spp']} spp. Truth: "
             f"{report['truth']['valid_pixels']} left pixels see the surface, "
             f"{report['truth']['overlap_pixels']} of them are seen by the right camera too (the "
             f"overlap). Search range {report['depth_range_mm'][0]:.1f}-"
             f"{report['depth_range_mm'][1]:.1f} mm along the port normal.", "",
             *verdict_lines(report),
             "## Accuracy per method", "", "```", surface_table(report["methods"]), "```", "",
             "`optical_path`: matched along the refractive epipolar curves, triangulated with the "
             "paper's model. `regular`: the same matcher and triangulation with straight rays "
             "(refraction ignored) — the baseline. Point-to-mesh: distance of each measured "
             "point to the true mesh; F@τ: harmonic mean of precision (measured points within τ "
             "of the mesh) and recall (truth points of the overlap within τ of the measured "
             "cloud); depth error: (measured − true)·N per pixel against the truth maps.", "",
             "## Matching", "", "| method | model | planes | matched pixels | median ZNCC | "
             "time (s) |", "|---|---|---|---|---|---|"]
    for method, m in report["matching"].items():
        lines.append(f"| {method} | {m['model']} | {m['planes']} | {m['matched_pixels']} | "
                     f"{fmt(m['median_score'])} | {fmt(m['timings_s']['total'], 1)} |")
    figures = report.get("figures") is None or bool(report["figures"])  # None: from before
    for method, u in report.get("uncertainty", {}).items():
        lines += ["", f"## Uncertainty ({method})", "", *uncertainty_lines(u, figures)]
    lines += ["", "Time per stage (s): " + "; ".join(
        f"{method}: " + ", ".join(f"{k} {v:.2f}" for k, v in m["timings_s"].items())
        for method, m in report["matching"].items()), "",
        "## Files", "", *(["- `views.png`, `distances.png`"] if figures else []),
        *[f"- {f'`depth_error_{m}.png`, ' if figures else ''}`points_{m}.ply` (colour = "
          f"point-to-mesh distance, 0 to {f['vmax_mm']:.3g} mm)"
          for m, f in report.get("files", {}).items()], "",
        "## Timings (s)", "", " · ".join(f"{k} {v:.2f}" for k, v in t.items())]
    return "\n".join(lines) + "\n"


def uncertainty_lines(u: dict, figures: bool = True) -> list:
    """report.md's lines on one method's covariances (``report["uncertainty"][method]``);
    ``figures``: whether the run drew ``sigma_z_*.png``."""
    m, sig = u["matching_sigma"], u["sigma"]
    noise = (f"; image noise σ_n {fmt(m['noise_sigma'], 4)} (the images' units)"
             if m.get("noise_sigma") is not None else "")
    lines = [f"Matching σ: {m['source']}{noise}; along the epipolar curve median "
             f"{fmt(m['median_px'], 4)} px, 95th percentile {fmt(m['p95_px'], 4)} px. Rig: "
             f"{u['rig']}."]
    if sig.get("n"):
        lines += ["", f"σ of the {sig['n']} points: median σx, σy, σz "
                      f"{fmt(sig['median_sigma_mm']['x'], 4)}, {fmt(sig['median_sigma_mm']['y'], 4)}, "
                      f"{fmt(sig['median_sigma_mm']['z'], 4)} mm; largest σ_P "
                      f"{fmt(sig['max_sigma_p_mm'], 4)} mm (`sigma_z_*.npy`"
                      f"{', `sigma_z_*.png`' if figures else ''})."]
    cov = u.get("coverage") or {}
    if cov.get("n"):
        z = cov["normalized"]["z"]
        lines += ["", f"Against the truth ({cov['n']} pixels of the overlap): coverage_95 "
                      f"{fmt(cov['coverage_95'], 3)} (0.95 expected), mean Mahalanobis² "
                      f"{fmt(cov['mahalanobis2_mean'], 3)} ({cov.get('dof', 3)} expected), "
                      f"normalized z error "
                      f"mean {fmt(z['mean'], 3)}, std {fmt(z['std'], 3)} (1 expected)."]
        if cov.get("verdict"):
            lines += ["", cov["verdict"]]
    return lines


def summary_line(report: dict) -> str:
    parts = []
    for method, s in report["methods"].items():
        fraction = s["measured_fraction"]
        parts.append(f"{method} {fmt(None if fraction is None else 100 * fraction, 1)} % "
                     f"measured, RMS {fmt(s['p2m_rms_mm'])} mm, F@1mm {fmt(s['fscore_1mm'])}")
    for method, u in report.get("uncertainty", {}).items():
        coverage = (u.get("coverage") or {}).get("coverage_95")
        parts.append(f"{method} median σz {fmt((u['sigma'].get('median_sigma_mm') or {}).get('z'))}"
                     f" mm, coverage_95 {fmt(coverage, 3)}")
    return (f"{report['scene']}: {report['truth']['overlap_pixels']} overlap pixels; "
            + "; ".join(parts) + f"; total {report['timings_s']['total']:.1f} s")


def main(config: RunConfig, out: str, print_json: bool, log) -> int:
    """The dense ``eval run`` into directory ``out``: check, claim the output, measure, write
    (whole or not at all); ``print_json``: also print report.json to stdout."""
    import json

    from synth.infra.fileio import OutputDir, atomic_write_json, atomic_write_text, jsonable
    from synth.infra.provenance import package_versions

    from eval.core.surface_metrics import surface_table

    methods = dense_methods(config)
    output = OutputDir(out, COMMAND).claim()
    start = time.perf_counter()
    report, arrays = measure_surface(config, methods, log)
    failures = dense_failures(report)
    report["verdict"] = {"passed": not failures, "failures": failures}
    log("write the report, figures and point clouds …")
    with output.staged() as tmp:
        t = time.perf_counter()
        report["versions"] = package_versions()
        write_outputs(tmp, report, arrays, figures=not config.no_figures)
        report["timings_s"]["report"] = time.perf_counter() - t
        report["timings_s"]["total"] = time.perf_counter() - start
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), report_markdown(report))
    stream = sys.stderr if print_json else sys.stdout
    print(summary_line(report), file=stream)
    print(surface_table(report["methods"]), file=stream)
    print(f"wrote {output.path}", file=stream)
    if print_json:
        print(json.dumps(report, indent=2))
    return verdict_exit_code(report, output.path)


def dense_failures(report: dict) -> list:
    """What the truth shows went wrong in a dense run (empty: nothing): the refractive method
    measured no pixel of the overlap."""
    fraction = report["methods"].get("optical_path", {}).get("measured_fraction")
    if "optical_path" in report["methods"] and not fraction:
        return ["optical_path measured 0 % of the overlap (no pixel matched: check the depth "
                "range, the spp and the speckle's size in pixels)"]
    return []
