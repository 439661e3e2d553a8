"""report.json and report.md of ``python -m eval paper`` (written atomically).

``report.json``: settings, the rig, per-experiment statistics (mm) and ``claims`` — one entry per
claim of the paper with ``id``, ``section``, ``paper`` (the paper's words), ``measured``,
``criterion`` (the threshold applied), ``holds`` (computed) and ``values`` (raw numbers).
``report.md``: the same for people, with the claims table first.
"""

from __future__ import annotations

import json
from pathlib import Path

from eval.paper.settings import COMPONENTS, INDEX_METHODS, INDEX_SIDES, NOISE_METHODS, PAPER_REFERENCE
from eval.core.results import jsonable, method_label
from synth.infra.fileio import atomic_write_text


def _distance_key(z: float) -> str:
    return f"{z / 1000:g}m"


def build_report(results: dict, figures: dict | None = None) -> dict:
    """The JSON-able report (no per-target arrays except the gap's summary)."""
    gap = results["gap"]
    noise = results["noise"]
    index = results["index"]
    report = {
        "title": "Li et al. 2024, section 3, reproduced on the analytic simulator",
        "paper": PAPER_REFERENCE,
        "command": f"python -m eval paper --trials {results['settings']['trials']} "
                   f"--seed {results['settings']['seed']}",
        "units": "mm (errors = measured - true, reference frame = left camera, OpenCV axes)",
        "settings": results["settings"],
        "rig": results["rig"],
        "targets": results["targets"],
        "gap": {"description": "common-perpendicular length between O_L A1 and O_R B1 "
                               "(triangulate(..., 'regular').gap on the refracted pixels)",
                "z_mm": gap["z_mm"], **gap["stats"]},
        "ideal": {_distance_key(z): {
            "z_mm": z, "methods": entry["stats"],
            "su_share_dP_within_1mm": entry["su_share_dP_within_1mm"],
            "su_spearman_rho_dP_vs_radius": entry["su_spearman_rho_dP_vs_radius"],
            "su_share_dZ_nonpositive": entry["su_share_dZ_nonpositive"]}
            for z, entry in results["ideal"].items()},
        "noise": {k: noise[k] for k in ("z_mm", "trials", "seed", "variance_px2", "sigma_px",
                                        "samples", "noise_sem", "su_share_dZ_negative",
                                        "optical_path_share_abs_dX_within_1mm",
                                        "su_ideal_mean_square_dP", "su_model_error_share")}
        | {"methods": noise["stats"],
           "rms_dP": {m: noise["stats"][m].dp.rms_mm for m in NOISE_METHODS}},
        "index_deviation": {
            "parameter": "n_water", "relative": index["relative"], "z_mm": index["z_mm"],
            "chosen_side": index["chosen_side"], "side_choice_rule": index["rule"],
            "noise_only_sem": index["noise_sem"],
            "sides": index["sides"]},
        "index_in_situ": results["in_situ"],
        "claims": results["claims"],
        "claims_holding": f"{sum(c['holds'] for c in results['claims'])}/{len(results['claims'])}",
        "figures": {k: Path(v).name for k, v in (figures or {}).items()},
        "compute_seconds": results.get("compute_seconds"),
        "wall_seconds": results.get("wall_seconds"),
    }
    return jsonable(report)


def _num(x, digits=3) -> str:
    if x is None:
        return "n/a"
    x = float(x)
    if x == 0:
        return "0"
    if 1e-3 <= abs(x) < 1e5:
        return f"{x:.{digits}g}" if abs(x) < 1 else f"{x:.{digits}f}".rstrip("0").rstrip(".")
    return f"{x:.2e}"


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def claims_table(claims: list[dict]) -> str:
    """Markdown table: claim, paper, measured, holds."""
    lines = ["| claim | paper | measured | criterion | holds |", "|---|---|---|---|---|"]
    for c in claims:
        lines.append(f"| `{c['id']}` (§{c['section']}) | {_cell(c['paper'])} | "
                     f"{_cell(c['measured'])} | {_cell(c['criterion'])} | "
                     f"{'yes' if c['holds'] else '**no**'} |")
    return "\n".join(lines)


def render_markdown(report: dict) -> str:
    """The paper report's ``report.md``: the claims, the set-up and each section of the
    paper's section 3 with its table and figures."""
    sections = (_header_lines, _gap_lines, _ideal_lines, _noise_lines, _index_lines,
                _in_situ_lines)
    return "\n".join(line for section in sections for line in section(report))


def _header_lines(report: dict) -> list[str]:
    """The title, the claims and the set-up (port, cameras, targets, noise)."""
    s = report["settings"]
    rig = report["rig"]
    port = rig["port"]
    lines = [f"# {report['title']}", "",
             f"Paper: {report['paper']}.  ",
             f"Command: `{report['command']}`; {report['claims_holding']} claims hold. "
             f"All lengths in mm, errors = measured − true.", "",
             "## Claims", "", claims_table(report["claims"]), "",
             "## Set-up", "",
             f"- Port (Table 1): D = {port['distance_mm']:g} mm, d = "
             f"{', '.join(f'{t:g}' for t in port['thicknesses_mm'])} mm, N = "
             f"({', '.join(f'{v:g}' for v in port['normal'])}), n = "
             f"{' / '.join(f'{n:g}' for n in port['indices'])}.",
             f"- Cameras ({rig['source']}): {rig['left']['size_px'][0]} × "
             f"{rig['left']['size_px'][1]} px, f = {rig['left']['K'][0][0]:g} px, baseline "
             f"{rig['baseline_mm']:g} mm, right camera turned {rig['right_toe_in_deg']:g}° "
             "towards the left one.",
             f"- Targets: {report['targets']['layout']} ({report['targets']['count']}), "
             f"at Z = {', '.join(f'{z:g}' for z in s['distances_mm'])} mm.",
             f"- Noise: Gaussian, variance {s['pixel_noise_variance_px2']:g} px² (σ = "
             f"{s['pixel_noise_sigma_px']:g} px) on u and v of both images, {s['trials']} trials "
             f"(seed {s['seed']}), {s['noise_draws']}.",
             f"- 'Near zero' / 'beyond the noise': {s['near_zero_rule']}.", ""]
    return lines


def _gap_lines(report: dict) -> list[str]:
    """Section 3.2: the gap between the rays."""
    lines = []
    gap = report["gap"]
    lines += ["## 3.2 Gap between the rays O_L A1 and O_R B1 (1 m)", "",
              f"{gap['count_above_threshold']} of {gap['n']} targets "
              f"({100 * gap['share_above_threshold']:.1f} %) have a gap > {gap['threshold_mm']:g} mm; "
              f"{100 * gap['share_above_0.6mm']:.1f} % > 0.6 mm. Gap min / median / mean / max = "
              f"{_num(gap['min'])} / {_num(gap['median'])} / {_num(gap['mean'])} / "
              f"{_num(gap['max'])} mm.", "", "![Figure 4](figure4_gap.png)", ""]
    return lines


def _ideal_lines(report: dict) -> list[str]:
    """Section 3.3.1: the errors without noise."""
    lines = []
    lines += ["## 3.3.1 Ideal conditions", "",
              "| distance | method | max \\|dX\\| | max \\|dY\\| | max \\|dZ\\| | max dP | mean dP "
              "| RMS dP |", "|---|---|---|---|---|---|---|---|"]
    for key, entry in report["ideal"].items():
        for method in NOISE_METHODS:
            st = entry["methods"][method]
            lines.append(f"| {key} | {method_label(method)} | "
                         + " | ".join(_num(st[f"max_abs_{c.lower()}_mm"]) for c in ("dX", "dY", "dZ"))
                         + f" | {_num(st['max_dp_mm'])} | {_num(st['mean_dp_mm'])} | "
                           f"{_num(st['rms_dp_mm'])} |")
    lines += ["", "![Figure 5](figure5_su_1m.png)", "", "![Figure 6](figure6_su_2m.png)", ""]
    return lines


def _noise_lines(report: dict) -> list[str]:
    """Section 3.3.2: the errors with pixel noise."""
    lines = []
    noise = report["noise"]
    lines += [f"## 3.3.2 Pixel noise ({noise['trials']} trials × 496 targets = "
              f"{noise['samples']} samples per method)", "",
              "| method | mean dX | mean dY | mean dZ | σX | σY | σZ | RMS dP | max dP |",
              "|---|---|---|---|---|---|---|---|---|"]
    for method in NOISE_METHODS:
        st = noise["methods"][method]
        lines.append(f"| {method_label(method)} | "
                     + " | ".join(f"{st['mean_' + c.lower() + '_mm']:+.4f}" for c in ("dX", "dY", "dZ"))
                     + " | "
                     + " | ".join(f"{st['std_' + c.lower() + '_mm']:.4f}" for c in ("dX", "dY", "dZ"))
                     + f" | {st['rms_dp_mm']:.4f} | {st['max_dp_mm']:.3f} |")
    nsem = noise["noise_sem"]
    lines += ["", "Noise standard errors of the mean (std of noisy − noise-free error / "
              "√samples), dX / dY / dZ: " + "; ".join(
                  f"{m} " + " / ".join(f"{nsem[m][c]:.1e}" for c in ("dX", "dY", "dZ"))
                  for m in NOISE_METHODS) + " mm."]
    lines += ["", "Figure 7 shows one Monte-Carlo draw (trial 0), as the paper's maps do; "
              "Figure 8 pools all targets × trials.", "",
              "![Figure 7](figure7_noise_maps.png)", "", "![Figure 8](figure8_noise_hist.png)",
              ""]
    return lines


def _index_lines(report: dict) -> list[str]:
    """Section 3.3.3: pixel noise and a water-index deviation."""
    lines = []
    index = report["index_deviation"]
    lines += [f"## 3.3.3 Pixel noise and a {100 * index['relative']:g} % water-index deviation",
              "", f"Chosen side: **{index['chosen_side']}** — "
              f"{index['sides'][index['chosen_side']]['description']}. Rule: "
              f"{index['side_choice_rule']}.", "",
              "Mean shifts against the noise-only run (same noise draws), both sides:", "",
              "| side | n3 true | n3 assumed | method | shift dX | shift dY | shift dZ | "
              "RMS dP |", "|---|---|---|---|---|---|---|---|"]
    for side in INDEX_SIDES:
        entry = index["sides"][side]
        for method in INDEX_METHODS:
            sh = entry["mean_shift"][method]
            lines.append(f"| {side} | {entry['n_water_true']:.7g} | "
                         f"{entry['n_water_assumed']:.7g} | {method} | "
                         + " | ".join(f"{sh[c]:+.4f}" for c in ("dX", "dY", "dZ"))
                         + f" | {entry['stats'][method]['rms_dp_mm']:.4f} |")
    sem = index["noise_only_sem"]["optical_path"]
    lines += ["", "Shifts are 'beyond the noise' when larger than 3 noise standard errors "
              "(optical_path: " + ", ".join(f"{c} {sem[c]:.1e}" for c in ("dX", "dY", "dZ"))
              + " mm; su: " + ", ".join(f"{c} {index['noise_only_sem']['su'][c]:.1e}"
                                         for c in ("dX", "dY", "dZ")) + " mm).", "",
              "![Figure 9](figure9_index_maps.png)", "", "![Figure 10](figure10_index_hist.png)",
              ""]
    return lines


def _in_situ_lines(report: dict) -> list[str]:
    """Section 4: the water index estimated in situ, and the run time."""
    lines = []
    s = report["index_in_situ"]
    lines += ["## 4 Future work: the water index estimated in situ", "",
              f"True n_water {s['n_true']:.7g}, assumed {s['n_assumed']:.7g}; {s['trials']} trials "
              f"with σ = {s['sigma_px']:g} px pixel noise at Z = {s['z_mm']:g} mm, each refined by "
              "`measure.calibration.selfcal.self_calibrate` (the targets' positions and n_water, no "
              "calibration object).", "",
              "| bias | standard error | spread | mean reported σ | mean dZ assumed → estimated |",
              "|---|---|---|---|---|",
              f"| {s['bias']:+.2e} | {s['bias_sem']:.1e} | {s['spread']:.2e} | {s['mean_sigma']:.2e} "
              f"| {s['mean_dz_before_mm']:+.3f} → {s['mean_dz_after_mm']:+.3f} mm |", "",
              "![Figure 11](figure11_index_profile.png)", ""]
    if report.get("wall_seconds") is not None:
        lines += [f"Run time: {report['wall_seconds']:.1f} s (experiments "
                  f"{report['compute_seconds']:.1f} s).", ""]
    return lines


def write_reports(results: dict, out, figures: dict | None = None) -> list[Path]:
    """Write ``out/report.json`` and ``out/report.md`` atomically; return their paths."""
    out = Path(out)
    report = build_report(results, figures)
    json_text = json.dumps(report, indent=2, allow_nan=False) + "\n"  # strict JSON
    return [atomic_write_text(out / "report.json", json_text),
            atomic_write_text(out / "report.md", render_markdown(report))]


__all__ = ["build_report", "claims_table", "render_markdown", "write_reports", "COMPONENTS"]
