"""One sea scene of a learning set, written whole: ``python -m synth learn``'s unit of work.

:func:`write_learn_scene` draws the scene of a seed (:mod:`synth.scene.sea_draw`), writes its
Mitsuba files (:mod:`synth.scene.sea_write`), computes its truth from the exact forward model
(:mod:`synth.products.learn_truth`), renders both views (Mitsuba, the project's integrators) and
writes every file a learner reads (:mod:`synth.formats.learn_formats`) into a staging folder
renamed into place (:class:`synth.infra.fileio.OutputDir`). The folder (``FILES`` lists it):

* ``scene/`` — ``scene.xml``, ``seabed.ply``, ``seabed_texture.png``: ``mi.load_file`` renders
  them (``spp``, ``seed`` are ``<default>`` values: ``python -m synth learn --spp`` and the seed);
* ``left.png``, ``right.png`` — 8-bit grey photos, one exposure for the pair, sRGB curve;
* ``truth/`` — per view ``{view}_depth_z.pfm`` (mm along the camera's own z), ``{view}_range.pfm``
  (mm from the camera centre), ``{view}_points.npy`` and ``{view}_normals.npy`` (float32
  ``(H, W, 3)``, reference frame = the left camera's, mm; NaN where the ray meets nothing),
  ``{view}_valid.png``; ``flow_left_to_right.flo`` (Middlebury, px, NaN where the left point has no
  right pixel) and ``occlusion_left.png`` (255: the left pixel's point is hidden from, or outside,
  the right view);
* ``rectified/`` — the port-exact row-aligned pair (``eval rectify`` at the scene's median
  distance): ``left.png``, ``right.png``, ``disparity.pfm`` (SceneFlow style, 0 where none),
  ``disparity_occ.png`` and ``disparity_noc.png`` (KITTI style: every pixel with truth /
  the ones the right camera sees), ``residual.pfm`` and ``row_error.pfm`` (px, NaN where none),
  ``occlusion.png``, ``depth_left.pfm`` (z along the virtual left camera, mm), ``calib.yaml``
  (the virtual pinhole pair);
* ``calib.yaml``, ``cameras.json`` — the rig and its port; ``colmap/`` — the refractive COLMAP
  fork's text model (FLATPORT or DOMEPORT per camera) with points seen by both views and
  ``depth_maps/{left,right}.png.geometric.bin`` (z in metres); ``colmap_pinhole/`` — the plain
  pinhole model of the rectified pair (upstream COLMAP) with its depth maps;
* ``manifest.json`` — every file's SHA-256 and size, the generator's parameters (seed, ranges,
  what was drawn), the checks (:func:`scene_checks`) and the timings.
"""

from __future__ import annotations

import hashlib
import json
import os
import time

import numpy as np

from measure.stereo.rectify import rectified_pixels
from synth.formats import learn_formats as lf
from synth.formats.exchange import write_cameras_json, write_colmap_model, write_flo, write_pfm
from synth.products import learn_truth as lt
from synth.products.truth_maps import MeshTracer
from synth.scene.sea_draw import SeaRanges, SeaScene, draw_scene
from synth.scene.sea_write import (DEFAULT_LEARN_SPP, MESH_FILE, SCENE_FILE, TEXTURE_FILE,
                                   write_sea_scene)

COMMAND = "synth learn"
#: Version of the folder's layout (in the manifest and the request key).
LEARN_FORMAT = 2
#: Pixels sampled per view for the Fermat round trip, and per scene for the rectified check.
CHECK_PIXELS = 2000
#: The largest Fermat round trip (px) and disagreement between the rectified disparity and the
#: correspondence truth carried through the warp (px) a scene passes with.
ROUND_TRIP_BOUND_PX, RECTIFIED_BOUND_PX = 0.01, 0.01
#: Where the warp counts as exact (its residual, px), and the largest spread of the four
#: disparities a bilinear sample of the disparity file may straddle (px: no depth edge).
EXACT_RESIDUAL_PX, SMOOTH_SPREAD_PX = 0.01, 0.5
#: Step (px) of the left-pixel grid whose points set the rectified pair's disparity offset
#: (:func:`synth.products.learn_truth.disparity_offset`).
OFFSET_SAMPLE_STEP = 8
#: Step (px) of the left-pixel grid whose points the COLMAP models list.
COLMAP_POINT_STEP = 24


def _digest(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def object_digests(ranges: SeaRanges) -> list:
    """The SHA-256 of each object file of ``ranges`` (their bytes, not their paths, make a
    scene)."""
    return [_digest(path) for path in ranges.objects]


def request_key(seed: int, ranges: SeaRanges, spp: int) -> str:
    """What makes a scene's folder up to date: the seed, the ranges (the object files by their
    bytes), spp, the layout version."""
    described = ranges.describe()
    if ranges.objects:
        described["objects"] = object_digests(ranges)
    text = json.dumps({"seed": int(seed), "ranges": described, "spp": int(spp),
                       "format": LEARN_FORMAT}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def median_distance(scene: SeaScene, left: lt.ViewTruth) -> float:
    """The median distance (mm, along the rig's depth axis) of what the left camera sees."""
    return float(np.median(left.points[left.valid] @ scene.rig.depth_axis))


def render_pair(directory: str, scene: SeaScene, spp: int):
    """Both views of the scene file in ``directory`` (float32 linear images) and timings."""
    from synth.rendering.mitsuba_setup import import_mitsuba
    from synth.rendering.render import render_view_counted

    mi, variant = import_mitsuba()
    mscene = mi.load_file(os.path.join(directory, SCENE_FILE), spp=str(int(spp)), seed="0")
    images, info = [], {"variant": variant, "seconds": {}}
    for view, camera in enumerate(scene.rig.cameras):
        started = time.perf_counter()
        image, taken, _ = render_view_counted(mscene, mi, view, camera, int(spp),
                                              scene.seed % (1 << 31), adaptive=False)
        images.append(image)
        info["spp_rendered"] = int(taken)
        info["seconds"][("left", "right")[view]] = time.perf_counter() - started
    return images, info


class _Clock:
    """Seconds of each part of a scene: wall clock into ``seconds``, CPU into ``cpu`` (this
    process's, every thread's: Mitsuba's render threads too), each part from the end of the
    one before."""

    def __init__(self, seconds: dict, cpu: dict):
        self.seconds, self.cpu = seconds, cpu
        self.wall, self.process = time.perf_counter(), time.process_time()

    def lap(self, part: str) -> None:
        wall, process = time.perf_counter(), time.process_time()
        self.seconds[part], self.cpu[part] = wall - self.wall, process - self.process
        self.wall, self.process = wall, process


def _write_view_truth(folder: str, name: str, truth: lt.ViewTruth) -> None:
    write_pfm(os.path.join(folder, f"{name}_depth_z.pfm"), truth.z.astype(np.float32))
    write_pfm(os.path.join(folder, f"{name}_range.pfm"), truth.range.astype(np.float32))
    np.save(os.path.join(folder, f"{name}_points.npy"), truth.points.astype(np.float32))
    np.save(os.path.join(folder, f"{name}_normals.npy"), truth.normals.astype(np.float32))
    lf.write_png(os.path.join(folder, f"{name}_valid.png"), truth.valid.astype(np.uint8) * 255)


def _write_rectified(folder: str, rect: lt.RectifiedTruth, images, scale) -> dict:
    from synth.products.dataset import write_calib

    os.makedirs(folder, exist_ok=True)
    for view, name in enumerate(("left", "right")):
        warped = rect.rectification.warp(view, images[view])
        lf.write_png(os.path.join(folder, f"{name}.png"), lf.photo_8bit(warped, scale))
    seen = np.isfinite(rect.disparity) & ~rect.occluded
    lf.write_sceneflow_disparity(os.path.join(folder, "disparity.pfm"), rect.disparity)
    beyond = lf.write_kitti_disparity(os.path.join(folder, "disparity_occ.png"), rect.disparity)
    lf.write_kitti_disparity(os.path.join(folder, "disparity_noc.png"),
                             np.where(seen, rect.disparity, np.nan))
    write_pfm(os.path.join(folder, "residual.pfm"), rect.residual.astype(np.float32))
    write_pfm(os.path.join(folder, "row_error.pfm"), rect.row_error.astype(np.float32))
    write_pfm(os.path.join(folder, "depth_left.pfm"), rect.depth.astype(np.float32))
    write_pfm(os.path.join(folder, "depth_right.pfm"), rect.right_depth.astype(np.float32))
    lf.write_png(os.path.join(folder, "occlusion.png"), rect.occluded.astype(np.uint8) * 255)
    write_calib(os.path.join(folder, "calib.yaml"), rect.rectification.virtual, has_port=False)
    finite = rect.disparity[np.isfinite(rect.disparity)]
    virtual = rect.rectification.virtual
    return {"distance_mm": rect.rectification.distance_mm, "kitti_beyond_range": beyond,
            "disparity_offset_px": float(virtual.right.K[0, 2] - virtual.left.K[0, 2]),
            "disparity_px": [float(finite.min()), float(finite.max())] if finite.size else None,
            "residual_median_px": float(np.nanmedian(rect.residual)),
            "residual_max_px": float(np.nanmax(rect.residual)),
            "exact_fraction": float(np.mean(rect.residual[rect.valid] <= EXACT_RESIDUAL_PX))}


def _colmap_points(left: lt.ViewTruth, flow, seen):
    """Points on a :data:`COLMAP_POINT_STEP` grid of left pixels that the right camera sees,
    their left and right pixels."""
    h, w = seen.shape
    rows, cols = np.mgrid[0:h:COLMAP_POINT_STEP, 0:w:COLMAP_POINT_STEP]
    keep = seen[rows, cols]
    rows, cols = rows[keep], cols[keep]
    uv_left = np.column_stack([cols, rows]).astype(np.float64)
    return left.points[rows, cols], uv_left, uv_left + flow[rows, cols]


def _write_exchange(folder, scene, left, right, flow, seen, rect) -> str | None:
    from synth.products.dataset import write_calib

    write_calib(os.path.join(folder, "calib.yaml"), scene.rig, has_port=True)
    write_cameras_json(folder, scene.rig)
    points, uv_left, uv_right = _colmap_points(left, flow, seen)
    why = write_colmap_model(folder, scene.rig, True, np.arange(points.shape[0]), points,
                             uv_left, uv_right)
    if why is None:
        depth_dir = os.path.join(folder, "colmap", "depth_maps")
        os.makedirs(depth_dir)
        for name, truth in (("left", left), ("right", right)):
            lf.write_colmap_depth(os.path.join(depth_dir, f"{name}.png.geometric.bin"), truth.z)
    virtual = rect.rectification.virtual
    pinhole = os.path.join(folder, "colmap_pinhole")
    pixels = np.stack([virtual.left.project(points), virtual.right.project(points)], axis=1)
    lf.write_pinhole_colmap(pinhole, virtual.cameras, ("rectified/left.png",
                                                       "rectified/right.png"), points, pixels)
    os.makedirs(os.path.join(pinhole, "depth_maps"))
    lf.write_colmap_depth(os.path.join(pinhole, "depth_maps", "left.png.geometric.bin"),
                          rect.depth)
    lf.write_colmap_depth(os.path.join(pinhole, "depth_maps", "right.png.geometric.bin"),
                          rect.right_depth)
    return why


def scene_checks(scene, tracer, left, right, flow, seen, rect, rng) -> dict:
    """The checks every scene passes (bounds :data:`ROUND_TRIP_BOUND_PX`,
    :data:`RECTIFIED_BOUND_PX`):

    * the Fermat round trip: sampled truth points of both views (float32, as written) projected
      back into their cameras, px from their pixel centres;
    * the rectified disparity against the correspondence truth: sampled left pixels ``p`` that
      the right camera sees and their right pixels ``p + flow`` (the ``.flo`` values, float32)
      carried through the warp (:func:`measure.stereo.rectify.rectified_pixels`) give a
      disparity ``q_L,u − q_R,u``; the rectified truth at ``q_L`` (the function that wrote the
      disparity file, at that sub-pixel position) must agree — over every sampled pixel and
      over those where the warp is exact (residual ≤ :data:`EXACT_RESIDUAL_PX`);
    * the disparity file is that function on the pixel grid: sampled rectified pixels' file
      values (float32) against the function evaluated again there.

    Also reported: the file sampled bilinearly at ``q_L`` (where its four texels lie within
    :data:`SMOOTH_SPREAD_PX`) against the same disparities — the interpolation error a learner's
    bilinear warp makes (median and 99th percentile), not a bound."""
    out = {}
    for view, truth in ((0, left), (1, right)):
        uv = lt.sample_pixels(truth.valid, CHECK_PIXELS, rng)
        stored = truth.points.astype(np.float32).astype(np.float64)
        rows, cols = uv[:, 1].astype(int), uv[:, 0].astype(int)
        errors = lt.fermat_round_trip(scene.rig, view, stored[rows, cols], uv)
        out[("left", "right")[view] + "_round_trip_max_px"] = float(np.max(errors))
    out.update(_rectified_checks(tracer, flow, seen, rect, rng))
    worst = [out["rectified_vs_flow_max_px"], out["exact_rectified_vs_flow_max_px"],
             out["disparity_file_vs_truth_max_px"]]
    out["passed"] = bool(max(out["left_round_trip_max_px"], out["right_round_trip_max_px"])
                         <= ROUND_TRIP_BOUND_PX
                         and all(w is None or w <= RECTIFIED_BOUND_PX for w in worst))
    return out


def _largest(values, mask):
    return float(np.max(values[mask])) if np.any(mask) else None


def _rectified_checks(tracer, flow, seen, rect, rng) -> dict:
    """The rectified part of :func:`scene_checks`."""
    warp = rect.rectification
    uv = lt.sample_pixels(seen, CHECK_PIXELS, rng)
    rows, cols = uv[:, 1].astype(int), uv[:, 0].astype(int)
    stored_flow = flow.astype(np.float32).astype(np.float64)
    q_left = rectified_pixels(warp, 0, uv)
    q_right = rectified_pixels(warp, 1, uv + stored_flow[rows, cols])
    from_flow = q_left[:, 0] - q_right[:, 0]
    truth, _, residual, _, _, _ = lt.rectified_truth_at(tracer, warp, q_left)
    error = np.abs(truth - from_flow)
    compared = np.isfinite(error)
    exact = compared & (residual <= EXACT_RESIDUAL_PX)
    grid = lt.sample_pixels(np.isfinite(rect.disparity), CHECK_PIXELS, rng)
    again = lt.rectified_truth_at(tracer, warp, grid)[0]
    stored = rect.disparity.astype(np.float32).astype(np.float64)
    file_error = np.abs(stored[grid[:, 1].astype(int), grid[:, 0].astype(int)] - again)
    sampled, spread = lt.bilinear(stored, q_left)
    bilinear_error = np.abs(sampled - from_flow)
    smooth = np.isfinite(bilinear_error) & (spread <= SMOOTH_SPREAD_PX)
    return {"rectified_pixels_compared": int(compared.sum()),
            "rectified_vs_flow_max_px": _largest(error, compared),
            "exact_pixels_compared": int(exact.sum()),
            "exact_rectified_vs_flow_max_px": _largest(error, exact),
            "disparity_file_vs_truth_max_px": _largest(file_error, np.isfinite(file_error)),
            "bilinear_file_vs_flow_px": (
                [float(np.median(bilinear_error[smooth])),
                 float(np.quantile(bilinear_error[smooth], 0.99))] if smooth.any() else None)}


def write_learn_scene(out_dir: str, seed: int, ranges: SeaRanges | None = None,
                      spp: int = DEFAULT_LEARN_SPP) -> dict:
    """Draw, render and write the scene of ``seed`` into ``out_dir`` whole (module docs; the
    default ``ranges`` are :class:`synth.scene.sea_draw.SeaRanges`'); an earlier output of this
    command there is replaced. Returns the manifest."""
    from synth.infra.fileio import OutputDir

    ranges = SeaRanges() if ranges is None else ranges
    started, cpu_started = time.perf_counter(), time.process_time()
    scene = draw_scene(seed, ranges)
    out = OutputDir(out_dir, COMMAND).claim()
    with out.staged({"request_key": request_key(seed, ranges, spp)}) as tmp:
        seconds, cpu = {}, {}
        os.makedirs(os.path.join(tmp, "scene"))
        clock = _Clock(seconds, cpu)
        floor = write_sea_scene(os.path.join(tmp, "scene"), scene, spp)
        clock.lap("scene")
        tracer = MeshTracer(os.path.join(tmp, "scene", MESH_FILE), floor.mesh.vertices,
                            floor.mesh.triangles)
        left, right = lt.view_truth(tracer, scene.rig, 0), lt.view_truth(tracer, scene.rig, 1)
        flow, seen, occluded = lt.flow_truth(tracer, scene.rig, left)
        sample = left.points[::OFFSET_SAMPLE_STEP, ::OFFSET_SAMPLE_STEP].reshape(-1, 3)
        offset = lt.disparity_offset(scene.rig, sample)
        rect = lt.rectified_truth(tracer, scene.rig, median_distance(scene, left), offset)
        clock.lap("truth")
        images, render = render_pair(os.path.join(tmp, "scene"), scene, spp)
        clock.lap("render")
        images = [lf.remove_fireflies(image) for image in images]
        scale = lf.exposure(*images)
        for view, name in enumerate(("left", "right")):
            lf.write_png(os.path.join(tmp, f"{name}.png"), lf.photo_8bit(images[view], scale))
        truth_dir = os.path.join(tmp, "truth")
        os.makedirs(truth_dir)
        _write_view_truth(truth_dir, "left", left)
        _write_view_truth(truth_dir, "right", right)
        write_flo(os.path.join(truth_dir, "flow_left_to_right.flo"), flow.astype(np.float32))
        lf.write_png(os.path.join(truth_dir, "occlusion_left.png"),
                     occluded.astype(np.uint8) * 255)
        rectified = _write_rectified(os.path.join(tmp, "rectified"), rect, images, scale)
        colmap = _write_exchange(tmp, scene, left, right, flow, seen, rect)
        clock.lap("write")
        checks = scene_checks(scene, tracer, left, right, flow, seen, rect,
                              np.random.default_rng(seed))
        clock.lap("checks")
        seconds["total"] = time.perf_counter() - started
        cpu["total"] = time.process_time() - cpu_started
        manifest = _manifest(tmp, scene, ranges, spp, floor, render, rectified, colmap, checks,
                             (seconds, cpu), left, seen, occluded)
    return manifest


def _manifest(tmp, scene, ranges, spp, floor, render, rectified, colmap, checks, timings,
              left, seen, occluded) -> dict:
    """``manifest.json`` of a scene folder (module docs), written into ``tmp``; ``timings``
    the wall-clock and CPU seconds of each part (:class:`_Clock`)."""
    from synth.infra.fileio import atomic_write_json

    files = {}
    for root, _, names in os.walk(tmp):
        for name in sorted(names):
            path = os.path.join(root, name)
            rel = os.path.relpath(path, tmp).replace(os.sep, "/")
            if not rel.startswith("."):
                files[rel] = {"sha256": _digest(path), "bytes": os.path.getsize(path)}
    manifest = {
        "command": COMMAND, "format": LEARN_FORMAT, "seed": scene.seed,
        "request_key": request_key(scene.seed, ranges, spp),
        "generator": {"ranges": ranges.describe(), "spp": int(spp),
                      "port": scene.port_kind, "water": scene.water, "light": scene.light,
                      "distance_mm": scene.distance_mm, "drawn": scene.drawn,
                      "seabed": scene.seabed.describe(),
                      "mesh": {"vertices": int(floor.mesh.vertices.shape[0]),
                               "triangles": int(floor.mesh.triangles.shape[0])},
                      "texture": {"texel_mm": floor.texel_mm,
                                  "shape": list(floor.texture_shape)},
                      "objects": {"files": [os.path.basename(p) for p in ranges.objects],
                                  "sha256": object_digests(ranges), "placed": floor.objects}},
        "image_size": list(scene.rig.left.size),
        "pixels": {"valid_left": int(left.valid.sum()), "seen_by_right": int(seen.sum()),
                   "occluded_left": int(occluded.sum())},
        "render": render, "rectified": rectified,
        "colmap": colmap or "written (colmap/: the refractive fork's model)",
        "checks": checks, "seconds": timings[0], "cpu_seconds": timings[1], "files": files,
        "scene_files": [f"scene/{SCENE_FILE}", f"scene/{MESH_FILE}", f"scene/{TEXTURE_FILE}"]}
    atomic_write_json(os.path.join(tmp, "manifest.json"), manifest)
    return manifest
