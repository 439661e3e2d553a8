"""The target detector's shared options (eval run and eval measure) and detect_view."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from eval.core.detection import (DETECTOR_OPTIONS, add_detector_options, detect_view, fraction,
                                 median_filtered)
from measure import detect_targets


def _disks(dtype=np.uint8, level=200):
    image = np.zeros((60, 80), dtype=np.float64)
    v, u = np.mgrid[0:60, 0:80]
    for cu, cv in ((20.3, 20.7), (55.6, 30.2), (40.1, 45.5)):
        image[(u - cu) ** 2 + (v - cv) ** 2 <= 16] = level
    return image.astype(dtype)


def test_the_options_and_their_defaults():
    parser = argparse.ArgumentParser()
    add_detector_options(parser)
    assert vars(parser.parse_args([])) == DETECTOR_OPTIONS
    args = parser.parse_args(["--threshold-fraction", "0.3", "--max-elongation", "2",
                              "--max-area-ratio", "3", "--median-filter", "5"])
    assert (args.threshold_fraction, args.max_elongation, args.max_area_ratio,
            args.median_filter) == (0.3, 2.0, 3.0, 5)
    for bad in ("0", "1", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            fraction(bad)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float64])
def test_median_filter_keeps_integer_images_integer(dtype):
    image = _disks(dtype)
    out = median_filtered(image, 3)
    assert out.dtype == (dtype if dtype in (np.uint8, np.uint16) else np.float32)
    assert median_filtered(image, 0) is image


def test_detect_view_is_detect_targets_with_the_options():
    image = _disks()
    plain, view = detect_targets(image), detect_view(image)
    assert view.n_found == plain.n_found == 3
    assert np.array_equal(view.centers, plain.centers)
    given = detect_view(image, threshold_fraction=0.5)
    assert given.threshold_rule == "given" and given.n_found == 3
    assert detect_view(image, median_filter=3).n_found == 3
