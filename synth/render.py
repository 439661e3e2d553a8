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

Passes: a view is rendered in as few ``mi.render`` calls as keep each call at most
:data:`MAX_SAMPLES_PER_CALL` samples, and the passes are averaged, weighted by their samples.
Large wavefronts are slower, but the sampler stratifies within one call only; the limit is the
measured balance of the two (see the constant).

Seeds: one seed, one meaning. The scene's ``seed`` parameter (``-D seed=S``, or ``--seed S``,
which sets it) is the only seed: pass ``k`` of view ``i`` (0 left, 1 right) is rendered with
``mi.render(seed=S + i + 2^21·k)`` from a scene loaded with its sampler's own seed at 0 (Mitsuba
adds the two), so ``--seed 7`` and ``-D seed=7`` render the same bytes, and a one-pass render
uses ``S + i``. Mitsuba's seed is 32-bit: a seed whose sums do not fit is refused before the
render (:func:`check_render_request`, :mod:`synth.seeds`), never wrapped.

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

from synth.integrator import integrator_name, render_integrator
from synth import interrupt
from synth.mitsuba_setup import import_mitsuba
from synth.mitsuba_setup import render as quiet_render
from synth.scene import SceneError, SceneSpec, load_scene
from synth.seeds import PASS_SEED_STRIDE, SEED_LIMIT, largest_seed, render_offset
from synth.sensor import sensor_parameters

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
                         poses: int = 0) -> None:
    """Raise ``ValueError`` (one line) for a render that cannot work: a lens distortion that is
    not invertible over the image, an estimated memory need beyond what is available, or a
    ``seed`` (default: the scene's) whose pass seeds would not fit Mitsuba's 32-bit seed
    (``poses``: ``synth boards``, whose pose p renders with the seed ``seed + 2p``)."""
    spp = spec.spp if spp is None else int(spp)
    if spp <= 0:
        raise ValueError(f"spp must be positive, got {spp}")
    for name, camera in zip(("left", "right"), spec.cameras):
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
    check_render_seed(spec, spp, spec.seed if seed is None else int(seed), poses)


def check_render_seed(spec: SceneSpec, spp: int, seed: int, poses: int = 0) -> None:
    """ValueError (one line, stating the largest seed) unless every sampler seed of the render,
    ``seed + view + 2^21·pass`` (``synth boards``: ``+ 2·pose`` for ``poses`` poses), fits
    Mitsuba's 32-bit seed (:mod:`synth.seeds`)."""
    passes = [len(pass_plan(spp, int(np.prod(_render_size(c))))) for c in spec.cameras]
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


def _render_passes(mi, scene, sensor, spp: int, seed: int, view: int, film_pixels: int):
    """The average of the passes of :func:`pass_plan`, weighted by the samples each took, and
    the samples per pixel taken in all (the sampler may round each pass up)."""
    total, weight = None, 0
    integrator = render_integrator(mi, scene)
    for k, pass_spp in enumerate(pass_plan(spp, film_pixels)):
        interrupt.check()  # a pass takes seconds to minutes: stop between them
        image = develop_image(mi, quiet_render(mi, scene, sensor=sensor, spp=pass_spp,
                                               seed=pass_seed(seed, view, k),
                                               integrator=integrator))
        taken = _sample_count(scene, sensor, pass_spp)
        total = image.astype(np.float64) * taken if total is None else total + image * taken
        weight += taken
    return (total / weight).astype(np.float32), weight


def _sample_count(scene, sensor, requested: int) -> int:
    """Samples per pixel the sampler really took (multijitter rounds to a near-square)."""
    try:
        chosen = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
        return int(chosen.sampler().sample_count())
    except (AttributeError, RuntimeError, TypeError, IndexError):
        return int(requested)


def render_view(scene, mi, index: int, camera: Camera, spp: int, seed: int,
                oversample: int = DISTORTION_OVERSAMPLE) -> np.ndarray:
    """One view as a float32 ``(H, W)`` linear image, rendered in passes (:func:`pass_plan`);
    distortion by oversampled render + warp. ``seed`` is the scene seed."""
    return render_view_counted(scene, mi, index, camera, spp, seed, oversample)[0]


def render_view_counted(scene, mi, index: int, camera: Camera, spp: int, seed: int,
                        oversample: int = DISTORTION_OVERSAMPLE):
    """:func:`render_view` and the samples per pixel the sampler took in all its passes."""
    if camera.dist is None:
        w, h = camera.size
        return _render_passes(mi, scene, index, spp, seed, index, w * h)
    K, size, map_x, map_y = _ideal_camera_for(camera, oversample, DISTORTION_MARGIN_PX)
    sensor = _ideal_sensor(mi, scene.sensors()[index], camera, K, size)
    ideal, taken = _render_passes(mi, scene, sensor, spp, seed, index, size[0] * size[1])
    if oversample > 1:
        ideal = cv2.blur(ideal, (oversample, oversample), borderType=cv2.BORDER_CONSTANT)
    return cv2.remap(ideal, map_x, map_y, interpolation=cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0.0), taken


def render_stereo(scene, spp: int | None = None, variant: str | None = None,
                  defines: dict | None = None, progress: bool = True, seed: int | None = None):
    """Render the left and right views of a scene.

    ``scene`` a :class:`SceneSpec` or a path (then ``defines`` are the ``-D`` overrides);
    ``spp`` samples per pixel (default: the scene's ``spp``); ``variant`` a Mitsuba variant
    (default: automatic, see :mod:`synth.mitsuba_setup`); ``seed`` (default: the scene's).
    Returns ``(left, right, info)``: float32 ``(H, W)`` linear images and a dict with
    ``variant``, ``spp`` (requested), ``spp_rendered`` (after the sampler's rounding), ``seed``,
    ``size``, ``seconds`` (load, left, right), ``samples_per_second``.
    """
    from tqdm import tqdm

    spec = scene if isinstance(scene, SceneSpec) else load_scene(scene, defines)
    spp = spec.spp if spp is None else int(spp)
    seed = spec.seed if seed is None else int(seed)
    check_render_request(spec, spp, seed)
    t0 = time.perf_counter()
    mscene, mi, chosen = load_mitsuba_scene(spec, variant)
    seconds = {"load": time.perf_counter() - t0}
    images = []
    names = ("left", "right")
    bar = tqdm(names, desc=f"render {chosen} {spp} spp", unit="view", disable=not progress,
               leave=False)
    film_pixels = {name: int(np.prod(_render_size(c))) for name, c in zip(names, spec.cameras)}
    speeds, taken = {}, {}
    for i, (name, camera) in enumerate(zip(bar, spec.cameras)):
        t = time.perf_counter()
        image, taken[name] = render_view_counted(mscene, mi, i, camera, spp, seed)
        images.append(image)
        seconds[name] = time.perf_counter() - t
        speeds[name] = film_pixels[name] * taken[name] / seconds[name]
        bar.set_postfix_str(f"{name} {speeds[name] / 1e6:.1f} M samples/s")
    bar.close()
    # Samplers may round each pass up (multijitter: to a product of two near-equal integers).
    spp_rendered = int(taken["left"])
    samples = sum(film_pixels[name] * taken[name] for name in names)
    w, h = spec.size
    render_seconds = seconds["left"] + seconds["right"]
    plans = {name: pass_plan(spp, film_pixels[name]) for name in names}
    info = {"variant": chosen, "integrator": integrator_name(mi, mscene), "spp": spp,
            "spp_rendered": spp_rendered, "seed": seed,
            "size": [w, h], "seconds": seconds, "passes": plans,
            "samples_per_second": samples / render_seconds if render_seconds > 0 else None,
            "samples_per_second_per_view": speeds}
    return images[0], images[1], info


# ---------------------------------------------------------------------------------------------
# image files
# ---------------------------------------------------------------------------------------------
def png16_scale(*images, headroom: float = 1.0) -> float:
    """Factor so that ``image * factor`` of the brightest pixel of all images is 65535 (linear)."""
    peak = max(float(np.max(img)) for img in images)
    return 65535.0 / (peak * headroom) if peak > 0 else 1.0


def to_png16(image: np.ndarray, scale: float) -> np.ndarray:
    """Linear float image to uint16 (``round(image * scale)``, clipped)."""
    return np.clip(np.rint(image.astype(np.float64) * scale), 0, 65535).astype(np.uint16)


def srgb_preview(image: np.ndarray, white: float | None = None) -> np.ndarray:
    """8-bit sRGB-encoded preview of a linear image (``white`` maps to 255; default its max)."""
    white = float(np.max(image)) if white is None else float(white)
    x = np.clip(image.astype(np.float64) / (white if white > 0 else 1.0), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(srgb * 255.0).astype(np.uint8)


def write_png(path, image: np.ndarray) -> None:
    """Write a uint8/uint16 single-channel PNG; raise OSError if OpenCV cannot."""
    if not cv2.imwrite(str(path), image):
        raise OSError(f"cannot write {path}")


def write_exr(path, image: np.ndarray, variant: str | None = None) -> None:
    """Write a float32 single-channel OpenEXR image with Mitsuba's Bitmap (linear, no curve)."""
    mi, _ = import_mitsuba(variant)
    mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32)).write(str(path))
