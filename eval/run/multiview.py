"""``python -m eval run`` on a scene of more than two cameras (``synth scene --cameras N``).

Every view is rendered (:func:`synth.rendering.render.render_views`) — or read from a ``--from``
dataset of N cameras (:mod:`synth.products.dataset_layout`, :func:`dataset_views`) — and goes
through the two-camera run's stages (:mod:`eval.run.pipeline`, over every view): its targets
detected (:func:`~eval.run.pipeline.detect_stage`); the detections matched across all views
without ground truth (:func:`~eval.run.pipeline.match_stage`:
:func:`measure.stereo.multimatch.match_views`, pairwise refractive epipolar matching, tracks
from their union, a track with a conflict dropped); every track triangulated from all its
views with each method (``optical_path``, ``reprojection``:
:func:`~eval.run.pipeline.triangulate_stage`, :func:`measure.triangulate_rig`), after the disk
targets' eccentricity is removed from every view's centre (as the two-camera run does,
:func:`correct_views`). Only then is the truth used: each
detection is associated with the simulator's pixel of a target (the cross-check's mutual
nearest neighbours; the report's ``crosscheck``, per camera and over all, is the two-camera
run's cross-check of those detections against the simulator), a track is correct when all its
detections belong to one target, and the points are scored against the targets. The report
gives, per target, how many views saw it
(the simulator: wholly inside the image), how many its track joined, and its error; the RMS
error against the number of views k; and, from the same detections, the first two cameras
measured as a stereo pair (the two-camera run's optical path) for comparison.

A target seen by one view only is reported, never triangulated. Exit 1 when a track joins
detections of different targets. Units mm, reference frame the first camera's.
"""

from __future__ import annotations

import os
import sys
import time
import xml.etree.ElementTree as ET

import numpy as np

from eval.cli import CLIError
from eval.run.config import RunConfig
from eval.core.views_uncertainty import (add_method, uncertainty_lines, views_uncertainty,
                                         write_views_uncertainty)
from measure.stereo.rig_triangulation import VIEW_METHODS

#: The options of a two-camera run that a run of N cameras does not take (refused, never
#: ignored): (config field, option).
NOT_FOR_N_CAMERAS = (("assumptions", "--assume"),
                     ("compare_calib", "--compare-calib"), ("absorbed_calib", "--absorbed-calib"),
                     ("self_calibrate", "--self-calibrate"), ("sensor", "--sensor"),
                     ("no_figures", "--no-figures"))  # a run of N cameras draws no figure
#: The default method of a run of N cameras (``--methods``: any of
#: :data:`measure.stereo.rig_triangulation.VIEW_METHODS`, the first the headline).
METHOD = "optical_path"


def is_multiview_scene(path: str) -> bool:
    """Whether the scene file holds more than two sensors — read with ElementTree, no Mitsuba;
    False for anything unreadable (the scene loader then says what is wrong)."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return False
    return sum(1 for _ in root.iter("sensor")) > 2


def refuse_inapplicable(config: RunConfig, cameras: int) -> None:
    for field_name, option in NOT_FOR_N_CAMERAS:
        if getattr(config, field_name):
            raise CLIError(f"{option} does not apply to {config.scene}, a scene of {cameras} "
                           f"cameras")
    other = set(view_methods(config)) - set(VIEW_METHODS)
    if other:
        raise CLIError(f"--methods: a scene of {cameras} cameras is measured with "
                       f"{' or '.join(VIEW_METHODS)} (N views), not {', '.join(sorted(other))}")


def view_methods(config: RunConfig) -> tuple:
    """The run's methods: ``--methods`` or :data:`METHOD`; the first is the headline
    (``report.json``'s ``method``, ``targets.csv``, the ratio to the pair)."""
    return tuple(config.methods) if config.methods else (METHOD,)


def measurement_rig(config: RunConfig, spec):
    """The scene's rig, or ``--calib`` (a ``calib.yaml`` of N cameras) when given; CLIError
    (exit 2) for a file that cannot be used or does not fit the scene."""
    if not config.calib:
        return spec.multirig
    from synth.products.dataset import DatasetError
    from synth.products.rig_file import read_rig_file

    try:
        rig = read_rig_file(config.calib)
    except DatasetError as exc:
        raise CLIError(f"--calib {exc}") from None
    if len(rig) != len(spec.all_cameras):
        raise CLIError(f"--calib {config.calib}: {len(rig)} cameras, but the scene has "
                       f"{len(spec.all_cameras)}")
    for name, camera in zip(rig.names, rig.cameras):
        if tuple(camera.size) != tuple(spec.size):
            raise CLIError(f"--calib {config.calib}: {name}: image size {camera.size[0]}x"
                           f"{camera.size[1]} px, but the scene renders {spec.size[0]}x"
                           f"{spec.size[1]} px")
    return rig


def rig_differences(truth, other) -> list[str]:
    """What differs (beyond :data:`eval.core.assumption.ROUND_OFF`) between two rigs of N
    cameras (:class:`measure.stereo.rig.Rig`): per camera its name, intrinsics,
    distortion, pose and port, as ``camK K``, ``camK port normal`` …; ``[]`` when they agree."""
    from eval.core.assumption import ROUND_OFF

    if len(truth) != len(other):
        return [f"{len(other)} cameras, not {len(truth)}"]

    def differs(a, b) -> bool:
        a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
        return a.shape != b.shape or bool(np.max(np.abs(a - b), initial=0.0) > ROUND_OFF)

    out = []
    for k, (name, a, b) in enumerate(zip(truth.names, truth.cameras, other.cameras)):
        if other.names[k] != name:
            out.append(f"camera {k} named {other.names[k]}, not {name}")
        dist_a = np.zeros(8) if a.dist is None else np.pad(a.dist, (0, 8 - a.dist.size))
        dist_b = np.zeros(8) if b.dist is None else np.pad(b.dist, (0, 8 - b.dist.size))
        for what, x, y in (("K", a.K, b.K), ("distortion", dist_a, dist_b),
                           ("size", a.size, b.size), ("pose", np.r_[a.R.ravel(), a.t],
                                                      np.r_[b.R.ravel(), b.t])):
            if differs(x, y):
                out.append(f"{name} {what}")
        p, q = truth.view_port(k), other.view_port(k)
        if type(p) is not type(q):
            out.append(f"{name} port")
            continue
        diff = {}
        p.difference(q, differs, diff)
        out += [f"{name} {key}" for key in diff]
    return out


def dataset_views(config: RunConfig, spec) -> tuple[list, dict]:
    """The images of the ``--from`` dataset of N cameras and the render's ``info``
    (variant, spp, seed, the per-view render entries, as the manifest recorded them); CLIError
    (exit 2, one line) for a dataset that is not one of this scene, or whose ``calib.yaml``
    disagrees with the scene rendered with the manifest's parameters."""
    from synth.products.dataset import DatasetError, is_views_dataset, read_dataset

    if not is_views_dataset(config.from_dir):
        raise CLIError(f"--from {config.from_dir}: not a dataset of {len(spec.all_cameras)} "
                       f"cameras (cam0/, cam1/, …), but {config.scene} is a scene of "
                       f"{len(spec.all_cameras)}")
    try:
        data = read_dataset(config.from_dir)
    except DatasetError as exc:
        raise CLIError(f"--from {exc}") from None
    if data.manifest["scene"].get("sha256") != spec.sha256:
        from eval.run.inputs import another_scene

        raise another_scene(config) or CLIError(
            f"--from {config.from_dir}: the dataset was rendered from another scene than "
            f"{config.scene}")
    difference = rig_differences(spec.multirig, data.rig)
    if difference:
        raise CLIError(f"--from {config.from_dir}: calib.yaml disagrees with the scene rendered "
                       f"with manifest.json's parameters (in {', '.join(difference)}); the run "
                       f"takes the scene as the truth: render the dataset again, or measure "
                       f"with --calib {os.path.join(config.from_dir, 'calib.yaml')} to believe it")
    m = data.manifest
    info = {"variant": m.get("variant", "?"), "spp": m.get("spp"),
            "spp_rendered": m.get("spp_rendered"), "seed": m.get("seed"),
            "from": os.path.abspath(config.from_dir),
            "render": {name: (m.get("render") or {}).get(name) for name in data.names}}
    return list(data.images), info


def correct_views(rig, pixels, radius_mm, iterations: int = 2):
    """The N-view form of :func:`measure.images.eccentricity.correct_eccentricity`: the disk
    targets' outline-centroid offsets predicted in every view from the triangulated points and
    the normals of their neighbours, removed, and triangulated again. ``pixels`` ``(T, V, 2)``;
    returns ``(MultiViewTriangulation, corrected pixels, offsets (T, V, 2))``."""
    from measure.images.eccentricity import local_normals, outline_centroid_offsets
    from measure.stereo.multiview import triangulate_views

    views = rig.views()
    result = triangulate_views(views, pixels)
    corrected, offsets = pixels, np.zeros_like(pixels)
    toward = np.mean([c.center for c in rig.cameras], axis=0)
    for _ in range(iterations):
        normals = local_normals(result.points, toward=toward)
        offsets = np.full_like(pixels, np.nan)
        ok = result.valid
        for v, view in enumerate(views):
            seen = ok & np.all(np.isfinite(pixels[:, v]), axis=1)
            if seen.any():
                offsets[seen, v] = outline_centroid_offsets(view.camera, view.port,
                                                            result.points[seen], normals[seen],
                                                            radius_mm)
        corrected = pixels - np.nan_to_num(offsets)
        result = triangulate_views(views, corrected)
    return result, corrected, offsets


def _rms(values) -> float | None:
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values ** 2))) if values.size else None


def measure(config: RunConfig, log) -> tuple[dict, dict]:
    """The run (module docs): ``(report, arrays)``. Detection, matching and the cross-check are
    the two-camera run's stages over every view (:mod:`eval.run.pipeline`)."""
    from eval.run.inputs import load_run_scene
    from eval.run.pipeline import crosscheck_stage, detect_stage, match_stage

    timings = {}
    spec = load_run_scene(config)
    names = spec.camera_names
    refuse_inapplicable(config, len(names))
    rig = measurement_rig(config, spec)
    seed = spec.seed if config.seed is None else config.seed
    visible_views = _visible_views(spec)
    if not (visible_views >= 2).any():
        raise CLIError(f"{config.scene}: no target is visible in two views")
    t = time.perf_counter()
    images, info = _views(config, spec, log)
    timings["render"] = time.perf_counter() - t
    inputs = _run_inputs(config, spec, rig, images, info, seed, timings["render"])
    t = time.perf_counter()
    detections, centers = detect_stage(inputs, config.noise_px, config.threshold_fraction,
                                       config.max_elongation, config.max_area_ratio,
                                       config.median_filter)
    detections, centers = list(detections.values()), list(centers.values())
    timings["detect"] = time.perf_counter() - t
    t = time.perf_counter()
    tracks, window = match_stage(inputs, dict(zip(names, centers)), config.gate_mm,
                                 config.depth_range_mm)
    timings["match"] = time.perf_counter() - t
    methods, head = view_methods(config), view_methods(config)[0]
    t = time.perf_counter()
    results, pixels = _triangulate(config, inputs, centers, tracks, methods)
    timings["triangulate"] = time.perf_counter() - t
    # the truth, for scoring only
    _, _, truth_of, crosscheck = crosscheck_stage(inputs, dict(zip(names, detections)))
    truth_of = list(truth_of.values())
    scored = {m: _scored_tracks(tracks, truth_of, r, spec.targets) for m, r in results.items()}
    t = time.perf_counter()
    # how a --calib rig differs from the truth: an understated σ's verdict names it
    differs = rig_differences(spec.multirig, rig) if config.calib else []
    covariance, uncertainty = views_uncertainty(config.pixel_sigma, config.noise_px, rig,
                                                detections, tracks, pixels, results[head], head,
                                                scored[head], rig_differs=differs)
    for method in methods[1:]:
        add_method(uncertainty, method, covariance, results[method], scored[method], differs)
    timings["covariance"] = time.perf_counter() - t
    t = time.perf_counter()
    entries = {m: _method_entry(tracks, scored[m], results[m], spec.targets[visible_views >= 2],
                                seed, uncertainty, m, len(names)) for m in methods}
    timings["evaluate"] = time.perf_counter() - t
    pair_report = _pair_report(config, rig, tracks, centers, truth_of, spec, names)
    rms = entries[head]["rms_dp_mm"]
    matching = _matching(config, tracks, scored[head], visible_views, window, names)
    failures = []
    if matching["wrong"]:
        failures.append(f"{matching['wrong']} tracks join detections of different targets")
    report = {
        "scene": config.scene, "cameras": list(names), "method": head,
        "rig": "--calib " + config.calib if config.calib else "the scene's rig",
        "variant": info["variant"], "spp": info["spp"], "spp_rendered": info["spp_rendered"],
        "seed": seed, "noise_px": config.noise_px,
        "eccentricity": bool(config.corrects_eccentricity),
        "detections": {name: int(len(c)) for name, c in zip(names, centers)},
        "matching": matching, "crosscheck": crosscheck,
        "methods": entries,
        "stereo_pair": pair_report,
        "ratio_to_pair": (rms / pair_report["rms_dp_mm"] if pair_report and rms
                          and pair_report["rms_dp_mm"] else None),
        "uncertainty": uncertainty, "timings_s": timings, "render": info,
        "verdict": {"passed": not failures, "failures": failures},
    }
    return report, {"targets": _per_target(spec, visible_views, scored[head], results[head],
                                           tracks.views_per_track),
                    "uncertainty": [(m, results[m], covariance, scored[m]) for m in methods]}


def _per_target(spec, visible_views, scored, result, k_views) -> np.ndarray:
    """``targets.csv``'s rows: per target its id, the views it is visible in, detected in and
    triangulated from (0: not), the headline method's point and its error dP (mm)."""
    ok, target, errors = scored["ok"], scored["target"], scored["errors"]
    per_target = np.full((len(spec.targets), 8), np.nan)
    per_target[:, 0] = spec.target_ids
    per_target[:, 1] = visible_views
    per_target[:, 2] = scored["detected_views"]
    per_target[:, 3] = 0
    per_target[target[ok], 3] = k_views[ok]
    per_target[target[ok], 4:7] = result.points[ok]
    per_target[target[ok], 7] = np.linalg.norm(errors[ok], axis=1)
    return per_target


def _method_entry(tracks, scored, result, truth_visible, seed, uncertainty, method,
                  n_views) -> dict:
    """The report's ``methods.<method>``, in the pair's schema
    (:func:`eval.run.pipeline.score_method`: the error statistics ``n``, ``rms_dp_mm`` …, the
    cloud, alignment, flatness, lengths, ``coverage_95``), with the N views' addition
    ``by_views``: per number of views k the tracks, those scored and their RMS dP and
    statistics."""
    from eval.core.results import ErrorStats
    from eval.run.pipeline import methods_with_coverage, score_method

    scores, _ = score_method(result, scored["correct"], scored["target"],
                             scored["targets"], truth_visible, seed)
    entry = methods_with_coverage({method: scores}, uncertainty)[method]
    ok, errors, k_views = scored["ok"], scored["errors"], tracks.views_per_track
    by_k = {}
    for k in range(2, n_views + 1):
        rows = ok & (k_views == k)
        by_k[str(k)] = {"tracks": int((k_views == k).sum()), "scored": int(rows.sum()),
                        "rms_dp_mm": _rms(np.linalg.norm(errors[rows], axis=1)),
                        "stats": ErrorStats.of(errors[rows]).to_json()}
    entry["by_views"] = by_k
    return entry


def view_scores(report: dict) -> dict:
    """``{n, rms_dp_mm, by_views}`` of a report of N cameras, where it holds them: since one
    report schema, ``methods.<method>`` (``method`` the report's); before, ``scores``."""
    entry = (report["scores"] if "scores" in report
             else report["methods"][report.get("method", METHOD)])
    return {key: entry[key] for key in ("n", "rms_dp_mm", "by_views")}


def _run_inputs(config, spec, rig, images, info, seed, render_seconds):
    """The pipeline's :class:`eval.run.inputs.RunInputs` of N views: the measurement's ``rig``
    and the scene's rig of N as the truth, every view's image by camera name, the default
    depth window along the scene's first pair's port."""
    from eval.run.inputs import RunInputs

    return RunInputs(scene=config.scene, rig=rig, has_port=spec.has_port, targets=spec.targets,
                     target_ids=spec.target_ids, target_radius=spec.target_radius,
                     left=images[0], right=images[1], params=spec.params,
                     variant=info["variant"], spp=info["spp"], render_seconds=render_seconds,
                     seed=seed, target_normals=spec.target_normals, truth_rig=spec.multirig,
                     views=dict(zip(spec.camera_names, images)), depth_port=spec.rig.port)


def _visible_views(spec) -> np.ndarray:
    """In how many views each target is wholly inside the image (the simulator's count)."""
    from eval.core.analytic import visible_targets

    truth_rig = spec.multirig
    return np.sum([visible_targets(camera, truth_rig.view_port(k), spec.targets,
                                   spec.target_radius)[1]
                   for k, camera in enumerate(truth_rig.cameras)], axis=0)


def _views(config, spec, log) -> tuple[list, dict]:
    """The views' images and how they were made: read from ``--from`` or rendered now."""
    from synth.rendering.render import render_summary, render_views

    if config.from_dir:
        images, info = dataset_views(config, spec)
        log(f"reusing the images of {config.from_dir}")
        return images, info
    log(f"render {len(spec.camera_names)} views ({spec.size[0]}x{spec.size[1]} px, "
        f"{config.spp or spec.spp} spp, {'full film' if config.full_film else 'adaptive'}) …")
    images, info = render_views(spec, spp=config.spp, variant=config.variant,
                                progress=config.progress, adaptive=not config.full_film)
    for name in spec.camera_names:
        log(f"  {name}: {render_summary(info['render'][name])}")
    return images, info


def _triangulate(config, inputs, centers, tracks, methods):
    """``({method: points}, pixels)``: the tracks triangulated from every view with each
    method (:func:`eval.run.pipeline.triangulate_stage`) — with the eccentricity correction
    when the run corrects it (the offsets from the optical path, :func:`correct_views`, then
    each method on the corrected pixels, as for two views) — and the pixels they were
    triangulated from (corrected)."""
    from measure import triangulate_rig

    from eval.run.pipeline import triangulate_stage

    if config.corrects_eccentricity:
        result, corrected, _ = correct_views(inputs.rig, tracks.pixels(centers),
                                             inputs.target_radius)
        return {m: result if m == "optical_path" else triangulate_rig(inputs.rig, corrected, m)
                for m in methods}, corrected
    views = dict(zip(inputs.view_images(), centers))
    return triangulate_stage(inputs, views, tracks, methods), tracks.pixels(centers)


def _scored_tracks(tracks, truth_of, result, targets) -> dict:
    """Each track against the truth (``truth_of[k]``: the target of each detection of view k,
    −1 none): its ``target``, whether it is ``correct`` (every detection of one target),
    ``ok`` (correct and triangulated), ``errors`` (mm, NaN where not ok), and per target in
    how many views it was detected and whether a correct track holds it."""
    views = len(truth_of)
    ids = np.full(tracks.detections.shape, -1)
    for k in range(views):
        seen = tracks.detections[:, k] >= 0
        ids[seen, k] = truth_of[k][tracks.detections[seen, k]]
    target = ids.max(axis=1) if len(ids) else np.zeros(0, int)
    has = ids >= 0
    correct = (((ids == target[:, None]) | ~has).all(axis=1)
               & (has.sum(axis=1) == (tracks.detections >= 0).sum(axis=1)))
    ok = correct & result.valid
    errors = np.full((len(target), 3), np.nan)
    errors[ok] = result.points[ok] - targets[target[ok]]
    detected_views = np.zeros(len(targets), int)
    for k in range(views):
        np.add.at(detected_views, truth_of[k][truth_of[k] >= 0], 1)
    matched = np.zeros(len(targets), bool)
    matched[target[correct]] = True
    return {"target": target, "correct": correct, "ok": ok, "errors": errors,
            "detected_views": detected_views, "matched": matched, "targets": targets}


def _pair_report(config, rig, tracks, centers, truth_of, spec, names):
    """The first two cameras as a stereo pair, from the same detections (the two-camera run);
    None when they share no match."""
    from measure import triangulate
    from measure.images.eccentricity import correct_eccentricity

    from eval.core.results import ErrorStats

    pair = tracks.pairs.get((0, 1))
    if pair is None or not len(pair.left):
        return None
    stereo = rig.pair(0, 1)
    uv0, uv1 = centers[0][pair.left], centers[1][pair.right]
    pair_result = (correct_eccentricity(stereo, uv0, uv1, spec.target_radius).triangulation
                   if config.corrects_eccentricity else triangulate(stereo, uv0, uv1))
    t0, t1 = truth_of[0][pair.left], truth_of[1][pair.right]
    pair_ok = (t0 >= 0) & (t0 == t1) & pair_result.valid
    pair_errors = pair_result.points[pair_ok] - spec.targets[t0[pair_ok]]
    return {"cameras": [names[0], names[1]], "pairs": int(len(pair.left)),
            "correct": int(((t0 >= 0) & (t0 == t1)).sum()),
            "stats": ErrorStats.of(pair_errors).to_json(),
            "rms_dp_mm": _rms(np.linalg.norm(pair_errors, axis=1))}


def _matching(config, tracks, scored, visible_views, window, names) -> dict:
    """The report's ``matching``: tracks right and wrong, targets seen and matched."""
    correct, matched, detected = scored["correct"], scored["matched"], scored["detected_views"]
    twice = visible_views >= 2
    return {"tracks": int(len(scored["target"])), "correct": int(correct.sum()),
            "wrong": int((~correct).sum()), "conflicts_dropped": int(tracks.n_conflicts),
            "visible_in_two_or_more": int(twice.sum()),
            "visible_in_two_or_more_matched": int((twice & matched).sum()),
            "detected_in_two_or_more": int((detected >= 2).sum()),
            "detected_in_two_or_more_matched": int(((detected >= 2) & matched).sum()),
            "seen_once": int((visible_views == 1).sum()),
            "gate_mm": config.gate_mm,
            "depth_window_mm": [None if v is None else float(v) for v in window],
            "pairs": {f"{names[i]}-{names[j]}": int(len(m.left))
                      for (i, j), m in tracks.pairs.items()}}


def report_markdown(report: dict) -> str:
    m, s = report["matching"], view_scores(report)

    def mm(v):
        return "–" if v is None else f"{v:.4f}"

    lines = [f"# eval run: {report['scene']} ({len(report['cameras'])} cameras)", "",
             f"{m['tracks']} tracks ({m['correct']} correct, {m['wrong']} wrong, "
             f"{m['conflicts_dropped']} dropped for a conflict); "
             f"{m['visible_in_two_or_more_matched']} of {m['visible_in_two_or_more']} targets "
             f"visible in two or more views matched; {m['seen_once']} seen by one view only "
             f"(reported, not triangulated).", "",
             "| views k | tracks | RMS dP (mm) |", "|---|---|---|"]
    for k, row in s["by_views"].items():
        lines.append(f"| {k} | {row['tracks']} | {mm(row['rms_dp_mm'])} |")
    lines.append(f"| all | {s['n']} | {mm(s['rms_dp_mm'])} |")
    others = {m: e for m, e in (report.get("methods") or {}).items() if m != report["method"]}
    if others:
        lines += ["", f"The table is {report['method']}'s; the same tracks by "
                  + ", ".join(f"{m}: RMS dP {mm(e['rms_dp_mm'])} mm ({e['n']} scored)"
                              for m, e in others.items()) + "."]
    lines += uncertainty_lines(report)
    c = report.get("crosscheck")
    if c:
        lines += ["", "| camera | detections associated | cross-check RMS / max (px) | "
                      "outline RMS / max (px) |", "|---|---|---|---|"]
        for name in report["cameras"]:
            r = c[name]
            lines.append(f"| {name} | {r['associated']} | {r['rms_px']:.4f} / {r['max_px']:.4f} "
                         f"| {r['rms_px_outline']:.4f} / {r['max_px_outline']:.4f} |")
        lines.append(f"| all | | {c['rms_px']:.4f} / {c['max_px']:.4f} | "
                     f"{c['rms_px_outline']:.4f} / {c['max_px_outline']:.4f} |")
    pair = report.get("stereo_pair")
    if pair:
        lines += ["", f"Stereo pair {pair['cameras'][0]}–{pair['cameras'][1]} from the same "
                      f"detections: {pair['pairs']} pairs, RMS dP {mm(pair['rms_dp_mm'])} mm; "
                      f"all views / pair: {report['ratio_to_pair']:.3f}."
                  if report.get("ratio_to_pair") else ""]
    if report["verdict"]["failures"]:
        lines += ["", "Failed: " + "; ".join(report["verdict"]["failures"])]
    return "\n".join(lines) + "\n"


def main(config: RunConfig, out: str, print_json: bool, log) -> int:
    """The command's body for a scene of N cameras: measure, write ``report.json``,
    ``report.md`` and ``targets.csv`` (per target: id, views it is visible in, views it was
    detected in, views of its track (0: not triangulated), the point, its error dP) into
    ``out``, print the summary."""
    import json

    from synth.infra.cli import EXIT_CHECK_FAILED
    from synth.infra.fileio import OutputDir, atomic_write_json, atomic_write_text, jsonable
    from synth.infra.provenance import package_versions

    from eval.run.config import COMMAND

    output = OutputDir(out, COMMAND).claim()
    start = time.perf_counter()
    report, arrays = measure(config, log)
    with output.staged() as tmp:
        report["versions"] = package_versions()
        for method, *found in arrays["uncertainty"]:
            write_views_uncertainty(tmp, method, *found, report["uncertainty"])
        report["timings_s"]["total"] = time.perf_counter() - start
        report = jsonable(report)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), report_markdown(report))
        np.savetxt(os.path.join(tmp, "targets.csv"), arrays["targets"], delimiter=",",
                   header="id,views_visible,views_detected,views_triangulated,x,y,z,dp_mm",
                   comments="", fmt="%.10g")
    stream = sys.stderr if print_json else sys.stdout
    m, s = report["matching"], view_scores(report)
    pair = report.get("stereo_pair") or {}
    print(f"{report['scene']}: {len(report['cameras'])} cameras, "
          f"{m['visible_in_two_or_more']} targets visible in two or more views, "
          f"{m['visible_in_two_or_more_matched']} matched ({m['correct']} tracks correct, "
          f"{m['wrong']} wrong, {m['conflicts_dropped']} dropped), {m['seen_once']} seen once; "
          f"cross-check RMS {report['crosscheck']['rms_px']:.4f} px; RMS dP {s['rms_dp_mm']:.4f} mm"
          + (f" (stereo pair {pair['cameras'][0]}-{pair['cameras'][1]}: "
             f"{pair['rms_dp_mm']:.4f} mm, ratio {report['ratio_to_pair']:.3f})"
             if pair.get("rms_dp_mm") and report.get("ratio_to_pair") else "")
          + f"; total {report['timings_s']['total']:.1f} s", file=stream)
    print("  by views: " + ", ".join(
        f"k={k}: {row['tracks']} tracks, RMS dP "
        + ("–" if row["rms_dp_mm"] is None else f"{row['rms_dp_mm']:.4f} mm")
        for k, row in s["by_views"].items()), file=stream)
    for line in filter(None, uncertainty_lines(report)):
        print("  " + line, file=stream)
    print(f"wrote {output.path}", file=stream)
    if print_json:
        print(json.dumps(report, indent=2))
    if report["verdict"]["failures"]:
        print(f"failed: {report['scene']}: {'; '.join(report['verdict']['failures'])} "
              f"(report in {output.path})", file=sys.stderr)
        return EXIT_CHECK_FAILED
    return 0


__all__ = ["correct_views", "dataset_views", "is_multiview_scene", "main", "measure",
           "report_markdown", "rig_differences", "view_scores"]
