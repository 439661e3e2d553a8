"""Benchmark datasets: render a scene and write files anyone can read without this project.

A dataset directory holds (units mm, reference frame = the left camera's, OpenCV axes):

* ``left.png``, ``right.png`` -- 16-bit single-channel **linear** images,
  ``png = round(linear * png_scale)`` with one ``png_scale`` for both views (manifest) such that
  the brightest pixel is 65535; ``left_preview.png``, ``right_preview.png`` -- 8-bit sRGB;
  ``left.exr``, ``right.exr`` -- float32 linear, on request;
* ``calib.yaml`` -- OpenCV FileStorage: ``image_width``, ``image_height``, ``K1``, ``D1``,
  ``K2``, ``D2``, ``R``, ``T`` (OpenCV stereo convention ``X_right = R·X_left + T``), ``units``
  and a map ``port`` {``normal`` (3x1), ``distance``, ``thicknesses`` (sequence),
  ``indices`` (sequence), ``present`` (0 for an all-air scene, whose port is index-matched)};
* ``targets.ply`` -- ground-truth target centres in target order (Open3D, ASCII);
* ``pixels.csv`` -- ``id,x,y,z,u_left,v_left,u_right,v_right``: the Fermat simulator's pixel of
  every target in each view (NaN where it has none; pixels outside the image are kept);
* ``manifest.json`` -- versions, scene hash and parameters, variant, spp, seed, image
  statistics, ``png_scale``, the time of every stage, and the request key.

Writing is atomic: everything goes to a temporary sibling directory that is renamed at the end.
A rerun with the same request (scene bytes, resolved parameters, spp, seed, variant request,
EXR) finds the manifest's key and does nothing.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import platform
import time
from dataclasses import dataclass
from datetime import datetime, timezone

import cv2
import numpy as np

from measure import Camera, FlatPort, StereoRig

from .fileio import staged_dir
from .project import project
from .render import png16_scale, render_stereo, srgb_preview, to_png16, write_exr, write_png
from .scene import SceneError, SceneSpec, load_scene

FORMAT_VERSION = 1
PIXELS_HEADER = ["id", "x", "y", "z", "u_left", "v_left", "u_right", "v_right"]
#: Bounds of ``python -m synth check`` (issue 3): RMS and max centre distance, px.
CHECK_RMS_PX = 0.05
CHECK_MAX_PX = 0.15


class DatasetError(ValueError):
    """A dataset directory that cannot be read or written."""


# ---------------------------------------------------------------------------------------------
# calibration in OpenCV's stereo convention
# ---------------------------------------------------------------------------------------------
def stereo_extrinsics(left: Camera, right: Camera) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's stereo ``R, T`` (``X_right = R·X_left + T``) from two camera-to-reference poses."""
    R = right.R.T @ left.R
    T = right.R.T @ (left.t - right.t)
    return R, T


def _dist5(camera: Camera) -> np.ndarray:
    return np.zeros(5) if camera.dist is None else camera.dist.copy()


def write_calib(path, rig: StereoRig, has_port: bool = True) -> None:
    """Write ``calib.yaml`` (see module docs) with ``cv2.FileStorage``."""
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
        fs.write("R", R)
        fs.write("T", T.reshape(3, 1))
        port = rig.port
        fs.startWriteStruct("port", cv2.FileNode_MAP)
        fs.write("present", int(has_port))
        fs.write("normal", port.normal.reshape(3, 1))
        fs.write("distance", float(port.distance))
        for name, values in (("thicknesses", port.thicknesses), ("indices", port.indices)):
            fs.startWriteStruct(name, cv2.FileNode_SEQ)
            for v in values:
                fs.write("", float(v))
            fs.endWriteStruct()
        fs.endWriteStruct()
    finally:
        fs.release()


def _seq(node) -> list[float]:
    if node.isSeq():
        return [node.at(i).real() for i in range(node.size())]
    mat = node.mat()
    return [] if mat is None else [float(v) for v in mat.ravel()]


def read_calib(path) -> dict:
    """Read ``calib.yaml``: a dict with ``size``, ``K1``, ``D1``, ``K2``, ``D2``, ``R``, ``T``,
    ``port`` (:class:`measure.FlatPort`), ``has_port`` and ``rig`` (:class:`measure.StereoRig`,
    the left camera at the reference origin)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise DatasetError(f"{path}: cannot open as OpenCV FileStorage")
    try:
        out = {"size": (int(fs.getNode("image_width").real()),
                        int(fs.getNode("image_height").real()))}
        for name in ("K1", "D1", "K2", "D2", "R", "T"):
            mat = fs.getNode(name).mat()
            if mat is None:
                raise DatasetError(f"{path}: no matrix {name}")
            out[name] = np.asarray(mat, dtype=np.float64)
        pnode = fs.getNode("port")
        out["port"] = FlatPort(pnode.getNode("normal").mat().ravel(),
                               pnode.getNode("distance").real(),
                               tuple(_seq(pnode.getNode("thicknesses"))),
                               tuple(_seq(pnode.getNode("indices"))))
        present = pnode.getNode("present")
        out["has_port"] = bool(present.real()) if not present.empty() else True
    finally:
        fs.release()
    left = Camera(out["K1"], out["size"], dist=out["D1"].ravel())
    R, T = out["R"], out["T"].ravel()
    right = Camera(out["K2"], out["size"], dist=out["D2"].ravel(), R=R.T, t=-R.T @ T)
    out["rig"] = StereoRig(left, right, out["port"])
    return out


# ---------------------------------------------------------------------------------------------
# small writers
# ---------------------------------------------------------------------------------------------
def write_targets_ply(path, points: np.ndarray) -> None:
    """Ground-truth centres ``(N, 3)`` mm as an ASCII PLY point cloud written by Open3D."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    if not o3d.io.write_point_cloud(str(path), cloud, write_ascii=True):
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
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header != PIXELS_HEADER:
            raise DatasetError(f"{path}: header is {header}, expected {PIXELS_HEADER}")
        rows = np.array([[float(v) for v in row] for row in reader], dtype=np.float64)
    rows = rows.reshape(-1, len(PIXELS_HEADER))
    return {"id": rows[:, 0].astype(int), "points": rows[:, 1:4], "left": rows[:, 4:6],
            "right": rows[:, 6:8]}


def package_versions() -> dict:
    """Versions of Python, the platform and the packages a result depends on (for manifests)."""
    import importlib.metadata as md

    out = {"python": platform.python_version(), "platform": platform.platform()}
    for dist in ("refractive-stereo", "numpy", "scipy", "opencv-python-headless",
                 "opencv-python", "mitsuba", "drjit", "open3d-cpu", "open3d", "matplotlib", "tqdm"):
        try:
            out[dist] = md.version(dist)
        except md.PackageNotFoundError:
            pass
    out["cv2"] = cv2.__version__
    return out


def _image_stats(image: np.ndarray) -> dict:
    return {"min": float(image.min()), "max": float(image.max()), "mean": float(image.mean()),
            "lit_fraction": float(np.mean(image > 0))}


def request_key(spec: SceneSpec, spp: int, seed: int, variant: str | None, exr: bool) -> str:
    """Hash of everything that determines a dataset's content."""
    blob = json.dumps({"format": FORMAT_VERSION, "scene": spec.sha256, "params": spec.params,
                       "spp": spp, "seed": seed, "variant": variant, "exr": bool(exr)},
                      sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


# ---------------------------------------------------------------------------------------------
# write / read / check
# ---------------------------------------------------------------------------------------------
def write_dataset(scene, out_dir, spp: int | None = None, defines: dict | None = None,
                  variant: str | None = None, exr: bool = False, progress: bool = True,
                  seed: int | None = None) -> dict:
    """Render ``scene`` (a path or :class:`SceneSpec`) and write a dataset to ``out_dir``.

    Returns the manifest (dict); ``manifest["skipped"]`` is True when ``out_dir`` already held
    the same request and nothing was done. An existing ``out_dir`` that is not a dataset of ours
    (no ``manifest.json``) is an error; one with another request is replaced atomically.
    """
    t_start = time.perf_counter()
    times = {}
    t = time.perf_counter()
    spec = scene if isinstance(scene, SceneSpec) else load_scene(scene, defines)
    times["load_scene"] = time.perf_counter() - t
    left_cam = spec.rig.left
    if not (np.allclose(left_cam.R, np.eye(3), atol=1e-12) and np.allclose(left_cam.t, 0)):
        raise SceneError(f"{spec.path}: the left sensor must sit at the reference origin with "
                         f"identity rotation (the reference frame is the left camera's)")
    spp = spec.spp if spp is None else int(spp)
    seed = spec.seed if seed is None else int(seed)
    key = request_key(spec, spp, seed, variant, exr)

    out_dir = os.path.abspath(os.fspath(out_dir))
    manifest_path = os.path.join(out_dir, "manifest.json")
    if os.path.exists(out_dir):
        if not os.path.isdir(out_dir):
            raise DatasetError(f"{out_dir}: exists and is not a directory")
        if os.listdir(out_dir) and not os.path.isfile(manifest_path):
            raise DatasetError(f"{out_dir}: exists, is not empty and holds no manifest.json; "
                               f"refusing to replace it")
        if os.path.isfile(manifest_path):
            try:
                with open(manifest_path) as fh:
                    old = json.load(fh)
            except (OSError, ValueError):
                old = {}
            if old.get("request_key") == key:
                old["skipped"] = True
                return old

    with staged_dir(out_dir) as tmp:
        left, right, info = render_stereo(spec, spp=spp, variant=variant, progress=progress,
                                          seed=seed)
        times["render_left"] = info["seconds"]["left"]
        times["render_right"] = info["seconds"]["right"]
        times["load_mitsuba"] = info["seconds"]["load"]

        t = time.perf_counter()
        scale = png16_scale(left, right)
        white = max(float(left.max()), float(right.max()))
        for name, img in (("left", left), ("right", right)):
            write_png(os.path.join(tmp, f"{name}.png"), to_png16(img, scale))
            write_png(os.path.join(tmp, f"{name}_preview.png"), srgb_preview(img, white))
            if exr:
                write_exr(os.path.join(tmp, f"{name}.exr"), img, info["variant"])
        times["write_images"] = time.perf_counter() - t

        t = time.perf_counter()
        uv_left = project(spec.rig.left, spec.rig.port, spec.targets)
        uv_right = project(spec.rig.right, spec.rig.port, spec.targets)
        times["project"] = time.perf_counter() - t

        t = time.perf_counter()
        write_calib(os.path.join(tmp, "calib.yaml"), spec.rig, spec.has_port)
        write_targets_ply(os.path.join(tmp, "targets.ply"), spec.targets)
        write_pixels_csv(os.path.join(tmp, "pixels.csv"), spec.target_ids, spec.targets,
                         uv_left, uv_right)
        times["write_files"] = time.perf_counter() - t
        times["total"] = time.perf_counter() - t_start

        manifest = {
            "format_version": FORMAT_VERSION,
            "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "request_key": key,
            "versions": package_versions(),
            "scene": {"path": spec.path, "sha256": spec.sha256, "params": spec.params,
                      "has_port": spec.has_port, "n_targets": int(spec.targets.shape[0]),
                      "target_radius_mm": spec.target_radius},
            "variant": info["variant"], "variant_requested": variant,
            "spp": spp, "spp_rendered": info["spp_rendered"], "seed": seed,
            "seeds": {"left": seed, "right": seed + 1},
            "image_size": list(spec.size),
            "png_scale": scale,
            "images": {"left": _image_stats(left), "right": _image_stats(right)},
            "samples_per_second": info["samples_per_second"],
            "seconds": times,
            "files": sorted(os.listdir(tmp)) + ["manifest.json"],
        }
        with open(os.path.join(tmp, "manifest.json"), "w") as fh:
            json.dump(manifest, fh, indent=2, sort_keys=False)
            fh.write("\n")
    manifest["skipped"] = False
    return manifest


@dataclass(frozen=True)
class Dataset:
    """A dataset read back. Images are float32 linear (``png / png_scale``), ``(H, W)``.

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


def _read_png16(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"{path}: cannot read image")
    if img.ndim != 2 or img.dtype != np.uint16:
        raise DatasetError(f"{path}: expected a 16-bit single-channel PNG")
    return img


def read_dataset(path) -> Dataset:
    """Read a dataset directory written by :func:`write_dataset`."""
    path = os.fspath(path)
    manifest_path = os.path.join(path, "manifest.json")
    try:
        with open(manifest_path) as fh:
            manifest = json.load(fh)
    except OSError as exc:
        raise DatasetError(f"{path}: not a dataset ({exc.strerror or exc}: manifest.json)") from None
    except ValueError as exc:
        raise DatasetError(f"{manifest_path}: malformed JSON ({exc})") from None
    scale = float(manifest["png_scale"])
    left = _read_png16(os.path.join(path, "left.png")).astype(np.float32) / np.float32(scale)
    right = _read_png16(os.path.join(path, "right.png")).astype(np.float32) / np.float32(scale)
    calib = read_calib(os.path.join(path, "calib.yaml"))
    pixels = read_pixels_csv(os.path.join(path, "pixels.csv"))
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(os.path.join(path, "targets.ply"))
    targets = np.asarray(cloud.points, dtype=np.float64)
    return Dataset(path=path, left=left, right=right, rig=calib["rig"],
                   has_port=calib["has_port"], targets=targets, ids=pixels["id"],
                   pixels_left=pixels["left"], pixels_right=pixels["right"], manifest=manifest)


def match_detections(detected: np.ndarray, expected: np.ndarray, gate_px: float):
    """Mutual nearest neighbours within ``gate_px``: ``(index_into_expected, distance)`` per
    detection (-1 and inf where unmatched)."""
    detected = np.asarray(detected, float).reshape(-1, 2)
    expected = np.asarray(expected, float).reshape(-1, 2)
    idx = np.full(detected.shape[0], -1)
    dist = np.full(detected.shape[0], np.inf)
    if detected.size == 0 or expected.size == 0:
        return idx, dist
    from scipy.spatial import cKDTree

    finite = np.all(np.isfinite(expected), axis=1)
    tree_e = cKDTree(np.where(finite[:, None], expected, 1e12))
    d1, j = tree_e.query(detected)
    tree_d = cKDTree(detected)
    _, back = tree_d.query(np.where(finite[:, None], expected, 1e12))
    ok = (d1 <= gate_px) & (back[j] == np.arange(detected.shape[0]))
    idx[ok], dist[ok] = j[ok], d1[ok]
    return idx, dist


def wholly_in_image(camera: Camera, uv: np.ndarray, points: np.ndarray,
                    radius_mm: float) -> np.ndarray:
    """Whether each target's image lies wholly inside the image, ``(N,)`` bool.

    ``uv`` are the simulator's pixels of the target centres ``points`` (NaN where none). A
    target's image may reach twice its pinhole radius (``f · radius / z``, the port magnifies it)
    plus 2 px from its centre; it must stay that far from the border.
    """
    z = camera.to_camera(points)[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        radius_px = camera.K[0, 0] * radius_mm / np.where(z > 0, z, np.nan)
    margin = 2.0 * np.nan_to_num(radius_px, nan=0.0) + 2.0
    w, h = camera.size
    with np.errstate(invalid="ignore"):
        return ((uv[:, 0] >= margin - 0.5) & (uv[:, 0] <= w - 0.5 - margin)
                & (uv[:, 1] >= margin - 0.5) & (uv[:, 1] <= h - 0.5 - margin))


def check_dataset(path, rms_px: float = CHECK_RMS_PX, max_px: float = CHECK_MAX_PX,
                  gate_px: float = 2.0) -> dict:
    """Detect the targets in both images and compare them with ``pixels.csv``.

    A target is *in the image* when its simulated pixel lies farther inside the image than its
    image can reach (twice its pinhole radius + 2 px): those must all be found. Detections are
    paired with simulated pixels as mutual nearest neighbours within ``gate_px``. Returns a dict:
    per view (``left``, ``right``) ``in_image``, ``found``, ``missed`` (ids), ``detected``,
    ``unmatched_detections``, ``rejected`` {reason: count}, ``rms_px``, ``max_px``, ``mean_px``
    (mean offset detected − simulated, (du, dv)); overall ``rms_px``, ``max_px``; the bounds and
    ``passed``.
    """
    from measure.detect import detect_targets

    data = read_dataset(path)
    radius = float(data.manifest.get("scene", {}).get("target_radius_mm", 0.0))
    report = {"path": os.fspath(path), "bounds": {"rms_px": rms_px, "max_px": max_px}}
    all_d = []
    all_found = True
    for name, img, camera, expected in (("left", data.left, data.rig.left, data.pixels_left),
                                        ("right", data.right, data.rig.right, data.pixels_right)):
        det = detect_targets(img)
        inside = wholly_in_image(camera, expected, data.targets, radius)
        idx, dist = match_detections(det.centers, expected, gate_px)
        matched = idx >= 0
        found_ids = set(idx[matched].tolist())
        in_ids = np.flatnonzero(inside)
        missed = [int(data.ids[i]) for i in in_ids if i not in found_ids]
        d = dist[matched]
        all_d.append(d)
        offs = det.centers[matched] - expected[idx[matched]]
        all_found &= not missed
        report[name] = {
            "in_image": int(inside.sum()), "found": int(sum(1 for i in in_ids if i in found_ids)),
            "missed": missed, "detected": det.n_found,
            "unmatched_detections": int((~matched).sum()),
            "rejected": {k: int(v) for k, v in det.rejected.items()},
            "rms_px": float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan"),
            "max_px": float(d.max()) if d.size else float("nan"),
            "mean_px": offs.mean(axis=0).tolist() if d.size else [float("nan")] * 2,
        }
    d = np.concatenate(all_d)
    report["rms_px"] = float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan")
    report["max_px"] = float(d.max()) if d.size else float("nan")
    report["all_found"] = bool(all_found)
    report["passed"] = bool(all_found and d.size and report["rms_px"] <= rms_px
                            and report["max_px"] <= max_px)
    return report
