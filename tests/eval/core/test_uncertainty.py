"""eval.core.uncertainty: --pixel-sigma, the pairs' pixel σ, and the covariance files."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from eval.cli import CLIError
from eval.core.uncertainty import (AUTO, COLUMNS, TRUTH_COLUMNS, pair_sigmas, parse_pixel_sigma,
                                   rig_covariance_note, write_uncertainty_files)
from measure.geometry.projection import project
from measure.stereo.uncertainty import point_covariances
from synth.formats.cloudfile import ply_layout, read_cloud_points
from synth.scene.layouts import paper_plane
from synth.scene.rig import paper_rig


def test_parse_pixel_sigma():
    assert parse_pixel_sigma("auto") == AUTO and parse_pixel_sigma(None) == AUTO
    assert parse_pixel_sigma("0.05") == 0.05
    for bad in ("0", "-1", "nan", "inf", "x"):
        with pytest.raises(CLIError, match="--pixel-sigma"):
            parse_pixel_sigma(bad)


def test_pair_sigmas_stated_and_from_the_residuals():
    rig = paper_rig()
    points = paper_plane(1000.0)
    uv_left, uv_right = (project(c, rig.port, points) for c in rig.cameras)
    rng = np.random.default_rng(4)
    uv_left = uv_left + rng.normal(0, 0.05, uv_left.shape)
    uv_right = uv_right + rng.normal(0, 0.05, uv_right.shape)
    stated, info = pair_sigmas(0.03, uv_left, uv_right, points, rig, noise_px=0.04)
    assert np.allclose(stated, 0.05) and info["stated_px"] == 0.03
    auto, info = pair_sigmas(AUTO, uv_left, uv_right, points, rig)
    assert auto.shape == (len(points), 2)
    assert info["detector_median_px"] == 0.0  # no detections given
    assert info["residual_sigma0_px"] == pytest.approx(0.05, rel=0.1)


def test_uncertainty_files_round_trip(tmp_path):
    rig = paper_rig()
    points = paper_plane(1000.0)[:20]
    covariance = point_covariances(rig, points, 0.1).total
    errors = np.full((20, 3), 0.01)
    entry = write_uncertainty_files(tmp_path, "optical_path", points, covariance, errors)
    assert entry["columns"] == list(COLUMNS + TRUTH_COLUMNS)
    layout = ply_layout(tmp_path / entry["ply"], "ply")
    assert layout["format"] == "binary_little_endian"
    assert np.allclose(read_cloud_points(tmp_path / entry["ply"]), points)
    raw = (tmp_path / entry["ply"]).read_bytes()
    body = np.frombuffer(raw[raw.index(b"end_header\n") + 11:], dtype="<f8").reshape(20, -1)
    assert np.array_equal(body[:, 3:6], np.sqrt(np.einsum("nii->ni", covariance)))
    assert np.array_equal(body[:, 7], covariance[:, 0, 1])
    with open(tmp_path / entry["csv"], newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == list(COLUMNS + TRUTH_COLUMNS) and len(rows) == 21
    table = np.array(rows[1:], dtype=float)
    assert np.allclose(table[:, 11], covariance[:, 2, 2], rtol=1e-9)
    assert np.all(table[:, -1] > 0)  # the Mahalanobis distance² of the errors


def test_rig_covariance_note_says_when_the_calibration_has_none():
    assert "pixel-noise part only" in rig_covariance_note(None, "--calib c.yaml")
    assert "c.yaml holds no covariance" in rig_covariance_note(None, "--calib c.yaml")
    assert "exact" in rig_covariance_note(None, None)


def test_the_coverage_verdict_says_when_sigma_is_dishonest():
    from eval.core.uncertainty import coverage_verdict

    assert coverage_verdict({"coverage_95": 0.95, "n": 496}) == ""
    assert "understates" in coverage_verdict({"coverage_95": 0.786, "n": 496})
    assert "overstates" in coverage_verdict({"coverage_95": 1.0, "n": 496})
    assert coverage_verdict({"coverage_95": 0.5, "n": 10}) == ""  # too few points to judge
    assert coverage_verdict({"coverage_95": None, "n": 0}) == ""
    # a wrong --assume is the first suspect, not --eccentricity (which it always named)
    wrong = coverage_verdict({"coverage_95": 0.0, "n": 496}, {"n_water": {"truth": 1.333}})
    assert "differs from the truth (n_water" in wrong and "--eccentricity" not in wrong
    assert "--eccentricity" in coverage_verdict({"coverage_95": 0.786, "n": 496}, {})


def test_elongated_detections_scatter_more_across_their_minor_axis():
    """``elongated_pixel_covariance``: per view the eigenvectors are the ellipse's axes, σ along
    the major one and σ · e^k across it; a round detection (e = 1) is isotropic; the views do not
    correlate. Reference: the rotation written out by hand for one angle."""
    from measure.stereo.uncertainty import MINOR_AXIS_EXPONENT, elongated_pixel_covariance

    sigma = np.array([[0.01, 0.02]])
    cov = elongated_pixel_covariance(sigma, [[3.0, 1.0]], [[np.radians(30.0), 1.0]])[0]
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    major, minor = 0.01 ** 2, (0.01 * 3.0 ** MINOR_AXIS_EXPONENT) ** 2
    expected = np.array([[major * c * c + minor * s * s, (major - minor) * c * s],
                         [(major - minor) * c * s, major * s * s + minor * c * c]])
    np.testing.assert_allclose(cov[:2, :2], expected, rtol=1e-12)
    np.testing.assert_allclose(cov[2:, 2:], 0.02 ** 2 * np.eye(2), rtol=1e-12)
    assert np.all(cov[:2, 2:] == 0)
