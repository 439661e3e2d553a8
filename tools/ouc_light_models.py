"""Which light explains the ``ouc_flat/air`` photos' square levels: point lamp, spot lamp, two
lamps, a lamp and the ambient, each with one exposure or one per photo, fitted to the same
280 squares (:func:`ouc_twin.square_samples`), and the RMS of the log levels each leaves.

    python tools/ouc_light_models.py $REFSTEREO_REAL_PHOTOS/ouc_flat [--models point,spot]

The models (all: a matte board, a linear camera, cos⁴ vignetting; lamp positions mm in the
camera's frame, OpenCV axes; the stored level of a square ``DARK_DN + g · ρ · E · cos⁴`` with
``ρ`` 1 for a white square and the fitted black/white ratio for a black one):

* ``point``: ``E = 10⁶ · cos θ / r²`` (:func:`ouc_twin.lamp_levels`);
* ``spot``: the same times Mitsuba's ``spot`` falloff
  (:func:`synth.products.board_light.spot_falloff`: 1 within the beam's half-angle, falling
  linearly in angle to 0 at the cut-off), its axis (azimuth, elevation), cut-off and beam
  fitted — a photo lamp's hot spot and edge. Outside the cut-off the fit sees 10⁻³ of the
  light (the logarithms stay finite); the render sees none;
* ``two-points``: two point lamps, the second's intensity fitted;
* ``point+ambient``, ``spot+ambient``: the lamp plus an even irradiance over the board.

``--exposure per-photo``: each photo's exposure free within :data:`EXPOSURE_RANGE` of the
first photo's (an automatic exposure; unbounded, a board facing away from the lamp takes an
exposure of hundreds to match its few levels with its light at the 10⁻³ floor). Least squares
on the logarithms; a square clipped in the photo (≥ 245) counts only where the model leaves it
below 245; several starting places (:func:`starts`), the lamps within
:data:`LAMP_BOUND_MM` of the camera along each axis.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from ouc_twin import DARK_DN  # tools/ is the script's folder, first on sys.path

MODELS = ("point", "spot", "two-points", "point+ambient", "spot+ambient")
#: How many parameters each model's light has before the exposure and the black/white ratio.
LIGHT_PARAMS = {"point": 3, "spot": 7, "two-points": 7, "point+ambient": 4, "spot+ambient": 8}
#: The lamps' box (mm along each camera axis).
LAMP_BOUND_MM = 3000.0
#: ``--exposure per-photo``: each photo's exposure within this factor of the first photo's.
EXPOSURE_RANGE = 4.0
#: The light a spot gives outside its cut-off, as the fit sees it (module docs).
OUTSIDE_CUTOFF = 1e-3


def axis_vector(azimuth, elevation) -> np.ndarray:
    """Unit vector (camera frame) of ``azimuth`` (about y, from +z towards +x) and
    ``elevation`` (towards +y), radians."""
    return np.array([np.cos(elevation) * np.sin(azimuth), np.sin(elevation),
                     np.cos(elevation) * np.cos(azimuth)])


def point_irradiance(position, samples):
    """``(cos θ / r², unit vectors lamp → square)`` of a lamp at ``position`` (mm) for every
    square of ``samples`` (cos θ floored at 10⁻³)."""
    d = np.asarray(position, float) - samples["P"]
    r = np.linalg.norm(d, axis=1)
    cos = np.maximum(np.sum(samples["n"] * d, axis=1) / r, 1e-3)
    return cos / r ** 2, -d / r[:, None]


def spot_factor(light, rays, floor: float = OUTSIDE_CUTOFF) -> np.ndarray:
    """The spot's falloff along ``rays`` (unit, lamp → square) for spot parameters ``light``
    ``(x, y, z, azimuth, elevation, cut-off rad, beam / cut-off)``."""
    from synth.products.board_light import spot_falloff

    cutoff = np.degrees(light[5])
    factor = spot_falloff(rays @ axis_vector(light[3], light[4]), cutoff, cutoff * light[6])
    return np.maximum(factor, floor)


def irradiance(model: str, light, samples) -> np.ndarray:
    """The light on every square (in units of a lamp of intensity 10⁶ at 1 mm), ``light`` the
    model's first :data:`LIGHT_PARAMS` parameters (module docs; intensities as logarithms)."""
    e, rays = point_irradiance(light[:3], samples)
    if model.startswith("spot"):
        e = e * spot_factor(light, rays)
    if model == "two-points":
        e = e + np.exp(light[6]) * point_irradiance(light[3:6], samples)[0]
    if model.endswith("ambient"):
        e = e + np.exp(light[-1]) * 1e-6
    return e * 1e6


def model_levels(model: str, params, samples, per_photo: bool) -> np.ndarray:
    """Stored levels before clipping: ``params`` = light, log exposure, log black/white, then
    (``per_photo``) the log exposures of photos 2… relative to the first."""
    m = LIGHT_PARAMS[model]
    rho = np.where(samples["dark"], np.exp(params[m + 1]), 1.0)
    gain = np.exp(params[m])
    if per_photo:
        gain = gain * np.exp(np.concatenate([[0.0], params[m + 2:]]))[samples["photo"]]
    return DARK_DN + gain * rho * irradiance(model, params[:m], samples) * samples["cos4"]


def starts(model: str, samples) -> list:
    """The fit's starting lights: lamps on a grid round the camera (a spot aimed at the boards'
    middle, cut-offs 8°, 20°, 40°; a second lamp on a coarser grid)."""
    grid = [np.array([x, y, z], float) for x in (-2500, 0, 2500) for y in (-1500, 0, 1500)
            for z in (-1500, 300)]
    middle = np.median(samples["P"], axis=0)
    out = []
    for p in grid:
        if model.startswith("spot"):
            d = (middle - p) / np.linalg.norm(middle - p)
            aim = [np.arctan2(d[0], d[2]), np.arcsin(d[1])]
            out += [[*p, *aim, np.radians(c), 0.75] for c in (8.0, 20.0, 40.0)]
        elif model == "two-points":
            out += [[*p, *q, 0.0] for q in grid[::5]]
        else:
            out.append(list(p))
    if model.endswith("ambient"):
        out = [s + [0.0] for s in out]   # the ambient's log irradiance
    return out


def bounds(model: str, n_params: int, per_photo: bool):
    """``(lower, upper)``: lamps within :data:`LAMP_BOUND_MM`, a spot's cut-off 2–89° and its
    beam 0–0.99 of it, the exposures within :data:`EXPOSURE_RANGE`."""
    m = LIGHT_PARAMS[model]
    lo, hi = np.full(n_params, -np.inf), np.full(n_params, np.inf)
    lo[:3], hi[:3] = -LAMP_BOUND_MM, LAMP_BOUND_MM
    if model.startswith("spot"):
        lo[3:7] = [-np.pi, -np.pi / 2, np.radians(2.0), 0.0]
        hi[3:7] = [np.pi, np.pi / 2, np.radians(89.0), 0.99]
    if model == "two-points":
        lo[3:6], hi[3:6] = -LAMP_BOUND_MM, LAMP_BOUND_MM
    if per_photo:
        lo[m + 2:], hi[m + 2:] = -np.log(EXPOSURE_RANGE), np.log(EXPOSURE_RANGE)
    return lo, hi


def fit_light(samples, model: str = "spot", per_photo: bool = True):
    """The ``model``'s light, exposure(s) and black/white ratio that best give the photos'
    square levels (module docs). ``(params, exposures of the photos relative to the first,
    RMS of the log residuals)``."""
    from scipy.optimize import least_squares

    level, clipped = samples["level"], samples["level"] >= 245
    n_extra = int(samples["photo"].max()) if per_photo else 0

    def residuals(p):
        m = np.maximum(model_levels(model, p, samples, per_photo), 1e-6)
        return np.where(clipped, np.maximum(0.0, np.log(245.0) - np.log(m)),
                        np.log(m) - np.log(level))

    best = None
    for light in starts(model, samples):
        p0 = np.concatenate([light, [0.0, np.log(0.12)], np.zeros(n_extra)])
        lo, hi = bounds(model, p0.size, per_photo)
        p0 = np.clip(p0, lo + 1e-9, hi - 1e-9)
        first = model_levels(model, p0, samples, per_photo) - DARK_DN
        p0[len(light)] = np.median(np.log(np.maximum(level - DARK_DN, 1.0))
                                   - np.log(np.maximum(first, 1e-12)))
        fit = least_squares(residuals, p0, bounds=(lo, hi), max_nfev=3000)
        if best is None or fit.cost < best.cost:
            best = fit
    m = LIGHT_PARAMS[model]
    exposures = np.exp(np.concatenate([[0.0], best.x[m + 2:]]))
    return best.x, exposures, float(np.sqrt(np.mean(best.fun ** 2)))


def describe(model: str, params) -> str:
    """One line: where the model's lamps are and, for a spot, its aim, cut-off and beam."""
    text = f"lamp at {np.round(params[:3]).tolist()} mm"
    if model.startswith("spot"):
        axis = axis_vector(params[3], params[4])
        text += (f", aimed along {np.round(axis, 3).tolist()}, cut-off "
                 f"{np.degrees(params[5]):.1f}°, beam {np.degrees(params[5] * params[6]):.1f}°")
    if model == "two-points":
        text += f", a second at {np.round(params[3:6]).tolist()} mm ({np.exp(params[6]):.2f}×)"
    return text


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="the ouc_flat folder (Calib_Results_export.json, air/)")
    parser.add_argument("--models", default=",".join(MODELS),
                        help=f"comma-separated, from {', '.join(MODELS)}")
    args = parser.parse_args(argv)
    import cv2

    from ouc_twin import load_export, square_samples

    K, kc, poses, square = load_export(args.folder)
    photos = [cv2.imread(os.path.join(args.folder, "air", f"{p[0]}.BMP"), cv2.IMREAD_GRAYSCALE)
              for p in poses]
    samples = square_samples(photos, poses, K, kc, square)
    print("| light | log RMS, one exposure | log RMS, one per photo | the lamp (one per photo) |")
    print("|---|---|---|---|")
    for model in args.models.split(","):
        if model not in MODELS:
            print(f"error: unknown model {model!r}", file=sys.stderr)
            return 2
        fixed = fit_light(samples, model, per_photo=False)
        free = fit_light(samples, model, per_photo=True)
        spread = free[1] / np.median(free[1])
        print(f"| {model} | {fixed[2]:.3f} | {free[2]:.3f} | {describe(model, free[0])}; "
              f"exposures {spread.min():.2f}–{spread.max():.2f}× their median |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
