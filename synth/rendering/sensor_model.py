"""A machine-vision sensor applied to rendered radiance: exposure, shot noise, read noise, dark
level, gain and quantization (the linear camera model of the EMVA 1288 standard).

Mitsuba renders radiance (linear, arbitrary units, with Monte-Carlo noise only). A camera turns
it into electrons and then into digital numbers (DN):

* **exposure** (automatic): the brightest pixel of the noise-free render collects
  ``exposure × full_well_e`` electrons; every pixel collects in proportion
  (``electrons_per_unit`` = ``exposure × full_well_e / peak``);
* **photon shot noise**: the electron count is Poisson-distributed about that mean;
* **read noise**: Gaussian, ``read_noise_e`` electrons RMS (EMVA's temporal dark noise);
* **saturation** at ``full_well_e``;
* **gain** ``full_well_e / (2^bit_depth − 1 − dark_level_dn)`` electrons per DN, so that a full
  well is the largest code; a **dark level** (black level) of ``dark_level_dn`` is added, and
  the result is rounded to integers in ``[0, 2^bit_depth − 1]``.

:func:`expose` returns the DN image (uint16; a 12-bit sensor's codes stored as they are in a
16-bit PNG) and :func:`to_radiance` maps DN back to the render's radiance units
(``(DN − dark_level) × gain / electrons_per_unit``), which is what the detector measures on.
Everything is seeded: the same seed gives the same bytes.

Presets (:data:`PRESETS`): ``imx174`` — the Sony IMX174 (1/1.2", 5.86 µm global-shutter pixels),
whose EMVA 1288 data as quoted publicly give a saturation capacity of 32 691 e⁻ and a temporal
dark noise of 6.83 e⁻ with a 12-bit ADC (docs/architecture.md gives the source). Any value can
be overridden (``"imx174,full_well_e=10000,read_noise_e=2.5"``). The dark level, 16 DN, keeps
the read noise (about 0.85 DN) off the zero clip.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

#: Bit depths a sensor may have.
BIT_DEPTH_RANGE = (8, 16)


class SensorError(ValueError):
    """A sensor parameter out of range (a user-facing error)."""


@dataclass(frozen=True)
class SensorModel:
    """A linear sensor (module docs). Electrons (e⁻), digital numbers (DN), fractions."""

    name: str
    full_well_e: float
    read_noise_e: float
    bit_depth: int = 12
    dark_level_dn: float = 16.0
    exposure: float = 0.8

    def __post_init__(self):
        checks = [
            (np.isfinite(self.full_well_e) and self.full_well_e >= 1, "full_well_e",
             "a finite number ≥ 1 electron"),
            (np.isfinite(self.read_noise_e) and self.read_noise_e >= 0, "read_noise_e",
             "finite and ≥ 0 electrons"),
            (float(self.bit_depth).is_integer()
             and BIT_DEPTH_RANGE[0] <= self.bit_depth <= BIT_DEPTH_RANGE[1], "bit_depth",
             f"an integer from {BIT_DEPTH_RANGE[0]} to {BIT_DEPTH_RANGE[1]}"),
            (np.isfinite(self.exposure) and 0 < self.exposure <= 1, "exposure",
             "a fraction of the full well in (0, 1]"),
        ]
        for ok, name, what in checks:
            if not ok:
                raise SensorError(f"sensor {name} must be {what}, got {getattr(self, name)!r}")
        if not (np.isfinite(self.dark_level_dn)
                and 0 <= self.dark_level_dn < 2 ** int(self.bit_depth) - 1):
            raise SensorError(f"sensor dark_level_dn must be from 0 to below "
                              f"{2 ** int(self.bit_depth) - 1} DN, got {self.dark_level_dn!r}")

    @property
    def max_dn(self) -> int:
        return 2 ** int(self.bit_depth) - 1

    @property
    def gain_e_per_dn(self) -> float:
        """Electrons per DN: a full well is the largest code."""
        return self.full_well_e / (self.max_dn - self.dark_level_dn)

    def to_dict(self) -> dict:
        return {**asdict(self), "gain_e_per_dn": self.gain_e_per_dn, "max_dn": self.max_dn}


PRESETS = {
    "imx174": SensorModel("imx174", full_well_e=32691.0, read_noise_e=6.83),
}
#: What ``with_overrides`` accepts, and each one's type.
OVERRIDABLE = {"full_well_e": float, "read_noise_e": float, "bit_depth": int,
               "dark_level_dn": float, "exposure": float}


def sensor_from_spec(text: str) -> SensorModel:
    """``"PRESET[,name=value…]"`` → a :class:`SensorModel`; SensorError names what is wrong."""
    name, *pairs = [part.strip() for part in str(text).split(",")]
    if name not in PRESETS:
        raise SensorError(f"unknown sensor {name!r} (presets: {', '.join(PRESETS)})")
    values = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        key = key.strip()
        if not sep or key not in OVERRIDABLE:
            raise SensorError(f"sensor setting {pair!r}: expected name=value with name one of "
                              f"{', '.join(OVERRIDABLE)}")
        try:
            number = float(value)
        except ValueError:
            raise SensorError(f"sensor setting {key}: {value!r} is not a number") from None
        if OVERRIDABLE[key] is int:
            if not number.is_integer():
                raise SensorError(f"sensor setting {key} must be an integer, got {value!r}")
            number = int(number)
        values[key] = number
    return replace(PRESETS[name], **values)


def expose(radiance: np.ndarray, sensor: SensorModel, rng: np.random.Generator,
           peak: float | None = None):
    """``(dn, info)``: the DN image ``(H, W)`` uint16 of the linear ``radiance`` ``(H, W)``.

    ``peak``: the radiance that collects ``sensor.exposure × full_well`` electrons (default:
    the image's maximum — automatic exposure). ``info``: ``electrons_per_unit`` (e⁻ per unit
    of radiance), ``peak``, ``saturated_pixels``."""
    radiance = np.asarray(radiance, dtype=np.float64)
    peak = float(np.max(radiance)) if peak is None else float(peak)
    if not (np.isfinite(peak) and peak > 0):
        raise SensorError(f"the image has no positive radiance to expose (peak {peak!r})")
    per_unit = sensor.exposure * sensor.full_well_e / peak
    mean_e = np.clip(radiance, 0.0, None) * per_unit
    electrons = rng.poisson(mean_e).astype(np.float64)
    electrons += rng.normal(0.0, sensor.read_noise_e, radiance.shape)
    saturated = electrons >= sensor.full_well_e
    electrons = np.minimum(electrons, sensor.full_well_e)
    dn = np.rint(electrons / sensor.gain_e_per_dn + sensor.dark_level_dn)
    dn = np.clip(dn, 0, sensor.max_dn).astype(np.uint16)
    return dn, {"electrons_per_unit": per_unit, "peak": peak,
                "saturated_pixels": int(saturated.sum())}


def to_radiance(dn: np.ndarray, sensor: SensorModel, electrons_per_unit: float) -> np.ndarray:
    """DN back to the render's radiance units, float32 ``(H, W)`` (the dark level removed)."""
    return ((np.asarray(dn, np.float64) - sensor.dark_level_dn) * sensor.gain_e_per_dn
            / electrons_per_unit).astype(np.float32)


def view_generator(seed: int, view: int) -> np.random.Generator:
    """The sensor noise generator of one view, derived from the run's seed: ``view`` its index
    in the rig (0, 1, …; a pair's left 0, right 1)."""
    return np.random.default_rng([int(seed), 0x5E5, int(view)])


__all__ = ["BIT_DEPTH_RANGE", "PRESETS", "SensorError", "SensorModel", "expose",
           "sensor_from_spec", "sensor_images", "sensor_views", "to_radiance", "view_generator"]


def sensor_views(left: np.ndarray, right: np.ndarray, sensor: SensorModel, seed: int):
    """Both views of a pair through ``sensor`` (:func:`sensor_images`): ``(left_dn, right_dn,
    info)``."""
    codes, info = sensor_images((left, right), ("left", "right"), sensor, seed)
    return codes[0], codes[1], info


def sensor_images(images, names, sensor: SensorModel, seed: int) -> tuple[list, dict]:
    """Every view through ``sensor`` with one exposure (synchronized cameras with equal
    settings: the brightest pixel of any view at ``sensor.exposure`` of the full well) and each
    view's own seeded noise (view k's: :func:`view_generator` of ``k``). ``images`` float32
    linear ``(H, W)``, ``names`` theirs. Returns ``(codes, info)``: uint16 codes per view, and
    ``info`` = the sensor's settings, ``electrons_per_unit``, ``peak``, ``dn_per_unit``
    (``(DN − dark_level) / radiance``) and per view name ``saturated_pixels``."""
    peak = max(float(np.max(image)) for image in images)
    codes, info = [], {"model": sensor.to_dict()}
    for k, (name, image) in enumerate(zip(names, images)):
        code, view_info = expose(image, sensor, view_generator(seed, k), peak=peak)
        codes.append(code)
        info.update(electrons_per_unit=view_info["electrons_per_unit"], peak=peak)
        info[name] = {"saturated_pixels": view_info["saturated_pixels"]}
    info["dn_per_unit"] = info["electrons_per_unit"] / sensor.gain_e_per_dn
    return codes, info
