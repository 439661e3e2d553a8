"""Shared fixtures and hypothesis strategies for the geometry tests, and the ``slow`` marker.

A test that renders with Mitsuba (``mi.render``, directly or through a fixture it uses) must be
marked ``@pytest.mark.slow``; ``make test-fast`` (``pytest -m "not slow"``) runs the others. The
marker is checked, not trusted: :func:`pytest_runtest_setup` records whether the test about to
run is marked, and a render in an unmarked test fails it (:func:`_guard_renders`).
"""

from __future__ import annotations

import os
from pathlib import Path

from synth.infra.blas import one_blas_thread

# One BLAS thread per test process, set before NumPy loads OpenBLAS (and inherited by the
# commands the tests start), as the commands do: the suite runs a process per core (``-n 2``),
# and OpenBLAS's own threads, spinning while they wait, then take the cores from the other
# process — a housing fit of the real Minions rig took 41.8 s of CPU with them and 17.6 s without.
one_blas_thread()

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402

from synth.scene.rig import paper_rig  # noqa: E402

settings.register_profile("ci", deadline=None, max_examples=60,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci")


#: The repository's root (the tests live in folders mirroring the packages below it).
REPO = Path(__file__).resolve().parent.parent

#: Whether the test now being set up, run or torn down is marked ``slow``.
_CURRENT = {"slow": True, "name": ""}


class UnmarkedRender(AssertionError):
    """A test (or a fixture it uses) rendered with Mitsuba without the ``slow`` marker."""


def _guard_renders() -> None:
    """Wrap ``mitsuba.render`` (variant-independent) so that a render outside a ``slow`` test
    fails. Imports Mitsuba once per session (a second or two); without Mitsuba nothing renders
    and nothing needs guarding."""
    try:
        from synth.rendering.mitsuba_setup import import_mitsuba

        mi, _ = import_mitsuba()
    except Exception:  # no Mitsuba here: the render tests say so themselves
        return
    render = mi.render
    if getattr(render, "_slow_guard", False):
        return

    def guarded(*args, **kwargs):
        if not _CURRENT["slow"]:
            raise UnmarkedRender(f"{_CURRENT['name']} renders with Mitsuba but is not marked "
                                 f"@pytest.mark.slow (directly or through a fixture it uses)")
        return render(*args, **kwargs)

    guarded._slow_guard = True
    mi.render = guarded


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: renders with Mitsuba (left out by make test-fast)")
    if not os.environ.get("REFSTEREO_NO_RENDER_GUARD"):
        _guard_renders()


def pytest_runtest_setup(item):
    _CURRENT["slow"] = item.get_closest_marker("slow") is not None
    _CURRENT["name"] = item.nodeid


SMALL_SCENE_SIZE = (320, 268)
SMALL_SCENE_SPP = 36


@pytest.fixture(scope="session")
def small_scene(tmp_path_factory):
    """A small scene file: the paper's port, a 320x268 rig (f = 150 px), 9x9 targets of radius
    16 mm, 80 mm apart on the plane Z = 1 m."""
    from synth.scene.layouts import grid_plane
    from synth.scene.rig import paper_cameras, paper_port
    from synth.scene import write_scene

    left, right = paper_cameras(SMALL_SCENE_SIZE, 150.0)
    targets = grid_plane(1000.0, 320.0, 80.0) + np.array([3.0, -2.0, 0.0])
    path = tmp_path_factory.mktemp("scene") / "small.xml"
    return str(write_scene(path, (left, right), paper_port(), targets, 16.0, spp=SMALL_SCENE_SPP))


@pytest.fixture(scope="session")
def rig():
    """The paper's rig behind the paper's port (full-size images)."""
    return paper_rig()


@pytest.fixture(scope="session")
def air_rig():
    """The same cameras with an index-matched (all-air) port."""
    return paper_rig(in_air=True)


def rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation matrix from small angles about x, y, z (radians), R = Rz Ry Rx."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", [rz, ry, rx]).as_matrix()


def assert_mitsuba_follows(mi, scene, camera, directions, want, atol_mm: float, label="") -> None:
    """Camera rays (``directions`` ``(N, 3)`` from its centre) followed through Mitsuba's
    ``scene`` — ``ray_intersect`` and the dielectric's delta transmission, twice — cross the
    port's two interfaces where ``want`` (the port's own trace with its interface points) says
    within ``atol_mm`` (float32), leave in its water directions within 2e-6, and then hit a
    target near z = 1 m or nothing (never another camera's glass)."""
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.DeltaTransmission
    d = directions
    ray = mi.Ray3f(mi.Point3f(*(float(c) for c in camera.center)),
                   mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
    for k in range(2):
        si = scene.ray_intersect(ray)
        hit = np.array(si.p).reshape(3, -1).T
        np.testing.assert_allclose(hit, want.interface_points[k], rtol=0, atol=atol_mm)
        sample, weight = si.bsdf().sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5))
        assert np.all(np.array(weight).reshape(3, -1) > 0)
        out = si.to_world(sample.wo)
        ray = mi.Ray3f(si.p + out * 1e-3, out)
    np.testing.assert_allclose(np.array(ray.d).reshape(3, -1).T, want.directions, rtol=0,
                               atol=2e-6)
    si = scene.ray_intersect(ray)
    valid = np.array(si.is_valid()).ravel()
    assert np.all(np.array(si.p).reshape(3, -1).T[valid, 2] > 990.0), label


@pytest.fixture
def surface_scene_of_three_cameras(tmp_path) -> Path:
    """The committed speckled plane (``scenes/speckle_plane.xml``) with a third sensor added by
    hand (``cam2``, 400 mm along x; the two others renamed ``cam0``, ``cam1``), written into
    ``tmp_path`` with the files it reads: a surface scene of three cameras, which
    ``synth scene`` does not write."""
    import re
    import shutil

    scenes = REPO / "scenes"
    text = (scenes / "speckle_plane.xml").read_text()
    for name in re.findall(r'(?:filename|value)="([^"]+\.(?:ply|png))"', text):
        shutil.copy(scenes / Path(name).name, tmp_path / Path(name).name)
    third = re.findall(r"<sensor.*?</sensor>", text, re.S)[1]
    third = third.replace('id="right"', 'id="cam2"').replace('origin="200, 0, 0"',
                                                            'origin="400, 0, 0"')
    text = text.replace('id="left"', 'id="cam0"').replace('id="right"', 'id="cam1"')
    at = text.rindex("</sensor>") + len("</sensor>")
    path = tmp_path / "three.xml"
    path.write_text(text[:at] + "\n    " + third + text[at:])
    return path
