"""The written output of a target run: the summary and error-budget tables, ``report.md``, the
PLY files coloured by dP and the figures (:mod:`eval.run.figures`)."""

from __future__ import annotations

import contextlib
import gc
import os
import sys

from synth.infra.cli import EXIT_CHECK_FAILED
from eval.core.formatting import format_number as fmt



def budget_table(report: dict) -> str:
    """The error budget as fixed-width text: one row per calibration, the first method."""
    budget = report.get("budget") or {}
    method = next(iter(report["methods"]))
    rows = [(label, b) for label, b in budget.items()]
    rows.append((f"this run ({report['rigs'].get('source', 'as measured')})",
                 {"matching": report["matching"], "methods": report["methods"]}))
    lines = [f"error budget ({method}): {'calibration':<44}{'pairs':>7}{'wrong':>7}"
             f"{'RMS dP':>10}{'mean dZ':>10}{'max dP':>10}"]
    for label, b in rows:
        st = b["methods"].get(method, {})
        lines.append(f"{'':<{len('error budget (' + method + '): ')}}{label[:43]:<44}"
                     f"{b['matching']['pairs']:>7}{b['matching']['wrong']:>7}"
                     f"{fmt(st.get('rms_dp_mm')):>10}{fmt(st.get('mean_dz_mm')):>10}"
                     f"{fmt(st.get('max_dp_mm')):>10}")
    return "\n".join(lines)


SUMMARY_COLUMNS = (("n", "n", 0), ("rms_dp_mm", "RMS dP", 3), ("max_dp_mm", "max dP", 3),
                   ("mean_dx_mm", "mean dX", 3), ("mean_dy_mm", "mean dY", 3),
                   ("mean_dz_mm", "mean dZ", 3), ("chamfer_mm", "Chamfer", 3),
                   ("fscore_1mm", "F@1mm", 3), ("fscore_5mm", "F@5mm", 3),
                   ("rms_dp_aligned_mm", "RMS dP aligned", 3), ("flatness_mm", "flatness", 3),
                   ("length_median_abs_pct", "length med %", 3),
                   ("length_worst_pct", "length worst %", 3))


def summary_table(report: dict) -> str:
    """The per-method table (mm) as fixed-width text."""
    rows = _method_rows(report)
    width = max([17] + [len(method) + 2 for method, _ in rows])
    header = f"{'method':<{width}}" + "".join(f"{title:>15}" for _, title, _ in SUMMARY_COLUMNS)
    lines = [header]
    for method, stats in rows:
        lines.append(f"{method:<{width}}" + "".join(f"{fmt(stats.get(key), digits):>15}"
                                                    for key, _, digits in SUMMARY_COLUMNS))
    return "\n".join(lines)


#: The figures of every target run (``ellipses.png`` too where points have covariances), unless
#: ``--no-figures``.
FIGURES = ("views.png", "error_maps.png", "histograms.png")
#: The label of a method's numbers on the raw centroids, when the run corrected the
#: eccentricity (its headline numbers are the corrected ones).
UNCORRECTED = "(raw centroids)"


def _method_rows(report: dict):
    """``(label, stats)`` per method (the eccentricity corrected, by default), then per method
    on the raw centroids."""
    rows = list(report["methods"].items())
    uncorrected = (report.get("eccentricity") or {}).get("uncorrected") or {}
    rows += [(f"{m} {UNCORRECTED}", st) for m, st in (uncorrected.get("methods") or {}).items()]
    return rows


def _sensor_lines(sensor) -> list:
    """report.md's paragraph on the ``--sensor`` (none without one)."""
    if not sensor:
        return []
    m = sensor["model"]
    return [f"Sensor `{m['name']}`: full well {m['full_well_e']:g} e⁻, read noise "
            f"{m['read_noise_e']:g} e⁻, {m['bit_depth']} bit, dark level {m['dark_level_dn']:g} DN, "
            f"gain {m['gain_e_per_dn']:.4g} e⁻/DN, brightest pixel exposed to "
            f"{m['exposure']:g} of the full well; saturated pixels left "
            f"{sensor['left']['saturated_pixels']}, right {sensor['right']['saturated_pixels']}.",
            ""]


def _render_lines(render) -> list:
    """How each view was rendered (adaptive or full film, lit fraction, samples), or nothing
    (images read with ``--from``)."""
    if not isinstance(render, dict) or not isinstance(render.get("render"), dict):
        return []
    from synth.rendering.render import render_summary

    views = render["render"]
    return ["## Render", "", *[f"- {view}: {render_summary(views[view])}"
                               for view in ("left", "right") if view in views], ""]


def report_markdown(report: dict) -> str:
    m, c, t = report["matching"], report["crosscheck"], report["timings_s"]
    vis, det = report["visibility"], report["detection"]
    lines = [f"# Run report: `{report['scene']}`", "",
             f"{report['targets']} targets; Mitsuba variant `{report['variant']}`, {report['spp']} spp; "
             f"added pixel noise σ = {report['noise_px']} px.", "",
             *verdict_lines(report),
             *_render_lines(report.get("inputs", {}).get("render")),
             *_sensor_lines(report.get("sensor")),
             "## Detection and matching", "",
             "| | left | right |", "|---|---|---|",
             f"| targets wholly in the image | {vis['in_both'] + vis['left_only']} "
             f"| {vis['in_both'] + vis['right_only']} |",
             f"| detections accepted | {det['left']['found']} | {det['right']['found']} |",
             f"| blobs rejected | {det['left']['rejected_by_reason']} "
             f"| {det['right']['rejected_by_reason']} |",
             f"| cross-check RMS / max (px) | {fmt(c['left']['rms_px'], 4)} / {fmt(c['left']['max_px'], 4)} "
             f"| {fmt(c['right']['rms_px'], 4)} / {fmt(c['right']['max_px'], 4)} |", "",
             f"Targets visible in both views: {m['visible_in_both']}; matched pairs: {m['pairs']} "
             f"({m['correct']} correct, {m['wrong']} wrong, {m['ambiguous_dropped']} ambiguous dropped); "
             f"visible-in-both targets matched: {m['visible_in_both_matched']}. Gate {m['gate_mm']} mm, "
             f"depth window {m['depth_window_mm']} mm. Cross-check of all detections against the "
             f"Fermat simulator: RMS {fmt(c['rms_px'], 4)} px, max {fmt(c['max_px'], 4)} px "
             f"(against the image of each target's centre); RMS {fmt(c['rms_px_outline'], 4)} px, "
             f"max {fmt(c['max_px_outline'], 4)} px against the area centroid of the image of its "
             f"outline (the eccentricity removed).", "",
             "## Truth and assumption", "",
             ("The measurement used the rendered rig (no assumption differs from the truth)."
              if not report.get("rigs", {}).get("difference") else
              "The measurement believed a rig that differs from the rendered truth (assumed − "
              "true): " + "; ".join(f"`{k}` {v}" for k, v in report["rigs"]["difference"].items())
              + ". Matching, triangulation and the eccentricity correction use the assumed rig; "
                "the cross-check uses the true one."), "",
             "## Accuracy per method (mm)", "",
             "| method | " + " | ".join(title for _, title, _ in SUMMARY_COLUMNS) + " |",
             "|---" * (len(SUMMARY_COLUMNS) + 1) + "|"]
    for method, stats in _method_rows(report):
        lines.append(f"| {method} | "
                     + " | ".join(fmt(stats.get(k), d) for k, _, d in SUMMARY_COLUMNS) + " |")
    lines += ["", "dP = |measured − true| over correctly matched targets; Chamfer = mean "
              "measured→truth + mean truth→measured nearest-neighbour distance (all matched points "
              "against the targets visible in both views); F@τ = harmonic mean of precision and "
              "recall at τ; aligned = after the best rigid transform with known correspondences; "
              "flatness = RMS distance to the RANSAC plane.", "",
              *uncertainty_lines(report),
              *(["## Error budget", "", "The same detections measured with each calibration "
                 "(matching, triangulation and scoring repeated):", "", "```",
                 budget_table(report), "```", ""] if report.get("budget") else []),
              "## Files", "",
              *(["- " + ", ".join(f"`{name}`" for name in figure_names(report))]
                if figure_names(report) else []),
              *[f"- `{f['ply']}`, `{f['csv']}`: each correctly matched point with σx, σy, σz "
                f"(mm) and its covariance (mm²), its error and Mahalanobis distance²"
                for f in ((report.get("uncertainty") or {}).get("files") or {}).values()],
              *[f"- `{p['file']}`: colour = dP on `{p['colormap']}` from {p['vmin_mm']} mm to "
                f"{fmt(p['vmax_mm'])} mm (clipped)" for p in report.get("ply", {}).values()], "",
              "## Timings (s)", "",
              " · ".join(f"{k} {v:.2f}" for k, v in t.items())]
    return "\n".join(lines) + "\n"


def uncertainty_lines(report: dict) -> list:
    """report.md's section on the points' covariances (none when no method has one)."""
    unc = report.get("uncertainty") or {}
    summaries = unc.get("summaries") or {}
    if not summaries:
        return ["## Uncertainty", "", unc.get("note", "No point covariances."), ""] if unc else []
    ps = unc.get("pixel_sigma") or {}
    if "stated_px" in ps:
        pixel = f"stated σ = {fmt(ps['stated_px'], 4)} px per coordinate"
    else:
        pixel = (f"per target from the detector (median {fmt(ps.get('detector_median_px'), 4)} "
                 f"px) plus σ₀ = {fmt(ps.get('residual_sigma0_px'), 4)} px that the "
                 f"reprojection residuals show beyond it (median {fmt(ps.get('median_px'), 4)} px)")
    lines = ["## Uncertainty", "", f"Point covariances: {unc['rig']}; pixel noise: {pixel}.",
             "", "| method | median σx | median σy | median σz | max σP | coverage 95 % | "
             "mean d² | normalized std x / y / z |", "|---|---|---|---|---|---|---|---|"]
    rows = [(m, v) for m, v in summaries.items()]
    raw = ((report.get("eccentricity") or {}).get("uncorrected") or {}).get("uncertainty") or {}
    rows += [(f"{m} {UNCORRECTED}", v) for m, v in (raw.get("summaries") or {}).items()]
    for method, summary in rows:
        sig, cov = summary["sigma"], summary.get("coverage") or {}
        med = sig.get("median_sigma_mm", {})
        norm = cov.get("normalized") or {}
        lines.append(f"| {method} | {fmt(med.get('x'), 4)} | {fmt(med.get('y'), 4)} | "
                     f"{fmt(med.get('z'), 4)} | {fmt(sig.get('max_sigma_p_mm'), 4)} | "
                     f"{fmt(cov.get('coverage_95'), 3)} | {fmt(cov.get('mahalanobis2_mean'), 2)} | "
                     + " / ".join(fmt(norm[a]['std'], 2) for a in "xyz" if a in norm) + " |")
    lines += ["", "σ in mm; coverage = fraction of the correctly matched points whose "
              "Mahalanobis distance² to the truth is at most χ²₃(0.95) = 7.81 (0.95 when the "
              "covariances are right; 3 the expected mean d²); normalized = error / σ per axis "
              "(std 1 expected).", ""]
    lines += [f"- {method}: {summary['coverage']['verdict']}" for method, summary in rows
              if (summary.get("coverage") or {}).get("verdict")]
    return lines


def write_outputs(tmp: str, result, figures: bool = True) -> None:
    """The PLY files (their entries go into ``result.report["ply"]``; ``points_<method>_all.ply``
    every valid point, wrong matches included) and figures of a run
    (:class:`eval.run.pipeline.RunResult`), into directory ``tmp``; ``figures=False``: no
    figure (and no matplotlib). The figures written go into ``result.report["figures"]``."""
    from eval.core.cloud_metrics import write_error_ply  # Open3D: only when writing
    from eval.core.uncertainty import write_uncertainty_files

    from synth.products.dataset import write_targets_ply

    result.report["ply"] = {method: write_error_ply(tmp, f"points_{method}.ply",
                                                    data["points"], data["errors"])
                            for method, data in result.per_method.items()}
    # every triangulated point, wrong matches included (what the cloud metrics score): with
    # eval score, a submission that gives back this run's numbers key by key
    for method, data in result.per_method.items():
        if "all_points" in data:
            write_targets_ply(os.path.join(tmp, f"points_{method}_all.ply"), data["all_points"])
    # the covariances of the correctly matched points, their errors against the truth
    uncertainty = result.report.get("uncertainty") or {}
    files = {method: write_uncertainty_files(tmp, method, data["points"], data["covariance"],
                                             data["errors"])
             for method, data in result.per_method.items() if "covariance" in data}
    if files:
        uncertainty["files"] = files
    result.report["figures"] = (FIGURES + (("ellipses.png",) if files else ())) if figures else ()
    if figures:
        _write_figures(tmp, result, bool(files))


def _write_figures(tmp: str, result, ellipses: bool) -> None:
    """:data:`FIGURES` (and ``ellipses.png`` with ``ellipses``) of a run into ``tmp``: the views
    here while the others are drawn in forked processes (:func:`_beside`)."""
    from eval.core.figures import ellipses_figure, error_maps_figure, histograms_figure
    from eval.run.figures import views_figure

    maps = os.path.join(tmp, "error_maps.png")
    histograms = os.path.join(tmp, "histograms.png")
    extra = ([(ellipses_figure, os.path.join(tmp, "ellipses.png"),
               {m: d for m, d in result.per_method.items() if "covariance" in d})]
             if ellipses else [])
    with _beside((error_maps_figure, maps, result.per_method),
                 (histograms_figure, histograms, result.per_method), *extra):
        views_figure(os.path.join(tmp, "views.png"), result.inputs.left, result.inputs.right,
                     result)


@contextlib.contextmanager
def _beside(*calls):
    """Run each ``(function, *args)`` of ``calls`` in a forked process while the body runs
    (matplotlib holds the GIL: one figure at a time per process); their exceptions, if any,
    are raised here. Without ``fork`` (or with one CPU) they simply run first."""
    import multiprocessing

    if "fork" not in multiprocessing.get_all_start_methods() or (os.cpu_count() or 1) < 2:
        for function, *args in calls:
            function(*args)
        yield
        return
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(len(calls), mp_context=multiprocessing.get_context("fork")) as pool:
        # frozen, what the children inherit is not walked by their collections (each child's
        # first full collection took 0.4-0.5 s of CPU over Mitsuba's, Open3D's and matplotlib's
        # objects; the documented use of gc.freeze before a fork)
        gc.freeze()
        try:
            futures = [pool.submit(function, *args) for function, *args in calls]
        finally:
            gc.unfreeze()
        yield
        for future in futures:
            future.result()


def figure_names(report: dict) -> tuple:
    """The figures a run wrote (``report["figures"]``; a report from before that key: all)."""
    if report.get("figures") is not None:
        return tuple(report["figures"])
    return FIGURES + (("ellipses.png",) if (report.get("uncertainty") or {}).get("files") else ())


def verdict_lines(report: dict) -> list:
    """report.md's verdict: passed, or what failed (the run exited 1)."""
    verdict = report.get("verdict")
    if not verdict:
        return []
    if verdict["passed"]:
        return ["**Verdict: passed** (no wrong match, the cross-check from both views).", ""]
    return ["**Verdict: failed** (exit code 1): " + "; ".join(verdict["failures"]) + ".", ""]


def verdict_exit_code(report: dict, out: str) -> int:
    """0 when the run's ``verdict`` passed; else one line ``failed: …`` on stderr and 1 (the
    report in ``out`` has been written: it says the same under ``verdict``)."""
    failures = report.get("verdict", {}).get("failures") or []
    if not failures:
        return 0
    print(f"failed: {report['scene']}: {'; '.join(failures)} (report in {out})", file=sys.stderr)
    return EXIT_CHECK_FAILED


__all__ = ["FIGURES", "SUMMARY_COLUMNS", "budget_table", "figure_names", "report_markdown", "summary_table",
           "uncertainty_lines", "verdict_exit_code",
           "verdict_lines",
           "write_outputs"]


