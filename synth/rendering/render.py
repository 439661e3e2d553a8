"""Render both views of a scene with Mitsuba 3: linear single-channel float32 images.

Images are in linear radiometric units of the scene (a target of radiance 1 seen in air through
no glass gives 1.0 on a fully covered pixel; through a port, ``T / n_water²`` of it). Pixel
``[v, u]`` is the box-filtered (exact pixel integral) radiance of the pixel whose centre is
``(u, v)`` in OpenCV pixel coordinates.

Lens distortion (a :class:`measure.Camera` with ``dist``): Mitsuba's sensor is a pinhole, so the
view is rendered by an undistorted pinhole camera ``oversample`` times finer and covering the
whole distorted field of view, pre-filtered with an ``oversample``-pixel box (one output pixel),
and warped with ``cv2.remap`` (bilinear) to the distorted pixel grid; the map is the exact
inverse of the OpenCV distortion (``Camera.undistort``, Newton to ~1e-16).

Adaptive rendering (the default, :func:`render_view_counted`): a pilot of
:data:`ADAPTIVE_PILOT_SPP` over the whole film, the mask of the pixels it saw light on grown by
:data:`ADAPTIVE_MARGIN_PX`, and the requested samples only on the mask (:func:`render_pixels`:
the scene's own sampler and integrator on an explicit list of pixels); a pixel off the mask
keeps its pilot. A film lit on more than :data:`ADAPTIVE_MAX_LIT_FRACTION` of its pixels is
rendered whole. ``adaptive=False`` renders the full film in passes, as below, with the seeds
and bytes of before.

Passes: a full film is rendered in as few ``mi.render`` calls as keep each call at most
:data:`MAX_SAMPLES_PER_CALL` samples, and the passes are averaged, weighted by their samples.
Large wavefronts are slower, but the sampler stratifies within one call only; the limit is the
measured balance of the two (see the constant).

Seeds: one seed, one meaning. The scene's ``seed`` parameter (``-D seed=S``, or ``--seed S``,
which sets it) is the only seed: pass ``k`` of view ``i`` (0 left, 1 right) is rendered with
``mi.render(seed=S + i + 2^21·k)`` from a scene loaded with its sampler's own seed at 0 (Mitsuba
adds the two), so ``--seed 7`` and ``-D seed=7`` render the same bytes, and a one-pass render
uses ``S + i``. An adaptive render's pilot is pass 0 and its masked calls (or the full-film
passes of a mostly lit film) passes 1, 2, …. Mitsuba's seed is 32-bit: a seed whose sums do
not fit is refused before the render (:func:`check_render_request`, :mod:`synth.infra.seeds`), never
wrapped.

Before rendering, :func:`check_render_request` refuses what cannot work: an image whose
wavefront would not fit in memory (the estimate is stated in the message) and a lens
distortion that cannot be inverted over the image.
"""

from __future__ import annotations

import math
import time

import cv2
import numpy as np

from measure import Camera

from synth.rendering.integrator import integrator_name, render_integrator
from synth.infra import interrupt
from synth.rendering.mitsuba_setup import import_mitsuba
from synth.rendering.mitsuba_setup import render as quiet_render
from synth.scene import SceneError, SceneSpec, load_scene
from synth.infra.seeds import PASS_SEED_STRIDE, SEED_LIMIT, largest_seed, render_offset
from synth.rendering.sensor import sensor_parameters

#: Oversampling factor of the undistorted render behind a distorted view.
DISTORTION_OVERSAMPLE = 2
#: Extra border (output pixels) of the undistorted render around the distorted field of view.
DISTORTION_MARGIN_PX = 3


#: Largest number of samples (spp × film pixels) one ``mi.render`` call carries. Mitsuba's JIT
#: variants trace the whole wavefront of a call at once and slow down above ~16 spp per call at
#: 2448 × 2048 (7–8 M samples/s up to 16, 5.3 at 36, 3.8 at 48), but the multijitter sampler
#: stratifies within one call only, so passes cost accuracy: at full size 36 spp in 3 passes took
#: 59 s against 68 s in one call (1.15×) but left a cross-check RMS of 0.0254 px against 0.0226;
#: 48 spp in 3 passes (72 s) matched one call of 36 (0.0229 px). Measured with
#: ``python -m eval render-bench`` (docs/architecture.md): passes pay off only above 36 spp.
MAX_SAMPLES_PER_CALL = 36 * 2448 * 2048
#: Memory per rendered pixel (bytes), about twice what was measured with ``llvm_ad_rgb`` on the
#: paper scene (peak RSS grew 32 bytes per pixel above ~190 MiB, the same at 4 and 16 spp:
#: Mitsuba splits a wavefront of more than 2^32 samples into passes itself). docs/architecture.md
BYTES_PER_PIXEL = 64

#: Adaptive rendering (:func:`render_view_counted`): samples per pixel of the pilot over the
#: whole film, the margin (film pixels) around every pixel the pilot saw light on, and the lit
#: fraction of the film above which a view is rendered on the full film instead. Measured in
#: docs/speed.md ("Adaptive rendering").
ADAPTIVE_PILOT_SPP = 1
ADAPTIVE_MARGIN_PX = 3
ADAPTIVE_MAX_LIT_FRACTION = 0.5
#: Largest number of samples of one call of the masked render (the samples of a pixel are
#: always in one call, stratified together; the call's radiance values are 4 bytes a sample).
MASKED_SAMPLES_PER_CALL = 1 << 26


def available_memory_bytes() -> int | None:
    """Memory available to this process (``MemAvailable`` of ``/proc/meminfo``), or None."""
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def render_memory_bytes(size, oversample: int = 1) -> int:
    """Estimated peak memory (bytes) of rendering one view of ``size`` (w, h) px (the render
    of a distorted camera is ``oversample`` times finer in each direction)."""
    return int(size[0]) * int(size[1]) * oversample * oversample * BYTES_PER_PIXEL


def check_render_request(spec: SceneSpec, spp: int | None = None, seed: int | None = None,
                         poses: int = 0, adaptive: bool = True) -> None:
    """Raise ``ValueError`` (one line) for a render that cannot work: a lens distortion that is
    not invertible over the image, an estimated memory need beyond what is available, or a
    ``seed`` (default: the scene's) whose pass seeds would not fit Mitsuba's 32-bit seed
    (``poses``: ``synth boards``, whose pose p renders with the seed ``seed + 2p``)."""
    spp = spec.spp if spp is None else int(spp)
    if spp <= 0:
        raise ValueError(f"spp must be positive, got {spp}")
    for name, camera in zip(spec.camera_names, spec.all_cameras):
        if camera.dist is not None:
            problem = camera.distortion_problem()
            if problem:
                raise ValueError(f"{spec.path}: {name}_dist: {problem}")
            if "aperture_radius" in spec.params:
                raise ValueError(f"{spec.path}: {name}_dist: a thin-lens camera is rendered "
                                 f"without lens distortion (set the coefficients to 0)")
    need = max(render_memory_bytes(_render_size(camera)) for camera in spec.cameras)
    have = available_memory_bytes()
    if have is not None and need > have:
        w, h = spec.size
        raise ValueError(f"{spec.path}: rendering {w}x{h} px needs about {need / 2**30:.1f} GiB "
                         f"of memory, {have / 2**30:.1f} GiB are available (use a smaller image"
                         f"{' or a milder lens distortion' if spec.cameras[0].dist is not None else ''})")
    check_render_seed(spec, spp, spec.seed if seed is None else int(seed), poses, adaptive)


def check_render_seed(spec: SceneSpec, spp: int, seed: int, poses: int = 0,
                      adaptive: bool = True) -> None:
    """ValueError (one line, stating the largest seed) unless every sampler seed of the render,
    ``seed + view + 2^21·pass`` (``synth boards``: ``+ 2·pose`` for ``poses`` poses), fits
    Mitsuba's 32-bit seed (:mod:`synth.infra.seeds`)."""
    passes = [view_passes_bound(spp, int(np.prod(_render_size(c))), adaptive)
              for c in spec.cameras]
    largest = largest_seed(render_offset(passes, 2 * max(poses - 1, 0)))
    if seed < 0 or seed > largest:
        w, h = spec.size
        plan = f"{max(passes)} passes per view" if max(passes) > 1 else "one pass per view"
        what = (f"--seed {seed} is too large: pose p of {poses} renders with seed + 2p, "
                if poses else f"{spec.path}: seed {seed} (--seed / -D seed=) is too large: ")
        limit = (f"the largest seed is {largest}" if largest >= 0 else
                 "no seed fits (use fewer samples per pixel)")
        raise ValueError(f"{what}pass k of view i {'' if poses else 'renders '}with seed + i + "
                         f"{PASS_SEED_STRIDE}*k ({plan} at "
                         f"{spp} spp, {w}x{h} px), and Mitsuba's sampler seed is 32-bit: {limit}")


def _render_size(camera: Camera) -> tuple[int, int]:
    """The film size (w, h) px Mitsuba renders for ``camera``: its own, or for a distorted
    camera the oversampled pinhole image that covers its field of view."""
    if camera.dist is None:
        return camera.size
    w, h = camera.size
    border = np.concatenate([np.stack([np.arange(w), np.zeros(w)], 1),
                             np.stack([np.arange(w), np.full(w, h - 1)], 1),
                             np.stack([np.zeros(h), np.arange(h)], 1),
                             np.stack([np.full(h, w - 1), np.arange(h)], 1)]).astype(float)
    return _ideal_extent(camera, camera.normalized(border), DISTORTION_OVERSAMPLE,
                         DISTORTION_MARGIN_PX)[1]


def _ideal_extent(camera: Camera, x: np.ndarray, oversample: int, margin: float):
    """``(K_ideal, (w, h))`` of the pinhole image covering normalized coordinates ``x``."""
    fi = camera.K[0, 0] * oversample
    lo = x.min(axis=0) * fi - margin * oversample
    hi = x.max(axis=0) * fi + margin * oversample
    size = (int(math.ceil(hi[0] - lo[0])) + 1, int(math.ceil(hi[1] - lo[1])) + 1)
    return np.array([[fi, 0.0, -lo[0]], [0.0, fi, -lo[1]], [0.0, 0.0, 1.0]]), size


def load_mitsuba_scene(spec: SceneSpec, variant: str | None = None):
    """``(mitsuba_scene, mi, variant)`` for a :class:`SceneSpec` (its resolved defaults), with
    the sampler's own seed at 0 (the seed is given to ``mi.render``; see module docs)."""
    mi, chosen = import_mitsuba(variant)
    params = spec.mitsuba_params
    if "seed" in params:
        params["seed"] = "0"
    try:
        scene = mi.load_file(spec.path, **params)
    except RuntimeError as exc:  # Mitsuba's loader: one line of its message
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        raise SceneError(f"{spec.path}: Mitsuba cannot load the scene: "
                         f"{' '.join(lines[:2])}") from None
    if len(scene.sensors()) < 2:
        raise ValueError(f"{spec.path}: Mitsuba found {len(scene.sensors())} sensors, need 2")
    return scene, mi, chosen


def _ideal_camera_for(camera: Camera, oversample: int, margin: float):
    """Pinhole (K_ideal, size_ideal) covering the distorted view, and the remap grids."""
    w, h = camera.size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    uv = np.column_stack([u.ravel(), v.ravel()])
    x = camera.normalized(uv)  # undistorted normalized coordinates of every output pixel
    if not np.all(np.isfinite(x)):
        raise ValueError(camera.distortion_problem() or
                         "the distortion model cannot be inverted over the whole image")
    K, (wi, hi_) = _ideal_extent(camera, x, oversample, margin)
    map_xy = x * K[0, 0] + K[:2, 2]
    if oversample % 2 == 0:
        map_xy += 0.5  # cv2.blur with an even box: value j is centred at j - 0.5
    map_x = map_xy[:, 0].reshape(h, w).astype(np.float32)
    map_y = map_xy[:, 1].reshape(h, w).astype(np.float32)
    return K, (wi, hi_), map_x, map_y


def _ideal_sensor(mi, template, camera: Camera, K, size):
    """A Mitsuba pinhole sensor at ``camera``'s pose with intrinsics ``K`` and film ``size``."""
    return mi.load_dict(sensor_dict(mi, camera, template.sampler(), K, size))


def sensor_dict(mi, camera: Camera, sampler, K=None, size=None) -> dict:
    """The ``mi.load_dict`` description of a pinhole sensor at ``camera``'s pose with
    intrinsics ``K`` and film ``size`` (default: the camera's own; its lens distortion is not
    part of it, see :func:`render_view`), a box-filtered luminance float32 film and ``sampler``
    (a Mitsuba sampler object or its dict)."""
    K = camera.K if K is None else K
    size = camera.size if size is None else size
    p = sensor_parameters(K, size, camera.R, camera.t)
    return {
        "type": "perspective",
        "fov": p["fov"], "fov_axis": "x",
        "principal_point_offset_x": p["principal_point_offset_x"],
        "principal_point_offset_y": p["principal_point_offset_y"],
        "near_clip": 1.0, "far_clip": 1e6,
        "to_world": mi.ScalarTransform4f(p["to_world"].tolist()),
        "sampler": sampler,
        "film": {"type": "hdrfilm", "width": int(size[0]), "height": int(size[1]),
                 "pixel_format": "luminance", "component_format": "float32",
                 "rfilter": {"type": "box"}},
    }


def develop_image(mi, image) -> np.ndarray:
    """A film that ``mi.render`` returned, as a contiguous float32 ``(H, W)`` array of its first
    channel (a luminance film has only one), linear units as rendered."""
    a = np.array(image, dtype=np.float32)
    if a.ndim == 3:
        a = a[..., 0]
    return np.ascontiguousarray(a)


def pass_plan(spp: int, film_pixels: int, max_samples: int = None) -> list[int]:
    """Samples per pixel of each ``mi.render`` call of one view: as few calls as keep every
    call at most ``max_samples`` (default :data:`MAX_SAMPLES_PER_CALL`) samples, as equal as
    possible (largest first)."""
    max_samples = MAX_SAMPLES_PER_CALL if max_samples is None else int(max_samples)
    per_call = max(1, max_samples // max(1, int(film_pixels)))
    calls = -(-int(spp) // per_call)
    base, extra = divmod(int(spp), calls)
    return [base + 1] * extra + [base] * (calls - extra)


def pass_seed(seed: int, view: int, k: int) -> int:
    """Sampler seed of pass ``k`` of view ``view`` (0 left, 1 right) for the scene seed
    ``seed``: ``seed + view + 2^21·k``. One pass is ``seed + view``, as before. ValueError when
    it does not fit Mitsuba's 32-bit seed (never wrapped: :func:`check_render_seed` refuses such
    a seed before the render)."""
    value = int(seed) + int(view) + PASS_SEED_STRIDE * int(k)
    if not 0 <= value < SEED_LIMIT:
        raise ValueError(f"sampler seed {value} (scene seed {seed}, view {view}, pass {k}) does "
                         f"not fit Mitsuba's 32-bit seed")
    return value


def _render_passes(mi, scene, sensor, spp: int, seed: int, view: int, film_pixels: int,
                   first_pass: int = 0):
    """The average of the passes of :func:`pass_plan`, weighted by the samples each took, and
    the samples per pixel taken in all (the sampler may round each pass up). Pass ``j`` is
    seeded as pass ``first_pass + j`` of the view (:func:`pass_seed`)."""
    total, weight = None, 0
    integrator = render_integrator(mi, scene)
    for k, pass_spp in enumerate(pass_plan(spp, film_pixels)):
        interrupt.check()  # a pass takes seconds to minutes: stop between them
        image = develop_image(mi, quiet_render(mi, scene, sensor=sensor, spp=pass_spp,
                                               seed=pass_seed(seed, view, first_pass + k),
                                               integrator=integrator))
        taken = _sample_count(scene, sensor, pass_spp)
        total = image.astype(np.float64) * taken if total is None else total + image * taken
        weight += taken
    return (total / weight).astype(np.float32), weight


# ---------------------------------------------------------------------------------------------
# adaptive rendering: a pilot over the whole film, the requested samples where it saw light
# ---------------------------------------------------------------------------------------------
def lit_mask(pilot: np.ndarray, margin: int) -> np.ndarray:
    """Boolean mask of the pixels of a rendered ``pilot`` film that received light (value > 0,
    NaN and inf included so that nothing odd is hidden) and of every pixel within ``margin``
    pixels of one (a square of side ``2·margin + 1``)."""
    lit = ~(pilot <= 0)
    if margin <= 0:
        return lit
    kernel = np.ones((2 * int(margin) + 1, 2 * int(margin) + 1), np.uint8)
    return cv2.dilate(lit.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT,
                      borderValue=0).astype(bool)


def masked_chunks(pixels: int, spp: int) -> list[int]:
    """Pixels of each call of the masked render of ``pixels`` pixels at ``spp`` samples each:
    as few calls as keep each at most :data:`MASKED_SAMPLES_PER_CALL` samples (largest first)."""
    if pixels <= 0:
        return []
    per_call = max(1, MASKED_SAMPLES_PER_CALL // max(1, int(spp)))
    calls = -(-int(pixels) // per_call)
    base, extra = divmod(int(pixels), calls)
    return [base + 1] * extra + [base] * (calls - extra)


def adaptive_passes_bound(spp: int, film_pixels: int) -> int:
    """The most passes (seeds) one adaptively rendered view can take: the pilot, then either
    the masked calls of a mask of at most :data:`ADAPTIVE_MAX_LIT_FRACTION` of the film or the
    full-film passes of the fallback."""
    masked = len(masked_chunks(int(film_pixels * ADAPTIVE_MAX_LIT_FRACTION) + 1, spp))
    return 1 + max(masked, len(pass_plan(spp, film_pixels)))


def view_passes_bound(spp: int, film_pixels: int, adaptive: bool = True) -> int:
    """The most passes (seeds) one view can take: :func:`adaptive_passes_bound`, or the passes
    of :func:`pass_plan` on the full film."""
    if adaptive:
        return adaptive_passes_bound(spp, film_pixels)
    return len(pass_plan(spp, film_pixels))


def _sensor_object(scene, sensor):
    return scene.sensors()[sensor] if isinstance(sensor, int) else sensor


def render_pixels(mi, scene, sensor, integrator, pixels: np.ndarray, spp: int, seed: int):
    """Render only the film pixels ``pixels`` (flat indices, row-major) of ``sensor`` with
    ``spp`` samples each through ``integrator``, as ``mi.render`` renders a pixel: a sample at
    ``pixel + sampler.next_2d()`` on the film, the sensor's ray there, the integrator's
    radiance times the ray weight, box filter (the sample counts for the pixel it falls in).
    The samples come from a fork of the sensor's own sampler (multijitter: stratified within
    each pixel) seeded with ``seed`` for a wavefront of ``len(pixels)·spp`` samples, the samples
    of a pixel consecutive. Returns ``(values, taken)``: float64 per-pixel means (luminance,
    as the film develops them) and the samples per pixel the sampler took."""
    import drjit as dr

    chosen = _sensor_object(scene, sensor)
    film = chosen.film()
    w, h = (int(x) for x in film.crop_size())
    sampler = chosen.sampler().fork()
    sampler.set_sample_count(int(spp))
    taken = int(sampler.sample_count())
    n = int(len(pixels))
    sampler.set_samples_per_wavefront(taken)
    sampler.seed(int(seed), n * taken)
    index = dr.arange(mi.UInt32, n * taken) // taken
    flat = dr.gather(mi.UInt32, mi.UInt32(np.ascontiguousarray(pixels, dtype=np.uint32)), index)
    position = mi.Point2f(mi.Float(flat % w), mi.Float(flat // w)) + sampler.next_2d()
    aperture = sampler.next_2d() if chosen.needs_aperture_sample() else mi.Point2f(0.5)
    time_ = chosen.shutter_open()
    if chosen.shutter_open_time() > 0:
        time_ = time_ + sampler.next_1d() * chosen.shutter_open_time()
    wavelength = sampler.next_1d() if mi.is_spectral else 0.0
    ray, ray_weight = chosen.sample_ray_differential(time_, wavelength,
                                                     position / mi.ScalarVector2f(w, h),
                                                     aperture)
    if ray.has_differentials:  # as mi.render does
        ray.scale_differential(1.0 / math.sqrt(taken))
    result = integrator.sample(scene, sampler, ray, chosen.get_medium(), True)
    value = mi.luminance(result[0] * ray_weight) if not mi.is_monochromatic \
        else (result[0] * ray_weight)[0]
    sums = dr.block_sum(value, taken)
    dr.eval(sums)
    return np.array(sums, dtype=np.float64) / taken, taken


def render_pilot(mi, scene, sensor, seed: int, view: int, integrator=None):
    """The pilot of an adaptive render (pass 0 of the view): ``(image, spp taken)``, the whole
    film at :data:`ADAPTIVE_PILOT_SPP`."""
    interrupt.check()
    integrator = render_integrator(mi, scene) if integrator is None else integrator
    pilot = develop_image(mi, quiet_render(mi, scene, sensor=sensor, spp=ADAPTIVE_PILOT_SPP,
                                           seed=pass_seed(seed, view, 0),
                                           integrator=integrator))
    return pilot, _sample_count(scene, sensor, ADAPTIVE_PILOT_SPP)


def _render_adaptive(mi, scene, sensor, spp: int, seed: int, view: int, size, margin: int):
    """One film rendered adaptively (see :func:`render_view_counted`): ``(image, taken,
    stats)``."""
    w, h = size
    film_pixels = w * h
    integrator = render_integrator(mi, scene)
    t = time.perf_counter()
    pilot, pilot_taken = render_pilot(mi, scene, sensor, seed, view, integrator)
    mask = lit_mask(pilot, margin)
    count = int(mask.sum())
    stats = {"mode": "adaptive", "pilot_spp": int(pilot_taken), "margin_px": int(margin),
             "film_pixels": int(film_pixels), "lit_pixels_pilot": int(np.count_nonzero(pilot > 0)),
             "mask_pixels": count, "lit_fraction": count / film_pixels,
             "seconds_pilot": time.perf_counter() - t}
    if count > ADAPTIVE_MAX_LIT_FRACTION * film_pixels:
        # most of the film is lit (surfaces, scattering water): the full film, and the pilot
        # is not used (its samples would not change the estimate's expectation, only its cost)
        image, taken = _render_passes(mi, scene, sensor, spp, seed, view, film_pixels,
                                      first_pass=1)
        stats.update(mode="full film", reason=f"lit fraction {count / film_pixels:.3f} > "
                     f"{ADAPTIVE_MAX_LIT_FRACTION}", samples_on_mask=count * taken,
                     samples_off_mask=(film_pixels - count) * taken,
                     samples=film_pixels * (taken + pilot_taken), spp_on_mask=taken,
                     spp_off_mask=taken, passes=[int(pilot_taken)] +
                     pass_plan(spp, film_pixels))
        return image, taken, stats
    image = pilot.astype(np.float32, copy=True)
    flat = np.flatnonzero(mask.ravel())
    taken, start = int(spp), 0
    chunks = masked_chunks(count, spp)
    for k, n in enumerate(chunks):
        interrupt.check()
        values, taken = render_pixels(mi, scene, sensor, integrator, flat[start:start + n],
                                       spp, pass_seed(seed, view, 1 + k))
        image.ravel()[flat[start:start + n]] = values.astype(np.float32)
        start += n
    stats.update(samples_on_mask=count * taken,
                 samples_off_mask=(film_pixels - count) * int(pilot_taken),
                 samples=film_pixels * int(pilot_taken) + count * taken,
                 spp_on_mask=taken, spp_off_mask=int(pilot_taken),
                 passes=[int(pilot_taken)] + [taken] * len(chunks))
    return image, taken, stats


def _sample_count(scene, sensor, requested: int) -> int:
    """Samples per pixel the sampler really took (multijitter rounds to a near-square)."""
    try:
        chosen = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
        return int(chosen.sampler().sample_count())
    except (AttributeError, RuntimeError, TypeError, IndexError):
        return int(requested)


def render_view(scene, mi, index: int, camera: Camera, spp: int, seed: int,
                oversample: int = DISTORTION_OVERSAMPLE, adaptive: bool = True) -> np.ndarray:
    """One view as a float32 ``(H, W)`` linear image (:func:`render_view_counted`). ``seed`` is
    the scene seed."""
    return render_view_counted(scene, mi, index, camera, spp, seed, oversample, adaptive)[0]


def adaptive_possible(mi, sensor=None) -> tuple[bool, str]:
    """Whether the Mitsuba variant can render a list of pixels (a JIT RGB or monochrome variant:
    ``llvm_*``, ``cuda_*``; spectral ones develop their films otherwise) of ``sensor``'s film
    (a film without a crop window), and why not."""
    if mi.variant().startswith("scalar"):
        return False, f"{mi.variant()} renders one ray at a time: the full film"
    if mi.is_spectral:
        return False, f"{mi.variant()} is spectral: the full film"
    if sensor is not None:
        film = sensor.film()
        if list(film.crop_offset()) != [0, 0] or list(film.crop_size()) != list(film.size()):
            return False, "the film has a crop window: the full film"
    return True, ""


def render_view_counted(scene, mi, index: int, camera: Camera, spp: int, seed: int,
                        oversample: int = DISTORTION_OVERSAMPLE, adaptive: bool = True):
    """:func:`render_view`, the samples per pixel a lit pixel took, and a dict that says how the
    view was rendered.

    ``adaptive`` (the default): a pilot of :data:`ADAPTIVE_PILOT_SPP` over the whole film (pass
    0), the pixels it saw light on dilated by :data:`ADAPTIVE_MARGIN_PX` (the mask,
    :func:`lit_mask`), and ``spp`` new samples on each pixel of the mask only (passes 1, 2, …:
    :func:`masked_chunks`); a pixel of the mask is the average of its new samples, a pixel off
    it keeps its pilot. Where the mask is more than :data:`ADAPTIVE_MAX_LIT_FRACTION` of the
    film (surfaces, scattering water) the view is rendered on the full film (passes 1, 2, …)
    and the pilot is not used. ``adaptive=False``: the full film in passes (:func:`pass_plan`,
    passes 0, 1, …), as before. A distorted camera's mask is on its oversampled pinhole film
    (margin × ``oversample``)."""
    if camera.dist is None:
        sensor, size, remap = index, camera.size, None
    else:
        K, size, map_x, map_y = _ideal_camera_for(camera, oversample, DISTORTION_MARGIN_PX)
        sensor, remap = _ideal_sensor(mi, scene.sensors()[index], camera, K, size), (map_x, map_y)
    possible, why = adaptive_possible(mi, _sensor_object(scene, sensor))
    film_pixels = int(size[0]) * int(size[1])
    if adaptive and possible:
        margin = ADAPTIVE_MARGIN_PX * (1 if remap is None else oversample)
        image, taken, stats = _render_adaptive(mi, scene, sensor, spp, seed, index, size, margin)
    else:
        image, taken = _render_passes(mi, scene, sensor, spp, seed, index, film_pixels)
        stats = {"mode": "full film", "reason": why if adaptive else "requested",
                 "film_pixels": film_pixels, "mask_pixels": film_pixels, "lit_fraction": None,
                 "samples_on_mask": film_pixels * taken, "samples_off_mask": 0,
                 "samples": film_pixels * taken, "spp_on_mask": taken, "spp_off_mask": taken,
                 "passes": pass_plan(spp, film_pixels)}
    if remap is None:
        return image, taken, stats
    if oversample > 1:
        image = cv2.blur(image, (oversample, oversample), borderType=cv2.BORDER_CONSTANT)
    return cv2.remap(image, remap[0], remap[1], interpolation=cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0.0), taken, stats


def render_stereo(scene, spp: int | None = None, variant: str | None = None,
                  defines: dict | None = None, progress: bool = True, seed: int | None = None,
                  adaptive: bool = True):
    """Render the left and right views of a scene.

    ``scene`` a :class:`SceneSpec` or a path (then ``defines`` are the ``-D`` overrides);
    ``spp`` samples per pixel of a lit pixel (default: the scene's ``spp``); ``variant`` a
    Mitsuba variant (default: automatic, see :mod:`synth.rendering.mitsuba_setup`); ``seed`` (default:
    the scene's); ``adaptive`` (default) renders each view adaptively, False on the full film
    (:func:`render_view_counted`).
    Returns ``(left, right, info)``: float32 ``(H, W)`` linear images and a dict with
    ``variant``, ``spp`` (requested), ``spp_rendered`` (a lit pixel's samples, after the
    sampler's rounding), ``seed``, ``size``, ``seconds`` (load, left, right),
    ``samples_per_second`` (every sample taken, pilot included), ``passes`` (spp of each pass,
    per view) and ``render`` (per view: ``mode`` "adaptive" or "full film" and why,
    ``lit_fraction`` of the film in the mask, samples on and off the mask, ...).
    """
    images, info = render_views(scene, spp, variant, defines, progress, seed, adaptive,
                                all_views=False)
    return images[0], images[1], info


def render_views(scene, spp: int | None = None, variant: str | None = None,
                 defines: dict | None = None, progress: bool = True, seed: int | None = None,
                 adaptive: bool = True, all_views: bool = True):
    """:func:`render_stereo` of every camera of the scene (``all_views``; False: the first
    two, ``left`` and ``right``): ``(images, info)``, one float32 image per camera in the
    order of :attr:`SceneSpec.all_cameras`, the ``info`` keyed by
    :attr:`SceneSpec.camera_names` (view k is rendered with the sampler seeds of
    :func:`pass_seed` for view k)."""
    from tqdm import tqdm

    spec = scene if isinstance(scene, SceneSpec) else load_scene(scene, defines)
    spp = spec.spp if spp is None else int(spp)
    seed = spec.seed if seed is None else int(seed)
    check_render_request(spec, spp, seed, adaptive=adaptive)
    t0 = time.perf_counter()
    mscene, mi, chosen = load_mitsuba_scene(spec, variant)
    seconds = {"load": time.perf_counter() - t0}
    images = []
    cameras = spec.all_cameras if all_views else spec.cameras
    names = spec.camera_names if all_views else ("left", "right")
    bar = tqdm(names, desc=f"render {chosen} {spp} spp{' adaptive' if adaptive else ''}",
               unit="view", disable=not progress, leave=False)
    speeds, taken, stats = {}, {}, {}
    for i, (name, camera) in enumerate(zip(bar, cameras)):
        t = time.perf_counter()
        image, taken[name], stats[name] = render_view_counted(mscene, mi, i, camera, spp, seed,
                                                              adaptive=adaptive)
        images.append(image)
        seconds[name] = time.perf_counter() - t
        speeds[name] = stats[name]["samples"] / seconds[name]
        stats[name]["seconds"] = seconds[name]
        stats[name]["samples_per_second"] = speeds[name]
        bar.set_postfix_str(f"{name} {render_summary(stats[name])}")
    bar.close()
    # Samplers may round each pass up (multijitter: to a product of two near-equal integers).
    spp_rendered = int(taken[names[0]])
    samples = sum(stats[name]["samples"] for name in names)
    w, h = spec.size
    render_seconds = sum(seconds[name] for name in names)
    info = {"variant": chosen, "integrator": integrator_name(mi, mscene), "spp": spp,
            "spp_rendered": spp_rendered, "seed": seed,
            "size": [w, h], "seconds": seconds,
            "passes": {name: stats[name]["passes"] for name in names},
            "samples_per_second": samples / render_seconds if render_seconds > 0 else None,
            "samples_per_second_per_view": speeds,
            "render": {"adaptive": bool(adaptive), **stats}}
    return images, info


def spp_text(requested, rendered=None) -> str:
    """``"5 spp"``, or when the sampler took another count ``"6 spp (5 requested: …)"``: what
    was rendered, said (the scenes' multijitter sampler rounds 5, 7, 10, 13 … up to a product of
    two near-equal integers)."""
    if rendered is None or int(rendered) == int(requested):
        return f"{requested} spp"
    return (f"{rendered} spp ({requested} requested: Mitsuba's sampler rounds the count up to "
            f"what it stratifies)")


def render_summary(stats: dict) -> str:
    """One line on how a view was rendered (a ``render`` entry of :func:`render_stereo`)."""
    speed = stats.get("samples_per_second")
    tail = f", {speed / 1e6:.1f} M samples/s" if speed else ""
    if stats["mode"] != "adaptive":
        lit = stats.get("lit_fraction")
        return (f"full film ({stats.get('reason')}{'' if lit is None else f', lit {lit:.1%}'}): "
                f"{stats['spp_on_mask']} spp{tail}")
    return (f"adaptive: lit {stats['lit_fraction']:.2%} of the film, {stats['spp_on_mask']} spp "
            f"on it ({stats['samples_on_mask'] / 1e6:.1f} M samples), pilot "
            f"{stats['spp_off_mask']} spp off it ({stats['samples_off_mask'] / 1e6:.1f} M)"
            f"{tail}")
