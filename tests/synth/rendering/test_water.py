"""Water that absorbs and scatters (synth.rendering.water, the refracted_volpath integrator).

Two independent checks of the medium: with absorption only, every target's flux falls by
Beer–Lambert's exp(−c·L) over its own path length in the water (the forward model's path); with
scattering, the image's energy agrees with Mitsuba's own ``volpath`` (emitter sampling and MIS,
a different estimator of the same integral)."""

from __future__ import annotations

import numpy as np
import pytest

from measure.images.detect import detect_targets
from measure.geometry.projection import solve_paths
from synth.products.crosscheck import associate_detections
from synth.scene.layouts import grid_plane
from synth.rendering.render import develop_image, load_mitsuba_scene, render_view
from synth.scene.rig import paper_cameras, paper_port
from synth.scene import SceneError, load_scene, write_scene
from synth.rendering.water import PRESETS

SMALL = (320, 268)


@pytest.fixture(scope="module")
def coastal_scene(tmp_path_factory):
    left, right = paper_cameras(SMALL, 150.0)
    targets = grid_plane(1000.0, 320.0, 80.0) + np.array([3.0, -2.0, 0.0])
    path = tmp_path_factory.mktemp("water") / "coastal.xml"
    return str(write_scene(path, (left, right), paper_port(), targets, 16.0,
                           water=PRESETS["coastal"]))


def _fluxes(image, camera, port, targets):
    """Detected flux per target (NaN where none), and the simulator's pixels."""
    expected = solve_paths(camera, port, targets).pixels
    detections = detect_targets(image)
    index, _ = associate_detections(np.asarray(detections.centers).reshape(-1, 2), expected)
    flux = np.full(len(targets), np.nan)
    flux[index[index >= 0]] = np.asarray(detections.flux)[index >= 0]
    return flux


@pytest.mark.slow
def test_absorption_follows_beer_lambert(coastal_scene):
    clear = load_scene(coastal_scene, {"water_c": "0"})
    absorbing = load_scene(coastal_scene, {"water_albedo": "0"})
    camera, port, targets = clear.rig.left, clear.rig.port, clear.targets
    images = []
    for spec in (clear, absorbing):
        mscene, mi, _ = load_mitsuba_scene(spec)
        images.append(render_view(mscene, mi, 0, camera, 256, 1))
    ratio = _fluxes(images[1], camera, port, targets) / _fluxes(images[0], camera, port, targets)
    paths = solve_paths(camera, port, targets)
    in_water_m = np.linalg.norm(targets - paths.interface_points[-1], axis=1) / 1000.0
    expected = np.exp(-PRESETS["coastal"].c_per_m * in_water_m)
    ok = np.isfinite(ratio)
    assert ok.sum() >= 40
    q = ratio[ok] / expected[ok]
    sem = q.std(ddof=1) / np.sqrt(q.size)
    # The analog estimator: each sample survives with probability ~0.7; the mean over targets
    # must be Beer–Lambert's within 4 standard errors (~0.1 %), and far from no attenuation.
    assert abs(q.mean() - 1.0) < 4 * sem, (q.mean(), sem)
    assert sem < 0.005 and abs(expected[ok].mean() - 1.0) > 0.25


@pytest.fixture(scope="module")
def quarter_coastal_scene(tmp_path_factory):
    """The coastal scene on a quarter of the pixels (160 x 134, the same field of view): the
    energy comparison below renders it seven times."""
    left, right = paper_cameras((160, 134), 75.0)
    targets = grid_plane(1000.0, 320.0, 80.0) + np.array([3.0, -2.0, 0.0])
    path = tmp_path_factory.mktemp("water") / "coastal_quarter.xml"
    return str(write_scene(path, (left, right), paper_port(), targets, 16.0,
                           water=PRESETS["coastal"]))


@pytest.mark.slow
def test_scattering_agrees_with_mitsubas_volpath(quarter_coastal_scene):
    coastal_scene = quarter_coastal_scene
    spec = load_scene(coastal_scene)
    mscene, mi, _ = load_mitsuba_scene(spec)
    ours = [render_view(mscene, mi, 0, spec.rig.left, 128, 10 * s).sum() for s in range(3)]
    theirs = [develop_image(mi, mi.render(mscene, sensor=0, spp=128, seed=s)).sum()
              for s in range(3)]
    clear = load_scene(coastal_scene, {"water_c": "0"})
    mclear, _, _ = load_mitsuba_scene(clear)
    no_water = render_view(mclear, mi, 0, clear.rig.left, 128, 0).sum()
    sem = np.sqrt(np.var(ours, ddof=1) / 3 + np.var(theirs, ddof=1) / 3)
    assert abs(np.mean(ours) - np.mean(theirs)) < 4 * sem + 1e-4 * np.mean(theirs), (ours, theirs)
    # the medium matters: 15 % of the light is lost (absorption beats in-scattering)
    assert np.mean(ours) < 0.9 * no_water


@pytest.mark.parametrize("define, fragment", [("water_albedo=1.5", "water_albedo"),
                                              ("water_g=1", "water_g"),
                                              ("water_c=-0.1", "water_c")])
def test_bad_water_parameters(coastal_scene, define, fragment):
    name, value = define.split("=")
    with pytest.raises(SceneError, match=fragment):
        load_scene(coastal_scene, {name: value})


def test_a_medium_needs_a_port():
    left, right = paper_cameras(SMALL, 150.0)
    with pytest.raises(ValueError, match="needs a port"):
        write_scene("unused.xml", (left, right), None, grid_plane(1000.0, 80.0, 80.0), 16.0,
                    water=PRESETS["coastal"])


@pytest.mark.slow
def test_eval_run_in_coastal_water(coastal_scene, tmp_path):
    """The whole pipeline through scattering water, with the speckle-proof threshold."""
    import json

    from eval.cli import main

    out = tmp_path / "run"
    assert main(["run", coastal_scene, "--out", str(out), "--spp", "64", "--no-progress",
                 "--methods", "optical_path", "--threshold-fraction", "0.2"]) == 0
    report = json.loads((out / "report.json").read_text())
    m = report["matching"]
    assert m["wrong"] == 0 and m["visible_in_both_matched"] == m["visible_in_both"] > 0
    assert report["threshold_fraction"] == 0.2 and report["crosscheck"]["rms_px"] < 0.1
