"""The paper's claims (section 3) as a table: each claim states the paper's words, the criterion
applied and a function that computes, from the measured results, the text of what was measured,
whether the claim holds and the raw values. :func:`evaluate_claims` runs the table; ``holds`` is
always computed, never set.

Units: mm. "SEM" is the standard error of the mean caused by the pixel noise (``noise_sem``).
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Callable

import numpy as np

from eval.paper.settings import (IDEAL_TOLERANCE_MM, INDEX_METHODS, NOISE_METHODS, SEM_FACTOR,
                                 SHIFT_AGREEMENT_MM)

XYZ = ("dX", "dY", "dZ")


def _fmt(x: float, unit: str = "mm") -> str:
    if x is None or not np.isfinite(x):
        return "n/a"
    text = f"{x:.3g}" if 1e-3 <= abs(x) < 1e4 or x == 0 else f"{x:.2e}"
    return f"{text} {unit}".strip()


class _Context:
    """The results, with the short names the claims use."""

    def __init__(self, results: dict):
        self.gap = results["gap"]["stats"]
        self.ideal = results["ideal"]
        self.noise = results["noise"]
        self.ns = self.noise["stats"]
        self.rms = {m: self.ns[m].dp.rms_mm for m in NOISE_METHODS}
        self.op, self.su = self.ns["optical_path"], self.ns["su"]
        self.nsem = self.noise["noise_sem"]
        self.index = results["index"]
        self.side = self.index["chosen_side"]
        self.shifts = self.index["sides"][self.side]["mean_shift"]
        self.index_stats = self.index["sides"][self.side]["stats"]
        self.sem = self.index["noise_sem"]
        self.in_situ = results.get("in_situ")
        self.side_text = f"[{self.side} side]"


#: ``check(context) -> (measured text, holds, values)``
Check = Callable[[_Context], tuple]


@dataclass(frozen=True)
class Claim:
    """One claim of the paper: ``id``, ``section``, the ``paper``'s words, the ``criterion``
    applied, and ``check``."""

    id: str
    section: str
    paper: str
    criterion: str
    check: Check

    def evaluate(self, context: _Context) -> dict:
        measured, holds, values = self.check(context)
        return {"id": self.id, "section": self.section, "paper": self.paper,
                "measured": measured, "criterion": self.criterion, "holds": bool(holds),
                "values": {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                           for k, v in values.items()}}


# --- 3.2: the common perpendicular of O_L A1 and O_R B1 ----------------------------------------
def _gap_claims():
    def nonintersecting(c):
        g = c.gap
        return (f"{100 * g['share_above_threshold']:.1f} % ({g['count_above_threshold']}/{g['n']})",
                g["share_above_threshold"] > 0.9, {"share": g["share_above_threshold"]})

    def above_06(c):
        g = c.gap
        return (f"{100 * g['share_above_0.6mm']:.1f} % of targets > 0.6 mm "
                f"(median {_fmt(g['median'])})", g["share_above_0.6mm"] > 0.5,
                {"share": g["share_above_0.6mm"], "median_mm": g["median"]})

    def grows(c):
        rho = c.gap["spearman_rho_vs_radius"]
        return f"Spearman rho(gap, radius) = {rho:.2f}", rho > 0.5, {"rho": rho}

    return [
        Claim("gap.share_nonintersecting", "3.2",
              "more than 90 % of the 496 targets have rays O_L A1, O_R B1 with a common "
              "perpendicular > 1e-6 mm (they do not intersect)",
              "share of targets with gap > 1e-6 mm > 0.9", nonintersecting),
        Claim("gap.most_above_0.6mm", "3.2",
              "the common perpendicular of most targets is greater than 0.6 mm",
              "share of targets with gap > 0.6 mm > 0.5", above_06),
        Claim("gap.grows_outwards", "3.2",
              "the closer to the centre of the area, the smaller the common perpendicular",
              "Spearman rank correlation of gap with the target's radius > 0.5", grows),
    ]


# --- 3.3.1: ideal conditions ---------------------------------------------------------------------
def _ideal_claims():
    claims = []
    for z, words in ((1000.0, "order of 1e-11 mm"), (2000.0, "order of 1e-10 or 1e-11 mm")):
        for method, label in (("optical_path", "optical-path (new) model"),
                              ("regular_in_air", "regular triangulation in air")):
            def exact(c, z=z, method=method):
                value = c.ideal[z]["stats"][method].dp.max_mm
                return (f"max dP = {_fmt(value)}",
                        value is not None and value <= IDEAL_TOLERANCE_MM, {"max_dP_mm": value})

            claims.append(Claim(
                f"ideal.{method}.{z / 1000:g}m.max_dP", "3.3.1",
                f"{label}, no errors, {z / 1000:g} m: deviations of the {words} "
                "(numerical error only)", f"max dP <= {IDEAL_TOLERANCE_MM:g} mm", exact))
    for z, limit, words in ((1000.0, 50.0, "the maximum dP exceeds 50 mm"),
                            (2000.0, 7.0, "the maximum dP is still more than 7 mm")):
        def su_max(c, z=z, limit=limit):
            value = c.ideal[z]["stats"]["su"].dp.max_mm
            return f"max dP = {value:.4f} mm", value > limit, {"max_dP_mm": value}

        claims.append(Claim(f"ideal.su.{z / 1000:g}m.max_dP", "3.3.1",
                            f"Su's method, {z / 1000:g} m: {words}", f"max dP > {limit:g} mm",
                            su_max))

    def centre_vs_edge(c):
        rho = c.ideal[1000.0]["su_spearman_rho_dP_vs_radius"]
        centre = float(np.linalg.norm(c.ideal[1000.0]["errors"]["su"][0]))
        return (f"Spearman rho(dP, radius) = {rho:.2f}; centre target dP = {_fmt(centre)}",
                rho > 0.5, {"rho": rho})

    def better_at_2m(c):
        s1, s2 = (c.ideal[z]["su_share_dP_within_1mm"] for z in (1000.0, 2000.0))
        m1, m2 = (c.ideal[z]["stats"]["su"].dp.max_mm for z in (1000.0, 2000.0))
        return (f"max dP {m1:.3f} -> {m2:.3f} mm; targets with dP <= 1 mm {100 * s1:.0f} % -> "
                f"{100 * s2:.0f} %", (m2 < m1) and (s2 > s1), {"share_1m": s1, "share_2m": s2})

    claims.append(Claim("ideal.su.1m.centre_vs_edge", "3.3.1",
                        "Su: targets near the centre of the field of view are close to their "
                        "true value, targets at the edge deviate by a large margin",
                        "Spearman rank correlation of Su's dP with the target's radius > 0.5",
                        centre_vs_edge))
    claims.append(Claim("ideal.su.2m_better", "3.3.1",
                        "at 2 m Su's results improve and the area inside the ±1 mm contour "
                        "becomes larger",
                        "max dP(2 m) < max dP(1 m) and share(dP <= 1 mm) larger at 2 m",
                        better_at_2m))
    return claims


# --- 3.3.2: pixel noise -------------------------------------------------------------------------
def _noise_beats(other):
    """The check that the optical path's RMS dP is below method ``other``'s (mm)."""
    def check(c):
        r = c.rms
        return (f"RMS dP {r['optical_path']:.3f} mm vs {r[other]:.3f} mm",
                r["optical_path"] < r[other],
                {"rms_optical_path": r["optical_path"], f"rms_{other}": r[other]})
    return check


def _noise_xy_minimal(c):
    op, air = c.ns["optical_path"], c.ns["regular_in_air"]
    names = ("dX", "dY", "dP")
    return (", ".join(f"{n} {op.component(n).rms_mm:.3f} vs {air.component(n).rms_mm:.3f}"
                      for n in names) + " mm RMS",
            all(op.component(n).rms_mm < air.component(n).rms_mm for n in names), {})


def _noise_x_within_1mm(c):
    within = c.noise["optical_path_share_abs_dX_within_1mm"]
    return (f"{100 * within:.2f} % of |dX| <= 1 mm (σX = {c.op.dx.std_mm:.3f} mm)",
            within >= 0.95, {"share": within})


def _noise_z_largest(c):
    op = c.op
    largest = op.dz.std_mm > max(op.dx.std_mm, op.dy.std_mm)
    return (f"σ = {op.dx.std_mm:.3f} / {op.dy.std_mm:.3f} / {op.dz.std_mm:.3f} mm (X/Y/Z); "
            f"max |dZ| = {op.dz.max_abs_mm:.2f} mm", largest and op.dz.max_abs_mm > 2.0,
            {"max_abs_dZ": op.dz.max_abs_mm})


def _noise_mean_near_zero(c):
    op, sem = c.op, c.nsem["optical_path"]
    ratios = {n: abs(op.component(n).mean_mm) / sem[n] for n in XYZ}
    return ("mean " + " / ".join(f"{op.component(n).mean_mm:+.4f}" for n in XYZ) + " mm = "
            + " / ".join(f"{ratios[n]:.1f}" for n in XYZ) + " SEM",
            all(r < SEM_FACTOR for r in ratios.values()),
            {**{f"mean_{n}": op.component(n).mean_mm for n in XYZ},
             **{f"sem_{n}": sem[n] for n in XYZ}})


def _noise_su_dz_negative(c):
    su, sem = c.su, c.nsem["su"]["dZ"]
    share = c.noise["su_share_dZ_negative"]
    return (f"mean dZ = {su.dz.mean_mm:.3f} mm ({su.dz.mean_mm / sem:.0f} SEM); "
            f"{100 * share:.1f} % of dZ < 0", su.dz.mean_mm < -SEM_FACTOR * sem,
            {"mean_dZ": su.dz.mean_mm, "share_negative": share})


def _noise_su_xy_near_zero(c):
    su = c.su
    ratios = {n: abs(su.component(n).mean_mm) / c.nsem["su"][n] for n in ("dX", "dY")}
    return ("mean " + " / ".join(f"{su.component(n).mean_mm:+.3f}" for n in ("dX", "dY"))
            + " mm = " + " / ".join(f"{ratios[n]:.1f}" for n in ("dX", "dY")) + " SEM",
            all(r < SEM_FACTOR for r in ratios.values()),
            {"mean_dX": su.dx.mean_mm, "mean_dY": su.dy.mean_mm})


def _noise_su_model_error(c):
    share = c.noise["su_model_error_share"]
    return (f"noise-free mean-square dP is {100 * share:.1f} % of the noisy one",
            share > 0.5, {"share": share})


def _noise_claims():
    """Section 3.3.2's claims (pixel noise), each with its check."""
    return [
        Claim("noise.optical_path_beats_su", "3.3.2",
              "with pixel noise (variance 0.01 px²) the new model is more accurate than Su's",
              "RMS dP(optical_path) < RMS dP(su)", _noise_beats("su")),
        Claim("noise.optical_path_beats_regular_in_air", "3.3.2",
              "our method even outperforms the regular model in the air",
              "RMS dP(optical_path) < RMS dP(regular in air)", _noise_beats("regular_in_air")),
        Claim("noise.optical_path_xy_minimal", "3.3.2",
              "the deviations of the X, Y and total coordinates of the new method are minimal "
              "(compared with regular triangulation in air)",
              "RMS of dX, dY and dP each smaller for optical_path than for regular in air",
              _noise_xy_minimal),
        Claim("noise.optical_path_x_within_1mm", "3.3.2",
              "the deviation in X was minimal, generally within ±1 mm",
              "share of |dX| <= 1 mm >= 0.95 (optical_path)", _noise_x_within_1mm),
        Claim("noise.optical_path_z_largest", "3.3.2",
              "the deviation in Z was the largest, exceeding ±2 mm",
              "σZ > σX, σY and max |dZ| > 2 mm (optical_path)", _noise_z_largest),
        Claim("noise.optical_path_mean_near_zero", "3.3.2",
              "the means of the three coordinate deviations of our model are all close to 0",
              f"|mean| < {SEM_FACTOR:g} SEM for dX, dY and dZ", _noise_mean_near_zero),
        Claim("noise.su_dZ_negative", "3.3.2",
              "Su's Z coordinate deviations are all negative (systematic)",
              f"mean dZ < -{SEM_FACTOR:g} SEM (systematically negative)", _noise_su_dz_negative),
        Claim("noise.su_xy_mean_near_zero", "3.3.2",
              "Su's X and Y coordinate deviations are also close to 0",
              f"|mean| < {SEM_FACTOR:g} SEM for dX and dY (su)", _noise_su_xy_near_zero),
        Claim("noise.su_dominated_by_model_error", "3.3.2",
              "with noise, Su's results are still primarily influenced by model error",
              "mean-square dP without noise / with noise > 0.5", _noise_su_model_error),
    ]


# --- 3.3.3: pixel noise and a water-index deviation ---------------------------------------------
def _index_claims():
    claims = []
    for axis in ("dX", "dZ"):
        def negative(c, axis=axis):
            s, sem = c.shifts, c.sem
            return (f"{c.side_text} shift optical_path {s['optical_path'][axis]:+.4f} mm, "
                    f"su {s['su'][axis]:+.4f} mm (SEM {sem['optical_path'][axis]:.4f} mm)",
                    all(s[m][axis] < -SEM_FACTOR * sem[m][axis] for m in INDEX_METHODS),
                    {"shift_optical_path": s["optical_path"][axis], "shift_su": s["su"][axis]})

        claims.append(Claim(f"index.{axis}_mean_shift_negative", "3.3.3",
                            f"with the 0.15 % water-index deviation the mean {axis} of both "
                            "models moves in the negative direction",
                            f"shift < -{SEM_FACTOR:g} noise SEM, both models", negative))

    def systematic(c):
        s, sem = c.shifts, c.sem
        return (f"{c.side_text} |shift| / SEM: " + ", ".join(
                    f"{m} {a} {abs(s[m][a]) / sem[m][a]:.0f}"
                    for m in INDEX_METHODS for a in ("dX", "dZ")),
                all(abs(s[m][a]) > SEM_FACTOR * sem[m][a]
                    for m in INDEX_METHODS for a in ("dX", "dZ")), {})

    def y_unchanged(c):
        s, sem = c.shifts, c.sem
        return (f"{c.side_text} shift optical_path {s['optical_path']['dY']:+.1e} mm, "
                f"su {s['su']['dY']:+.1e} mm (SEM {sem['optical_path']['dY']:.1e} mm)",
                all(abs(s[m]["dY"]) < SEM_FACTOR * sem[m]["dY"] for m in INDEX_METHODS), {})

    def alike(c):
        diffs = {a: abs(c.shifts["su"][a] - c.shifts["optical_path"][a]) for a in XYZ}
        return (f"{c.side_text} |shift(su) - shift(optical_path)| = "
                + " / ".join(f"{diffs[a]:.3f}" for a in XYZ) + " mm (X/Y/Z)",
                all(d <= SHIFT_AGREEMENT_MM for d in diffs.values()), diffs)

    def op_increases(c):
        before = c.ns["optical_path"].dp.rms_mm
        after = c.index_stats["optical_path"].dp.rms_mm
        return (f"{c.side_text} RMS dP {before:.3f} -> {after:.3f} mm", after > before,
                {"before": before, "after": after})

    def su_unchanged(c):
        before, after = c.ns["su"].dp.rms_mm, c.index_stats["su"].dp.rms_mm
        change = abs(after / before - 1.0)
        return (f"{c.side_text} RMS dP {before:.2f} -> {after:.2f} mm "
                f"({100 * change:.1f} % change)", change < 0.10, {"relative_change": change})

    return claims + [
        Claim("index.xz_shift_systematic", "3.3.3",
              "the water-index deviation gives small systematic errors in X and Z",
              f"|shift| > {SEM_FACTOR:g} noise SEM (dX and dZ, both models)", systematic),
        Claim("index.dY_unchanged", "3.3.3",
              "the distribution of the Y deviation does not change (both models)",
              f"|shift dY| < {SEM_FACTOR:g} SEM, both models", y_unchanged),
        Claim("index.models_alike", "3.3.3",
              "the magnitude of the change is the same for Su's model as for ours",
              f"mean shifts agree within {SHIFT_AGREEMENT_MM:g} mm in X, Y and Z", alike),
        Claim("index.optical_path_error_increases", "3.3.3",
              "compared with Figure 7 the deviations of our model have (slightly) increased",
              "RMS dP with the deviation > RMS dP without (optical_path)", op_increases),
        Claim("index.su_basically_unchanged", "3.3.3",
              "compared with Figure 7 the deviation of Su's model is basically unchanged",
              "RMS dP of su changes by less than 10 %", su_unchanged),
    ]


# --- section 4 (future work): the water index estimated in situ ---------------------------------
def _in_situ_claims():
    def unbiased(c):
        s = c.in_situ
        return (f"bias {s['bias']:+.2e} over {s['trials']} trials (standard error "
                f"{s['bias_sem']:.1e}); true {s['n_true']:.7g}, assumed {s['n_assumed']:.7g}",
                abs(s["bias"]) < SEM_FACTOR * s["bias_sem"],
                {"bias": s["bias"], "bias_sem": s["bias_sem"], "spread": s["spread"]})

    def honest_sigma(c):
        s = c.in_situ
        ratio = s["mean_sigma"] / s["spread"]
        return (f"mean reported σ {s['mean_sigma']:.2e} against the observed spread "
                f"{s['spread']:.2e} (ratio {ratio:.2f})", abs(ratio - 1.0) <= 0.2,
                {"mean_sigma": s["mean_sigma"], "spread": s["spread"], "ratio": ratio})

    def removes_dz(c):
        s = c.in_situ
        return (f"mean dZ {s['mean_dz_before_mm']:+.3f} mm assuming {s['n_assumed']:g} -> "
                f"{s['mean_dz_after_mm']:+.3f} mm with the estimated index",
                abs(s["mean_dz_after_mm"]) < 0.1 * abs(s["mean_dz_before_mm"]),
                {"before_mm": s["mean_dz_before_mm"], "after_mm": s["mean_dz_after_mm"]})

    return [
        Claim("in_situ.unbiased", "4",
              "future work: estimate the water index during the measurement itself",
              f"|mean estimate − truth| < {SEM_FACTOR:g} standard errors", unbiased),
        Claim("in_situ.sigma_honest", "4",
              "(this project) the reported uncertainty of the in-situ index is honest",
              "mean reported σ within 20 % of the observed spread", honest_sigma),
        Claim("in_situ.removes_depth_bias", "4",
              "(this project) the estimated index removes the depth bias of a wrong index",
              "|mean dZ| after < 10 % of before", removes_dz),
    ]


#: Every claim, in the order of the paper.
CLAIMS: tuple[Claim, ...] = tuple(_gap_claims() + _ideal_claims() + _noise_claims()
                                  + _index_claims() + _in_situ_claims())


def evaluate_claims(results: dict) -> list[dict]:
    """The paper's claims against the measured numbers (one dict per claim: ``id``,
    ``section``, ``paper``, ``measured``, ``criterion``, ``holds``, ``values``)."""
    context = _Context(results)
    return [claim.evaluate(context) for claim in CLAIMS]


__all__ = ["CLAIMS", "Claim", "evaluate_claims"]
