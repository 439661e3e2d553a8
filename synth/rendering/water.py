"""Water that absorbs and scatters: the optical water types a scene's medium is made of.

A homogeneous medium has a beam attenuation coefficient ``c = a + b`` (absorption plus
scattering, per metre), a single-scattering albedo ``b / c`` and a phase function; natural waters
scatter strongly forward, and the project uses a Henyey–Greenstein phase function with
``g = 0.92`` (about the mean cosine of Petzold's measured volume scattering functions).

Presets (:data:`PRESETS`): Petzold's three classic measurements at 530 nm as tabulated by C. D.
Mobley, *Light and Water* (1994), table 3.10 — clear ocean (Bahamas) a = 0.114, b = 0.037;
coastal ocean a = 0.179, b = 0.219; turbid harbour (San Diego) a = 0.366, b = 1.824 (per metre).
``clear`` is no medium at all. The numbers are quoted as they are widely reproduced from that
table; they were not re-read from the book here.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Henyey–Greenstein asymmetry of every preset.
DEFAULT_G = 0.92


@dataclass(frozen=True)
class Water:
    """A homogeneous water: ``c_per_m`` beam attenuation (1/m), ``albedo`` = b / c, ``g``."""

    name: str
    c_per_m: float
    albedo: float
    g: float = DEFAULT_G


def _petzold(name, a, b):
    return Water(name, round(a + b, 6), round(b / (a + b), 6))


PRESETS = {
    "clear_ocean": _petzold("clear ocean (Petzold, Bahamas)", 0.114, 0.037),
    "coastal": _petzold("coastal ocean (Petzold)", 0.179, 0.219),
    "turbid_harbor": _petzold("turbid harbour (Petzold, San Diego)", 0.366, 1.824),
}

__all__ = ["DEFAULT_G", "PRESETS", "Water"]
