"""Where a dataset's files go: the one thing that differs between a pair's dataset and one of
N > 2 cameras (:func:`synth.products.dataset.write_dataset` writes both with the same stages).

* A pair (:class:`PairLayout`, views ``left`` and ``right``): ``left.png``, ``left_preview.png``,
  ``left.exr`` and the same for ``right``; ``calib.yaml`` in OpenCV's stereo layout
  (:func:`synth.formats.calib_yaml.write_calib`), ``cameras.json`` of a pair, the pair's COLMAP
  model, ``pixels.csv`` with ``u_left,v_left,u_right,v_right``; a surface scene's truth maps; a
  design port's ``calib_design.yaml`` and ``cameras_design.json``.
* N > 2 cameras (:class:`ViewsLayout`, views ``cam0``, ``cam1``, … in the scene's sensor order,
  :attr:`synth.scene.model.SceneSpec.camera_names`): a folder per camera holding that view's
  files under one name per kind (:data:`VIEW_FILES`: ``camK/image.png``, ``camK/preview.png``,
  ``camK/image.exr``); ``calib.yaml`` the rig of N cameras
  (:func:`synth.products.rig_file.write_rig_file`), ``cameras.json`` of N views, the COLMAP
  model of N images (:func:`synth.formats.exchange.write_colmap_views`), ``pixels.csv`` with
  ``u_camK,v_camK`` per camera (:func:`pixels_header`); the manifest adds ``cameras``,
  ``view_files`` and ``colmap`` first. A surface scene and a design port are refused.

Units mm, reference frame the first camera's (OpenCV axes); pixels in OpenCV's convention
(integer coordinates are pixel centres).
"""

from __future__ import annotations

import json
import os
import re
import time

import numpy as np

from measure.geometry.projection import project
from measure.stereo.rig import Rig

from synth.formats.calib_yaml import DatasetError, write_calib
from synth.formats.pixels_csv import read_pixel_rows, write_pixel_rows, write_pixels_csv
from synth.scene import SceneError, SceneSpec

#: The files of one view inside its folder ``camK/`` (N > 2 cameras): kind → name.
VIEW_FILES = {"image": "image.png", "preview": "preview.png", "exr": "image.exr"}
#: A camera folder's name.
CAMERA_FOLDER = re.compile(r"cam(\d+)")


def write_targets_ply(path, points: np.ndarray) -> None:
    """Ground-truth centres ``(N, 3)`` mm as a binary PLY point cloud written by Open3D (doubles:
    exact; Open3D's ASCII PLY keeps 6 significant digits, 5e-4 mm at 1 m)."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    if not o3d.io.write_point_cloud(str(path), cloud, write_ascii=False):
        raise OSError(f"Open3D could not write {path}")


class PairLayout:
    """A stereo pair's files (module docs)."""

    names = ("left", "right")

    @staticmethod
    def image(name: str) -> str:
        return f"{name}.png"

    @staticmethod
    def preview(name: str) -> str:
        return f"{name}_preview.png"

    @staticmethod
    def exr(name: str) -> str:
        return f"{name}.exr"

    @staticmethod
    def check(spec: SceneSpec, design) -> None:
        """Nothing to refuse beyond the writer's own checks."""

    @staticmethod
    def write_truth(tmp, spec: SceneSpec, design, times) -> dict:
        """The truth and the rig's files into ``tmp``: a surface's truth maps and depth formats,
        or the targets' PLY and simulator pixels; ``calib.yaml``, ``cameras.json`` (and the
        design port's, with ``design``), the COLMAP model. Returns ``{counts, formats,
        colmap_note}``."""
        from synth.formats.exchange import (write_cameras_json, write_colmap_model,
                                            write_surface_formats)

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
            _write_design(tmp, spec, design)
        if spec.surface is None:
            write_targets_ply(os.path.join(tmp, "targets.ply"), spec.targets)
            write_pixels_csv(os.path.join(tmp, "pixels.csv"), spec.target_ids, spec.targets,
                             uv_left, uv_right)
            truth["colmap_note"] = write_colmap_model(tmp, spec.rig, spec.has_port,
                                                      spec.target_ids, spec.targets, uv_left,
                                                      uv_right)
        else:
            truth["colmap_note"] = write_colmap_model(tmp, spec.rig, spec.has_port, [],
                                                      np.zeros((0, 3)), np.zeros((0, 2)),
                                                      np.zeros((0, 2)))
        times["write_files"] = time.perf_counter() - t
        return truth

    @staticmethod
    def manifest_head(truth: dict, exr: bool) -> dict:
        """The pair's entries before ``scene``: none."""
        return {}

    @staticmethod
    def manifest_tail(spec: SceneSpec, truth: dict, design) -> dict:
        """The pair's entries after ``seconds``: the truth's formats, the design, the COLMAP
        model's note."""
        return {"truth_formats": truth["formats"],
                **({} if design is None else {"design": design}),
                "colmap": (f"colmap/: cameras.txt ({spec.rig.port.housing}, "
                           f"metres), images.txt, points3D.txt"
                           if truth["colmap_note"] is None
                           else f"not written: {truth['colmap_note']}")}


def _write_design(tmp, spec: SceneSpec, design: dict) -> None:
    """``calib_design.yaml`` and ``cameras_design.json``: the design port a user would believe."""
    from synth.formats.exchange import write_cameras_json
    from synth.scene.design import CALIB_DESIGN, CAMERAS_DESIGN, DESIGN_NOTE, design_rig

    if not spec.has_port:
        raise SceneError(f"{spec.path}: a design port needs a scene with a port")
    believed = design_rig(spec.rig, design.get("port", {}))
    write_calib(os.path.join(tmp, CALIB_DESIGN), believed, True,
                extra={"design": {"note": DESIGN_NOTE}})
    write_cameras_json(tmp, believed, True, name=CAMERAS_DESIGN)


class ViewsLayout:
    """The files of N > 2 cameras, a folder per camera (module docs)."""

    def __init__(self, names) -> None:
        self.names = tuple(names)

    @staticmethod
    def image(name: str) -> str:
        return f"{name}/{VIEW_FILES['image']}"

    @staticmethod
    def preview(name: str) -> str:
        return f"{name}/{VIEW_FILES['preview']}"

    @staticmethod
    def exr(name: str) -> str:
        return f"{name}/{VIEW_FILES['exr']}"

    @staticmethod
    def check(spec: SceneSpec, design) -> None:
        """SceneError for a surface scene or a design port of N cameras."""
        cameras = len(spec.all_cameras)
        if spec.surface is not None:
            raise SceneError(f"{spec.path}: a surface scene of {cameras} cameras: synth "
                             f"dataset writes surfaces (their truth maps) for two cameras")
        if design is not None:
            raise SceneError(f"{spec.path}: a scene of {cameras} cameras is written without "
                             f"a design port (a design port is a stereo pair's)")

    def write_truth(self, tmp, spec: SceneSpec, design, times) -> dict:
        """The rig's ``calib.yaml`` and ``cameras.json``, the COLMAP model, the targets and the
        simulator's pixels into ``tmp``; returns ``{counts, formats, colmap_note}`` (a
        pair's keys; no truth maps)."""
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
                                         [self.image(name) for name in self.names])
        write_targets_ply(os.path.join(tmp, "targets.ply"), spec.targets)
        write_views_pixels_csv(os.path.join(tmp, "pixels.csv"), self.names, spec.target_ids,
                               spec.targets, pixels)
        times["write_files"] = time.perf_counter() - t
        return {"counts": None, "formats": None, "colmap_note": colmap_note}

    def manifest_head(self, truth: dict, exr: bool) -> dict:
        """The entries of N cameras before ``scene``: ``cameras``, ``colmap``, ``view_files``."""
        note = truth["colmap_note"]
        return {"cameras": list(self.names),
                "colmap": ("colmap/: cameras.txt (each camera's port), rig_config.json, "
                           "images.txt, points3D.txt" if note is None else f"not written: {note}"),
                "view_files": {kind: name for kind, name in VIEW_FILES.items()
                               if kind != "exr" or exr}}

    @staticmethod
    def manifest_tail(spec: SceneSpec, truth: dict, design) -> dict:
        return {}


def dataset_layout(spec: SceneSpec):
    """The layout of ``spec``'s dataset: :class:`PairLayout` for two cameras,
    :class:`ViewsLayout` (a folder per camera) for more."""
    return ViewsLayout(spec.camera_names) if spec.extra_cameras else PairLayout()


def is_views_dataset(path) -> bool:
    """Whether the folder ``path`` is (or claims to be) a dataset of more than two cameras: its
    manifest names more than two cameras, or it holds a ``cam0/`` … folder and no
    ``left.png``. Nothing is checked here (:func:`synth.products.dataset_read.read_dataset`
    does)."""
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
