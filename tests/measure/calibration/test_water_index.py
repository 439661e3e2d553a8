"""measure.calibration.water_index: Quan & Fry 1995 against a published table, its range, its parser."""

from __future__ import annotations

import numpy as np
import pytest

from measure.calibration.water_index import (DEFAULT_WAVELENGTH_NM, QUAN_FRY_COEFFICIENTS, WaterIndexError,
                                 parse_water_index, water_index)

#: Pure water relative to air, 4 decimals (the table of "Refraction of light by water",
#: scubageek.com/articles/wwwh2o.html, after the CRC handbook): {T °C: {λ nm: n}}; its 706.5 nm
#: column lies outside the formula's 400–700 nm.
PURE_WATER = {10: {589.3: 1.3337, 501.6: 1.3371, 404.7: 1.3435},
              20: {589.3: 1.3330, 501.6: 1.3364, 404.7: 1.3427},
              30: {589.3: 1.3319, 501.6: 1.3353, 404.7: 1.3417}}


def test_coefficients_are_the_papers():
    """The ten numbers of Quan & Fry 1995 (also found, identical, in three independent public
    implementations)."""
    assert QUAN_FRY_COEFFICIENTS == (1.31405, 1.779e-4, -1.05e-6, 1.6e-8, -2.02e-6, 15.868,
                                     0.01155, -0.00423, -4382.0, 1.1455e6)


@pytest.mark.parametrize("temperature", sorted(PURE_WATER))
def test_pure_water_table(temperature):
    """Within 1e-4 of the 4-decimal table (measured: ≤ 7e-5); sodium D at 20 °C is 1.33300."""
    wavelengths = np.array(sorted(PURE_WATER[temperature]))
    table = np.array([PURE_WATER[temperature][w] for w in wavelengths])
    n = water_index(temperature, 0.0, wavelengths)
    assert n.shape == wavelengths.shape
    np.testing.assert_allclose(n, table, atol=1e-4)
    assert water_index(20, 0, 589.3) == pytest.approx(1.33300, abs=1e-5)


def test_seawater_hand_computed_and_vectorised():
    """T = 12 °C, S = 35 PSU, 550 nm: 1.3415179766 summed term by term; arrays broadcast."""
    assert water_index(12, 35, 550) == pytest.approx(1.3415179766, abs=1e-10)
    assert water_index(12, 35) == water_index(12, 35, DEFAULT_WAVELENGTH_NM)
    grid = water_index(np.array([[0.0], [15.0], [30.0]]), np.array([0.0, 17.5, 35.0]), 500.0)
    assert grid.shape == (3, 3)
    assert np.all(np.diff(grid, axis=1) > 0)      # saltier water refracts more
    assert np.all(np.diff(grid, axis=0) < 0)      # warmer water refracts less
    assert isinstance(water_index(10, 30, 500), float)


@pytest.mark.parametrize("args, word", [((31, 35, 550), "temperature 31"),
                                        ((-1, 35, 550), "temperature -1"),
                                        ((12, 36, 550), "salinity 36"),
                                        ((12, 35, 399), "wavelength 399"),
                                        ((12, 35, 701), "wavelength 701"),
                                        ((np.nan, 35, 550), "temperature nan")])
def test_outside_the_fitted_range_is_refused(args, word):
    with pytest.raises(WaterIndexError, match=word):
        water_index(*args)


def test_parse_number_and_temperature_salinity():
    assert parse_water_index("1.339") == (1.339, None)
    value, note = parse_water_index("T=12,S=35")
    assert value == water_index(12, 35, 550)
    assert note == "n_water = 1.34152 from T=12 °C, S=35 PSU, 550 nm (Quan & Fry 1995)"
    value, note = parse_water_index("temperature=4, salinity=0, wavelength=450")
    assert value == water_index(4, 0, 450) and "450 nm" in note


@pytest.mark.parametrize("text, word", [("0.9", "index >= 1"), ("abc", "index >= 1"),
                                        ("T=12", "salinity missing"),
                                        ("T=12,S=35,T=3", "each once"),
                                        ("T=12,X=3", "each once"), ("T=a,S=35", "not a number"),
                                        ("T=40,S=35", "temperature 40")])
def test_parse_errors(text, word):
    with pytest.raises(WaterIndexError, match=word):
        parse_water_index(text)
