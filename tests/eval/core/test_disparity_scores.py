"""Disparity scores as KITTI 2015 and the stereo benchmarks define them, on hand-made maps."""

from __future__ import annotations

import numpy as np
import pytest

from eval.core.disparity_scores import depth_errors_by_distance, disparity_scores, pooled


def test_epe_d1_and_density_follow_kittis_rule():
    truth = np.array([100.0, 50.0, 20.0, 10.0, np.nan, 80.0])
    predicted = np.array([104.0, 54.0, 20.5, 13.5, 7.0, np.nan])
    s = disparity_scores(predicted, truth)
    # errors 4, 4, 0.5, 3.5 on the 4 pixels with both; bad: > 3 px and > 5 % of the truth:
    # 4 > 5 (100) no; 4 > 2.5 (50) yes; 0.5 no; 3.5 > 0.5 (10) yes
    assert s["pixels"] == 5 and s["scored"] == 4 and s["density"] == pytest.approx(0.8)
    assert s["epe_px"] == pytest.approx(12.0 / 4) and s["d1"] == pytest.approx(0.5)


def test_pooled_counts_pixels_not_maps():
    a = disparity_scores(np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 7.0]))
    b = disparity_scores(np.array([10.0]), np.array([20.0]))
    p = pooled([a, b])
    assert p["epe_px"] == pytest.approx((4.0 + 10.0) / 4) and p["d1"] == pytest.approx(0.5)


def test_depth_errors_by_distance_bins_the_truth():
    truth = np.array([500.0, 900.0, 1200.0, 1800.0, 2500.0, np.nan])
    predicted = truth + np.array([5.0, -9.0, 24.0, 18.0, -100.0, 1.0])
    rows = depth_errors_by_distance(predicted, truth, bins=(0, 1000, 2000, np.inf))
    assert [r["pixels"] for r in rows] == [2, 2, 1]
    assert rows[0]["median_abs_mm"] == pytest.approx(7.0)
    assert rows[1]["median_rel_percent"] == pytest.approx(100 * np.median([24 / 1200, 18 / 1800]))
    assert rows[2]["median_abs_mm"] == pytest.approx(100.0)
