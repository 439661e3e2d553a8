"""Sea scenes drawn from a seed: the ranges of real rigs, the placement, and the scene file read
back by Mitsuba's parser as the rig that was drawn."""

from __future__ import annotations

import numpy as np
import pytest

from measure.geometry.projection import project
from synth.rendering.water import PRESETS
from synth.scene import load_scene
from synth.scene.sea_draw import MAX_ATTENUATION_LENGTHS, SeaRanges, draw_scene
from synth.scene.sea_write import (MESH_FILE, SCENE_FILE, flat_window_half_side, floor_patch,
                                   write_sea_scene)

SMALL = (160, 128)


def test_one_seed_one_scene():
    a, b, c = (draw_scene(s, SeaRanges(size=SMALL)) for s in (11, 11, 12))
    assert a.drawn == b.drawn and a.rig == b.rig and a.seabed == b.seabed
    assert a.drawn != c.drawn


def test_per_camera_ports_come_from_the_umvs_ranges():
    for seed in range(12):
        scene = draw_scene(seed, SeaRanges(size=SMALL, ports=("per-camera",)))
        rig = scene.rig
        for view in (0, 1):
            port, camera = rig.view_port(view), rig.cameras[view]
            distance = port.distance - port.normal @ camera.center
            tilt = np.degrees(np.arccos(port.normal @ camera.R[:, 2]))
            assert 18.0 <= distance <= 25.0 and 0.4 - 1e-9 <= tilt <= 2.0 + 1e-9
            assert port.thicknesses == (5.0,) and port.indices[1] == 1.5
        baseline = np.linalg.norm(rig.right.center - rig.left.center)
        assert 100.0 <= baseline <= 360.0
        assert scene.drawn["convergence_deg"] <= 34.0


def test_the_rig_looks_at_its_floor_point_from_its_distance():
    """The rig's centre is ``distance_mm`` from the floor point it looks at, along the bisector
    of the optical axes (within the right camera's drawn misalignment, at most 0.3° about two
    axes), pitched as drawn below the horizontal (the seabed frame's z is up)."""
    for seed in range(6):
        scene = draw_scene(seed, SeaRanges(size=SMALL))
        R, t = scene.to_reference
        look = R @ np.r_[scene.drawn["look_at_mm"]] + t
        rig = scene.rig
        centre = 0.5 * (rig.left.center + rig.right.center)
        bisector = rig.left.R[:, 2] + rig.right.R[:, 2]
        bisector /= np.linalg.norm(bisector)
        assert np.linalg.norm(look - centre) == pytest.approx(scene.distance_mm, rel=1e-9)
        ahead = (look - centre) / scene.distance_mm
        assert np.degrees(np.arccos(min(ahead @ bisector, 1.0))) < 0.3
        up = R @ np.array([0.0, 0.0, 1.0])
        assert np.degrees(np.arcsin(-ahead @ up)) == pytest.approx(scene.drawn["pitch_deg"],
                                                                  abs=1e-9)


def test_turbid_water_brings_the_rig_near():
    c = PRESETS["turbid_harbor"].c_per_m / 1000.0
    for seed in range(8):
        scene = draw_scene(seed, SeaRanges(size=SMALL, waters=("turbid_harbor",)))
        assert scene.distance_mm <= max(800.0, MAX_ATTENUATION_LENGTHS / c) + 1e-9


@pytest.mark.parametrize("port", ["flat", "per-camera"])
def test_the_scene_file_reads_back_as_the_drawn_rig(tmp_path, port):
    """``load_scene`` (Mitsuba's parser) finds the drawn cameras and port in the written file,
    and the floor's mesh where the truth traces it."""
    scene = draw_scene(3, SeaRanges(size=SMALL, ports=(port,)))
    floor = write_sea_scene(str(tmp_path), scene, spp=4)
    spec = load_scene(str(tmp_path / SCENE_FILE))
    for read, drawn in zip(spec.rig.cameras, scene.rig.cameras):
        np.testing.assert_allclose(read.K, drawn.K, rtol=1e-9)
        np.testing.assert_allclose(read.R, drawn.R, atol=1e-9)
        np.testing.assert_allclose(read.t, drawn.t, atol=1e-7)
    for view in (0, 1):
        read, drawn = spec.rig.view_port(view), scene.rig.view_port(view)
        np.testing.assert_allclose(read.normal, drawn.normal, atol=1e-9)
        assert read.distance == pytest.approx(drawn.distance, abs=1e-7)
        assert read.indices == pytest.approx(drawn.indices)
    np.testing.assert_array_equal(spec.surface.vertices, floor.mesh.vertices)
    assert spec.surface.mesh_path.endswith(MESH_FILE)


def test_the_dome_scene_holds_the_drawn_domes(tmp_path):
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba()
    scene = draw_scene(4, SeaRanges(size=SMALL, ports=("dome",)))
    write_sea_scene(str(tmp_path), scene, spp=4)
    loaded = mi.load_file(str(tmp_path / SCENE_FILE))
    spheres = {s.id(): s for s in loaded.shapes() if s.id().startswith("dome_")}
    for view, camera in enumerate(("left", "right")):
        dome = scene.rig.view_port(view)
        for sphere, radius in (("inner", dome.radii[0]), ("outer", dome.radii[1])):
            box = spheres[f"dome_{camera}_{sphere}"].bbox()
            centre = 0.5 * (np.array(box.min) + np.array(box.max))
            np.testing.assert_allclose(centre, dome.center, atol=1e-3)
            assert 0.5 * (box.max[0] - box.min[0]) == pytest.approx(radius, rel=1e-5)


def test_the_floor_patch_holds_what_both_cameras_see():
    scene = draw_scene(7, SeaRanges(size=SMALL))
    lower, upper = floor_patch(scene, 100.0)
    R, t = scene.to_reference
    for view, camera in enumerate(scene.rig.cameras):
        uv = np.array([[0, 0], [159, 0], [0, 127], [159, 127], [80, 64]], float)
        water = scene.rig.trace(view, camera.rays(uv))
        o, d = (water.origins - t) @ R, water.directions @ R  # seabed frame
        s = -o[:, 2] / d[:, 2]  # the mean floor z = 0 (the slope aside)
        hit = o[:, :2] + s[:, None] * d[:, :2]
        ok = s > 0
        assert np.all((hit[ok] >= lower - 1e-6) & (hit[ok] <= upper + 1e-6)) or (
            scene.seabed.slope != (0.0, 0.0))


def test_a_shared_window_covers_every_ray():
    """Every pixel's ray crosses each interface of the shared flat port inside the window (its
    Fermat path, computed independently of the tracing that sized it)."""
    scene = draw_scene(1, SeaRanges(size=SMALL, ports=("flat",)))
    half = flat_window_half_side(scene)
    port = scene.rig.port
    points = scene.rig.trace(0, scene.rig.left.rays(np.array([[0.0, 0.0], [159.0, 127.0]])))
    far = points.origins + 3000 * points.directions
    assert np.allclose(project(scene.rig.left, port, far), [[0, 0], [159, 127]], atol=1e-6)
    for k, offset in enumerate(port.offsets):
        crossing = scene.rig.trace(0, scene.rig.left.rays(np.array([[0.0, 0.0]])),
                                   keep_interface_points=True).interface_points[k]
        assert np.linalg.norm(crossing - port.normal * offset) < half
