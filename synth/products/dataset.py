"""Benchmark datasets: render a scene and write files anyone can read without this project.

One writer (:func:`write_dataset`) for any number of cameras: the same stages (the scene, every
view rendered, the images, the rig's files, the truth, the manifest, the request key and resume,
written atomically) for a pair and N > 2 cameras; only where the files go differs
(:mod:`synth.products.dataset_layout`: a pair's below, or a folder per camera ``camK/`` with
``image.png``, ``preview.png``, ``image.exr``, the rig file of N cameras as ``calib.yaml`` and
``pixels.csv`` with ``u_camK,v_camK`` per camera). :func:`read_dataset`
(:mod:`synth.products.dataset_read`) reads either; the manifest and request key are
:mod:`synth.products.dataset_manifest`'s.

A pair's dataset directory holds (units mm, reference frame = the left camera's, OpenCV axes):

* ``left.png``, ``right.png`` -- 16-bit single-channel **linear** images,
  ``png = round(linear * png_scale)`` with one ``png_scale`` for both views (manifest) such that
  the brightest pixel is 65535 — or, with a sensor (``--sensor``), the sensor's raw codes:
  ``linear ≈ (png − png_offset) / png_scale`` with its noise (``manifest["sensor"]``);
  ``left_preview.png``, ``right_preview.png`` -- 8-bit sRGB;
  ``left.exr``, ``right.exr`` -- float32 linear, on request;
* ``calib.yaml`` -- OpenCV FileStorage: ``image_width``, ``image_height``, ``K1``, ``D1``,
  ``K2``, ``D2``, ``R``, ``T`` (OpenCV stereo convention ``X_right = R·X_left + T``),
  ``D1_model``, ``D2_model`` (``fisheye`` for OpenCV's fisheye model, k1…k4; absent for
  OpenCV's Brown–Conrady model), ``units``
  (``mm``, the only one read) and a map ``port`` {``normal`` (3x1), ``distance``,
  ``thicknesses`` (sequence), ``indices`` (sequence), ``present`` (0 for an all-air scene,
  whose port is index-matched: read with every index 1, whatever the file says; 1 a port)} —
  or, for a dome scene, a map ``dome`` {``left``, ``right``: {``center`` (3x1, reference
  frame), ``radius`` (inner), ``thickness``, ``indices`` (air, glass, water)}} — or, for two
  housings (a flat port per camera), a map ``ports`` {``left``, ``right``: {``normal``,
  ``distance``, ``thicknesses``, ``indices``}, each in the reference frame};
* surface scenes (``python -m synth scene --layout surface``) instead of targets:
  ``surface.ply`` (the mesh) and per-view truth maps (:mod:`synth.products.truth_maps`):
  ``{left,right}_truth_points.npy`` (H, W, 3) float64 mm, ``{left,right}_truth_depth.npy``
  (H, W) float32 mm along the port normal, ``{left,right}_truth_valid.png`` and
  ``{left,right}_truth_overlap.png`` (8-bit masks);
* ``cameras.json`` -- the same rig as plain JSON (both pose conventions named, units stated) and
  ``colmap/`` -- a COLMAP text model (``cameras.txt`` with FLATPORT in metres, ``images.txt``,
  ``points3D.txt``; COLMAP's pixels), since format 4 (:mod:`synth.formats.exchange`); surface datasets
  also ``{left,right}_truth_zdepth.pfm`` / ``.png`` (depth along each camera's z; the PNG's
  scale in ``manifest["truth_formats"]``) and ``left_truth_flow.flo`` (left→right, NaN where
  none);
* ``targets.ply`` -- ground-truth target centres in target order (Open3D, binary doubles);
* ``pixels.csv`` -- ``id,x,y,z,u_left,v_left,u_right,v_right``: the Fermat simulator's pixel of
  every target in each view (NaN where it has none; pixels outside the image are kept);
* ``manifest.json`` -- versions, scene hash and parameters (``spp`` and ``seed`` as rendered),
  variant, spp, seed, image statistics, ``png_scale``, ``png_offset`` (0 without a sensor),
  ``sensor``, the time of every stage, ``render`` (the adaptive settings or None for a
  full-film render, and per view how it was rendered: :func:`synth.rendering.render.render_stereo`;
  absent in datasets written before adaptive rendering, read as full film), the request key,
  ``sha256`` (every other file's SHA-256) and ``manifest_sha256`` (the SHA-256 of the
  manifest's own content, :func:`manifest_digest`).

A dataset's manifest is not a place to edit the truth: :func:`read_manifest` refuses a
manifest that disagrees with itself (its ``manifest_sha256``, and its request key recomputed
from its fields) and :func:`read_dataset` a file whose SHA-256 is not the manifest's.

Writing is atomic: everything goes to a temporary sibling directory that is renamed at the end.
A rerun with the same request (scene bytes, resolved parameters, spp, seed, variant request,
EXR) finds the manifest's key and does nothing — when every file written is whole (the output
marker's sizes and SHA-256, :meth:`synth.infra.fileio.OutputDir.damage`); otherwise it renders again.
"""

from __future__ import annotations

import os
import time
from datetime import datetime, timezone

import numpy as np

from synth.formats.calib_yaml import DatasetError, read_calib, write_calib
from synth.infra.fileio import file_sha256
from synth.infra.provenance import package_versions
from synth.products.dataset_layout import (dataset_layout, is_views_dataset, simulated_pixels,
                                           write_targets_ply)
from synth.products.dataset_manifest import (FORMAT_VERSION, adaptive_settings, check_files,
                                             dataset_files, existing_output, image_stats,
                                             manifest_digest, manifest_request_key,
                                             read_manifest, request_key, write_manifest)
from synth.products.dataset_read import (Dataset, ViewsDataset, read_dataset, read_png16,
                                         read_truth_targets)
from synth.rendering.render import pass_seed, render_views
from synth.scene import SceneError, SceneSpec, load_scene


def write_dataset(scene, out_dir, spp: int | None = None, defines: dict | None = None,
                  variant: str | None = None, exr: bool = False, progress: bool = True,
                  seed: int | None = None, sensor=None, adaptive: bool = True,
                  design: dict | None = None) -> dict:
    """Render every camera of ``scene`` (a path or :class:`SceneSpec`) and write a dataset to
    ``out_dir``: a pair's files for two cameras, a folder per camera for more
    (:mod:`synth.products.dataset_layout`; the stages are the same).

    ``design`` (``{"error": {name: truth − design}, "port": {name: design value}}``,
    :mod:`synth.scene.design`; a pair only): the scene is the truth; the dataset also states the
    design port a user would believe (``calib_design.yaml``, ``cameras_design.json``; the
    manifest's ``design``), and the design is part of the request key.

    ``adaptive`` (default) renders each view adaptively, False on the full film
    (:func:`synth.rendering.render.render_view_counted`); the manifest's ``render`` says how each
    view was rendered (mode, lit fraction, samples on and off the mask, samples/s).

    ``sensor`` (a :class:`synth.rendering.sensor_model.SensorModel`): the PNGs hold that sensor's
    raw codes of the render (one exposure for every view, each view's noise seeded by the
    scene's seed and its index), ``png_offset`` its dark level and ``png_scale`` its DN per unit
    of radiance; the EXRs (``exr``) stay noise-free.

    Returns the manifest (dict); ``manifest["skipped"]`` is True when ``out_dir`` already held
    the same request, whole, and nothing was done; ``manifest["rendered_again"]`` says why an
    earlier output of the same request was rendered again (a file missing or changed), or
    None. ``out_dir`` follows the project's output rule (:class:`synth.infra.fileio.OutputDir`):
    a directory holding files this command did not write is refused before rendering; an
    earlier dataset with another request is replaced atomically. SceneError for a first camera
    off the reference origin, and for N > 2 cameras a surface scene or a design port.
    """
    t_start = time.perf_counter()
    times = {}
    spec, spp, seed = _dataset_spec(scene, defines, spp, seed, times)
    layout = dataset_layout(spec)
    layout.check(spec, design)
    key = request_key(spec, spp, seed, variant, exr, sensor, adaptive, design)

    output, old, damage = existing_output(out_dir, key)
    if old is not None:
        return old
    output.claim()

    with output.staged(extra={"request_key": key}) as tmp:
        images, info = render_views(spec, spp=spp, variant=variant, progress=progress,
                                    seed=seed, adaptive=adaptive)
        times.update({f"render_{name}": info["seconds"][name] for name in layout.names})
        times["load_mitsuba"] = info["seconds"]["load"]
        t = time.perf_counter()
        png = _write_images(tmp, layout, images, info, sensor, seed, exr)
        times["write_images"] = time.perf_counter() - t
        truth = layout.write_truth(tmp, spec, design, times)
        times["total"] = time.perf_counter() - t_start
        manifest = _manifest(tmp, spec, layout, key, info, (variant, spp, seed, exr, adaptive),
                             png, images, times, truth, design)
        write_manifest(tmp, manifest)
    manifest["skipped"] = False
    manifest["rendered_again"] = damage  # why an earlier output of this request was not whole
    return manifest


def _manifest(tmp, spec, layout, key, info, request, png, images, times, truth,
              design) -> dict:
    """The dataset's manifest (without its own SHA-256): versions, the layout's entries, the
    scene and how it was rendered (``request``: variant, spp, seed, EXR, adaptive), the PNGs'
    ``png`` (scale, offset, sensor), the images' statistics, the times, the truth's formats and
    every file's SHA-256."""
    variant, spp, seed, exr, adaptive = request
    names = layout.names
    return {
        "format_version": FORMAT_VERSION,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "request_key": key,
        "versions": package_versions(),
        **layout.manifest_head(truth, exr),
        "scene": {"path": spec.path, "sha256": spec.sha256, "params": spec.params,
                  "has_port": spec.has_port, "n_targets": int(spec.targets.shape[0]),
                  "target_radius_mm": spec.target_radius,
                  "surface": (None if spec.surface is None else
                              {"mesh": os.path.basename(spec.surface.mesh_path),
                               "texture": os.path.basename(spec.surface.texture_path),
                               "triangles": int(spec.surface.triangles.shape[0]),
                               "truth_pixels": truth["counts"]})},
        "variant": info["variant"], "variant_requested": variant,
        "integrator": info["integrator"],
        "spp": spp, "spp_rendered": info["spp_rendered"], "seed": seed,
        "seeds": {name: [pass_seed(seed, i, k) for k in range(len(info["passes"][name]))]
                  for i, name in enumerate(names)},
        "image_size": list(spec.size),
        "png_scale": png[0],
        "png_offset": png[1],
        "sensor": png[2],
        "images": {name: image_stats(image) for name, image in zip(names, images)},
        "samples_per_second": info["samples_per_second"],
        "samples_per_second_per_view": info["samples_per_second_per_view"],
        "passes": info["passes"],
        "render": {"settings": adaptive_settings() if adaptive else None,
                   **{name: info["render"][name] for name in names}},
        "seconds": times,
        **layout.manifest_tail(spec, truth, design),
        "files": dataset_files(tmp) + ["manifest.json"],
        "sha256": {name: file_sha256(os.path.join(tmp, name))
                   for name in dataset_files(tmp)},
    }


def _dataset_spec(scene, defines, spp, seed, times) -> tuple[SceneSpec, int, int]:
    """``(spec, spp, seed)``: the scene to render, ``spp`` and ``seed`` resolved (None: the
    scene's) and recorded in its parameters; SceneError for a first camera off the reference
    origin."""
    t = time.perf_counter()
    spec = scene if isinstance(scene, SceneSpec) else load_scene(scene, defines)
    times["load_scene"] = time.perf_counter() - t
    first = spec.all_cameras[0]
    if not (np.allclose(first.R, np.eye(3), atol=1e-12) and np.allclose(first.t, 0)):
        which = "first" if spec.extra_cameras else "left"
        raise SceneError(f"{spec.path}: the {which} sensor must sit at the reference origin "
                         f"with identity rotation (the reference frame is the {which} "
                         f"camera's)")
    spp = spec.spp if spp is None else int(spp)
    seed = spec.seed if seed is None else int(seed)
    # the parameters say what was rendered
    return spec.rendered_with(spp=spp, seed=seed), spp, seed


def _write_images(tmp, layout, images, info, sensor, seed, exr) -> tuple:
    """Every view as a 16-bit PNG (linear with one scale for all, or the ``sensor``'s raw
    codes), an 8-bit sRGB preview and, with ``exr``, a float32 EXR, where ``layout`` puts them
    in ``tmp``; returns ``(png_scale, png_offset, sensor_info)``."""
    from synth.rendering.image_files import png16_scale, srgb_preview, to_png16, write_exr, write_png

    white = max(float(image.max()) for image in images)
    if sensor is None:
        scale, offset, sensor_info = png16_scale(*images), 0.0, None
        pngs = [to_png16(image, scale) for image in images]
    else:
        from synth.rendering.sensor_model import sensor_images

        pngs, sensor_info = sensor_images(images, layout.names, sensor, seed)
        scale, offset = sensor_info["dn_per_unit"], sensor.dark_level_dn
    for name, image, png in zip(layout.names, images, pngs):
        os.makedirs(os.path.dirname(os.path.join(tmp, layout.image(name))), exist_ok=True)
        write_png(os.path.join(tmp, layout.image(name)), png)
        seen = image if sensor is None else (png - offset) / scale
        write_png(os.path.join(tmp, layout.preview(name)), srgb_preview(seen, white))
        if exr:
            write_exr(os.path.join(tmp, layout.exr(name)), image, info["variant"])
    return scale, offset, sensor_info


__all__ = ["FORMAT_VERSION", "Dataset", "DatasetError", "ViewsDataset", "adaptive_settings",
           "check_files", "dataset_files", "existing_output", "image_stats", "is_views_dataset",
           "manifest_digest", "manifest_request_key", "read_calib", "read_dataset",
           "read_manifest", "read_png16", "read_truth_targets", "request_key",
           "simulated_pixels", "write_calib", "write_dataset", "write_manifest",
           "write_targets_ply"]
