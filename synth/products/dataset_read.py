"""Reading a dataset back, of any number of cameras (:func:`read_dataset`): a pair's
(:class:`Dataset`: ``left.png``, ``right.png``, ``calib.yaml`` in OpenCV's stereo layout) or
N > 2 cameras' (:class:`ViewsDataset`: ``camK/image.png``, the rig file of N cameras) — the
layouts of :mod:`synth.products.dataset_layout`. Every reader checks the manifest
(:func:`synth.products.dataset_manifest.read_manifest`), the images' sizes against the rig, the
targets against ``pixels.csv`` and, last, every file's SHA-256; DatasetError (one line naming
the file or camera) for anything missing, inconsistent or changed.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np

from measure import Rig

from synth.formats.calib_yaml import DatasetError, read_calib
from synth.formats.pixels_csv import read_pixels_csv
from synth.infra.images import imread
from synth.products.dataset_layout import (VIEW_FILES, camera_folders, is_views_dataset,
                                           read_views_pixels_csv)
from synth.products.dataset_manifest import check_files, read_manifest


@dataclass(frozen=True)
class Dataset:
    """A pair's dataset read back. Images are float32 linear (``(png − png_offset) /
    png_scale``), ``(H, W)``.

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

    @property
    def views(self) -> list:
        """``(name, image, camera, simulated pixels (T, 2))`` of each view: left, right."""
        return [("left", self.left, self.rig.left, self.pixels_left),
                ("right", self.right, self.rig.right, self.pixels_right)]


@dataclass(frozen=True)
class ViewsDataset:
    """A dataset of N > 2 cameras read back.

    ``names`` the cameras (``cam0``, …); ``images`` one float32 linear image ``(H, W)`` per
    camera (``(png − png_offset) / png_scale``); ``rig`` the :class:`measure.stereo.rig.Rig` of
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

    #: N cameras' datasets hold targets (a surface scene is refused for them).
    is_surface = False

    @property
    def views(self) -> list:
        """``(name, image, camera, simulated pixels (T, 2))`` of each camera, in order."""
        return [(name, image, camera, self.pixels[:, k]) for k, (name, image, camera)
                in enumerate(zip(self.names, self.images, self.rig.cameras))]


def read_png16(path) -> np.ndarray:
    if not os.path.isfile(path):
        raise DatasetError(f"{path}: no such file")
    img = imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"{path}: cannot read image")
    if img.ndim != 2 or img.dtype != np.uint16:
        raise DatasetError(f"{path}: expected a 16-bit single-channel PNG")
    return img


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


def read_dataset(path) -> Dataset | ViewsDataset:
    """Read a dataset directory written by :func:`synth.products.dataset.write_dataset`: a
    pair's (:class:`Dataset`) or, where the manifest names more than two cameras or the folder
    holds ``camK/`` folders and no ``left.png``, N cameras' (:class:`ViewsDataset`)."""
    path = os.fspath(path)
    manifest = read_manifest(path)
    if is_views_dataset(path):
        return _read_views(path, manifest)
    return _read_pair(path, manifest)


def _png_scale_offset(path: str, manifest: dict) -> tuple[float, float]:
    """The manifest's ``png_scale`` (positive) and ``png_offset`` (0 when absent)."""
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
    return scale, offset


def _read_image(file: str, scale: float, offset: float) -> np.ndarray:
    """A 16-bit PNG as float32 linear: ``(png − offset) / scale``."""
    return (read_png16(file).astype(np.float32) - np.float32(offset)) / np.float32(scale)


def _read_pair(path: str, manifest: dict) -> Dataset:
    """A pair's dataset (module docs)."""
    scale, offset = _png_scale_offset(path, manifest)
    left, right = (_read_image(os.path.join(path, f"{view}.png"), scale, offset)
                   for view in ("left", "right"))
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


def _read_views(path: str, manifest: dict) -> ViewsDataset:
    """A dataset of N > 2 cameras (module docs)."""
    from synth.products.rig_file import read_rig_file

    names = manifest.get("cameras")
    if not (isinstance(names, list) and len(names) > 2 and all(isinstance(n, str) for n in names)):
        raise DatasetError(f"{os.path.join(path, 'manifest.json')}: names no cameras (not a "
                           f"dataset of more than two cameras)")
    _check_folders(path, names)
    scale, offset = _png_scale_offset(path, manifest)
    rig = read_rig_file(os.path.join(path, "calib.yaml"))
    if list(rig.names) != names:
        raise DatasetError(f"{path}/calib.yaml: cameras {', '.join(rig.names)}, but "
                           f"manifest.json lists {', '.join(names)}")
    images = []
    for name, camera in zip(names, rig.cameras):
        file = os.path.join(path, name, VIEW_FILES["image"])
        image = _read_image(file, scale, offset)
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
