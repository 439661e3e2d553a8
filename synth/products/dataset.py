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

import csv
import hashlib
import json
import os
import time
from dataclasses import dataclass
from datetime import datetime, timezone

import cv2
import numpy as np

from measure import Camera, FlatPort, StereoRig
from measure.geometry.camera import BROWN_CONRADY
from measure.geometry.dome import DomePair, DomePort
from measure.geometry.flat_pair import FlatPair
from measure.geometry.projection import project
from measure.geometry.flatport_format import write_calib_port

from synth.formats.calib_formats import (CalibFormatError, calib_dict, calib_format, read_calibmar,
                                 read_colmap, stereo_extrinsics)
from synth.formats.exchange import write_cameras_json, write_colmap_model, write_surface_formats
from synth.infra.fileio import OutputDir, file_sha256, read_marker
from synth.rendering.integrator import RENDERER
from synth.infra.provenance import package_versions
from synth.rendering.render import (pass_seed, png16_scale, render_stereo, srgb_preview, to_png16,
                          write_exr, write_png)
from synth.scene import SceneError, SceneSpec, load_scene
from synth.infra.images import imread

FORMAT_VERSION = 4  # 2: targets.ply in binary doubles (was ASCII, 6 digits); 3: hashes;
#                    4: cameras.json, colmap/, surfaces' PFM / PNG depth and .flo (synth.formats.exchange)
PIXELS_HEADER = ["id", "x", "y", "z", "u_left", "v_left", "u_right", "v_right"]


class DatasetError(ValueError):
    """A dataset directory that cannot be read or written."""


# ---------------------------------------------------------------------------------------------
# calibration in OpenCV's stereo convention
# ---------------------------------------------------------------------------------------------
def _dist5(camera: Camera) -> np.ndarray:
    return np.zeros(5) if camera.dist is None else camera.dist.copy()


def write_node(fs, name: str, value) -> None:
    """A number, string, list or map as the FileStorage node ``name`` (maps and lists nest)."""
    if isinstance(value, dict):
        fs.startWriteStruct(name, cv2.FileNode_MAP)
        for key, item in value.items():
            write_node(fs, str(key), item)
        fs.endWriteStruct()
    elif isinstance(value, (list, tuple)):
        fs.startWriteStruct(name, cv2.FileNode_SEQ)
        for item in value:
            write_node(fs, "", item)
        fs.endWriteStruct()
    elif isinstance(value, str):
        fs.write(name, value)
    else:
        fs.write(name, float(value))


def write_calib(path, rig: StereoRig, has_port: bool = True, extra: dict | None = None,
                covariance=None) -> None:
    """Write ``calib.yaml`` (see module docs) with ``cv2.FileStorage``; ``extra`` adds maps
    (e.g. ``uncertainty``) of numbers, strings, lists and maps after the standard nodes;
    ``covariance`` (:class:`measure.stereo.rig_covariance.RigCovariance`) a ``covariance`` node:
    ``names`` (a sequence of parameter names), ``matrix`` (P x P), ``normal_axes`` (2 x 3)."""
    left, right = rig.left, rig.right
    R, T = stereo_extrinsics(left, right)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        fs.write("image_width", int(left.size[0]))
        fs.write("image_height", int(left.size[1]))
        fs.write("units", "mm")
        fs.write("K1", left.K)
        fs.write("D1", _dist5(left).reshape(1, -1))
        fs.write("K2", right.K)
        fs.write("D2", _dist5(right).reshape(1, -1))
        for key, camera in (("D1_model", left), ("D2_model", right)):
            if camera.distortion_model != BROWN_CONRADY:  # absent: OpenCV's Brown–Conrady
                fs.write(key, camera.distortion_model)
        fs.write("R", R)
        fs.write("T", T.reshape(3, 1))
        write_calib_port(fs, rig.port, has_port)
        if covariance is not None:
            fs.startWriteStruct("covariance", cv2.FileNode_MAP)
            write_node(fs, "names", list(covariance.names))
            fs.write("matrix", covariance.matrix)
            if covariance.normal_axes is not None:
                fs.write("normal_axes", covariance.normal_axes)
            fs.endWriteStruct()
        for name, value in (extra or {}).items():
            write_node(fs, name, value)
    finally:
        fs.release()


def _seq(node) -> list[float]:
    if node.isSeq():
        return [node.at(i).real() for i in range(node.size())]
    mat = node.mat()
    return [] if mat is None else [float(v) for v in mat.ravel()]


def read_calib(path) -> dict:
    """Read a stereo calibration: a dict with ``size``, ``K1``, ``D1``, ``K2``, ``D2``, ``R``,
    ``T``, ``port`` (:class:`measure.FlatPort`, a FlatPair or a DomePair), ``has_port`` and ``rig``
    (:class:`measure.StereoRig`, the left camera at the reference origin). The file is this
    project's ``calib.yaml``, a calibmar stereo calibration (either of its two YAML files) or
    the COLMAP fork's ``cameras.txt`` with ``rig_config.json`` beside it, told apart by content
    (:mod:`synth.formats.calib_formats`). Anything unreadable or inconsistent raises
    :class:`DatasetError` naming the file."""
    kind = calib_format(path) if os.path.isfile(path) else "opencv"
    try:
        if kind == "calibmar":
            return read_calibmar(path)
        if kind == "colmap":
            return read_colmap(path)
        return _read_calib(path)
    except DatasetError:
        raise
    except CalibFormatError as exc:  # its message starts with the file
        raise DatasetError(str(exc)) from None
    except (cv2.error, SystemError):  # OpenCV's parser: not YAML/XML FileStorage
        raise DatasetError(f"{path}: not a valid OpenCV FileStorage calibration file") from None
    except (ValueError, TypeError, AttributeError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        raise DatasetError(f"{path}: not a valid calibration file ({message[:200]})") from None


def not_a_file(path) -> str:
    """What to say of a calibration ``path`` that is not a file: a folder (and the calibration
    file inside it, when there is one) or nothing at all."""
    if os.path.isdir(path):
        inside = [n for n in ("calib.yaml", "camera.yaml") if os.path.isfile(os.path.join(path, n))]
        return (f"{path}: a folder, not a calibration file"
                + (f" (give {os.path.join(path, inside[0])})" if inside else ""))
    return f"{path}: no such file"


def other_calibration(fs, path) -> str | None:
    """Why the OpenCV FileStorage ``fs`` of ``path`` is not a stereo pair's calibration when it
    is another one: one camera's ``camera.yaml`` (``camera_matrix``) or a rig of N cameras
    (``cameras``); None otherwise."""
    if fs.getNode("K1").empty() and not fs.getNode("camera_matrix").empty():
        return (f"{path}: a calibration of one camera (camera_matrix: eval calibrate of one "
                f"camera's folder), not of a stereo pair (K1, K2, R, T): give the rig's calib.yaml")
    cameras = fs.getNode("cameras")
    if fs.getNode("K1").empty() and cameras.isSeq():
        return (f"{path}: a calibration of {cameras.size()} cameras, not of a stereo pair "
                f"(K1, K2, R, T): this reads two cameras")
    return None


def _read_calib(path) -> dict:
    if not os.path.isfile(path):
        raise DatasetError(not_a_file(path))
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise DatasetError(f"{path}: cannot open as OpenCV FileStorage")
    try:
        other = other_calibration(fs, path)
        if other:
            raise DatasetError(other)
        units = fs.getNode("units")
        if not units.empty() and not (units.isString() and units.string().strip() == "mm"):
            said = units.string() if units.isString() else units.real()
            raise DatasetError(f"{path}: units: {said!r}: only mm is read (every length of "
                               f"calib.yaml in millimetres, units: mm)")
        out = {"size": (int(fs.getNode("image_width").real()),
                        int(fs.getNode("image_height").real()))}
        for name in ("K1", "D1", "K2", "D2", "R", "T"):
            mat = fs.getNode(name).mat()
            if mat is None:
                raise DatasetError(f"{path}: no matrix {name}")
            out[name] = np.asarray(mat, dtype=np.float64)
        pnode, dnode, pairnode = fs.getNode("port"), fs.getNode("dome"), fs.getNode("ports")
        given = [name for name, node in (("port", pnode), ("dome", dnode), ("ports", pairnode))
                 if not node.empty()]
        if len(given) > 1:
            raise DatasetError(f"{path}: holds both a {' and a '.join(given)} map; a calibration "
                               f"has one (port: one flat port, ports: a flat port per camera, "
                               f"dome: a dome per camera)")
        if not dnode.empty():
            out["port"], out["has_port"] = _read_domes(path, dnode), True
        elif not pairnode.empty():
            out["port"], out["has_port"] = _read_flat_pair(path, pairnode), True
        else:
            if pnode.empty() or pnode.getNode("normal").mat() is None:
                raise DatasetError(f"{path}: no port map (normal, distance, thicknesses, "
                                   f"indices) and no dome map")
            present = pnode.getNode("present")
            if not present.empty() and not (present.isInt() and present.real() in (0, 1)):
                said = present.string() if present.isString() else f"{present.real():g}"
                raise DatasetError(f"{path}: port: present: {said}: must be 0 (in air: the "
                                   f"port bends no ray) or 1 (the port refracts)")
            out["has_port"] = bool(present.real()) if not present.empty() else True
            indices = tuple(_seq(pnode.getNode("indices")))
            if not out["has_port"]:  # in air: what the rig measures through is index-matched
                indices = (1.0,) * len(indices)
            out["port"] = FlatPort(pnode.getNode("normal").mat().ravel(),
                                   pnode.getNode("distance").real(),
                                   tuple(_seq(pnode.getNode("thicknesses"))), indices)
        covariance = _read_covariance(path, fs.getNode("covariance"))
        models = []
        for key in ("D1_model", "D2_model"):
            node = fs.getNode(key)
            models.append(BROWN_CONRADY if node.empty() else node.string().strip())
    finally:
        fs.release()
    calib = calib_dict(out["size"], out["K1"], out["D1"], out["K2"], out["D2"], out["R"],
                       out["T"], out["port"], out["has_port"], str(path), tuple(models))
    calib["covariance"] = covariance
    return calib


def _read_flat_pair(path, node) -> FlatPair:
    """The ``ports`` map of ``calib.yaml`` (two housings): ``left`` and ``right`` maps of
    ``normal`` (3x1), ``distance``, ``thicknesses`` and ``indices`` (reference frame, mm), each
    the port that camera looks through."""
    ports = []
    for name in ("left", "right"):
        sub = node.getNode(name)
        normal = None if sub.empty() else sub.getNode("normal").mat()
        if normal is None:
            raise DatasetError(f"{path}: ports: no {name} map (normal, distance, thicknesses, "
                               f"indices): a port per camera needs both left and right")
        if sub.getNode("distance").empty():
            raise DatasetError(f"{path}: ports: {name}: no distance")
        try:
            ports.append(FlatPort(normal.ravel(), sub.getNode("distance").real(),
                                  tuple(_seq(sub.getNode("thicknesses"))),
                                  tuple(_seq(sub.getNode("indices")))))
        except ValueError as exc:
            raise DatasetError(f"{path}: ports: {name}: {exc}") from None
    return FlatPair(*ports)


def _read_domes(path, node) -> DomePair:
    """The ``dome`` map of ``calib.yaml``: ``left`` and ``right`` maps of ``center`` (3x1, mm,
    reference frame), ``radius``, ``thickness`` (mm) and ``indices`` (air, glass, water)."""
    domes = []
    for name in ("left", "right"):
        sub = node.getNode(name)
        centre = None if sub.empty() else sub.getNode("center").mat()
        if centre is None:
            raise DatasetError(f"{path}: dome map without a {name} dome (center, radius, "
                               f"thickness, indices)")
        try:
            from synth.scene.dome import check_dome_size

            check_dome_size(sub.getNode("radius").real(), sub.getNode("thickness").real())
            domes.append(DomePort(centre.ravel(), sub.getNode("radius").real(),
                                  sub.getNode("thickness").real(),
                                  tuple(_seq(sub.getNode("indices")))))
        except ValueError as exc:
            raise DatasetError(f"{path}: {name} dome: {exc}") from None
    return DomePair(*domes)


def _read_covariance(path, node):
    """The ``covariance`` node as a :class:`measure.stereo.rig_covariance.RigCovariance`, or None when
    the file has none; DatasetError naming the file when it is malformed, singular or not
    positive definite (:func:`synth.formats.calib_formats.read_covariance_node`)."""
    from synth.formats.calib_formats import read_covariance_node

    return read_covariance_node(path, node, DatasetError)


# ---------------------------------------------------------------------------------------------
# small writers
# ---------------------------------------------------------------------------------------------
def write_targets_ply(path, points: np.ndarray) -> None:
    """Ground-truth centres ``(N, 3)`` mm as a binary PLY point cloud written by Open3D (doubles:
    exact; Open3D's ASCII PLY keeps 6 significant digits, 5e-4 mm at 1 m)."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    if not o3d.io.write_point_cloud(str(path), cloud, write_ascii=False):
        raise OSError(f"Open3D could not write {path}")


def write_pixels_csv(path, ids, points, uv_left, uv_right) -> None:
    """``pixels.csv`` with header :data:`PIXELS_HEADER`; reals with 17 significant digits."""
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(PIXELS_HEADER)
        for i, p, a, b in zip(ids, points, uv_left, uv_right):
            writer.writerow([int(i)] + [f"{v:.17g}" for v in (*p, *a, *b)])


def read_pixels_csv(path) -> dict:
    """``{"id": (N,), "points": (N, 3), "left": (N, 2), "right": (N, 2)}`` from ``pixels.csv``."""
    with open(path, newline="", encoding="utf-8-sig") as fh:
        text = fh.read()
    reader = csv.reader(text.splitlines())
    header = next(reader, None)
    if header != PIXELS_HEADER:
        raise DatasetError(f"{path}: header is {header}, expected {PIXELS_HEADER}")
    values = []
    for line, row in enumerate(reader, start=2):
        if len(row) != len(PIXELS_HEADER):
            raise DatasetError(f"{path}: line {line} has {len(row)} values, the header "
                               f"{len(PIXELS_HEADER)}: truncated or malformed")
        values.append([float(v) for v in row])
    if values and not text.endswith("\n"):  # the writer ends every row: cut mid-row
        raise DatasetError(f"{path}: the last line is not complete: truncated")
    rows = np.array(values, dtype=np.float64).reshape(-1, len(PIXELS_HEADER))
    return {"id": rows[:, 0].astype(int), "points": rows[:, 1:4], "left": rows[:, 4:6],
            "right": rows[:, 6:8]}


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
    spec = spec.rendered_with(spp=spp, seed=seed)  # the parameters say what was rendered
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
        times["write_images"] = time.perf_counter() - t

        truth_counts = truth_formats = colmap_note = None
        if spec.surface is not None:
            from synth.products.truth_maps import write_truth_maps

            t = time.perf_counter()
            truth_counts = write_truth_maps(tmp, spec.rig, spec.surface.mesh_path,
                                            spec.surface.vertices, spec.surface.triangles)
            truth_formats = write_surface_formats(tmp, spec.rig)
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
            colmap_note = write_colmap_model(tmp, spec.rig, spec.has_port, spec.target_ids,
                                             spec.targets, uv_left, uv_right)
        else:
            colmap_note = write_colmap_model(tmp, spec.rig, spec.has_port, [], np.zeros((0, 3)),
                                             np.zeros((0, 2)), np.zeros((0, 2)))
        times["write_files"] = time.perf_counter() - t
        times["total"] = time.perf_counter() - t_start

        manifest = {
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
                                   "truth_pixels": truth_counts})},
            "variant": info["variant"], "variant_requested": variant,
            "integrator": info["integrator"],
            "spp": spp, "spp_rendered": info["spp_rendered"], "seed": seed,
            "seeds": {view: [pass_seed(seed, i, k) for k in range(len(info["passes"][view]))]
                      for i, view in enumerate(("left", "right"))},
            "image_size": list(spec.size),
            "png_scale": scale,
            "png_offset": offset,
            "sensor": sensor_info,
            "images": {"left": image_stats(left), "right": image_stats(right)},
            "samples_per_second": info["samples_per_second"],
            "samples_per_second_per_view": info["samples_per_second_per_view"],
            "passes": info["passes"],
            "render": {"settings": adaptive_settings() if adaptive else None,
                       **{view: info["render"][view] for view in ("left", "right")}},
            "seconds": times,
            "truth_formats": truth_formats,
            **({} if design is None else {"design": design}),
            "colmap": (f"colmap/: cameras.txt ({spec.rig.port.housing}, "
                       f"metres), images.txt, points3D.txt"
                       if colmap_note is None else f"not written: {colmap_note}"),
            "files": dataset_files(tmp) + ["manifest.json"],
            "sha256": {name: file_sha256(os.path.join(tmp, name))
                       for name in dataset_files(tmp)},
        }
        manifest["manifest_sha256"] = manifest_digest(manifest)
        with open(os.path.join(tmp, "manifest.json"), "w") as fh:
            json.dump(manifest, fh, indent=2, sort_keys=False)
            fh.write("\n")
    manifest["skipped"] = False
    manifest["rendered_again"] = damage  # why an earlier output of this request was not whole
    return manifest


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
    rig: StereoRig
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
    except (OSError, ValueError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else exc
        raise DatasetError(f"{path}/pixels.csv: {reason}") from None
    targets_path = os.path.join(path, "targets.ply")
    if not os.path.isfile(targets_path):
        raise DatasetError(f"{targets_path}: no such file")
    from synth.formats.cloudfile import CloudFileError, read_cloud_points

    try:  # whole or refused: Open3D reads a truncated PLY as far as it goes
        targets = read_cloud_points(targets_path)
    except CloudFileError as exc:
        raise DatasetError(str(exc)) from None
    n_targets = manifest["scene"].get("n_targets")
    for name, count in (("targets.ply", targets.shape[0]), ("pixels.csv", pixels["id"].shape[0])):
        if n_targets is not None and count != n_targets:
            raise DatasetError(f"{path}/{name}: {count} targets, but manifest.json says "
                               f"{n_targets}")
    if targets.shape[0] != pixels["id"].shape[0]:
        raise DatasetError(f"{path}: targets.ply has {targets.shape[0]} points but pixels.csv "
                           f"{pixels['id'].shape[0]} rows")
    check_files(path, manifest)  # last: the readers above say more precisely what is wrong
    return Dataset(path=path, left=left, right=right, rig=calib["rig"],
                   has_port=calib["has_port"], targets=targets, ids=pixels["id"],
                   pixels_left=pixels["left"], pixels_right=pixels["right"], manifest=manifest)
