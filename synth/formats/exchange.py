"""Files of a dataset that other pipelines read without this project.

* ``cameras.json`` — plain JSON: per camera ``K``, distortion (OpenCV's order), image size and
  pose ``X_ref = R·X_cam + t``; OpenCV's stereo ``R, T`` (``X_right = R·X_left + T``); the port
  (normal, distance, thicknesses, indices; or a dome rig's two domes: centre, radius,
  thickness, indices); units and conventions stated in the file (:func:`cameras_json`).
* ``colmap/`` — a COLMAP text model for the refractive COLMAP fork and calibmar:
  ``cameras.txt`` with ``FLATPORT`` in metres (:func:`synth.formats.calib_formats.write_colmap`, with
  ``rig_config.json``), ``images.txt`` (the two views, world-to-camera quaternions, the world
  being the left camera, metres) and ``points3D.txt`` (the targets seen in both views and their
  2D observations), in COLMAP's pixels (the top-left pixel's centre is (0.5, 0.5)); upstream
  COLMAP reads the files but ignores the port (:func:`write_colmap_model`); a dome rig's
  ``cameras.txt`` holds one DOMEPORT per camera.
* surfaces, per view, beside the ``.npy`` maps: depth along the camera's own z as PFM
  (``{view}_truth_zdepth.pfm``, float32, NaN where none) and as 16-bit PNG
  (``{view}_truth_zdepth.png``, ``png = round(z · scale)``, 0 where none, the scale in the
  manifest), and the left→right correspondence as a Middlebury ``.flo``
  (``left_truth_flow.flo``: float32 ``(u_right − u_left, v_right − v_left)`` per left pixel,
  NaN where the point is not seen by the right camera) (:func:`write_surface_formats`).
"""

from __future__ import annotations

import json
import os

import numpy as np
from scipy.spatial.transform import Rotation

from measure import Rig
from measure.geometry.flatport_format import METRES_PER_MM, cameras_json_port

from synth.formats.calib_formats import (COLMAP_PIXEL_OFFSET, CalibFormatError, stereo_extrinsics,
                                 write_colmap)

CAMERAS_JSON = "cameras.json"
COLMAP_DIR = "colmap"
COLMAP_NOTE = ("upstream COLMAP and pycolmap read these files but ignore FLATPORT (the port): "
               "only the refractive fork (github MDSKiel/colmap_underwater) and calibmar model it")
#: Depth codes per mm of the 16-bit depth PNGs (0.1 mm steps up to 6553.4 mm), and the coarser
#: scale used when a depth does not fit.
DEPTH_PNG_SCALES = (10.0, 1.0)


def _list(matrix) -> list:
    return np.asarray(matrix, dtype=np.float64).tolist()


def cameras_json(rig: Rig, has_port: bool = True) -> dict:
    """The rig as plain JSON (module docs)."""
    R, T = stereo_extrinsics(rig.left, rig.right)
    cameras = {}
    for name, camera in (("left", rig.left), ("right", rig.right)):
        dist = np.zeros(5) if camera.dist is None else np.asarray(camera.dist, np.float64)
        cameras[name] = {
            "K": _list(camera.K),
            "distortion": ({"model": "opencv_fisheye", "order": "k1 k2 k3 k4 (cv2.fisheye)",
                            "coefficients": _list(dist)} if camera.fisheye else
                           {"model": "opencv", "order": "k1 k2 p1 p2 [k3 [k4 k5 k6]]",
                            "coefficients": _list(dist)}),
            "image_size": {"width": int(camera.size[0]), "height": int(camera.size[1])},
            "pose_camera_to_reference": {"convention": "X_ref = R · X_cam + t",
                                         "R": _list(camera.R), "t": _list(camera.t)}}
    port_entry = cameras_json_port(rig.port, has_port)
    return {
        "format": "refractive-stereo cameras.json 1",
        "units": {"length": "mm", "pixels": "OpenCV: integer coordinates are pixel centres, "
                                            "(0, 0) is the centre of the top-left pixel"},
        "reference_frame": "the left camera's, OpenCV axes: x right, y down, z forward "
                           "(through the port into the water)",
        "cameras": cameras,
        "stereo_opencv": {"convention": "X_right = R · X_left + T (cv2.stereoCalibrate, "
                                        "cv2.stereoRectify)", "R": _list(R),
                          "T": _list(np.ravel(T))},
        "port": port_entry}


def cameras_json_views(rig) -> dict:
    """A rig of N cameras (:class:`measure.stereo.rig.Rig`) as plain JSON: per camera
    (by name, in order) ``K``, distortion, image size, pose ``X_ref = R·X_cam + t`` and the port
    it looks through (its own flat port, a share of one, a dome, or none); ``shared_port``
    says whether every camera looks through the same flat port."""
    from measure.geometry.flatport_format import cameras_json_view_port

    cameras = {}
    for name, camera, port in zip(rig.names, rig.cameras, rig.ports):
        dist = np.zeros(5) if camera.dist is None else np.asarray(camera.dist, np.float64)
        cameras[name] = {
            "K": _list(camera.K),
            "distortion": ({"model": "opencv_fisheye", "order": "k1 k2 k3 k4 (cv2.fisheye)",
                            "coefficients": _list(dist)} if camera.fisheye else
                           {"model": "opencv", "order": "k1 k2 p1 p2 [k3 [k4 k5 k6]]",
                            "coefficients": _list(dist)}),
            "image_size": {"width": int(camera.size[0]), "height": int(camera.size[1])},
            "pose_camera_to_reference": {"convention": "X_ref = R · X_cam + t",
                                         "R": _list(camera.R), "t": _list(camera.t)},
            "port": cameras_json_view_port(port)}
    return {
        "format": "refractive-stereo cameras.json 1",
        "units": {"length": "mm", "pixels": "OpenCV: integer coordinates are pixel centres, "
                                            "(0, 0) is the centre of the top-left pixel"},
        "reference_frame": f"the first camera's ({rig.names[0]}), OpenCV axes: x right, y "
                           f"down, z forward (through the port into the water)",
        "port_model": "per camera: a flat port's interfaces N · X = distance + cumulative "
                      "thicknesses (reference frame), or a dome (centre, inner radius, "
                      "thickness); indices from the camera side (air, glass…, water)",
        "shared_port": len(set(rig.ports)) == 1,
        "cameras": cameras}


def write_cameras_json(directory: str, rig, has_port: bool = True,
                       name: str = CAMERAS_JSON, views: bool = False) -> str:
    """``directory/name``: :func:`cameras_json` of a stereo pair, or with ``views``
    :func:`cameras_json_views` of a rig of N cameras (a folder per camera)."""
    path = os.path.join(directory, name)
    data = cameras_json_views(rig) if views else cameras_json(rig, has_port)
    with open(path, "w", encoding="utf-8") as handle:
        json.dump(data, handle, indent=1)
        handle.write("\n")
    return path


def _world_to_camera(camera) -> tuple[list, list]:
    """COLMAP's image pose: ``[qw, qx, qy, qz]`` and ``t`` (metres) of X_cam = R·X_world + t."""
    R = camera.R.T
    t = -R @ camera.t * METRES_PER_MM
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    quat = [float(w), float(x), float(y), float(z)]
    if quat[0] < 0:
        quat = [-q for q in quat]
    return quat, [float(v) for v in t]


def _inside(uv: np.ndarray, size) -> np.ndarray:
    w, h = size
    return (np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5)
            & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5))


def write_colmap_model(directory: str, rig: Rig, has_port: bool, ids, points, uv_left,
                       uv_right, image_names=("left.png", "right.png")) -> str | None:
    """``directory/colmap/``: ``cameras.txt`` (+ ``rig_config.json``), ``images.txt``,
    ``points3D.txt`` and ``README.txt`` (module docs). Points: the targets whose pixel in both
    views is inside the image, ids as in ``pixels.csv`` (+ 1: COLMAP's ids start at 1).
    Returns None, or why the model cannot be written (a port of several layers, a skewed K),
    in which case nothing is written."""
    folder = os.path.join(directory, COLMAP_DIR)
    try:
        os.makedirs(folder, exist_ok=True)
        write_colmap(os.path.join(folder, "cameras.txt"), rig, has_port)
    except CalibFormatError as exc:
        import shutil

        shutil.rmtree(folder, ignore_errors=True)
        return str(exc)
    points = np.asarray(points, np.float64).reshape(-1, 3)
    uvs = [np.asarray(uv_left, np.float64).reshape(-1, 2),
           np.asarray(uv_right, np.float64).reshape(-1, 2)]
    both = _inside(uvs[0], rig.left.size) & _inside(uvs[1], rig.right.size)
    rows = np.flatnonzero(both)
    ids = np.asarray(ids, dtype=np.int64)
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: 2, mean observations per image: {rows.size}",
             "# World frame: the left camera's (metres); poses are world-to-camera. Pixels: "
             "COLMAP's, the centre of the top-left pixel is (0.5, 0.5).",
             f"# NAME is relative to the dataset folder (the parent of this folder). {COLMAP_NOTE}."]
    for image_id, (camera, uv, name) in enumerate(zip((rig.left, rig.right), uvs, image_names),
                                                  start=1):
        quat, t = _world_to_camera(camera)
        lines.append(" ".join([str(image_id), *(repr(v) for v in quat), *(repr(v) for v in t),
                               str(image_id), name]))
        lines.append(" ".join(f"{float(uv[i, 0]) + COLMAP_PIXEL_OFFSET!r} "
                              f"{float(uv[i, 1]) + COLMAP_PIXEL_OFFSET!r} {int(ids[i]) + 1}"
                              for i in rows))
    with open(os.path.join(folder, "images.txt"), "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")
    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
             f"# Number of points: {rows.size}, mean track length: 2",
             "# Coordinates in metres, in the left camera's frame (OpenCV axes); the true target "
             "centres of targets.ply (mm there)."]
    for index, i in enumerate(rows):
        x, y, z = (float(v) * METRES_PER_MM for v in points[i])
        lines.append(f"{int(ids[i]) + 1} {x!r} {y!r} {z!r} 255 255 255 0 1 {index} 2 {index}")
    with open(os.path.join(folder, "points3D.txt"), "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")
    with open(os.path.join(folder, "README.txt"), "w", encoding="utf-8") as handle:
        handle.write(
            "A COLMAP text model of this dataset (metres; COLMAP's pixels: the top-left pixel's "
            "centre is (0.5, 0.5)).\ncameras.txt: camera 1 = left, 2 = right, OPENCV (or "
            "FULL_OPENCV) with FLATPORT Nx Ny Nz int_dist int_thick na ng nw (the port in that "
            "camera's frame, metres); rig_config.json: the stereo pose for the fork's rig "
            "bundle adjuster.\nimages.txt: the two views, world-to-camera (world = the left "
            "camera). points3D.txt: the targets seen in both views (id = pixels.csv id + 1).\n"
            f"WARNING: {COLMAP_NOTE}.\n")
    return None


def write_colmap_views(directory: str, rig, ids, points, pixels, image_names) -> str | None:
    """``directory/colmap/`` of a rig of N cameras (a Rig): ``cameras.txt`` with each
    camera's own FLATPORT or DOMEPORT and ``rig_config.json``
    (:func:`synth.formats.calib_formats.write_colmap_rig`), ``images.txt`` (one image per
    camera, world-to-camera, the world the first camera's frame, metres), ``points3D.txt`` (the
    targets inside two or more images, each with its track over those images) and
    ``README.txt``. ``pixels`` ``(T, V, 2)`` OpenCV px (NaN where none). Returns None, or why
    the model cannot be written (nothing is written then)."""
    from synth.formats.calib_formats import write_colmap_rig

    folder = os.path.join(directory, COLMAP_DIR)
    try:
        os.makedirs(folder, exist_ok=True)
        write_colmap_rig(os.path.join(folder, "cameras.txt"), rig)
    except CalibFormatError as exc:
        import shutil

        shutil.rmtree(folder, ignore_errors=True)
        return str(exc)
    points = np.asarray(points, np.float64).reshape(-1, 3)
    pixels = np.asarray(pixels, np.float64).reshape(points.shape[0], len(rig.cameras), 2)
    ids = np.asarray(ids, dtype=np.int64)
    inside = np.stack([_inside(pixels[:, v], camera.size)
                       for v, camera in enumerate(rig.cameras)], axis=1)  # (T, V)
    rows = np.flatnonzero(inside.sum(axis=1) >= 2)
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(rig.cameras)}, mean observations per image: "
             f"{inside[rows].sum() / len(rig.cameras):g}",
             f"# World frame: the first camera's ({rig.names[0]}, metres); poses are "
             f"world-to-camera. Pixels: COLMAP's, the centre of the top-left pixel is (0.5, 0.5).",
             f"# NAME is relative to the dataset folder (the parent of this folder). {COLMAP_NOTE}."]
    index_in_image = {}
    for view, (camera, name) in enumerate(zip(rig.cameras, image_names)):
        quat, t = _world_to_camera(camera)
        lines.append(" ".join([str(view + 1), *(repr(v) for v in quat), *(repr(v) for v in t),
                               str(view + 1), name]))
        seen = rows[inside[rows, view]]
        index_in_image[view] = {int(i): k for k, i in enumerate(seen)}
        lines.append(" ".join(f"{float(pixels[i, view, 0]) + COLMAP_PIXEL_OFFSET!r} "
                              f"{float(pixels[i, view, 1]) + COLMAP_PIXEL_OFFSET!r} "
                              f"{int(ids[i]) + 1}" for i in seen))
    with open(os.path.join(folder, "images.txt"), "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")
    lengths = inside[rows].sum(axis=1)
    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
             f"# Number of points: {rows.size}, mean track length: "
             f"{float(lengths.mean()) if rows.size else 0:g}",
             "# Coordinates in metres, in the first camera's frame (OpenCV axes); the true "
             "target centres of targets.ply (mm there)."]
    for i in rows:
        x, y, z = (float(v) * METRES_PER_MM for v in points[i])
        track = " ".join(f"{view + 1} {index_in_image[view][int(i)]}"
                         for view in range(len(rig.cameras)) if inside[i, view])
        lines.append(f"{int(ids[i]) + 1} {x!r} {y!r} {z!r} 255 255 255 0 {track}")
    with open(os.path.join(folder, "points3D.txt"), "w", encoding="utf-8") as handle:
        handle.write("\n".join(lines) + "\n")
    with open(os.path.join(folder, "README.txt"), "w", encoding="utf-8") as handle:
        handle.write(
            "A COLMAP text model of this dataset (metres; COLMAP's pixels: the top-left pixel's "
            "centre is (0.5, 0.5)).\ncameras.txt: camera k + 1 = "
            + ", ".join(f"{k + 1} {n}" for k, n in enumerate(rig.names))
            + "; OPENCV (or FULL_OPENCV) with each camera's own FLATPORT Nx Ny Nz int_dist "
            "int_thick na ng nw or DOMEPORT Cx Cy Cz int_radius int_thick na ng nw (in that "
            "camera's frame, metres); rig_config.json: every camera's pose for the fork's rig "
            "bundle adjuster.\nimages.txt: one image per camera, world-to-camera (world = the "
            "first camera). points3D.txt: the targets seen in two or more images (id = "
            "pixels.csv id + 1).\n"
            f"WARNING: {COLMAP_NOTE}.\n")
    return None


# ------------------------------------------------------------------------------------------------
# surfaces


def write_pfm(path: str, image: np.ndarray) -> None:
    """A single-channel float32 PFM (``Pf``, little-endian, rows bottom to top)."""
    image = np.asarray(image, dtype="<f4")
    h, w = image.shape
    with open(path, "wb") as handle:
        handle.write(f"Pf\n{w} {h}\n-1.0\n".encode("ascii"))
        handle.write(np.ascontiguousarray(image[::-1]).tobytes())


def read_pfm(path: str) -> np.ndarray:
    """A single-channel PFM as float32 ``(H, W)``, top row first."""
    with open(path, "rb") as handle:
        kind = handle.readline().strip()
        if kind != b"Pf":
            raise ValueError(f"{path}: not a single-channel PFM")
        w, h = (int(v) for v in handle.readline().split())
        scale = float(handle.readline())
        data = np.frombuffer(handle.read(), dtype="<f4" if scale < 0 else ">f4")
    if data.size != w * h:
        raise ValueError(f"{path}: {data.size} values, the header says {w} x {h}")
    return data.reshape(h, w)[::-1].astype(np.float32)


FLO_MAGIC = 202021.25


def write_flo(path: str, flow: np.ndarray) -> None:
    """A Middlebury ``.flo``: ``PIEH``, width, height, then float32 (u, v) per pixel."""
    flow = np.asarray(flow, dtype="<f4")
    h, w, _ = flow.shape
    with open(path, "wb") as handle:
        handle.write(np.array([FLO_MAGIC], "<f4").tobytes())
        handle.write(np.array([w, h], "<i4").tobytes())
        handle.write(np.ascontiguousarray(flow).tobytes())


def read_flo(path: str) -> np.ndarray:
    """A Middlebury ``.flo`` as float32 ``(H, W, 2)``."""
    with open(path, "rb") as handle:
        magic = np.frombuffer(handle.read(4), "<f4")
        if magic.size != 1 or magic[0] != FLO_MAGIC:
            raise ValueError(f"{path}: not a .flo file")
        w, h = (int(v) for v in np.frombuffer(handle.read(8), "<i4"))
        data = np.frombuffer(handle.read(), "<f4")
    if data.size != w * h * 2:
        raise ValueError(f"{path}: {data.size} values, the header says {w} x {h} x 2")
    return data.reshape(h, w, 2).copy()


def camera_z(points: np.ndarray, camera) -> np.ndarray:
    """Depth along ``camera``'s own z axis of reference-frame points ``(..., 3)``, mm."""
    return (np.asarray(points, np.float64) - camera.t) @ camera.R[:, 2]


def write_surface_formats(directory: str, rig: Rig) -> dict:
    """The common-format truth of a surface dataset (module docs), from its ``.npy`` maps in
    ``directory``; returns what the manifest records (the depth PNG scale, the files)."""
    import cv2

    from measure.geometry.projection import project

    from synth.products.truth_maps import TRUTH_FILES

    info = {"depth": "z along each camera's own optical axis, mm",
            "zdepth_png_scale": None, "zdepth_png_invalid": 0,
            "flow": "left_truth_flow.flo: (u_right - u_left, v_right - v_left) px, OpenCV "
                    "pixels, NaN where the right camera does not see the left pixel's point"}
    depths = {}
    for view, camera in (("left", rig.left), ("right", rig.right)):
        points = np.load(os.path.join(directory, TRUTH_FILES["points"].format(view=view)))
        depths[view] = camera_z(points, camera).astype(np.float32)
        write_pfm(os.path.join(directory, f"{view}_truth_zdepth.pfm"), depths[view])
    finite = np.concatenate([d[np.isfinite(d)] for d in depths.values()])
    top = float(finite.max()) if finite.size else 0.0
    scale = next((s for s in DEPTH_PNG_SCALES if top * s <= 65534.5), DEPTH_PNG_SCALES[-1])
    info["zdepth_png_scale"] = scale
    for view, depth in depths.items():
        codes = np.where(np.isfinite(depth), np.clip(np.round(depth * scale), 1, 65535), 0)
        if not cv2.imwrite(os.path.join(directory, f"{view}_truth_zdepth.png"),
                           codes.astype(np.uint16)):
            raise OSError(f"cannot write the {view} depth PNG")
    points = np.load(os.path.join(directory, TRUTH_FILES["points"].format(view="left")))
    overlap = cv2.imread(os.path.join(directory, TRUTH_FILES["overlap"].format(view="left")),
                         cv2.IMREAD_UNCHANGED) > 0
    h, w = overlap.shape
    flow = np.full((h, w, 2), np.nan, dtype=np.float32)
    rows, cols = np.nonzero(overlap)
    if rows.size:
        uv = project(rig.right, rig.port, points[rows, cols])
        flow[rows, cols] = (uv - np.column_stack([cols, rows])).astype(np.float32)
    write_flo(os.path.join(directory, "left_truth_flow.flo"), flow)
    return info


__all__ = ["CAMERAS_JSON", "COLMAP_DIR", "COLMAP_NOTE", "DEPTH_PNG_SCALES", "camera_z",
           "cameras_json", "read_flo", "read_pfm", "write_cameras_json", "write_colmap_model",
           "write_flo", "write_pfm", "write_surface_formats"]
