"""A known object moving along a trajectory, rendered frame by frame with its true pose
(``python -m synth sequence``; ``python -m eval track`` follows it with
:mod:`measure.stereo.pose`).

The object is the docking frame of :func:`synth.scene.layouts.docking_frame` (12 self-luminous
disk markers facing the cameras). It follows the poses of a trajectory file
(:func:`read_trajectory`), or approaches the rig along the rig's depth axis (the port
normal; for domes the left optical axis): frame k of N has its origin at ``z_k`` mm along that
axis from the left camera's centre, ``z`` running linearly from ``FROM`` to ``TO``, and its axes
turned by ``yaw_k`` about the reference y axis, running linearly from 0 to ``yaw_deg``. The
rig, the port, the image size and the renderer settings come from the scene file; its targets
and water are not used (the markers are rendered in clear water).

A sequence directory holds (units mm, reference frame = the left camera's, OpenCV axes):

* ``frames/NNNN_left.png``, ``frames/NNNN_right.png`` — 16-bit linear images, each frame
  scaled so its brightest pixel is 65535 (``manifest["png_scales"]``);
* ``object.csv`` — ``id,x_mm,y_mm,z_mm``: the markers in the object frame;
* ``poses.csv`` — ``frame,time_s,tx_mm,ty_mm,tz_mm,qx,qy,qz,qw``: the true pose of each frame,
  ``X_ref = R · X_obj + t`` (R as a unit quaternion, scalar last);
* ``poses_tum.txt`` — the same in the TUM RGB-D format ``timestamp tx ty tz qx qy qz qw``
  (**metres**, as TUM tools expect; the object's pose in the reference frame);
* ``pixels.csv`` — ``frame,id,u_left,v_left,u_right,v_right``: the Fermat simulator's pixel of
  every marker (NaN where it has none; pixels outside the image are kept);
* ``calib.yaml`` — the rig (:func:`synth.formats.calib_yaml.write_calib`); ``manifest.json``.

The directory is written whole or not at all (:class:`synth.infra.fileio.OutputDir`).
"""

from __future__ import annotations

import csv
import os
import tempfile
import time
from datetime import datetime, timezone

import numpy as np
from scipy.spatial.transform import Rotation

from measure.geometry.projection import project
from synth.infra.fileio import OutputDir, atomic_write_json, file_sha256, jsonable
from synth.infra.provenance import package_versions
from synth.scene import SceneSpec, load_scene
from synth.scene.layouts import docking_frame

COMMAND = "synth sequence"
FORMAT_VERSION = 1
#: Marker disk radius (mm): about 3 px at 5 m behind the paper's port at full size.
DEFAULT_MARKER_RADIUS_MM = 10.0
DEFAULT_FPS = 10.0
POSES_HEADER = ["frame", "time_s", "tx_mm", "ty_mm", "tz_mm", "qx", "qy", "qz", "qw"]
PIXELS_HEADER = ["frame", "id", "u_left", "v_left", "u_right", "v_right"]
OBJECT_HEADER = ["id", "x_mm", "y_mm", "z_mm"]


def approach_poses(spec: SceneSpec, approach, frames: int, yaw_deg: float = 0.0):
    """The true poses ``(R (N, 3, 3), t (N, 3))`` of the approach (module docs)."""
    start, end = (float(v) for v in approach)
    axis = spec.rig.depth_axis
    z = np.linspace(start, end, frames) if frames > 1 else np.array([start])
    yaw = np.radians(np.linspace(0.0, yaw_deg, frames)) if frames > 1 else np.zeros(1)
    R = Rotation.from_rotvec(np.outer(yaw, [0.0, 1.0, 0.0])).as_matrix()
    t = spec.rig.left.center + z[:, None] * axis
    return R, t


def read_trajectory(path):
    """``(times (N,) s, R (N, 3, 3), t (N, 3) mm)`` of a trajectory file: a TUM trajectory
    (``timestamp tx ty tz qx qy qz qw`` per line, **metres**, ``#`` comments; what
    ``poses_tum.txt`` holds) or a ``poses.csv`` (module docs, mm), told apart by its first
    line; the object's pose in the reference frame. ValueError naming the file and the line
    for anything else (a quaternion that is not a rotation, times that do not increase)."""
    try:
        with open(path, encoding="utf-8") as fh:
            lines = fh.read().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot be read ({exc})") from None
    if lines and lines[0].startswith("frame,"):
        frames, R, t = read_poses(path)
        data = np.genfromtxt(path, delimiter=",", names=True, ndmin=1)
        times = np.asarray(data["time_s"], dtype=float)
    else:
        rows = []
        for number, line in enumerate(lines, 1):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            try:
                values = [float(v) for v in line.split()]
            except ValueError:
                values = []
            if len(values) != 8 or not np.all(np.isfinite(values)):
                raise ValueError(f"{path}: line {number}: expected 8 numbers (a TUM trajectory: "
                                 f"timestamp tx ty tz qx qy qz qw, metres), got {line.strip()!r}")
            rows.append(values)
        if not rows:
            raise ValueError(f"{path}: no poses (a TUM trajectory or a poses.csv)")
        rows = np.array(rows)
        norm = np.linalg.norm(rows[:, 4:], axis=1)
        if np.any(np.abs(norm - 1.0) > 1e-3):
            bad = int(np.argmax(np.abs(norm - 1.0)))
            raise ValueError(f"{path}: pose {bad}: the quaternion's norm is {norm[bad]:.6g}, "
                             f"not 1")
        times, t = rows[:, 0], rows[:, 1:4] * 1000.0
        R = Rotation.from_quat(rows[:, 4:]).as_matrix()
    if np.any(np.diff(times) <= 0):
        raise ValueError(f"{path}: the time stamps do not increase")
    return times, R, t


def write_poses(directory, R, t, fps: float, times=None) -> None:
    """``poses.csv`` and ``poses_tum.txt`` (module docs) of poses ``R (N, 3, 3)``, ``t (N, 3)``
    at ``times`` (s; default frame k at k / ``fps``)."""
    q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
    times = np.arange(len(t)) / fps if times is None else np.asarray(times, dtype=float)
    with open(os.path.join(directory, "poses.csv"), "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(POSES_HEADER)
        for k in range(len(t)):
            writer.writerow([k, f"{times[k]:.6f}", *(repr(float(v)) for v in t[k]),
                             *(repr(float(v)) for v in q[k])])
    write_tum(os.path.join(directory, "poses_tum.txt"), times, R, t)


def write_tum(path, times, R, t) -> None:
    """Poses in the TUM RGB-D format: ``timestamp tx ty tz qx qy qz qw`` per line, metres."""
    q = Rotation.from_matrix(R).as_quat()
    with open(path, "w") as fh:
        fh.write("# timestamp tx ty tz qx qy qz qw (metres; the object's pose in the left "
                 "camera's frame)\n")
        for k in range(len(t)):
            fh.write(" ".join([f"{times[k]:.6f}", *(f"{v / 1000.0:.9f}" for v in t[k]),
                               *(f"{v:.12f}" for v in q[k])]) + "\n")


def read_poses(path):
    """``(frames (N,), R (N, 3, 3), t (N, 3))`` from a ``poses.csv``; ValueError naming the
    file when it is not one."""
    try:
        data = np.genfromtxt(path, delimiter=",", names=True, ndmin=1)
        frames = np.asarray(data["frame"], dtype=int)
        t = np.column_stack([data["tx_mm"], data["ty_mm"], data["tz_mm"]])
        q = np.column_stack([data["qx"], data["qy"], data["qz"], data["qw"]])
        R = Rotation.from_quat(q).as_matrix()
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{path}: not a poses.csv ({exc})") from None
    return frames, R, t


#: The fewest markers whose centres a frame must show inside one camera's image: a pose needs four
#: observations (:func:`measure.stereo.pose.estimate_pose`).
MIN_MARKERS_IN_VIEW = 4


def check_marker_spacing(object_points: np.ndarray, marker_radius_mm: float) -> None:
    """ValueError when two markers' disks (radius ``marker_radius_mm``, mm) would overlap:
    their centres nearer than two radii."""
    gaps = np.linalg.norm(object_points[:, None] - object_points[None], axis=2)
    gaps[np.diag_indices_from(gaps)] = np.inf
    i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
    if gaps[i, j] <= 2.0 * marker_radius_mm:
        raise ValueError(f"--marker-radius-mm {marker_radius_mm:g}: markers {min(i, j)} and "
                         f"{max(i, j)} are {gaps[i, j]:.1f} mm apart, so their disks overlap "
                         f"(a radius below {gaps[i, j] / 2:.1f} mm, or a larger --size-mm)")


def check_markers_in_view(rig, pixels, approach) -> None:
    """ValueError naming the first frame in which no camera sees
    :data:`MIN_MARKERS_IN_VIEW` markers inside its image (``pixels``: per frame ``(views, M,
    2)`` px, the Fermat simulator's; NaN where there is none). ``approach``: ``(FROM, TO)``
    mm, or the trajectory file's path, for the message."""
    what = (f"--trajectory {approach}" if isinstance(approach, (str, os.PathLike))
            else f"--approach {approach[0]:g},{approach[1]:g}")
    for k, uv in enumerate(pixels):
        seen = [int(camera.in_image(uv[v]).sum()) for v, camera in enumerate(rig.cameras)]
        if max(seen) < MIN_MARKERS_IN_VIEW:
            raise ValueError(f"frame {k}: the cameras see {'/'.join(map(str, seen))} markers "
                             f"inside their images, fewer than the {MIN_MARKERS_IN_VIEW} a pose "
                             f"needs ({what} goes beyond the field of view: a larger "
                             f"distance or a smaller --size-mm)")


def write_sequence(spec: SceneSpec, out_dir, approach, frames: int, *,
                   yaw_deg: float = 0.0, size_mm: float = 1000.0,
                   marker_radius_mm: float = DEFAULT_MARKER_RADIUS_MM, fps: float = DEFAULT_FPS,
                   spp: int | None = None, seed: int | None = None, variant=None,
                   progress: bool = True, adaptive: bool = True, trajectory=None) -> dict:
    """Render the sequence into ``out_dir`` (module docs); returns the manifest. ValueError
    for a request that cannot work (a marker not in the water, fewer than one frame).
    ``trajectory``: ``(path, times, R, t)`` of :func:`read_trajectory` — the poses to render
    instead of the approach (``approach``, ``frames``, ``yaw_deg`` and ``fps`` then unused)."""
    from synth.rendering.render import check_render_request

    t_start = time.perf_counter()
    if trajectory is not None:
        frames = len(trajectory[3])
    if frames < 1:
        raise ValueError(f"--frames must be at least 1, got {frames}")
    spp = spec.spp if spp is None else int(spp)
    seed = spec.seed if seed is None else int(seed)
    obj = docking_frame(size_mm)
    check_marker_spacing(obj, marker_radius_mm)
    if trajectory is None:
        R, t = approach_poses(spec, approach, frames, yaw_deg)
        times, source = None, None
    else:
        source, times, R, t = trajectory
        frames, approach, yaw_deg = len(t), None, None
    markers = np.einsum("fij,mj->fmi", R, obj) + t[:, None, :]
    _check_markers_in_water(spec.rig.port, markers, source)
    rig = spec.rig
    pixels = [np.stack([project(c, rig.view_port(v), markers[k])
                        for v, c in enumerate(rig.cameras)]) for k in range(frames)]
    check_markers_in_view(rig, pixels, approach if source is None else source)
    output = OutputDir(out_dir, COMMAND).claim()
    check_render_request(spec, spp, seed, poses=frames, adaptive=adaptive)
    t_render = time.perf_counter()
    images, stats = _render_frames(spec, markers, np.einsum("fij,j->fi", R, [0.0, 0.0, -1.0]),
                                   marker_radius_mm, spp, seed, variant, progress, adaptive)
    render_seconds = time.perf_counter() - t_render
    with output.staged() as tmp:
        scales = _write_frames(tmp, images)
        _write_truth(tmp, spec, obj, R, t, fps, times, pixels)
        files = sorted(os.path.relpath(os.path.join(d, f), tmp)
                       for d, _, names in os.walk(tmp) for f in names)
        manifest = {
            "format_version": FORMAT_VERSION, "command": COMMAND,
            "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "versions": package_versions(),
            "scene": {"path": spec.path, "sha256": spec.sha256, "params": spec.params},
            "object": {"kind": "docking_frame", "size_mm": size_mm,
                       "marker_radius_mm": marker_radius_mm, "markers": len(obj)},
            "approach_mm": None if approach is None else [float(v) for v in approach],
            "yaw_deg": yaw_deg, "trajectory": None if source is None else os.path.abspath(source),
            "frames": frames, "fps": fps if source is None else None, "spp": spp, "seed": seed,
            "variant": stats[0]["variant"], "image_size": list(spec.size),
            "png_scales": scales, "adaptive": adaptive,
            "seconds": {"render": render_seconds, "total": time.perf_counter() - t_start},
            "sha256": {name: file_sha256(os.path.join(tmp, name)) for name in files},
        }
        manifest = jsonable(manifest)
        atomic_write_json(os.path.join(tmp, "manifest.json"), manifest)
    return manifest


def _check_markers_in_water(port, markers, source) -> None:
    """ValueError naming the first frame and marker (mm) not on the water side of both views'
    ports (``source``: the trajectory file, None for an approach)."""
    for k in range(len(markers)):
        inside = np.all([port.view(v).water_side(markers[k]) for v in range(2)], axis=0)
        if not inside.all():
            raise ValueError(f"frame {k}: marker {int(np.flatnonzero(~inside)[0])} at "
                             f"{np.round(markers[k][~inside][0], 1).tolist()} mm is not in the "
                             f"water (" + ("--approach starts or ends too near)" if source is None
                                           else f"--trajectory {source} comes too near)"))


def _render_frames(spec, markers, normals, marker_radius_mm, spp, seed, variant, progress,
                   adaptive) -> tuple[list, list]:
    """``(images, stats)``: each frame's scene written with its markers (``(F, M, 3)`` mm,
    facing ``normals``) and rendered (seed ``seed + 2 k``): the (left, right) linear images
    and each render's variant and seconds."""
    from tqdm import tqdm

    from synth.rendering.render import render_stereo
    from synth.scene.write import scene_xml

    frames = len(markers)
    images, stats = [], []
    bar = tqdm(range(frames), desc=f"render sequence {spp} spp", unit="frame",
               disable=not progress, leave=False)
    with tempfile.TemporaryDirectory(prefix="synth-sequence-") as scratch:
        for k in bar:
            path = os.path.join(scratch, f"frame_{k:04d}.xml")
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(scene_xml(spec.cameras, spec.port, markers[k], marker_radius_mm,
                                   spp=spp, seed=seed + 2 * k,
                                   target_normals=np.tile(normals[k], (markers.shape[1], 1)),
                                   comment=f"{COMMAND}: frame {k} of {spec.path}"))
            left, right, info = render_stereo(load_scene(path), spp=spp, variant=variant,
                                              progress=False, seed=seed + 2 * k,
                                              adaptive=adaptive)
            images.append((left, right))
            stats.append({"variant": info["variant"], "seconds": info["seconds"]})
    return images, stats


def _write_frames(tmp, images) -> list:
    """Each frame's views as 16-bit linear PNGs in ``tmp/frames/`` (one scale per frame);
    returns the scales."""
    from synth.rendering.image_files import png16_scale, to_png16, write_png

    os.makedirs(os.path.join(tmp, "frames"))
    scales = []
    for k, pair in enumerate(images):
        scale = png16_scale(*pair)
        scales.append(scale)
        for name, image in zip(("left", "right"), pair):
            write_png(os.path.join(tmp, "frames", f"{k:04d}_{name}.png"), to_png16(image, scale))
    return scales


def _write_truth(tmp, spec, obj, R, t, fps, times, pixels) -> None:
    """``calib.yaml``, the object's markers, the true poses and the simulator's pixels of every
    marker in every frame into ``tmp``."""
    from synth.formats.calib_yaml import write_calib

    write_calib(os.path.join(tmp, "calib.yaml"), spec.rig, spec.has_port)
    with open(os.path.join(tmp, "object.csv"), "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(OBJECT_HEADER)
        for i, p in enumerate(obj):
            writer.writerow([i, *(repr(float(v)) for v in p)])
    write_poses(tmp, R, t, fps, times)
    with open(os.path.join(tmp, "pixels.csv"), "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(PIXELS_HEADER)
        for k, uv in enumerate(pixels):
            for i in range(len(obj)):
                writer.writerow([k, i, *(repr(float(v)) for v in uv[:, i].ravel())])


__all__ = ["COMMAND", "DEFAULT_MARKER_RADIUS_MM", "approach_poses", "read_poses",
           "read_trajectory", "write_poses", "write_sequence", "write_tum"]
