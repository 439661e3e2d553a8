"""What a housing calibration that found no housing says (eval.calibrate.causes): the
adjustment's reason in words a user can act on, with the likely causes — the --intrinsics file,
water with the index of air — and the cure of two parameters the boards cannot tell apart kept
for that case alone."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from eval.calibrate.causes import housing_failure


def test_the_likely_causes_are_named():
    args = SimpleNamespace(intrinsics="air/calib.yaml", n_water=1.0)
    text = str(housing_failure("water", ValueError(
        "cam1 centre lies on the water side of the port's first interface (normal·centre = "
        "0 mm >= distance = -4.98e+14 mm)"), args))
    assert text.startswith("water: the adjustment moved the port behind a camera"), text
    assert "--intrinsics air/calib.yaml is the in-air calibration of another camera" in text
    assert "--n-water 1 is no water" in text and "e+14" not in text
    text = str(housing_failure("water", np.linalg.LinAlgError("Singular matrix"),
                               SimpleNamespace(intrinsics="a.yaml", n_water=1.33)))
    assert "singular normal equations" in text and "the design port" in text, text
    assert not text.startswith("water: Singular matrix")


def test_a_correlation_keeps_its_own_cure():
    text = str(housing_failure("water", "port.distance and port.thickness[0] are correlated at "
                               "+0.9999: these boards cannot tell them apart",
                               SimpleNamespace(intrinsics="a.yaml", n_water=1.33), "render"))
    assert "likely" not in text and "render more varied poses" in text, text
