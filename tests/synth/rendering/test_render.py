"""Rendering: the Mitsuba sensor reproduces measure.Camera; distortion by render + warp."""

from __future__ import annotations

import numpy as np
import pytest

from measure import Camera
from measure.images.detect import detect_targets
from synth.scene.layouts import grid_plane
from measure.geometry.projection import project
from synth.rendering.image_files import png16_scale, srgb_preview, to_png16
from synth.rendering.render import render_stereo
from synth.scene.rig import paper_cameras
from synth.scene import load_scene, write_scene

SMALL = (320, 268)
FOCAL = 150.0


def _match(detected, expected):
    d = np.linalg.norm(detected[:, None, :] - expected[None, :, :], axis=2)
    j = d.argmin(axis=1)
    return detected - expected[j], j


def test_variant_selection_never_picks_llvm_15(monkeypatch, tmp_path):
    from synth.rendering import mitsuba_setup as ms

    assert ms.llvm_major_from_name("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert ms.llvm_major_from_name("libLLVM.so.19.1") == 19
    fake = tmp_path / "libLLVM-15.so"
    fake.write_bytes(b"")
    monkeypatch.setattr(ms, "_LLVM_DIRS", (str(tmp_path),))
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(fake))
    assert ms.find_libllvm() is None
    good = tmp_path / "libLLVM-19.so"
    good.write_bytes(b"")
    assert ms.find_libllvm() == str(good)


@pytest.mark.slow
def test_sensor_matches_camera_pinhole_in_air(tmp_path):
    """Disks of ~4 px radius in air, off-centre principal point: centroid within 0.02 px of K·X."""
    left, right = paper_cameras(SMALL, FOCAL)
    K = left.K.copy()
    K[0, 2] += 6.3   # principal point away from the image centre
    K[1, 2] -= 4.7
    left = Camera(K, SMALL)
    targets = grid_plane(1000.0, 420.0, 70.0) + np.array([0.37, -0.21, 0.0])
    spec = load_scene(write_scene(tmp_path / "air.xml", (left, right), None, targets, 28.0))
    img, _, info = render_stereo(spec, spp=256, progress=False)
    assert img.dtype == np.float32 and img.shape == (SMALL[1], SMALL[0])
    expected = left.project(targets)
    inside = left.in_image(expected, margin_px=8)
    det = detect_targets(img)
    assert det.n_found == inside.sum()
    err, j = _match(det.centers, expected)
    assert set(j) == set(np.flatnonzero(inside))
    assert np.abs(err).max() <= 0.02, np.abs(err).max()
    assert info["variant"] in ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")


@pytest.mark.slow
def test_distorted_camera_centroids_follow_synth_project(tmp_path):
    dist = (-0.08, 0.015, 0.0008, -0.0005, 0.0)
    left, right = paper_cameras(SMALL, FOCAL, dist=dist)
    targets = grid_plane(1000.0, 560.0, 80.0)
    spec = load_scene(write_scene(tmp_path / "d.xml", (left, right), None, targets, 16.0))
    images = render_stereo(spec, spp=64, progress=False)[:2]
    for img, cam in zip(images, spec.cameras):
        expected = project(cam, spec.rig.port, targets)
        assert np.allclose(expected, cam.project(targets), atol=1e-6)  # air: pinhole + dist
        det = detect_targets(img)
        inside = cam.in_image(expected, margin_px=8)
        err, j = _match(det.centers, expected)
        assert det.n_found >= inside.sum() and set(np.flatnonzero(inside)) <= set(j)
        ok = np.isin(j, np.flatnonzero(inside))
        dist_px = np.linalg.norm(err[ok], axis=1)
        assert dist_px.max() <= 0.05, dist_px.max()
        # the distortion is large enough to matter: the ideal pinhole is pixels away
        ideal = Camera(cam.K, cam.size, R=cam.R, t=cam.t).project(targets)
        assert np.abs(ideal - expected)[inside].max() > 2.0


def test_image_encodings():
    img = np.array([[0.0, 0.25], [0.5, 1.0]], dtype=np.float32)
    scale = png16_scale(img, img * 0.5)
    png = to_png16(img, scale)
    assert png.dtype == np.uint16 and png.max() == 65535 and png[0, 1] == round(0.25 * 65535)
    prev = srgb_preview(img)
    assert prev.dtype == np.uint8 and prev[1, 1] == 255 and prev[1, 0] == 188  # sRGB(0.5)


def test_pass_plan():
    from synth.rendering.render import MAX_SAMPLES_PER_CALL, pass_plan

    assert pass_plan(36, 2448 * 2048) == [36]
    assert pass_plan(64, 2448 * 2048) == [32, 32]
    assert pass_plan(36, 320 * 268) == [36]
    assert pass_plan(7, 100, max_samples=300) == [3, 2, 2]
    for spp, pixels in ((1, 10), (64, 2448 * 2048), (100, 5000 * 4000), (5, 10 ** 9)):
        plan = pass_plan(spp, pixels)
        assert sum(plan) == spp and max(plan) - min(plan) <= 1
        assert max(plan) * pixels <= MAX_SAMPLES_PER_CALL or max(plan) == 1


def test_seeds_that_do_not_fit_mitsubas_32_bit_seed_are_refused_not_wrapped(small_scene):
    """Seeds used to wrap at 2^32 (``--seed 4294967296`` rendered the bytes of seed 0): the
    largest accepted seed leaves room for the offsets of the views, passes and board poses."""
    from synth.rendering.render import check_render_request, pass_seed
    from synth.scene import SceneError
    from synth.infra.seeds import MAX_SEED, PASS_SEED_STRIDE

    assert MAX_SEED == 2 ** 32 - 2 and pass_seed(MAX_SEED, 1, 0) == 2 ** 32 - 1
    with pytest.raises(ValueError, match="32-bit"):
        pass_seed(MAX_SEED + 1, 1, 0)
    with pytest.raises(ValueError, match="32-bit"):
        pass_seed(2 ** 32 - 1 - PASS_SEED_STRIDE, 1, 1)
    spec = load_scene(small_scene)  # 320 x 268: one pass per view up to 2104 spp
    check_render_request(spec, 36, seed=MAX_SEED, adaptive=False)
    largest = 2 ** 32 - 1 - (1 + PASS_SEED_STRIDE)  # two passes: the right view's second
    check_render_request(spec, 3000, seed=largest, adaptive=False)
    with pytest.raises(ValueError, match=f"the largest seed is {largest}"):
        check_render_request(spec, 3000, seed=largest + 1, adaptive=False)
    # adaptive: the pilot (pass 0), then two masked calls or two full-film passes at most
    largest = 2 ** 32 - 1 - (1 + 2 * PASS_SEED_STRIDE)
    check_render_request(spec, 3000, seed=largest)
    with pytest.raises(ValueError, match=f"the largest seed is {largest}"):
        check_render_request(spec, 3000, seed=largest + 1)
    with pytest.raises(ValueError, match=f"the largest seed is {2 ** 32 - 1 - 1 - 2 * 14}"):
        check_render_request(spec, 16, seed=MAX_SEED - 27, poses=15, adaptive=False)
    check_render_request(spec, 16, seed=MAX_SEED - 28, poses=15, adaptive=False)
    with pytest.raises(ValueError, match="no seed fits"):  # more than 2048 passes per view
        check_render_request(spec, 2105 * 2049, seed=0)
    # the scene's own parameter, however it is set
    with pytest.raises(SceneError, match="4294967294"):
        load_scene(small_scene, {"seed": str(2 ** 32)})
    assert load_scene(small_scene, {"seed": str(MAX_SEED)}).seed == MAX_SEED


@pytest.mark.slow
def test_passes_are_reproducible_and_seeded_per_pass(small_scene, monkeypatch):
    """Same seed, same bytes with several passes; the passes are independent draws."""
    import synth.rendering.render as render

    spec = load_scene(small_scene)
    monkeypatch.setattr(render, "MAX_SAMPLES_PER_CALL", 4 * SMALL[0] * SMALL[1])
    a = render.render_stereo(spec, spp=8, progress=False, adaptive=False)
    b = render.render_stereo(spec, spp=8, progress=False, adaptive=False)
    assert a[2]["passes"]["left"] == [4, 4]
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    monkeypatch.setattr(render, "MAX_SAMPLES_PER_CALL", 8 * SMALL[0] * SMALL[1])
    one = render.render_stereo(spec, spp=8, progress=False, adaptive=False)
    assert one[2]["passes"]["left"] == [8] and not np.array_equal(one[0], a[0])
    # both estimate the same image: their difference is Monte-Carlo noise of zero mean
    assert abs(float(np.mean(one[0] - a[0]))) < 0.02 * float(np.mean(one[0]))
    assert a[2]["samples_per_second_per_view"]["left"] > 0


# ---------------------------------------------------------------------------------------------
# adaptive rendering
# ---------------------------------------------------------------------------------------------
TINY = (96, 80)


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    """A 96 x 80 px rig behind the paper's port and 3 x 3 disks of radius 30 mm at 1 m (about a
    fifth of the film lit once the margin is added)."""
    from synth.scene.rig import paper_port

    left, right = paper_cameras(TINY, 45.0)
    targets = grid_plane(1000.0, 240.0, 120.0) + np.array([3.0, -2.0, 0.0])
    path = tmp_path_factory.mktemp("tiny") / "tiny.xml"
    return str(write_scene(path, (left, right), paper_port(), targets, 30.0, spp=16))


@pytest.mark.slow
def test_adaptive_render_is_unbiased_and_its_mask_misses_no_lit_pixel(tiny_scene):
    """32 adaptive renders (16 spp on the mask) with different seeds: every pixel's mean agrees
    with a 1024-spp full-film render within 5 standard errors (the larger of the measured one
    and the bound Var ≤ mean · largest sample of a non-negative estimate, which covers pixels
    that only rare paths light), the image energies agree, and the mask of every pilot holds
    every pixel the full-film render shows lit."""
    from synth.rendering import render as R

    spec = load_scene(tiny_scene)
    scene, mi, _ = R.load_mitsuba_scene(spec)
    camera = spec.cameras[0]
    ref = R.render_view(scene, mi, 0, camera, 1024, 99991, adaptive=False).astype(np.float64)
    images, lit_ref = [], ref > 0
    for k in range(32):
        seed = 1000 + 7 * k
        image, taken, stats = R.render_view_counted(scene, mi, 0, camera, 16, seed)
        assert stats["mode"] == "adaptive" and taken == 16 and stats["passes"] == [1, 16]
        pilot, _ = R.render_pilot(mi, scene, 0, seed, 0)
        mask = R.lit_mask(pilot, R.ADAPTIVE_MARGIN_PX)
        assert stats["mask_pixels"] == int(mask.sum()) < 0.3 * TINY[0] * TINY[1]
        assert not np.any(lit_ref & ~mask), f"seed {seed}: the mask misses lit pixels"
        assert np.array_equal(image[~mask], pilot[~mask])  # off the mask: the pilot
        images.append(image)
    a = np.array(images, dtype=np.float64)
    mean, n = a.mean(axis=0), a.shape[0] * 16
    se = a.std(axis=0, ddof=1) / np.sqrt(a.shape[0])
    bound = np.sqrt(ref * 0.6 * (1.0 / n + 1.0 / 1024))  # a sample is at most ~0.55 here
    tol = 5 * np.maximum(se * np.sqrt(1 + n / 1024), bound) + 1e-9
    worst = np.unravel_index(np.argmax(np.abs(mean - ref) / tol), ref.shape)
    assert np.all(np.abs(mean - ref) <= tol), (worst, mean[worst], ref[worst], tol[worst])
    energy_se = np.sqrt(np.sum(se ** 2) * (1 + n / 1024))
    assert abs(mean.sum() - ref.sum()) < 5 * energy_se


@pytest.mark.slow
def test_adaptive_render_same_seed_same_bytes(tiny_scene):
    """Both views, twice with one seed: the same bytes; another seed: other bytes. The info says
    how each view was rendered."""
    spec = load_scene(tiny_scene)
    a = render_stereo(spec, spp=9, seed=5, progress=False)
    b = render_stereo(spec, spp=9, seed=5, progress=False)
    c = render_stereo(spec, spp=9, seed=6, progress=False)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])
    left = a[2]["render"]["left"]
    assert a[2]["render"]["adaptive"] and left["mode"] == "adaptive"
    assert 0 < left["lit_fraction"] < 0.5 and left["spp_on_mask"] == 9
    assert left["samples"] == left["samples_on_mask"] + TINY[0] * TINY[1]
    assert left["samples_off_mask"] == TINY[0] * TINY[1] - left["mask_pixels"]
    assert a[2]["passes"]["left"] == [1, 9]


@pytest.mark.slow
def test_adaptive_render_falls_back_to_the_full_film_where_most_is_lit(tiny_scene, monkeypatch):
    """A view whose mask covers more than ADAPTIVE_MAX_LIT_FRACTION of the film is rendered on
    the full film (here with the threshold lowered), and says so."""
    import synth.rendering.render as R

    monkeypatch.setattr(R, "ADAPTIVE_MAX_LIT_FRACTION", 0.05)
    spec = load_scene(tiny_scene)
    left, _, info = render_stereo(spec, spp=4, progress=False)
    stats = info["render"]["left"]
    assert stats["mode"] == "full film" and "lit fraction" in stats["reason"]
    assert stats["passes"] == [1, 4] and stats["samples_off_mask"] > 0
    full = R.render_stereo(spec, spp=4, progress=False, adaptive=False)[0]
    assert abs(float(left.sum()) - float(full.sum())) < 0.05 * float(full.sum())


def test_spp_text_says_what_was_rendered():
    from synth.rendering.render import spp_text

    assert spp_text(4, 4) == spp_text(4) == "4 spp"
    assert spp_text(5, 6).startswith("6 spp (5 requested: Mitsuba's sampler rounds")


@pytest.mark.slow
def test_mitsubas_log_goes_to_stderr(capfd):
    """Mitsuba's warnings (the sampler's rounding of 5 spp to 6) reach stderr, not stdout."""
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, _ = import_mitsuba()
    sampler = mi.load_dict({"type": "multijitter", "sample_count": 5})
    assert sampler.sample_count() == 6
    captured = capfd.readouterr()
    assert "rounded up to 6" in captured.err and "rounded" not in captured.out
