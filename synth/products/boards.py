"""Rendered calibration boards: a planar board at seeded random poses, seen by the scene's two
cameras behind its port (or in air), written as a folder anyone can calibrate from.

The board is a Mitsuba ``rectangle`` whose ``area`` emitter's radiance is a ``bitmap`` texture
of the pattern OpenCV draws (:meth:`measure.calibration.board.Board.pattern`, nearest-texel lookup, linear
values 0 and 1), so its corners are exactly where OpenCV's model of the board says they are.
One Mitsuba scene is built per folder; each pose only moves the board (``mi.traverse``).

Poses (reference frame = the left camera's, mm): the board's centre at a depth (along the
port normal; in a dome rig along the left optical axis) drawn uniformly from
``distance_range``, at a random place of the left view, tilted about a random in-plane axis by
up to ``max_tilt_deg`` and turned about its normal by up to :data:`MAX_ROLL_DEG`; a pose is kept
only when the forward model puts the whole board (its outline and every corner) inside both
images, :data:`IMAGE_MARGIN_PX` from the border, and in the water (outside both domes).

Folder (same output rule as ``synth dataset``: atomic, rerunnable, never over someone else's
files): ``left_PP.png``, ``right_PP.png`` (16-bit linear, one ``png_scale``), ``board.json``,
``poses.csv`` (``pose,rx,ry,rz,tx,ty,tz``: rotation vector in rad and translation in mm of
``X_ref = R·X_board + t``), ``corners.csv`` (``pose,id,x,y,z,u_left,v_left,u_right,v_right``:
every corner's 3D position and its forward-model pixel in each view), ``calib.yaml`` (the true
rig, the dataset format) and ``manifest.json`` (with every other file's SHA-256 and its own,
checked when the folder is read: :func:`read_boards` reads it whole or refuses it).
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import time
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np
from scipy.spatial.transform import Rotation

from measure import Rig
from measure.calibration.board import PATTERN_TEXELS_PER_SQUARE, Board, BoardError
from measure.geometry.projection import project

from synth.products.board_poses import (DEFAULT_AIR_DISTANCE_RANGE_MM, DEFAULT_DISTANCE_RANGE_MM,
                                        DEFAULT_MAX_TILT_DEG, BoardCameras, BoardPose, board_rig,
                                        sample_poses)
from synth.products.board_camera import (CameraEffects, check_band_seeds, prepared_effects,
                                         render_blurred_view, render_rolling_view, rolling_pixels,
                                         thin_lens_sensor)
from synth.products.board_light import BoardLight, check_light, light_record
from synth.rendering.camera_effects import vignetting_map
from synth.products.dataset import (DatasetError, adaptive_settings, check_files, manifest_digest,
                           read_calib, write_calib)
from synth.infra.fileio import OutputDir, atomic_write_json, file_sha256, jsonable, read_marker
from synth.rendering.integrator import RENDERER, integrator_name
from synth.infra.provenance import package_versions
from synth.rendering.image_files import png16_scale, to_png16, write_png
from synth.rendering.render import check_render_request, render_view_counted, sensor_dict
from synth.scene import SceneSpec
from synth.scene.write import port_shapes
from synth.infra.images import imread

FORMAT_VERSION = 2  # 2: the manifest holds every file's SHA-256 and its own
COMMAND = "synth boards"
DEFAULT_POSES = 15
DEFAULT_SPP = 16
#: Scene parameters that the boards' scene does not use (it holds the scene's cameras, port and
#: ``max_depth`` and a board; no targets, no water medium, no lights, pinhole sensors): a
#: ``-D`` of one of them is refused, never ignored.
NOT_RENDERED = ("target_radius", "target_z", "target_albedo", "light_intensity", "water_c",
                "water_albedo", "water_g", "aperture_radius", "focus_distance")
CORNERS_HEADER = ["pose", "id", "x", "y", "z", "u_left", "v_left", "u_right", "v_right"]
POSES_HEADER = ["pose", "rx", "ry", "rz", "tx", "ty", "tz"]


def _board_local_to_board(board: Board) -> np.ndarray:
    """Mitsuba's rectangle ([-1, 1]², normal +z, uv = ((x+1)/2, (y+1)/2) with v = 0 the
    texture's first row) to the board frame, its emitting side towards −z_board (the viewer)."""
    x0, y0 = board.outline()[0, :2]
    x1, y1 = board.outline()[2, :2]
    return np.array([[(x1 - x0) / 2, 0, 0, (x0 + x1) / 2], [0, (y1 - y0) / 2, 0, (y0 + y1) / 2],
                     [0, 0, -1, 0], [0, 0, 0, 1.0]])


def build_board_scene(spec: SceneSpec, board: Board, air: bool, variant=None,
                      light: BoardLight | None = None, effects: CameraEffects | None = None):
    """``(mitsuba_scene, mi, variant)``: the scene's sensors (same order: ``left``, ``right``
    or ``cam0`` …), its port interfaces unless ``air``, and the board (moved by
    :func:`render_pose`): self-luminous, or with ``light`` (aimed,
    :meth:`synth.products.board_light.BoardLight.aimed`) printed on diffuse paper and lit by
    that lamp; with ``effects`` of a thin lens, ``thinlens`` sensors
    (:func:`synth.products.board_camera.thin_lens_sensor`)."""
    from synth.rendering.mitsuba_setup import import_mitsuba

    mi, chosen = import_mitsuba(variant)
    pattern = board.pattern(PATTERN_TEXELS_PER_SQUARE)
    sampler = {"type": "multijitter", "sample_count": 4, "seed": 0}
    if light is None:
        texture = pattern.astype(np.float32)[..., None] / np.float32(255)
        surface = {"bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
                   "emitter": {"type": "area", "radiance": {
                       "type": "bitmap", "data": mi.TensorXf(texture), "raw": True,
                       "filter_type": "nearest"}}}
    else:
        surface = {"bsdf": {"type": "diffuse", "reflectance": {
            "type": "bitmap", "data": mi.TensorXf(light.reflectance(pattern)), "raw": True,
            "filter_type": "nearest"}}}
    scene = {"type": "scene",
             "integrator": {"type": "path", "max_depth": int(float(spec.params.get("max_depth", 8)))},
             **{name: sensor_dict(mi, camera, sampler)
                for name, camera in zip(spec.camera_names, spec.all_cameras)},
             "board": {"type": "rectangle", "to_world": mi.ScalarTransform4f(np.eye(4).tolist()),
                       **surface}}
    if effects is not None and effects.aperture_radius_mm > 0:
        for name in spec.camera_names:
            scene[name] = thin_lens_sensor(scene[name], effects)
    if light is not None:
        scene["lamp"] = light.emitter_dict(mi, spec.all_cameras[0])
    if not air and spec.has_port:  # the glass as the scene writer makes it, for any port
        scene.update(port_shapes(mi, spec.camera_ports, cameras=spec.all_cameras))
    return mi.load_dict(scene), mi, chosen


def place_board(mscene, mi, board: Board, pose: BoardPose) -> None:
    """Move the board of a scene of :func:`build_board_scene` to ``pose``."""
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = pose.R, pose.t
    params = mi.traverse(mscene)
    params["board.to_world"] = mi.ScalarTransform4f((M @ _board_local_to_board(board)).tolist())
    params.update()


def render_pose(mscene, mi, spec: SceneSpec, board: Board, pose: BoardPose, index: int,
                spp: int, seed: int, adaptive: bool = True, rig=None,
                effects: CameraEffects | None = None):
    """Every view (float32 linear) of the board at ``pose`` and, per view, how it was rendered
    (:func:`synth.rendering.render.render_view_counted`): ``([left, right], [stats_left, stats_right])``;
    pose ``index`` renders with the scene seeds ``seed + 2·index`` (view 0) and ``+ 1``
    (view 1) — of N cameras ``seed + N·index + view``. ``effects``: a rolling shutter (needs
    ``rig``), motion blur (needs ``rig``) and vignetting (:mod:`synth.products.board_camera`)."""
    cameras = spec.all_cameras
    scene_seed = seed + len(cameras) * index
    if effects is not None and effects.moving:
        render_moving = render_rolling_view if effects.rolling else render_blurred_view
        views = [render_moving(
            mscene, mi, view, camera, rig.view_port(view),
            np.concatenate([board.outline(), board.corners()]), pose, effects, spp, scene_seed,
            lambda shift: place_board(mscene, mi, board, BoardPose(pose.R, pose.t + shift)))
            for view, camera in
            enumerate(cameras)]
    else:
        place_board(mscene, mi, board, pose)
        views = [render_view_counted(mscene, mi, view, camera, spp, scene_seed,
                                     adaptive=adaptive)
                 for view, camera in enumerate(cameras)]
    images = [v[0] for v in views]
    if effects is not None and effects.vignetting:
        images = [image * vignetting_map(camera, effects.cos4, effects.lens_falloff)
                  for image, camera in zip(images, cameras)]
    return images, [v[2] for v in views]


# ---------------------------------------------------------------------------------------------
# the folder
# ---------------------------------------------------------------------------------------------
def request_key(spec: SceneSpec, board: Board, n_poses, spp, seed, air, distance_range,
                max_tilt_deg, variant, adaptive: bool = True,
                light: BoardLight | None = None,
                effects: CameraEffects | None = None) -> str:
    """Hash of everything that determines the folder; the adaptive settings only for an
    adaptive render (a full-film request keeps the key of earlier folders, rendered so), a lamp
    and camera effects only when given (without them the key of before)."""
    request = {"format": FORMAT_VERSION, "scene": spec.sha256, "params": spec.params,
               "board": board.to_dict(), "poses": n_poses, "spp": spp, "seed": seed,
               "air": bool(air), "distance_range": list(distance_range),
               "max_tilt_deg": max_tilt_deg, "variant": variant, "renderer": RENDERER}
    if adaptive:
        request["adaptive"] = adaptive_settings()
    for name, given in (("light", light), ("camera_effects", effects)):  # only when given
        if given is not None:
            request[name] = given.to_dict()
    return hashlib.sha256(json.dumps(request, sort_keys=True).encode()).hexdigest()


def write_boards(spec: SceneSpec, out_dir, board: Board, n_poses: int = DEFAULT_POSES,
                 spp: int = DEFAULT_SPP, seed: int = 0, air: bool = False,
                 distance_range=None,
                 max_tilt_deg: float = DEFAULT_MAX_TILT_DEG, variant=None,
                 progress: bool = True, adaptive: bool = True,
                 light: BoardLight | None = None,
                 effects: CameraEffects | None = None) -> dict:
    """Render ``n_poses`` stereo pairs of ``board`` and write the folder (module docs). Returns
    the manifest; ``manifest["skipped"]`` when ``out_dir`` already held the same request, whole
    (:meth:`synth.infra.fileio.OutputDir.damage`); ``manifest["rendered_again"]`` why an earlier output
    of the same request was rendered again, or None. ``adaptive`` (default) renders each view
    adaptively, False on the full film (:func:`synth.rendering.render.render_view_counted`); the
    manifest's ``render`` says how (lit fraction and samples per pose and view). ``light``: the
    board printed and lit by that lamp (:mod:`synth.products.board_light`; placed by
    :meth:`~synth.products.board_light.BoardLight.placed`, its aim by default the left optical
    axis at the middle of ``distance_range``); ValueError when the
    lamp is not in the water of a port. ``effects``: vignetting, a thin lens, a rolling shutter
    (:mod:`synth.products.board_camera`; None or all off: the board of before)."""
    t_start = time.perf_counter()
    if n_poses < 1:
        raise ValueError(f"--poses must be at least 1, got {n_poses}")
    if not air and not spec.has_port:
        raise ValueError(f"{spec.path}: the scene has no port; render its boards with --air")
    if distance_range is None:
        distance_range = DEFAULT_AIR_DISTANCE_RANGE_MM if air else DEFAULT_DISTANCE_RANGE_MM
    rig = board_rig(spec, air)
    if light is not None:
        light = light.placed(air, 0.5 * sum(distance_range))
        check_light(rig, light, air)
    effects = prepared_effects(effects, rig, air, distance_range)  # None: the board of before
    key = request_key(spec, board, n_poses, spp, seed, air, distance_range, max_tilt_deg, variant,
                      adaptive, light, effects)
    output, old, damage = _existing(out_dir, key)
    if old is not None:
        return old
    output.claim()
    n_views = len(spec.all_cameras)  # pose p renders with seed + N·p (N = 2: seed + 2p)
    check_render_request(spec, spp, seed, poses=-(-n_poses * n_views // 2), adaptive=adaptive)
    shifts = ([effects.board_shift(s * effects.motion_s / 2) for s in (-1.0, 1.0)]
              if effects is not None and effects.moving else ())
    poses = sample_poses(rig, board, n_poses, seed, not air, distance_range, max_tilt_deg,
                         shifts)
    if shifts:
        check_band_seeds(seed, n_poses, n_views)
    times = {}
    t = time.perf_counter()
    mscene, mi, chosen = build_board_scene(spec, board, air, variant, light, effects)
    times["load_mitsuba"] = time.perf_counter() - t
    t = time.perf_counter()
    images, stats = _render_poses(mscene, mi, spec, board, poses, spp, seed, adaptive, rig,
                                  effects, f"render boards {chosen} {spp} spp"
                                  f"{' adaptive' if adaptive else ''}", progress)
    times["render"] = time.perf_counter() - t
    names = tuple(spec.camera_names)
    with output.staged(extra={"request_key": key}) as tmp:
        scale = _write_files(tmp, images, names, rig, board, poses, air, effects)
        times["total"] = time.perf_counter() - t_start
        manifest = _manifest(spec, key, board, n_poses, air, light, rig, effects, names,
                             distance_range, max_tilt_deg, (chosen, mi, mscene), spp, seed,
                             scale, stats, adaptive, times)
        manifest["files"] = sorted(os.listdir(tmp)) + ["manifest.json"]
        manifest["sha256"] = {name: file_sha256(os.path.join(tmp, name))
                              for name in sorted(os.listdir(tmp))}
        manifest = jsonable(manifest)  # as written: the digest is of what is read back
        manifest["manifest_sha256"] = manifest_digest(manifest)
        atomic_write_json(os.path.join(tmp, "manifest.json"), manifest)
    return {**manifest, "skipped": False, "rendered_again": damage}


def _manifest(spec, key, board, n_poses, air, light, rig, effects, names, distance_range,
              max_tilt_deg, renderer, spp, seed, scale, stats, adaptive, times) -> dict:
    """The folder's manifest but for its files and hashes: the request, the board, its light
    and the camera's effects, how it was rendered (``renderer``: the variant, Mitsuba and its
    scene) and each view's render statistics."""
    chosen, mi, mscene = renderer
    w, h = spec.size
    samples = sum(s["samples"] for pair in stats for s in pair)
    return {
        "format_version": FORMAT_VERSION, "command": COMMAND,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "request_key": key, "versions": package_versions(),
        "scene": {"path": spec.path, "sha256": spec.sha256, "params": spec.params},
        "air": bool(air), "board": board.to_dict(), "poses": n_poses,
        **({} if light is None else {"light": light_record(light, rig)}),
        **({} if effects is None else {"camera_effects": effects.to_dict()}),
        **({"cameras": list(names)} if len(names) > 2 else {}),
        "distance_range_mm": list(distance_range), "max_tilt_deg": max_tilt_deg,
        "variant": chosen, "integrator": integrator_name(mi, mscene), "spp": spp,
        "seed": seed, "image_size": [w, h],
        "png_scale": scale, "samples_per_second": samples / times["render"],
        "render": {"settings": adaptive_settings() if adaptive else None,
                   "samples": samples,
                   "views": [{view: {k: s[k] for k in _POSE_STATS if k in s}
                              for view, s in zip(names, pair)}
                             for pair in stats]},
        "seconds": times,
    }


def _existing(out_dir, key):
    """``(output, old, damage)``: the output folder; ``old`` the manifest of an earlier output of
    the same request that is whole (nothing to do), else None and ``damage`` why an earlier
    output of this request is rendered again (or None)."""
    output = OutputDir(out_dir, COMMAND)
    damage = None
    if output.exists_as_output() and (read_marker(output.path) or {}).get("request_key") == key:
        damage = output.damage()  # up to date only when every file is whole
        try:
            if damage is None:
                with open(os.path.join(output.path, "manifest.json")) as fh:
                    return output, {**json.load(fh), "skipped": True}, None
        except (OSError, ValueError):
            damage = "manifest.json cannot be read"
    return output, None, damage


def _render_poses(mscene, mi, spec, board, poses, spp, seed, adaptive, rig, effects, desc,
                  progress) -> tuple[list, list]:
    """``(images, stats)``: every pose rendered (:func:`render_pose`), a progress bar showing
    each pose's lit fractions."""
    from tqdm import tqdm

    images, stats = [], []
    bar = tqdm(poses, desc=desc, unit="pose", disable=not progress, leave=False)
    for k, pose in enumerate(bar):
        pair, pair_stats = render_pose(mscene, mi, spec, board, pose, k, spp, seed, adaptive,
                                       rig, effects)
        images.append(pair)
        stats.append(pair_stats)
        lit = [1.0 if v["lit_fraction"] is None else v["lit_fraction"] for v in pair_stats]
        bar.set_postfix_str("lit " + " / ".join(f"{v:.1%}" for v in lit))
    bar.close()
    return images, stats


def _write_files(tmp, images, names, rig, board, poses, air, effects) -> float:
    """The views' 16-bit linear PNGs (one scale for all; returned), the rig's ``calib.yaml``,
    ``board.json`` and the corners' truth into ``tmp``."""
    scale = png16_scale(*[img for pair in images for img in pair])
    for k, pair in enumerate(images):
        for view, img in zip(names, pair):
            write_png(os.path.join(tmp, f"{view}_{k:02d}.png"), to_png16(img, scale))
    if isinstance(rig, BoardCameras):
        from synth.products.rig_file import write_rig_file

        write_rig_file(os.path.join(tmp, "calib.yaml"), rig.multirig())
    else:
        write_calib(os.path.join(tmp, "calib.yaml"), rig, not air)
    atomic_write_json(os.path.join(tmp, "board.json"), board.to_dict())
    _write_truth(tmp, rig, board, poses, names, effects)
    return scale


#: What the manifest keeps of each view's render statistics.
_POSE_STATS = ("mode", "reason", "lit_fraction", "mask_pixels", "samples_on_mask",
               "samples_off_mask", "spp_on_mask", "spp_off_mask", "bands")


def corner_pixels(rig: Rig, board: Board, poses, effects: CameraEffects | None = None):
    """Per pose ``(corners (M, 3) mm, (left pixels, right pixels) (M, 2))``: every corner of
    ``board`` at that :class:`BoardPose` in the reference frame and where each camera sees it
    through its port (the Fermat forward model); with a rolling shutter (``effects``) where
    it sees it at the instant of the corner's own row
    (:func:`synth.products.board_camera.rolling_pixels`)."""
    corners = board.corners()
    rolling = effects is not None and effects.rolling
    out = []
    for pose in poses:
        world = pose.apply(corners)
        out.append((world, tuple(
            rolling_pixels(camera, rig.view_port(view), corners, pose, effects)[0] if rolling
            else project(camera, rig.view_port(view), world)
            for view, camera in enumerate(rig.cameras))))
    return out


def corners_header(names) -> list:
    """The header of ``corners.csv``: :data:`CORNERS_HEADER` for ``left``, ``right``; for N
    cameras ``u_NAME, v_NAME`` per camera."""
    if tuple(names) == ("left", "right"):
        return CORNERS_HEADER
    return CORNERS_HEADER[:5] + [f"{a}_{name}" for name in names for a in ("u", "v")]


def _write_truth(directory, rig, board: Board, poses, names=("left", "right"),
                 effects: CameraEffects | None = None) -> None:
    ids = np.arange(board.corners().shape[0])
    with open(os.path.join(directory, "poses.csv"), "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(POSES_HEADER)
        for k, pose in enumerate(poses):
            rv = Rotation.from_matrix(pose.R).as_rotvec()
            writer.writerow([k] + [f"{v:.17g}" for v in (*rv, *pose.t)])
    with open(os.path.join(directory, "corners.csv"), "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(corners_header(names))
        for k, (world, views) in enumerate(corner_pixels(rig, board, poses, effects)):
            pixels = np.concatenate(views, axis=1)
            for i, p, uv in zip(ids, world, pixels):
                writer.writerow([k, int(i)] + [f"{v:.17g}" for v in (*p, *uv)])


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BoardImages:
    """A boards folder read back: ``images`` ``[(left, right), …]`` float32 linear per pose,
    ``board``, ``calib`` (the truth, :func:`synth.formats.calib_yaml.read_calib`), ``poses`` (truth),
    ``corners`` truth rows ``(M, 9)`` in :data:`CORNERS_HEADER` order, ``air``, ``manifest``.
    Of N > 2 cameras: ``images`` ``[(cam0, cam1, …), …]``, ``calib`` ``{"multirig": Rig,
    "size", "names"}``, ``corners`` in :func:`corners_header` order."""

    path: str
    images: list
    board: Board
    calib: dict
    poses: list
    corners: np.ndarray
    air: bool
    manifest: dict


def read_boards(path) -> BoardImages:
    """Read a folder written by :func:`write_boards`; :class:`DatasetError` names what is wrong."""
    import cv2

    path = os.fspath(path)
    if not os.path.isdir(path):
        raise DatasetError(f"{path}: not a boards folder (no such directory)")
    try:
        with open(os.path.join(path, "manifest.json")) as fh:
            manifest = json.load(fh)
        with open(os.path.join(path, "board.json")) as fh:
            board = Board.from_dict(json.load(fh))
    except OSError as exc:
        raise DatasetError(f"{path}: not a boards folder ({exc.strerror}: "
                           f"{os.path.basename(exc.filename or '')})") from None
    except (ValueError, BoardError) as exc:
        raise DatasetError(f"{path}: {exc}") from None
    if manifest.get("command") != COMMAND:
        raise DatasetError(f"{path}: not a boards folder (manifest of {manifest.get('command')!r})")
    if "board" in manifest and manifest["board"] != board.to_dict():
        def described(b):
            return f"{b.get('kind')} {'x'.join(map(str, b.get('squares', [])))}, {b.get('square_mm')} mm"

        raise DatasetError(f"{path}/board.json: a {described(board.to_dict())} board, but "
                           f"manifest.json says a {described(manifest['board'])} board was "
                           f"rendered")
    scale = float(manifest["png_scale"])
    n = int(manifest["poses"])
    names = tuple(manifest.get("cameras") or ("left", "right"))
    if len(names) > 2:  # N cameras: calib.yaml of N (synth.products.rig_file)
        from synth.products.rig_file import read_rig_file

        multirig = read_rig_file(os.path.join(path, "calib.yaml"))
        if multirig.names != names:
            raise DatasetError(f"{path}/calib.yaml: cameras {', '.join(multirig.names)}, but "
                               f"manifest.json says {', '.join(names)}")
        calib = {"multirig": multirig, "size": multirig.cameras[0].size, "names": names}
    else:
        calib = read_calib(os.path.join(path, "calib.yaml"))
    images = []
    for k in range(n):
        pair = []
        for view in names:
            file = os.path.join(path, f"{view}_{k:02d}.png")
            img = imread(file, cv2.IMREAD_UNCHANGED)
            if img is None or img.ndim != 2:
                raise DatasetError(f"{file}: missing or not a single-channel image")
            if img.shape[::-1] != tuple(calib["size"]):
                raise DatasetError(f"{file}: {img.shape[1]}x{img.shape[0]} px, but calib.yaml "
                                   f"says {calib['size'][0]}x{calib['size'][1]}")
            pair.append(img.astype(np.float32) / np.float32(scale))
        images.append(tuple(pair))
    poses_rows = read_truth_table(os.path.join(path, "poses.csv"), POSES_HEADER, n)
    poses = [BoardPose(Rotation.from_rotvec(r[1:4]).as_matrix(), r[4:7]) for r in poses_rows]
    corners = read_truth_table(os.path.join(path, "corners.csv"), corners_header(names),
                               n * board.n_corners)
    check_files(path, manifest, COMMAND)  # last: the readers above say more precisely what is wrong
    return BoardImages(path, images, board, calib, poses, corners, bool(manifest.get("air")),
                       manifest)


def read_truth_table(file, header, rows: int) -> np.ndarray:
    """``(rows, len(header))`` numbers of a CSV that :func:`_write_truth` wrote, read whole:
    :class:`DatasetError` unless it has ``header``, exactly ``rows`` complete rows of numbers
    (what the manifest's pose count says) and ends with its last row's newline."""
    try:
        with open(file, newline="", encoding="utf-8-sig") as fh:  # a BOM (Excel) is read
            text = fh.read()
    except OSError as exc:
        raise DatasetError(f"{file}: {exc.strerror or exc}") from None
    table = list(csv.reader(text.splitlines()))
    if not table or table[0] != header:
        raise DatasetError(f"{file}: header is {table[0] if table else None}, expected {header}")
    body = table[1:]
    bad = next((i for i, row in enumerate(body) if len(row) != len(header)), None)
    if bad is not None or (body and not text.endswith("\n")):
        line = (bad if bad is not None else len(body) - 1) + 2
        raise DatasetError(f"{file}: line {line} is not complete: truncated or malformed")
    if len(body) != rows:
        raise DatasetError(f"{file}: {len(body)} rows, but the manifest's poses and board.json "
                           f"say {rows}")
    try:
        return np.array(body, dtype=np.float64).reshape(rows, len(header))
    except ValueError:
        raise DatasetError(f"{file}: not numbers") from None


__all__ = ["BoardImages", "BoardPose", "board_rig", "build_board_scene", "read_boards",
           "read_truth_table",
           "render_pose", "sample_poses", "write_boards"]
