"""The files of a dataset other pipelines read (synth.formats.exchange): cameras.json, the COLMAP text
model with FLATPORT, the surfaces' PFM / PNG depth and .flo correspondence.

The COLMAP model is checked against an independent implementation of the refractive COLMAP
fork's flat-port ray model, written here from its published equations (Snell's law in vector
form at two parallel planes given in each camera's frame by the unit normal N and the distance
d of the first interface from the camera centre, the glass thickness; COLMAP's camera model and
pixel convention; images.txt's world-to-camera pose) — not from this project's code: every
exported pixel's ray passes through its 3D point to 1e-9 m."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from measure import Camera, FlatPort, StereoRig
from measure.geometry.flatport_format import to_flatport
from measure.geometry.projection import project
from synth.formats.exchange import (cameras_json, read_flo, read_pfm, write_colmap_model, write_flo,
                            write_pfm)
from synth.scene.rig import paper_rig


# ------------------------------------------------------------------------------------------------
# an independent reader and ray model


def _read_model(folder):
    cameras, images, points = {}, {}, {}
    for line in (folder / "cameras.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        parts = line.split(" ")
        camera_id, model = int(parts[0]), parts[1]
        assert model == "OPENCV"
        fx, fy, cx, cy, k1, k2, p1, p2 = map(float, parts[4:12])
        assert (k1, k2, p1, p2) == (0.0, 0.0, 0.0, 0.0)  # the test's rigs have no distortion
        assert parts[12] == "FLATPORT"
        cameras[camera_id] = {"f": (fx, fy), "c": (cx, cy),
                              "port": [float(v) for v in parts[13:21]]}
    lines = [x for x in (folder / "images.txt").read_text().splitlines()
             if not x.startswith("#")]
    for header, observations in zip(lines[0::2], lines[1::2]):
        parts = header.split()
        values = [float(v) for v in observations.split()]
        images[int(parts[0])] = {
            "q": [float(v) for v in parts[1:5]], "t": np.array([float(v) for v in parts[5:8]]),
            "camera": int(parts[8]), "name": parts[9],
            "xy": [(values[i], values[i + 1], int(values[i + 2]))
                   for i in range(0, len(values), 3)]}
    for line in (folder / "points3D.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        parts = line.split()
        track = [int(v) for v in parts[8:]]
        points[int(parts[0])] = {"xyz": np.array([float(v) for v in parts[1:4]]),
                                 "track": list(zip(track[0::2], track[1::2]))}
    return cameras, images, points


def _rotation(q):
    """Hamilton unit quaternion (w, x, y, z) → rotation matrix (COLMAP's convention)."""
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _refract(d, n, n1, n2):
    """Snell's law in vector form: unit direction ``d`` through a plane of unit normal ``n``
    (on the side ``d`` travels to), from index n1 into n2."""
    r = n1 / n2
    cos_i = float(d @ n)
    k = 1.0 - r * r * (1.0 - cos_i * cos_i)
    return r * d + (np.sqrt(k) - r * cos_i) * n


def _flatport_ray(camera, x, y):
    """Origin and direction (camera frame, metres) of the ray in the water of COLMAP pixel
    (x, y): the pinhole ray refracted at N·X = d (air → glass) and N·X = d + thickness
    (glass → water)."""
    (fx, fy), (cx, cy) = camera["f"], camera["c"]
    nx, ny, nz, d, thickness, na, ng, nw = camera["port"]
    n = np.array([nx, ny, nz])
    ray = np.array([(x - cx) / fx, (y - cy) / fy, 1.0])
    ray /= np.linalg.norm(ray)
    hit = ray * (d / (ray @ n))
    ray = _refract(ray, n, na, ng)
    hit = hit + ray * ((d + thickness - hit @ n) / (ray @ n))
    ray = _refract(ray, n, ng, nw)
    return hit, ray


def _rigs():
    rig = paper_rig()
    yield "paper", rig
    c, s = np.cos(np.radians(1.0)), np.sin(np.radians(1.0))
    tilted = FlatPort(normal=(s, 0.3 * s, c), distance=95.0, thicknesses=(8.0,),
                      indices=(1.0, 1.49, 1.345))
    right = Camera(rig.right.K, rig.right.size, R=rig.right.R @ np.array(
        [[1, 0, 0], [0, c, -s], [0, s, c]]), t=rig.right.t + np.array([0.0, 3.0, -2.0]))
    yield "tilted port, rotated right camera", StereoRig(rig.left, right, tilted)


def _targets():
    xs, ys = np.meshgrid(np.linspace(-600, 600, 9), np.linspace(-450, 450, 7))
    points = [np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)])
              for z in (700.0, 1500.0, 3000.0)]
    return np.concatenate(points)


@pytest.mark.parametrize("name, rig", list(_rigs()), ids=[n for n, _ in _rigs()])
def test_every_exported_ray_meets_its_point_in_the_forks_model(tmp_path, name, rig):
    points = _targets()
    uv_left, uv_right = project(rig.left, rig.port, points), project(rig.right, rig.port, points)
    assert write_colmap_model(str(tmp_path), rig, True, np.arange(len(points)), points, uv_left,
                              uv_right) is None
    cameras, images, model_points = _read_model(tmp_path / "colmap")
    assert len(model_points) > 0.8 * len(points)
    worst, checked = 0.0, 0
    for point in model_points.values():
        for image_id, index in point["track"]:
            image = images[image_id]
            x, y, point_id = image["xy"][index]
            assert model_points[point_id] is point
            origin, direction = _flatport_ray(cameras[image["camera"]], x, y)
            R = _rotation(image["q"])  # X_cam = R·X_world + t
            world_origin = R.T @ (origin - image["t"])
            world_direction = R.T @ direction
            offset = point["xyz"] - world_origin
            distance = np.linalg.norm(offset - (offset @ world_direction) * world_direction)
            worst, checked = max(worst, distance), checked + 1
    assert checked == 2 * len(model_points)
    assert worst <= 1e-9, f"{name}: a ray misses its point by {worst:.3g} m"


@pytest.mark.parametrize("name, rig", list(_rigs()), ids=[n for n, _ in _rigs()])
def test_flatport_round_trips_exactly(tmp_path, name, rig):
    from synth.products.dataset import read_calib

    write_colmap_model(str(tmp_path), rig, True, [], np.zeros((0, 3)), np.zeros((0, 2)),
                       np.zeros((0, 2)))
    cameras, _, _ = _read_model(tmp_path / "colmap")
    assert cameras[1]["port"] == to_flatport(rig.port, rig.left)
    assert cameras[2]["port"] == to_flatport(rig.port, rig.right)
    back = read_calib(str(tmp_path / "colmap" / "cameras.txt"))
    assert np.allclose(back["port"].normal, rig.port.normal, atol=1e-15, rtol=0)
    assert back["port"].distance == pytest.approx(rig.port.distance, abs=1e-12)
    assert back["port"].indices == rig.port.indices


def test_cameras_json_names_both_conventions_and_agrees_with_the_rig():
    from synth.formats.calib_formats import stereo_extrinsics

    _, rig = list(_rigs())[1]
    data = json.loads(json.dumps(cameras_json(rig)))
    right = data["cameras"]["right"]["pose_camera_to_reference"]
    assert right["convention"] == "X_ref = R · X_cam + t"
    assert np.array_equal(right["R"], rig.right.R) and np.array_equal(right["t"], rig.right.t)
    R, T = stereo_extrinsics(rig.left, rig.right)
    assert data["stereo_opencv"]["convention"].startswith("X_right = R · X_left + T")
    assert np.array_equal(data["stereo_opencv"]["R"], R)
    assert np.array_equal(data["stereo_opencv"]["T"], np.ravel(T))
    assert data["units"]["length"] == "mm" and data["port"]["indices"] == list(rig.port.indices)
    # a point of the left frame maps into the right frame both ways
    X = np.array([10.0, -20.0, 1000.0])
    via_pose = np.asarray(right["R"]).T @ (X - np.asarray(right["t"]))
    via_stereo = np.asarray(data["stereo_opencv"]["R"]) @ X + data["stereo_opencv"]["T"]
    assert np.allclose(via_pose, via_stereo, atol=1e-9)


def test_pfm_and_flo_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    depth = rng.uniform(500, 2000, (5, 7)).astype(np.float32)
    depth[1, 2] = np.nan
    write_pfm(str(tmp_path / "d.pfm"), depth)
    assert np.array_equal(read_pfm(str(tmp_path / "d.pfm")), depth, equal_nan=True)
    assert (tmp_path / "d.pfm").read_bytes().startswith(b"Pf\n7 5\n-1.0\n")
    flow = rng.normal(size=(5, 7, 2)).astype(np.float32)
    flow[0, 0] = np.nan
    write_flo(str(tmp_path / "f.flo"), flow)
    assert np.array_equal(read_flo(str(tmp_path / "f.flo")), flow, equal_nan=True)
    assert (tmp_path / "f.flo").stat().st_size == 12 + 5 * 7 * 8


@pytest.mark.slow
def test_a_dataset_holds_the_exchange_files_and_old_datasets_stay_readable(small_scene,
                                                                           tmp_path):
    from synth.products.dataset import (manifest_digest, manifest_request_key, read_calib, read_dataset,
                               write_dataset)

    out = tmp_path / "ds"
    manifest = write_dataset(small_scene, out, spp=2, progress=False,
                             defines={"width": "96", "height": "80"})
    assert manifest["format_version"] == 4
    for name in ("cameras.json", "colmap/cameras.txt", "colmap/images.txt",
                 "colmap/points3D.txt"):
        assert name in manifest["sha256"] and (out / name).is_file()
    dataset = read_dataset(out)
    data = json.loads((out / "cameras.json").read_text())
    assert np.allclose(data["cameras"]["right"]["K"], dataset.rig.right.K)
    colmap = read_calib(str(out / "colmap" / "cameras.txt"))
    assert np.allclose(colmap["rig"].right.t, dataset.rig.right.t, atol=1e-9)
    # a dataset of format 3 (no cameras.json, no colmap/) is still read
    old = tmp_path / "old"
    shutil.copytree(out, old)
    (old / "cameras.json").unlink()
    shutil.rmtree(old / "colmap")
    m = json.loads((old / "manifest.json").read_text())
    m["format_version"] = 3
    for key in ("truth_formats", "colmap"):
        m.pop(key)
    m["files"] = [f for f in m["files"] if f != "cameras.json" and not f.startswith("colmap/")]
    m["sha256"] = {k: v for k, v in m["sha256"].items() if k in m["files"]}
    m["request_key"] = manifest_request_key(m)
    m["manifest_sha256"] = manifest_digest(m)
    (old / "manifest.json").write_text(json.dumps(m))
    assert read_dataset(old).targets.shape == dataset.targets.shape


@pytest.mark.slow
def test_a_surface_dataset_holds_depth_and_correspondence_in_common_formats(tmp_path):
    import cv2

    from synth.products.dataset import read_dataset, write_dataset
    from synth.scene import load_scene
    from tests.conftest import REPO

    out = tmp_path / "surface"
    manifest = write_dataset(load_scene(str(REPO / "scenes" / "speckle_tilted.xml"),
                                        {"width": "96", "height": "80"}), out, spp=2,
                             progress=False)
    rig = read_dataset(out).rig
    scale = manifest["truth_formats"]["zdepth_png_scale"]
    for view, camera in (("left", rig.left), ("right", rig.right)):
        points = np.load(out / f"{view}_truth_points.npy")
        z = (points - camera.t) @ camera.R[:, 2]
        depth = read_pfm(str(out / f"{view}_truth_zdepth.pfm"))
        assert np.array_equal(np.isfinite(depth), np.isfinite(z))
        assert np.nanmax(np.abs(depth - z)) <= 1e-4  # float32 of ~1000 mm
        codes = cv2.imread(str(out / f"{view}_truth_zdepth.png"), cv2.IMREAD_UNCHANGED)
        assert codes.dtype == np.uint16 and np.array_equal(codes > 0, np.isfinite(z))
        assert np.nanmax(np.abs(codes[codes > 0] / scale - z[codes > 0])) <= 0.5 / scale + 1e-4
        assert f"{view}_truth_zdepth.pfm" in manifest["sha256"]
    flow = read_flo(str(out / "left_truth_flow.flo"))
    overlap = cv2.imread(str(out / "left_truth_overlap.png"), cv2.IMREAD_UNCHANGED) > 0
    assert overlap.sum() > 100 and np.array_equal(np.isfinite(flow[..., 0]), overlap)
    rows, cols = np.nonzero(overlap)
    points = np.load(out / "left_truth_points.npy")[rows, cols]
    right_pixels = np.column_stack([cols, rows]) + flow[rows, cols]
    # the right camera's refracted ray through the right pixel meets the same point
    assert np.allclose(right_pixels, project(rig.right, rig.port, points), atol=1e-3)
