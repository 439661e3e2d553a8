"""Benchmarks beyond one plane of LED targets: target layouts on tilted planes, cylinders and
sphere caps, multi-layer ports, lit (diffuse) targets with lights beside the housing, and thin
lenses.

Independent checks: the layouts against their closed-form surfaces; scene files read back by
Mitsuba's parser; the lit renders' energy against Mitsuba's own ``path`` and ``volpath``
(different estimators of the same integral) and against the radiance of a diffuse disk under a
spot light; thin-lens blur against the pinhole render of the same scene."""

from __future__ import annotations

import numpy as np
import pytest

from measure import FlatPort
from measure.images.detect import detect_targets
from measure.geometry.projection import project
from synth.scene import layouts
from synth.products.crosscheck import associate_detections
from synth.rendering.render import develop_image, load_mitsuba_scene, render_view
from synth.scene.rig import paper_cameras, paper_port
from synth.scene import LIGHT_INTENSITY, LIT_TARGET_ALBEDO, light_placements, load_scene, write_scene
from synth.rendering.water import PRESETS

SMALL = (320, 268)
FOCAL = 150.0


@pytest.mark.parametrize("make", [
    lambda: layouts.tilted_plane(1000.0, (10.0, 30.0)),
    lambda: layouts.cylinder(1000.0, 400.0, 60.0, 800.0, 50.0),
    lambda: layouts.sphere_cap(1000.0, 400.0, 60.0, 50.0)])
def test_layouts_lie_on_their_surfaces_and_face_the_cameras(make):
    points, normals = make()
    assert points.shape == normals.shape and points.shape[0] > 100
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    assert np.all(normals[:, 2] < 0)  # towards the cameras
    assert points[:, 2].min() > 500.0  # well beyond the port


def test_surface_geometry_closed_form():
    points, normals = layouts.cylinder(1000.0, 400.0, 60.0, 800.0, 50.0)
    axis_x, axis_z = 0.0, 1400.0
    r = np.hypot(points[:, 0] - axis_x, points[:, 2] - axis_z)
    assert np.allclose(r, 400.0, atol=1e-9)
    # the normal is the radial direction, outwards
    radial = np.column_stack([points[:, 0] - axis_x, np.zeros(len(points)), points[:, 2] - axis_z])
    assert np.allclose(normals, radial / 400.0, atol=1e-12)
    points, normals = layouts.sphere_cap(1000.0, 400.0, 60.0, 50.0)
    assert np.allclose(points - [0, 0, 1400.0], 400.0 * normals, atol=1e-9)
    neighbours = np.linalg.norm(points[:, None] - points[None], axis=2) + np.eye(len(points)) * 1e9
    assert neighbours.min() > 0.5 * 50.0  # no two targets on top of each other
    points, normals = layouts.tilted_plane(1000.0, (0.0, 30.0))
    assert np.allclose((points - [0, 0, 1000.0]) @ normals[0], 0.0, atol=1e-9)
    assert np.allclose(normals[0], [np.sin(np.radians(-30.0)), 0.0, -np.cos(np.radians(30.0))],
                       atol=1e-12)


def test_oriented_targets_and_layered_port_round_trip(tmp_path):
    left, right = paper_cameras(SMALL, FOCAL)
    port = FlatPort([0.0, 0.0, 1.0], 100.0, (10.0, 5.0), (1.0, 1.49, 1.54, 1.33))
    points, normals = layouts.cylinder(1000.0, 400.0, 45.0, 400.0, 100.0)
    path = write_scene(tmp_path / "cyl.xml", (left, right), port, points, 5.0,
                       target_normals=normals)
    spec = load_scene(path)
    assert np.allclose(spec.targets, points, atol=1e-9)
    assert np.allclose(spec.target_normals, normals, atol=1e-6)
    assert spec.port.thicknesses == (10.0, 5.0) and spec.port.indices == (1.0, 1.49, 1.54, 1.33)
    with pytest.raises(ValueError, match="face the cameras"):
        write_scene(tmp_path / "bad.xml", (left, right), port, points, 5.0, target_normals=-normals)


@pytest.fixture(scope="module")
def lit_scenes(tmp_path_factory):
    """A small grid of large lit disks at 1 m, in clear and in coastal water."""
    left, right = paper_cameras(SMALL, FOCAL)
    targets = layouts.grid_plane(1000.0, 240.0, 80.0) + np.array([3.0, -2.0, 0.0])
    folder = tmp_path_factory.mktemp("lit")
    return {name: str(write_scene(folder / f"{name}.xml", (left, right), paper_port(), targets,
                                  16.0, lighting="lit", water=water))
            for name, water in (("clear", None), ("coastal", PRESETS["coastal"]))}


def test_lit_scene_reads_back_with_its_targets_and_lights(lit_scenes):
    spec = load_scene(lit_scenes["clear"])
    assert spec.targets.shape == (49, 3)
    assert float(spec.params["target_albedo"]) == LIT_TARGET_ALBEDO
    mscene, mi, _ = load_mitsuba_scene(spec)
    kinds = sorted(str(e).split("[")[0] for e in mscene.emitters())
    assert kinds == ["SpotLight", "SpotLight"]  # the disks do not glow


@pytest.mark.slow
def test_lit_targets_have_the_radiance_of_a_diffuse_disk_under_a_spot(lit_scenes):
    """Clear water: a disk's mean pixel value is ρ/π · Σ_lights I·cos θ / r² (spots within
    their beam width, no falloff), times the port's Fresnel transmittance T (measured against a
    render of the same scene with LED disks of radiance 1: same path, same T)."""
    spec = load_scene(lit_scenes["clear"])
    mscene, mi, _ = load_mitsuba_scene(spec)
    image = render_view(mscene, mi, 0, spec.rig.left, 64, 0)
    uv = project(spec.rig.left, spec.rig.port, spec.targets)
    lights = light_placements(spec.rig.left, spec.rig.right, spec.rig.port, spec.targets)
    irradiance = np.zeros(len(spec.targets))
    for origin, _aim in lights:
        to_light = origin - spec.targets
        r = np.linalg.norm(to_light, axis=1)
        irradiance += LIGHT_INTENSITY * (-to_light[:, 2] / r) / r ** 2  # cos to the normal -z
    expected = LIT_TARGET_ALBEDO / np.pi * irradiance
    led = write_scene(lit_scenes["clear"].replace("clear", "led"), spec.cameras, spec.rig.port,
                      spec.targets, 16.0)
    led_spec = load_scene(led)
    led_scene, _, _ = load_mitsuba_scene(led_spec)
    led_image = render_view(led_scene, mi, 0, spec.rig.left, 64, 0)
    centre = np.rint(uv).astype(int)
    inside = (centre[:, 0] > 2) & (centre[:, 0] < SMALL[0] - 3) & (centre[:, 1] > 2) \
        & (centre[:, 1] < SMALL[1] - 3)
    u, v = centre[inside, 0], centre[inside, 1]
    lit = np.array([image[y - 1:y + 2, x - 1:x + 2].mean() for x, y in zip(u, v)])
    transmit = np.array([led_image[y - 1:y + 2, x - 1:x + 2].mean() for x, y in zip(u, v)])
    ratio = lit / (expected[inside] * transmit)
    assert inside.sum() >= 20
    assert abs(np.median(ratio) - 1.0) < 0.01, np.median(ratio)


@pytest.mark.slow
@pytest.mark.parametrize("water", ["clear", "coastal"])
def test_lit_renders_agree_with_mitsubas_own_integrators(lit_scenes, water):
    """Our integrators (surface next-event estimation with MIS, refracted ray starts) against
    Mitsuba's ``path`` / ``volpath`` on the same lit scene: the image energies agree."""
    spec = load_scene(lit_scenes[water])
    mscene, mi, _ = load_mitsuba_scene(spec)
    spp = 64 if water == "clear" else 32  # Mitsuba's volpath is slow here; its spread counts
    ours = [render_view(mscene, mi, 0, spec.rig.left, spp, 10 * s).sum() for s in range(3)]
    theirs = [develop_image(mi, mi.render(mscene, sensor=0, spp=spp, seed=s)).sum() for s in range(3)]
    sem = np.sqrt(np.var(ours, ddof=1) / 3 + np.var(theirs, ddof=1) / 3)
    assert abs(np.mean(ours) - np.mean(theirs)) < 4 * sem + 2e-3 * np.mean(theirs), (ours, theirs)


@pytest.mark.slow
def test_scattering_water_shows_backscatter_between_the_targets(lit_scenes):
    """Lit targets: clear water leaves the background black; coastal water fills it with the
    veil of light scattered back from the beams."""
    backgrounds = {}
    for water in ("clear", "coastal"):
        spec = load_scene(lit_scenes[water])
        mscene, mi, _ = load_mitsuba_scene(spec)
        image = render_view(mscene, mi, 0, spec.rig.left, 32, 0)
        backgrounds[water] = float(np.median(image))
        detections = detect_targets(image)
        if water == "clear":
            index, distance = associate_detections(
                np.asarray(detections.centers).reshape(-1, 2),
                project(spec.rig.left, spec.rig.port, spec.targets))
            assert (index >= 0).sum() >= 20 and np.sqrt(np.mean(distance[index >= 0] ** 2)) < 0.1
    assert backgrounds["clear"] == 0.0
    assert backgrounds["coastal"] > 0.0


@pytest.mark.slow
def test_thin_lens_blurs_off_the_focus_plane(tmp_path):
    left, right = paper_cameras(SMALL, FOCAL)
    targets = layouts.grid_plane(1000.0, 240.0, 80.0) + np.array([3.0, -2.0, 0.0])
    sharp = write_scene(tmp_path / "pin.xml", (left, right), paper_port(), targets, 16.0)
    thin = write_scene(tmp_path / "thin.xml", (left, right), paper_port(), targets, 16.0,
                       thin_lens=(20.0, 400.0))  # focused far in front of the targets
    spec_pin, spec_thin = load_scene(sharp), load_scene(thin)
    assert np.allclose(spec_thin.rig.left.K, spec_pin.rig.left.K)
    images = []
    for spec in (spec_pin, spec_thin):
        mscene, mi, _ = load_mitsuba_scene(spec)
        images.append(render_view(mscene, mi, 0, spec.rig.left, 64, 0))
    # the same light, spread over more pixels: far fewer pixels near the sharp disks' level
    assert abs(images[1].sum() / images[0].sum() - 1.0) < 0.02
    level = 0.9 * images[0].max()
    assert (images[1] > level).sum() < 0.5 * (images[0] > level).sum()
    with pytest.raises(ValueError, match="principal point"):
        from measure import Camera

        K = left.K.copy()
        K[0, 2] += 3.0
        off = Camera(K, left.size, R=left.R, t=left.t)
        write_scene(tmp_path / "off.xml", (off, right), paper_port(), targets, 16.0,
                    thin_lens=(2.0, 800.0))


def test_thin_lens_with_distortion_is_refused(tmp_path):
    from synth.rendering.render import check_render_request

    left, right = paper_cameras(SMALL, FOCAL)
    targets = layouts.grid_plane(1000.0, 240.0, 80.0)
    thin = write_scene(tmp_path / "thin.xml", (left, right), paper_port(), targets, 16.0,
                       thin_lens=(2.0, 800.0))
    check_render_request(load_scene(thin))
    with pytest.raises(ValueError, match="thin-lens"):
        check_render_request(load_scene(thin, {"left_dist": "-0.05 0 0 0 0"}))


@pytest.mark.slow
def test_eval_run_on_a_cylinder_matches_every_target(tmp_path):
    """Targets seen obliquely (up to 60° on a cylinder): with --max-elongation for the
    foreshortened disks, every target visible in both views is detected and matched, none
    wrongly, and the detections agree with the simulator's outline centroids."""
    import json

    from eval.cli import main as eval_main
    from synth.__main__ import main as synth_main

    scene = tmp_path / "cylinder.xml"
    assert synth_main(["scene", "--out", str(scene), "--layout", "cylinder", "--size", "320",
                       "268", "--target-radius", "14", "--spacing", "110"]) == 0
    out = tmp_path / "run"
    assert eval_main(["run", str(scene), "--out", str(out), "--spp", "64", "--no-progress",
                      "--methods", "optical_path", "--max-elongation", "3"]) == 0
    report = json.loads((out / "report.json").read_text())
    m = report["matching"]
    assert m["wrong"] == 0 and m["visible_in_both_matched"] == m["visible_in_both"] == 49
    assert report["max_elongation"] == 3.0
    assert report["crosscheck"]["rms_px_outline"] < 0.03
    lo, hi = m["depth_window_mm"]
    assert 0.8 * 1000.0 - 1e-6 <= lo and hi <= 1.25 * 1400.0 + 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["cylinder", "sphere"])
def test_eval_run_with_no_options_on_oblique_layouts(tmp_path, layout):
    """Targets up to 60° oblique (elongated) and over a range of depths (different sizes):
    with no detection option every target visible in both views is matched, none wrongly —
    the merged-blob test looks for a waist, not at the elongation."""
    import json

    from eval.cli import main as eval_main
    from synth.__main__ import main as synth_main

    scene = tmp_path / f"{layout}.xml"
    assert synth_main(["scene", "--out", str(scene), "--layout", layout, "--size", "320",
                       "268", "--target-radius", "14", "--spacing", "110"]) == 0
    out = tmp_path / "run"
    assert eval_main(["run", str(scene), "--out", str(out), "--spp", "64", "--no-progress",
                      "--methods", "optical_path"]) == 0
    report = json.loads((out / "report.json").read_text())
    m = report["matching"]
    assert m["wrong"] == 0 and m["visible_in_both_matched"] == m["visible_in_both"] > 20
    assert max(d["rejected_by_reason"]["merged"] for d in report["detection"].values()) == 0
    assert report["crosscheck"]["rms_px_outline"] < 0.03


def test_median_filter_removes_a_firefly_beside_a_target():
    """A lone saturated pixel (a firefly of a light seen through scattering water) inside a
    disk's centroid window pulls its centroid; ``median_filter=3`` removes it and leaves a
    symmetric disk's centre where it was."""
    from eval.run.inputs import RunInputs
    from eval.run.pipeline import detect_stage

    yy, xx = np.mgrid[0:64, 0:80]
    disk = ((xx - 40.3) ** 2 + (yy - 31.6) ** 2 <= 5.0 ** 2).astype(np.float32)
    noisy = disk.copy()
    noisy[31, 47] = 20.0  # two pixels outside the disk's edge, inside its window
    centres = {}
    for name, image in (("clean", disk), ("firefly", noisy)):
        for k in (0, 3):
            inputs = RunInputs("synthetic", None, True, np.zeros((1, 3)), np.zeros(1), 5.0,
                               image, image, {}, "none", 1, 0.0)
            _, found = detect_stage(inputs, 0.0, median_filter=k)
            assert found["left"].shape == (1, 2)
            centres[name, k] = found["left"][0]
    # unfiltered, the firefly pulls the centroid by more than a pixel; filtered, the centroid
    # is the filtered clean disk's (the filter leaves nothing of the firefly)
    assert np.linalg.norm(centres["firefly", 0] - centres["clean", 0]) > 1.0
    np.testing.assert_allclose(centres["firefly", 3], centres["clean", 3], atol=1e-12)
