"""Datasets of a scene of more than two cameras (``synth scene --cameras N``), written and read.

A two-camera dataset (:mod:`synth.products.dataset`) holds ``left.png`` and ``right.png``; a
dataset of N > 2 cameras holds one folder per camera, ``cam0/``, ``cam1/``, … (the scene's
sensor order, :attr:`synth.scene.model.SceneSpec.camera_names`), each with that view's files
under one name per kind (:data:`VIEW_FILES`):

* ``camK/image.png`` -- 16-bit single-channel **linear**, ``png = round(linear · png_scale)``
  with one ``png_scale`` for every view (manifest), the brightest pixel of all views at 65535;
* ``camK/preview.png`` -- 8-bit sRGB, to look at only; ``camK/image.exr`` (float32 linear)
  with ``--exr``.

Beside them (units mm, reference frame = ``cam0``'s, OpenCV axes):

* ``calib.yaml`` -- the rig of N cameras (:func:`synth.products.rig_file.write_rig_file`:
  ``cameras`` with each pose ``X_ref = R · X_cam + t``, the shared ``port`` or each camera's
  own);
* ``cameras.json`` -- the same rig as plain JSON, every camera with its port
  (:func:`synth.formats.exchange.cameras_json_views`), and ``colmap/`` -- a COLMAP text model
  for the refractive COLMAP fork (``cameras.txt`` with each camera's FLATPORT or DOMEPORT and
  ``rig_config.json``, ``images.txt`` of one image per camera, ``points3D.txt`` with each
  target's track over the images it lies inside: :func:`synth.formats.exchange.write_colmap_views`;
  not written, with the reason in the manifest, for a rig the format cannot hold);
* ``targets.ply`` -- the true target centres (binary doubles, mm), in target order;
* ``pixels.csv`` -- ``id,x,y,z,u_cam0,v_cam0,u_cam1,v_cam1,…``: the Fermat simulator's pixel
  of every target in every view (:func:`measure.geometry.projection.project` through the port
  that camera looks through; NaN where it has none; pixels outside the image are kept);
* ``manifest.json`` -- as a two-camera dataset's (versions, scene hash and parameters, variant,
  spp, seed, ``png_scale``, image statistics, times, ``render``, the request key, ``sha256`` of
  every other file, ``manifest_sha256``) with ``cameras`` (the folders' names, in order) and the
  per-view entries keyed by those names.

A surface scene, ``--sensor`` and a design port are refused for N cameras. Writing is atomic
and a rerun of the same request on a whole dataset does nothing
(:func:`synth.products.dataset.existing_output`). Reading (:func:`read_views_dataset`) checks
the folders against the manifest (``cam3/`` with no ``cam2/``, a folder missing a file, a file
whose SHA-256 is not the manifest's: one :class:`synth.formats.calib_yaml.DatasetError` line
naming the file or camera).
"""

from __future__ import annotations

import json
import os
import re
import time
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

from measure.geometry.projection import project
from measure.stereo.rig import Rig

from synth.infra.fileio import file_sha256
from synth.infra.provenance import package_versions
from synth.products.dataset import (FORMAT_VERSION, DatasetError, adaptive_settings, check_files,
                                    dataset_files, existing_output, image_stats, read_manifest,
                                    read_png16, read_truth_targets, request_key, write_manifest,
                                    write_targets_ply)
from synth.formats.pixels_csv import read_pixel_rows, write_pixel_rows
from synth.scene import SceneError, SceneSpec

#: The files of one view inside its folder ``camK/``: kind → name.
VIEW_FILES = {"image": "image.png", "preview": "preview.png", "exr": "image.exr"}
#: A camera folder's name.
CAMERA_FOLDER = re.compile(r"cam(\d+)")


def is_views_dataset(path) -> bool:
    """Whether the folder ``path`` is (or claims to be) a dataset of more than two cameras: its
    manifest names more than two cameras, or it holds a ``cam0/`` … folder and no
    ``left.png``. Nothing is checked here (:func:`read_views_dataset` does)."""
    path = os.fspath(path)
    try:
        with open(os.path.join(path, "manifest.json")) as fh:
            cameras = json.load(fh).get("cameras")
        if isinstance(cameras, list) and len(cameras) > 2:
            return True
    except (OSError, ValueError, AttributeError):
        pass
    return bool(camera_folders(path)) and not os.path.isfile(os.path.join(path, "left.png"))


def camera_folders(path) -> list[str]:
    """The names of the ``camK`` folders in ``path``, ordered by ``K`` (none: ``[]``)."""
    try:
        entries = os.listdir(path)
    except OSError:
        return []
    found = [(int(m.group(1)), e) for e in entries
             if (m := CAMERA_FOLDER.fullmatch(e)) and os.path.isdir(os.path.join(path, e))]
    return [e for _, e in sorted(found)]


def pixels_header(names) -> list[str]:
    """``id,x,y,z`` and ``u_<name>,v_<name>`` per camera."""
    return ["id", "x", "y", "z"] + [f"{axis}_{name}" for name in names for axis in ("u", "v")]


def write_views_pixels_csv(path, names, ids, points, pixels) -> None:
    """``pixels.csv`` of N views: ``ids`` ``(T,)``, ``points`` ``(T, 3)`` mm, ``pixels``
    ``(T, V, 2)`` px (OpenCV: integer coordinates are pixel centres); reals with 17 significant
    digits."""
    pixels = np.asarray(pixels, dtype=np.float64)
    rows = np.column_stack([np.asarray(points, np.float64), pixels.reshape(len(points), -1)])
    write_pixel_rows(path, pixels_header(names), ids, rows)


def read_views_pixels_csv(path, names) -> dict:
    """``{"id": (T,), "points": (T, 3), "pixels": (T, V, 2)}`` from a ``pixels.csv`` of the
    cameras ``names``; DatasetError (naming the file) for another header or a cut row."""
    if not os.path.isfile(path):
        raise DatasetError(f"{path}: no such file")
    rows = read_pixel_rows(path, pixels_header(names))
    return {"id": rows[:, 0].astype(int), "points": rows[:, 1:4],
            "pixels": rows[:, 4:].reshape(len(rows), len(names), 2)}


def simulated_pixels(rig: Rig, targets) -> np.ndarray:
    """The Fermat simulator's pixel of every target in every camera, ``(T, V, 2)`` px (NaN where
    none): :func:`measure.geometry.projection.project` through the port each camera looks
    through. ``targets`` ``(T, 3)`` mm, reference frame."""
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
    return np.stack([project(camera, rig.view_port(k), targets)
                     for k, camera in enumerate(rig.cameras)], axis=1)


def write_views_dataset(spec: SceneSpec, out_dir, spp: int | None = None,
                        variant: str | None = None, exr: bool = False, progress: bool = True,
                        seed: int | None = None, adaptive: bool = True) -> dict:
    """Render every camera of ``spec`` (a scene of more than two cameras) and write the dataset
    ``out_dir`` (module docs) atomically; the manifest, with ``skipped`` (True: the same
    request was already there, whole, and nothing was done) and ``rendered_again`` (why an
    earlier output of the same request was rendered again, or None) — as
    :func:`synth.products.dataset.write_dataset`."""
    from synth.rendering.render import pass_seed, render_views

    t_start = time.perf_counter()
    spec, spp, seed = _views_spec(spec, spp, seed)
    key = request_key(spec, spp, seed, variant, exr, None, adaptive, None)
    output, old, damage = existing_output(out_dir, key)
    if old is not None:
        return old
    output.claim()
    names = list(spec.camera_names)
    times = {}
    with output.staged(extra={"request_key": key}) as tmp:
        images, info = render_views(spec, spp=spp, variant=variant, progress=progress,
                                    seed=seed, adaptive=adaptive)
        times.update({f"render_{name}": info["seconds"][name] for name in names})
        times["load_mitsuba"] = info["seconds"]["load"]
        t = time.perf_counter()
        scale = _write_view_images(tmp, names, images, info, exr)
        times["write_images"] = time.perf_counter() - t
        colmap_note = _write_view_files(tmp, spec, names, times)
        times["total"] = time.perf_counter() - t_start
        files = dataset_files(tmp)
        manifest = {
            "format_version": FORMAT_VERSION,
            "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "request_key": key,
            "versions": package_versions(),
            "cameras": names,
            "colmap": ("colmap/: cameras.txt (each camera's port), rig_config.json, images.txt, "
                       "points3D.txt" if colmap_note is None else f"not written: {colmap_note}"),
            "view_files": {kind: name for kind, name in VIEW_FILES.items()
                           if kind != "exr" or exr},
            "scene": {"path": spec.path, "sha256": spec.sha256, "params": spec.params,
                      "has_port": spec.has_port, "n_targets": int(spec.targets.shape[0]),
                      "target_radius_mm": spec.target_radius, "surface": None},
            "variant": info["variant"], "variant_requested": variant,
            "integrator": info["integrator"],
            "spp": spp, "spp_rendered": info["spp_rendered"], "seed": seed,
            "seeds": {name: [pass_seed(seed, i, k) for k in range(len(info["passes"][name]))]
                      for i, name in enumerate(names)},
            "image_size": list(spec.size),
            "png_scale": scale,
            "png_offset": 0.0,
            "sensor": None,
            "images": {name: image_stats(img) for name, img in zip(names, images)},
            "samples_per_second": info["samples_per_second"],
            "samples_per_second_per_view": info["samples_per_second_per_view"],
            "passes": info["passes"],
            "render": {"settings": adaptive_settings() if adaptive else None,
                       **{name: info["render"][name] for name in names}},
            "seconds": times,
            "files": files + ["manifest.json"],
            "sha256": {name: file_sha256(os.path.join(tmp, name)) for name in files},
        }
        write_manifest(tmp, manifest)
    manifest["skipped"] = False
    manifest["rendered_again"] = damage
    return manifest


def _views_spec(spec: SceneSpec, spp, seed) -> tuple[SceneSpec, int, int]:
    """``(spec, spp, seed)``: the scene of N > 2 cameras to render with ``spp`` and ``seed``
    resolved (None: the scene's) and recorded; SceneError for two cameras, a surface scene or
    a first camera off the reference origin."""
    if not spec.extra_cameras:
        raise SceneError(f"{spec.path}: a scene of two cameras is written as a stereo dataset "
                         f"(synth.products.dataset.write_dataset)")
    if spec.surface is not None:
        raise SceneError(f"{spec.path}: a surface scene of {len(spec.all_cameras)} cameras: "
                         f"synth dataset writes surfaces (their truth maps) for two cameras")
    first = spec.all_cameras[0]
    if not (np.allclose(first.R, np.eye(3), atol=1e-12) and np.allclose(first.t, 0)):
        raise SceneError(f"{spec.path}: the first sensor must sit at the reference origin with "
                         f"identity rotation (the reference frame is the first camera's)")
    spp = spec.spp if spp is None else int(spp)
    seed = spec.seed if seed is None else int(seed)
    return spec.rendered_with(spp=spp, seed=seed), spp, seed


def _write_view_images(tmp, names, images, info, exr) -> float:
    """Each camera's folder with its 16-bit linear PNG (one scale for all), sRGB preview and,
    with ``exr``, EXR; returns the PNGs' scale."""
    from synth.rendering.image_files import png16_scale, srgb_preview, to_png16, write_exr, write_png

    scale = png16_scale(*images)
    white = max(float(img.max()) for img in images)
    for name, img in zip(names, images):
        folder = os.path.join(tmp, name)
        os.makedirs(folder)
        write_png(os.path.join(folder, VIEW_FILES["image"]), to_png16(img, scale))
        write_png(os.path.join(folder, VIEW_FILES["preview"]), srgb_preview(img, white))
        if exr:
            write_exr(os.path.join(folder, VIEW_FILES["exr"]), img, info["variant"])
    return scale


def _write_view_files(tmp, spec: SceneSpec, names, times):
    """The rig's ``calib.yaml`` and ``cameras.json``, the COLMAP model, the targets and the
    simulator's pixels into ``tmp``; returns why the COLMAP model was not written, or None."""
    from synth.formats.exchange import write_cameras_json, write_colmap_views
    from synth.products.rig_file import write_rig_file

    rig = spec.multirig
    t = time.perf_counter()
    pixels = simulated_pixels(rig, spec.targets)
    times["project"] = time.perf_counter() - t
    t = time.perf_counter()
    write_rig_file(os.path.join(tmp, "calib.yaml"), rig)
    write_cameras_json(tmp, rig, views=True)
    colmap_note = write_colmap_views(tmp, rig, spec.target_ids, spec.targets, pixels,
                                     [f"{name}/{VIEW_FILES['image']}" for name in names])
    write_targets_ply(os.path.join(tmp, "targets.ply"), spec.targets)
    write_views_pixels_csv(os.path.join(tmp, "pixels.csv"), names, spec.target_ids,
                           spec.targets, pixels)
    times["write_files"] = time.perf_counter() - t
    return colmap_note


@dataclass(frozen=True)
class ViewsDataset:
    """A dataset of N cameras read back (module docs).

    ``names`` the cameras (``cam0``, …); ``images`` one float32 linear image ``(H, W)`` per
    camera (``png / png_scale``); ``rig`` the :class:`measure.stereo.rig.Rig` of
    ``calib.yaml`` (mm, reference frame ``cam0``'s); ``targets`` ``(T, 3)`` mm from
    ``targets.ply``; ``ids`` ``(T,)`` and ``pixels`` ``(T, V, 2)`` px, the simulator's, from
    ``pixels.csv``; ``manifest`` the dict."""

    path: str
    names: tuple
    images: tuple
    rig: Rig
    targets: np.ndarray
    ids: np.ndarray
    pixels: np.ndarray
    manifest: dict


def _check_folders(path: str, names: list) -> None:
    """DatasetError unless the ``camK`` folders are exactly ``cam0 … cam{N-1}``, the manifest's
    cameras, and each holds its image."""
    folders = camera_folders(path)
    for k, folder in enumerate(folders):
        if folder != f"cam{k}":
            raise DatasetError(f"{os.path.join(path, folder)}: a camera folder with no "
                               f"{os.path.join(path, f'cam{k}')} (the cameras are cam0, cam1, "
                               f"… without a gap)")
    if folders != names:
        extra = [f for f in folders if f not in names]
        missing = [n for n in names if n not in folders]
        what = (f"{os.path.join(path, missing[0])}: no such folder (manifest.json lists "
                f"camera {missing[0]})" if missing else
                f"{os.path.join(path, extra[0])}: a camera manifest.json does not list (it "
                f"lists {', '.join(names)})")
        raise DatasetError(what)
    for name in names:
        file = os.path.join(path, name, VIEW_FILES["image"])
        if not os.path.isfile(file):
            raise DatasetError(f"{file}: no such file (camera {name} has no image)")


def read_views_dataset(path) -> ViewsDataset:
    """Read a dataset of N cameras written by :func:`write_views_dataset`; DatasetError (one
    line naming the file or camera) for anything missing, inconsistent or changed."""
    from synth.products.rig_file import read_rig_file

    path = os.fspath(path)
    manifest = read_manifest(path)
    names = manifest.get("cameras")
    if not (isinstance(names, list) and len(names) > 2 and all(isinstance(n, str) for n in names)):
        raise DatasetError(f"{os.path.join(path, 'manifest.json')}: names no cameras (not a "
                           f"dataset of more than two cameras)")
    _check_folders(path, names)
    try:
        scale = float(manifest["png_scale"])
    except (KeyError, TypeError, ValueError):
        raise DatasetError(f"{path}/manifest.json: no valid png_scale") from None
    if not (np.isfinite(scale) and scale > 0):
        raise DatasetError(f"{path}/manifest.json: png_scale must be positive, got {scale}")
    rig = read_rig_file(os.path.join(path, "calib.yaml"))
    if list(rig.names) != names:
        raise DatasetError(f"{path}/calib.yaml: cameras {', '.join(rig.names)}, but "
                           f"manifest.json lists {', '.join(names)}")
    images = []
    for name, camera in zip(names, rig.cameras):
        file = os.path.join(path, name, VIEW_FILES["image"])
        image = read_png16(file).astype(np.float32) / np.float32(scale)
        if image.shape[::-1] != tuple(camera.size):
            raise DatasetError(f"{file}: {image.shape[1]}x{image.shape[0]} px, but calib.yaml "
                               f"says {camera.size[0]:g}x{camera.size[1]:g} for {name}")
        images.append(image)
    pixels = read_views_pixels_csv(os.path.join(path, "pixels.csv"), names)
    targets = read_truth_targets(path, manifest, len(pixels["id"]))
    check_files(path, manifest)  # last: the readers above say more precisely what is wrong
    return ViewsDataset(path=path, names=tuple(names), images=tuple(images), rig=rig,
                        targets=targets, ids=pixels["id"], pixels=pixels["pixels"],
                        manifest=manifest)


__all__ = ["CAMERA_FOLDER", "VIEW_FILES", "ViewsDataset", "camera_folders", "is_views_dataset",
           "pixels_header", "read_views_dataset", "read_views_pixels_csv", "simulated_pixels",
           "write_views_dataset", "write_views_pixels_csv"]
