"""Benchmark datasets: render a scene and write files anyone can read without this project.

A dataset directory holds (units mm, reference frame = the left camera's, OpenCV axes):

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

import hashlib
import json
import os
import time
from dataclasses import dataclass
from datetime import datetime, timezone

import cv2
import numpy as np

from measure import Rig
from measure.geometry.projection import project

from synth.formats.exchange import write_cameras_json, write_colmap_model, write_surface_formats
from synth.infra.fileio import OutputDir, file_sha256, read_marker
from synth.rendering.integrator import RENDERER
from synth.infra.provenance import package_versions
from synth.rendering.image_files import png16_scale, srgb_preview, to_png16, write_exr, write_png
from synth.rendering.render import pass_seed, render_stereo
from synth.scene import SceneError, SceneSpec, load_scene
from synth.infra.images import imread
from synth.formats.calib_yaml import DatasetError, read_calib, write_calib
from synth.formats.pixels_csv import read_pixels_csv, write_pixels_csv

FORMAT_VERSION = 4  # 2: targets.ply in binary doubles (was ASCII, 6 digits); 3: hashes;
#                    4: cameras.json, colmap/, surfaces' PFM / PNG depth and .flo (synth.formats.exchange)



def write_targets_ply(path, points: np.ndarray) -> None:
    """Ground-truth centres ``(N, 3)`` mm as a binary PLY point cloud written by Open3D (doubles:
    exact; Open3D's ASCII PLY keeps 6 significant digits, 5e-4 mm at 1 m)."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    if not o3d.io.write_point_cloud(str(path), cloud, write_ascii=False):
        raise OSError(f"Open3D could not write {path}")


def read_truth_targets(path, manifest: dict, n_pixel_rows: int) -> np.ndarray:
    """The true target centres ``(T, 3)`` mm of a dataset folder ``path`` (``targets.ply``,
    whole or refused), checked against the manifest's count and ``pixels.csv``'s rows
    (``n_pixel_rows``): DatasetError naming the file — a pair's dataset and N views' alike."""
    from synth.formats.cloudfile import CloudFileError, read_cloud_points

    targets_path = os.path.join(path, "targets.ply")
    if not os.path.isfile(targets_path):
        raise DatasetError(f"{targets_path}: no such file")
    try:  # whole or refused: Open3D reads a truncated PLY as far as it goes
        targets = read_cloud_points(targets_path)
    except CloudFileError as exc:
        raise DatasetError(str(exc)) from None
    n_targets = manifest["scene"].get("n_targets")
    for name, count in (("targets.ply", targets.shape[0]), ("pixels.csv", n_pixel_rows)):
        if n_targets is not None and count != n_targets:
            raise DatasetError(f"{path}/{name}: {count} targets, but manifest.json says "
                               f"{n_targets}")
    if targets.shape[0] != n_pixel_rows:
        raise DatasetError(f"{path}: targets.ply has {targets.shape[0]} points but pixels.csv "
                           f"{n_pixel_rows} rows")
    return targets


def image_stats(image: np.ndarray) -> dict:
    return {"min": float(image.min()), "max": float(image.max()), "mean": float(image.mean()),
            "lit_fraction": float(np.mean(image > 0))}


def request_key(spec: SceneSpec, spp: int, seed: int, variant: str | None, exr: bool,
                sensor=None, adaptive: bool = True, design: dict | None = None) -> str:
    """Hash of everything that determines a dataset's content."""
    return _request_key(FORMAT_VERSION, spec.sha256, spec.params, spp, seed, variant, exr,
                        None if sensor is None else sensor.to_dict(), RENDERER,
                        adaptive_settings() if adaptive else None, design)


def adaptive_settings() -> dict:
    """What an adaptive render's content depends on beyond the scene, spp and seed (the
    ``render`` entry of the manifest and request key; :func:`synth.rendering.render.render_view_counted`)."""
    from synth.rendering import render

    return {"mode": "adaptive", "pilot_spp": render.ADAPTIVE_PILOT_SPP,
            "margin_px": render.ADAPTIVE_MARGIN_PX,
            "max_lit_fraction": render.ADAPTIVE_MAX_LIT_FRACTION}


def _request_key(format_version, scene_sha256, params, spp, seed, variant, exr, sensor,
                 renderer, adaptive: dict | None = None, design: dict | None = None) -> str:
    """The key; ``adaptive`` (the settings of an adaptive render) is part of it only when given,
    so that a full-film dataset — what every dataset was before adaptive rendering, with the
    same seeds and bytes — keeps its key."""
    request = {"format": format_version, "scene": scene_sha256, "params": params,
               "spp": spp, "seed": seed, "variant": variant, "exr": bool(exr),
               "sensor": sensor, "renderer": renderer}
    if adaptive is not None:
        request["adaptive"] = adaptive
    if design is not None:  # a port that deviates from its design (synth.scene.design)
        request["design"] = design
    blob = json.dumps(request, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def manifest_request_key(manifest: dict) -> str:
    """The request key recomputed from a manifest's own fields (scene hash and parameters,
    spp, seed, requested variant, EXR files, sensor model, this renderer)."""
    sensor = manifest.get("sensor")
    files = manifest.get("files") or []
    render = manifest.get("render")  # absent before adaptive rendering: the full film
    settings = render.get("settings") if isinstance(render, dict) else None
    return _request_key(manifest.get("format_version"), manifest["scene"].get("sha256"),
                        manifest["scene"]["params"], manifest.get("spp"), manifest.get("seed"),
                        manifest.get("variant_requested"),
                        "left.exr" in files or "cam0/image.exr" in files,
                        sensor.get("model") if isinstance(sensor, dict) else None, RENDERER,
                        settings, manifest.get("design"))


def manifest_digest(manifest: dict) -> str:
    """SHA-256 of a manifest's content: its JSON with sorted keys, without ``manifest_sha256``
    itself (and the ``skipped`` / ``rendered_again`` flags :func:`write_dataset` returns)."""
    content = {k: v for k, v in manifest.items()
               if k not in ("manifest_sha256", "skipped", "rendered_again")}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()

def write_manifest(directory, manifest: dict) -> None:
    """``manifest.json`` into ``directory`` with the manifest's own SHA-256 added
    (:func:`manifest_digest`; ``manifest`` gains ``manifest_sha256``)."""
    manifest["manifest_sha256"] = manifest_digest(manifest)
    with open(os.path.join(directory, "manifest.json"), "w") as fh:
        json.dump(manifest, fh, indent=2, sort_keys=False)
        fh.write("\n")



# ---------------------------------------------------------------------------------------------
# write / read / check
# ---------------------------------------------------------------------------------------------
def existing_output(out_dir, key: str):
    """``(output, old, damage)`` for a dataset of request ``key`` about to be written to
    ``out_dir``: the :class:`synth.infra.fileio.OutputDir` (not yet claimed); ``old`` the
    manifest already there (``old["skipped"]`` True) when that output holds the same request,
    whole — nothing is to be done —, else None; ``damage`` why an output of the same request is
    not whole (a file missing or changed), or None."""
    output = OutputDir(out_dir, "synth dataset")
    damage = None
    if output.exists_as_output():
        marker = read_marker(output.path) or {}
        if marker.get("request_key") == key:
            damage = output.damage()  # up to date only when every file is whole
            try:
                if damage is None:
                    with open(os.path.join(output.path, "manifest.json")) as fh:
                        old = json.load(fh)
                    old["skipped"] = True
                    return output, old, None
            except (OSError, ValueError):
                damage = "manifest.json cannot be read"
    return output, None, damage


def write_dataset(scene, out_dir, spp: int | None = None, defines: dict | None = None,
                  variant: str | None = None, exr: bool = False, progress: bool = True,
                  seed: int | None = None, sensor=None, adaptive: bool = True,
                  design: dict | None = None) -> dict:
    """Render ``scene`` (a path or :class:`SceneSpec`) of two cameras and write a dataset to
    ``out_dir`` (a scene of N > 2 cameras is refused:
    :func:`synth.products.views_dataset.write_views_dataset` writes it, a folder per camera).

    ``design`` (``{"error": {name: truth − design}, "port": {name: design value}}``,
    :mod:`synth.scene.design`): the scene is the truth; the dataset also states the design port a
    user would believe (``calib_design.yaml``, ``cameras_design.json``; the manifest's
    ``design``), and the design is part of the request key.

    ``adaptive`` (default) renders each view adaptively, False on the full film
    (:func:`synth.rendering.render.render_view_counted`); the manifest's ``render`` says how each view was
    rendered (mode, lit fraction, samples on and off the mask, samples/s).

    ``sensor`` (a :class:`synth.rendering.sensor_model.SensorModel`): the PNGs hold that sensor's raw
    codes of the render (seeded by the scene's seed), ``png_offset`` its dark level and
    ``png_scale`` its DN per unit of radiance; the EXRs (``exr``) stay noise-free.

    Returns the manifest (dict); ``manifest["skipped"]`` is True when ``out_dir`` already held
    the same request, whole, and nothing was done; ``manifest["rendered_again"]`` says why an
    earlier output of the same request was rendered again (a file missing or changed), or
    None. ``out_dir`` follows the project's output rule (:class:`synth.infra.fileio.OutputDir`): a
    directory holding files this command did not write is
    refused before rendering; an earlier dataset with another request is replaced atomically.
    """
    t_start = time.perf_counter()
    times = {}
    spec, spp, seed = _stereo_spec(scene, defines, spp, seed, times)
    key = request_key(spec, spp, seed, variant, exr, sensor, adaptive, design)

    output, old, damage = existing_output(out_dir, key)
    if old is not None:
        return old
    output.claim()

    with output.staged(extra={"request_key": key}) as tmp:
        left, right, info = render_stereo(spec, spp=spp, variant=variant, progress=progress,
                                          seed=seed, adaptive=adaptive)
        times["render_left"] = info["seconds"]["left"]
        times["render_right"] = info["seconds"]["right"]
        times["load_mitsuba"] = info["seconds"]["load"]
        t = time.perf_counter()
        scale, offset, sensor_info = _write_images(tmp, left, right, info, sensor, seed, exr)
        times["write_images"] = time.perf_counter() - t
        truth = _write_truth(tmp, spec, design, times)
        times["total"] = time.perf_counter() - t_start
        manifest = _manifest(tmp, spec, key, info, variant, spp, seed, (scale, offset),
                             sensor_info, (left, right), adaptive, times, truth, design)
        write_manifest(tmp, manifest)
    manifest["skipped"] = False
    manifest["rendered_again"] = damage  # why an earlier output of this request was not whole
    return manifest


def _manifest(tmp, spec, key, info, variant, spp, seed, png, sensor_info, images, adaptive,
              times, truth, design) -> dict:
    """The dataset's manifest (without its own SHA-256): versions, the scene and how it was
    rendered, the PNGs' ``png`` (scale, offset), the images' statistics, the times, the
    truth's formats and every file's SHA-256."""
    return {
        "format_version": FORMAT_VERSION,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "request_key": key,
        "versions": package_versions(),
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
        "seeds": {view: [pass_seed(seed, i, k) for k in range(len(info["passes"][view]))]
                  for i, view in enumerate(("left", "right"))},
        "image_size": list(spec.size),
        "png_scale": png[0],
        "png_offset": png[1],
        "sensor": sensor_info,
        "images": {"left": image_stats(images[0]), "right": image_stats(images[1])},
        "samples_per_second": info["samples_per_second"],
        "samples_per_second_per_view": info["samples_per_second_per_view"],
        "passes": info["passes"],
        "render": {"settings": adaptive_settings() if adaptive else None,
                   **{view: info["render"][view] for view in ("left", "right")}},
        "seconds": times,
        "truth_formats": truth["formats"],
        **({} if design is None else {"design": design}),
        "colmap": (f"colmap/: cameras.txt ({spec.rig.port.housing}, "
                   f"metres), images.txt, points3D.txt"
                   if truth["colmap_note"] is None
                   else f"not written: {truth['colmap_note']}"),
        "files": dataset_files(tmp) + ["manifest.json"],
        "sha256": {name: file_sha256(os.path.join(tmp, name))
                   for name in dataset_files(tmp)},
    }


def _stereo_spec(scene, defines, spp, seed, times) -> tuple[SceneSpec, int, int]:
    """``(spec, spp, seed)``: the scene of two cameras to render, ``spp`` and ``seed`` resolved
    (None: the scene's) and recorded in its parameters; SceneError for N > 2 cameras or a left
    camera off the reference origin."""
    t = time.perf_counter()
    spec = scene if isinstance(scene, SceneSpec) else load_scene(scene, defines)
    times["load_scene"] = time.perf_counter() - t
    if spec.extra_cameras:  # never the first two alone
        raise SceneError(f"{spec.path}: a scene of {len(spec.all_cameras)} cameras is written "
                         f"a folder per camera (synth.products.views_dataset."
                         f"write_views_dataset), not as a stereo pair")
    left_cam = spec.rig.left
    if not (np.allclose(left_cam.R, np.eye(3), atol=1e-12) and np.allclose(left_cam.t, 0)):
        raise SceneError(f"{spec.path}: the left sensor must sit at the reference origin with "
                         f"identity rotation (the reference frame is the left camera's)")
    spp = spec.spp if spp is None else int(spp)
    seed = spec.seed if seed is None else int(seed)
    # the parameters say what was rendered
    return spec.rendered_with(spp=spp, seed=seed), spp, seed


def _write_images(tmp, left, right, info, sensor, seed, exr) -> tuple:
    """Both views as 16-bit PNGs (linear, or the ``sensor``'s raw codes), 8-bit sRGB previews
    and, with ``exr``, float32 EXRs into ``tmp``; returns ``(png_scale, png_offset,
    sensor_info)``."""
    white = max(float(left.max()), float(right.max()))
    if sensor is None:
        scale, offset, sensor_info = png16_scale(left, right), 0.0, None
        pngs = {"left": to_png16(left, scale), "right": to_png16(right, scale)}
    else:
        from synth.rendering.sensor_model import sensor_views

        codes_left, codes_right, sensor_info = sensor_views(left, right, sensor, seed)
        scale, offset = sensor_info["dn_per_unit"], sensor.dark_level_dn
        pngs = {"left": codes_left, "right": codes_right}
    for name, img in (("left", left), ("right", right)):
        write_png(os.path.join(tmp, f"{name}.png"), pngs[name])
        seen = img if sensor is None else (pngs[name] - offset) / scale
        write_png(os.path.join(tmp, f"{name}_preview.png"), srgb_preview(seen, white))
        if exr:
            write_exr(os.path.join(tmp, f"{name}.exr"), img, info["variant"])
    return scale, offset, sensor_info


def _write_truth(tmp, spec: SceneSpec, design, times) -> dict:
    """The truth and the rig's files into ``tmp``: a surface's truth maps and depth formats, or
    the targets' PLY and simulator pixels; ``calib.yaml``, ``cameras.json`` (and the design
    port's, with ``design``), the COLMAP model. Returns ``{counts, formats, colmap_note}``."""
    truth = {"counts": None, "formats": None, "colmap_note": None}
    if spec.surface is not None:
        from synth.products.truth_maps import write_truth_maps

        t = time.perf_counter()
        truth["counts"] = write_truth_maps(tmp, spec.rig, spec.surface.mesh_path,
                                           spec.surface.vertices, spec.surface.triangles)
        truth["formats"] = write_surface_formats(tmp, spec.rig)
        times["truth_maps"] = time.perf_counter() - t
    else:
        t = time.perf_counter()
        uv_left = project(spec.rig.left, spec.rig.view_port(0), spec.targets)
        uv_right = project(spec.rig.right, spec.rig.view_port(1), spec.targets)
        times["project"] = time.perf_counter() - t
    t = time.perf_counter()
    write_calib(os.path.join(tmp, "calib.yaml"), spec.rig, spec.has_port)
    write_cameras_json(tmp, spec.rig, spec.has_port)
    if design is not None:  # the port a user would believe, beside the truth
        from synth.scene.design import CALIB_DESIGN, CAMERAS_DESIGN, DESIGN_NOTE, design_rig

        if not spec.has_port:
            raise SceneError(f"{spec.path}: a design port needs a scene with a port")
        believed = design_rig(spec.rig, design.get("port", {}))
        write_calib(os.path.join(tmp, CALIB_DESIGN), believed, True,
                    extra={"design": {"note": DESIGN_NOTE}})
        write_cameras_json(tmp, believed, True, name=CAMERAS_DESIGN)
    if spec.surface is None:
        write_targets_ply(os.path.join(tmp, "targets.ply"), spec.targets)
        write_pixels_csv(os.path.join(tmp, "pixels.csv"), spec.target_ids, spec.targets,
                         uv_left, uv_right)
        truth["colmap_note"] = write_colmap_model(tmp, spec.rig, spec.has_port, spec.target_ids,
                                                  spec.targets, uv_left, uv_right)
    else:
        truth["colmap_note"] = write_colmap_model(tmp, spec.rig, spec.has_port, [],
                                                  np.zeros((0, 3)), np.zeros((0, 2)),
                                                  np.zeros((0, 2)))
    times["write_files"] = time.perf_counter() - t
    return truth


def dataset_files(directory: str) -> list:
    """Every file below ``directory`` (paths relative to it, ``/``-separated, sorted), hidden
    files left out."""
    out = []
    for root, dirs, files in os.walk(directory):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        rel = os.path.relpath(root, directory)
        out += [name if rel == "." else f"{rel}/{name}" for name in files
                if not name.startswith(".")]
    return sorted(out)


@dataclass(frozen=True)
class Dataset:
    """A dataset read back. Images are float32 linear (``(png − png_offset) / png_scale``),
    ``(H, W)``.

    ``rig`` from ``calib.yaml`` (left camera at the reference origin); ``targets`` ``(N, 3)`` mm
    from ``targets.ply``; ``ids`` and the simulator's ``pixels_left`` / ``pixels_right``
    ``(N, 2)`` from ``pixels.csv``; ``manifest`` the dict.
    """

    path: str
    left: np.ndarray
    right: np.ndarray
    rig: Rig
    has_port: bool
    targets: np.ndarray
    ids: np.ndarray
    pixels_left: np.ndarray
    pixels_right: np.ndarray
    manifest: dict

    @property
    def is_surface(self) -> bool:
        """A surface (dense) dataset: truth maps and ``surface.ply`` instead of targets."""
        return bool(self.manifest["scene"].get("surface"))


def read_png16(path) -> np.ndarray:
    if not os.path.isfile(path):
        raise DatasetError(f"{path}: no such file")
    img = imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"{path}: cannot read image")
    if img.ndim != 2 or img.dtype != np.uint16:
        raise DatasetError(f"{path}: expected a 16-bit single-channel PNG")
    return img


def read_manifest(path) -> dict:
    """The ``manifest.json`` of dataset directory ``path`` (DatasetError if absent or malformed)."""
    path = os.fspath(path)
    if not os.path.isdir(path):
        raise DatasetError(f"{path}: not a dataset directory")
    manifest_path = os.path.join(path, "manifest.json")
    try:
        with open(manifest_path) as fh:
            manifest = json.load(fh)
    except OSError as exc:
        raise DatasetError(f"{path}: not a dataset ({exc.strerror or exc}: manifest.json)") from None
    except ValueError as exc:
        raise DatasetError(f"{manifest_path}: malformed JSON ({exc})") from None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("scene"), dict) \
            or not isinstance(manifest["scene"].get("params"), dict):
        raise DatasetError(f"{manifest_path}: not a dataset manifest (no scene parameters)")
    again = ("a dataset's truth is what was rendered: render it again with python -m synth "
             "dataset (-D changes the scene; eval run --assume what the measurement believes)")
    if "manifest_sha256" in manifest and manifest["manifest_sha256"] != manifest_digest(manifest):
        raise DatasetError(f"{manifest_path} was changed after synth dataset wrote it (its "
                           f"content no longer matches its manifest_sha256); {again}")
    try:
        key = manifest_request_key(manifest)
    except (TypeError, ValueError, AttributeError):
        key = None
    if manifest.get("request_key") != key:
        raise DatasetError(f"{manifest_path}: its scene parameters, spp, seed, variant or sensor "
                           f"disagree with its request key (edited by hand, or written by "
                           f"another renderer than {RENDERER}); {again}")
    return manifest


def check_files(path, manifest: dict, command: str = "synth dataset") -> None:
    """DatasetError unless every file of the folder ``path`` that ``manifest["sha256"]`` lists
    is there with that SHA-256 (a manifest before format 3 lists none), and the manifest's
    ``manifest_sha256``, when it has one, is its content's. ``command`` wrote the folder."""
    if "manifest_sha256" in manifest and manifest["manifest_sha256"] != manifest_digest(manifest):
        raise DatasetError(f"{os.path.join(path, 'manifest.json')} was changed after {command} "
                           f"wrote it (its content no longer matches its manifest_sha256): "
                           f"render it again with python -m {command}")
    digests = manifest.get("sha256")
    if not isinstance(digests, dict):
        return
    for name in sorted(digests):
        file = os.path.join(path, name)
        if not os.path.isfile(file):
            raise DatasetError(f"{file}: no such file (manifest.json lists it)")
        if file_sha256(file) != digests[name]:
            raise DatasetError(f"{file}: changed since {command} wrote it (its SHA-256 is not "
                               f"the one manifest.json records): render it again with "
                               f"python -m {command}")


def read_dataset(path) -> Dataset:
    """Read a dataset directory written by :func:`write_dataset`; DatasetError names what is
    missing or inconsistent."""
    path = os.fspath(path)
    manifest = read_manifest(path)
    cameras = manifest.get("cameras")
    if isinstance(cameras, list) and len(cameras) > 2:
        raise DatasetError(f"{path}: a dataset of {len(cameras)} cameras "
                           f"({', '.join(f'{c}/' for c in cameras)}), not a stereo pair "
                           f"(left.png, right.png): this reads two views (synth check, synth "
                           f"photos and eval run --from read every camera)")
    try:
        scale = float(manifest["png_scale"])
    except (KeyError, TypeError, ValueError):
        raise DatasetError(f"{path}/manifest.json: no valid png_scale") from None
    if not (np.isfinite(scale) and scale > 0):
        raise DatasetError(f"{path}/manifest.json: png_scale must be positive, got {scale}")
    try:
        offset = float(manifest.get("png_offset", 0.0))
    except (TypeError, ValueError):
        raise DatasetError(f"{path}/manifest.json: png_offset must be a number") from None
    left, right = ((read_png16(os.path.join(path, f"{view}.png")).astype(np.float32)
                    - np.float32(offset)) / np.float32(scale) for view in ("left", "right"))
    calib = read_calib(os.path.join(path, "calib.yaml"))
    for name, image in (("left.png", left), ("right.png", right)):
        if image.shape[::-1] != tuple(calib["size"]):
            raise DatasetError(f"{path}/{name}: {image.shape[1]}x{image.shape[0]} px, but "
                               f"calib.yaml says {calib['size'][0]}x{calib['size'][1]}")
    if manifest["scene"].get("surface"):
        check_files(path, manifest)
        empty = np.zeros((0, 2))
        return Dataset(path=path, left=left, right=right, rig=calib["rig"],
                       has_port=calib["has_port"], targets=np.zeros((0, 3)),
                       ids=np.zeros(0, dtype=int), pixels_left=empty, pixels_right=empty,
                       manifest=manifest)
    try:
        pixels = read_pixels_csv(os.path.join(path, "pixels.csv"))
    except DatasetError:  # it names the file
        raise
    except (OSError, ValueError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else exc
        raise DatasetError(f"{path}/pixels.csv: {reason}") from None
    targets = read_truth_targets(path, manifest, len(pixels["id"]))
    check_files(path, manifest)  # last: the readers above say more precisely what is wrong
    return Dataset(path=path, left=left, right=right, rig=calib["rig"],
                   has_port=calib["has_port"], targets=targets, ids=pixels["id"],
                   pixels_left=pixels["left"], pixels_right=pixels["right"], manifest=manifest)
