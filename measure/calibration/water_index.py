"""The refractive index of (sea)water from its temperature, salinity and the wavelength.

Users know the water's temperature T and salinity S, not its index. Quan & Fry 1995 (X. Quan,
E. S. Fry, "Empirical equation for the index of refraction of seawater", Applied Optics 34(18),
3477–3480) fitted ten coefficients to the data collected by Austin & Halikas 1976 (SIO Ref. 76-1):

    n(S, T, λ) = n0 + (n1 + n2·T + n3·T²)·S + n4·T² + (n5 + n6·S + n7·T)/λ + n8/λ² + n9/λ³

with T in °C, S in PSU (‰) and λ in nm, at atmospheric pressure; the index is relative to air
(the data were measured against air), which is what a port model with ``n_air = 1`` wants. The
fit holds for 0–30 °C, 0–35 PSU and 400–700 nm; outside that range :func:`water_index` refuses
(an extrapolated index would be a guess presented as a number): give the index itself instead.
Against the pure-water table relative to air (4 decimals) at 10/20/30 °C and 404.7–706.5 nm it
agrees to 1e-4 (tests), e.g. 1.33300 at 20 °C, 589.3 nm (table: 1.3330).
"""

from __future__ import annotations

import numpy as np

#: n0 … n9 of Quan & Fry 1995 (λ in nm, T in °C, S in PSU).
QUAN_FRY_COEFFICIENTS = (1.31405, 1.779e-4, -1.05e-6, 1.6e-8, -2.02e-6,
                         15.868, 0.01155, -0.00423, -4382.0, 1.1455e6)
#: The range of the data the coefficients were fitted to: (low, high), inclusive.
TEMPERATURE_RANGE_C = (0.0, 30.0)
SALINITY_RANGE_PSU = (0.0, 35.0)
WAVELENGTH_RANGE_NM = (400.0, 700.0)
#: The wavelength when none is given: green, the middle of the visible range (nm).
DEFAULT_WAVELENGTH_NM = 550.0
CITATION = "Quan & Fry 1995"
#: Names accepted by :func:`parse_water_index` for each quantity (case-insensitive).
_KEYS = {"t": "temperature", "temperature": "temperature", "s": "salinity",
         "salinity": "salinity", "wavelength": "wavelength", "lambda": "wavelength",
         "wl": "wavelength"}


class WaterIndexError(ValueError):
    """A temperature, salinity or wavelength that the formula cannot take."""


def _checked(name: str, unit: str, values, limits) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    bad = ~np.isfinite(array) | (array < limits[0]) | (array > limits[1])
    if np.any(bad):
        first = float(array[bad].ravel()[0])
        raise WaterIndexError(
            f"{name} {first:g} {unit} is outside {limits[0]:g}–{limits[1]:g} {unit}, the range "
            f"of the data {CITATION} fitted; give the water index itself if you know it")
    return array


def water_index(temperature_c, salinity_psu, wavelength_nm=DEFAULT_WAVELENGTH_NM):
    """The water's index (relative to air) by Quan & Fry 1995 (module docs); arguments broadcast
    like numpy arrays. A float when all three are scalars, else an array. WaterIndexError names
    the first value outside the fitted range."""
    T = _checked("temperature", "°C", temperature_c, TEMPERATURE_RANGE_C)
    S = _checked("salinity", "PSU", salinity_psu, SALINITY_RANGE_PSU)
    L = _checked("wavelength", "nm", wavelength_nm, WAVELENGTH_RANGE_NM)
    n0, n1, n2, n3, n4, n5, n6, n7, n8, n9 = QUAN_FRY_COEFFICIENTS
    n = (n0 + (n1 + n2 * T + n3 * T**2) * S + n4 * T**2 + (n5 + n6 * S + n7 * T) / L
         + n8 / L**2 + n9 / L**3)
    return float(n) if np.ndim(n) == 0 else n


def parse_water_index(text: str) -> tuple[float, str | None]:
    """``(index, note)`` of a plain number (``"1.339"``, note None) or of
    ``"T=12,S=35[,wavelength=550]"`` (°C, PSU, nm; also ``temperature=``, ``salinity=``),
    whose note says how the index was computed, e.g. ``n_water = 1.33925 from T=12 °C,
    S=35 PSU, 550 nm (Quan & Fry 1995)``. WaterIndexError (a ValueError) says what is wrong."""
    text = str(text).strip()
    if "=" not in text:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not (np.isfinite(value) and value >= 1.0):
            raise WaterIndexError(f"expected an index >= 1 or T=<°C>,S=<PSU>[,wavelength=<nm>], "
                                  f"got {text!r}")
        return value, None
    given = {}
    for part in text.replace(";", ",").split(","):
        key, sep, value = part.partition("=")
        name = _KEYS.get(key.strip().lower())
        if not sep or name is None or name in given:
            raise WaterIndexError(f"{text!r}: expected T=<°C>,S=<PSU>[,wavelength=<nm>] (each "
                                  f"once), got {part.strip()!r}")
        try:
            given[name] = float(value)
        except ValueError:
            raise WaterIndexError(f"{text!r}: {key.strip()}={value.strip()!r} is not a "
                                  f"number") from None
    missing = [k for k in ("temperature", "salinity") if k not in given]
    if missing:
        raise WaterIndexError(f"{text!r}: {' and '.join(missing)} missing (T=<°C>,S=<PSU>"
                              f"[,wavelength=<nm>])")
    wavelength = given.get("wavelength", DEFAULT_WAVELENGTH_NM)
    value = water_index(given["temperature"], given["salinity"], wavelength)
    note = (f"n_water = {value:.5f} from T={given['temperature']:g} °C, "
            f"S={given['salinity']:g} PSU, {wavelength:g} nm ({CITATION})")
    return value, note


__all__ = ["CITATION", "DEFAULT_WAVELENGTH_NM", "QUAN_FRY_COEFFICIENTS", "SALINITY_RANGE_PSU",
           "TEMPERATURE_RANGE_C", "WAVELENGTH_RANGE_NM", "WaterIndexError", "parse_water_index",
           "water_index"]
