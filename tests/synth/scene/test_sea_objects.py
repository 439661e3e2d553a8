"""Objects the user gives, set on a generated sea floor: where they are, that the truth sees them,
and that a bad file is refused."""

from __future__ import annotations

import numpy as np
import pytest

from synth.products.truth_maps import MeshTracer
from synth.scene.sea_draw import SeaRanges, draw_scene
from synth.scene.sea_objects import SINK_SHARE, read_object
from synth.scene.sea_write import MESH_FILE, write_sea_scene
from synth.scene.surfaces import SurfaceMesh, write_ply


def _pipe(path, radius=120.0, length=1500.0, segments=24):
    """A closed pipe lying along x (mm, z up), its axis 500 mm above z = 0."""
    angles = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.column_stack([np.zeros(segments), radius * np.cos(angles),
                            500 + radius * np.sin(angles)])
    vertices = np.vstack([ring, ring + [length, 0, 0]])
    k = np.arange(segments)
    n = (k + 1) % segments
    triangles = np.vstack([np.column_stack([k, n, k + segments]),
                           np.column_stack([n, n + segments, k + segments])])
    write_ply(str(path), SurfaceMesh(vertices, triangles, vertices[:, :2], "pipe"),
              vertices[:, :2].min(axis=0), vertices[:, :2].max(axis=0))
    return str(path)


def test_an_object_is_centred_on_its_footprint_with_its_base_at_zero(tmp_path):
    item = read_object(_pipe(tmp_path / "pipe.ply"))
    lower, upper = item.vertices.min(axis=0), item.vertices.max(axis=0)
    np.testing.assert_allclose([lower[0] + upper[0], lower[1] + upper[1], lower[2]], 0,
                               atol=1e-4)
    assert upper[2] == pytest.approx(240.0, abs=1e-3)


@pytest.mark.parametrize("content, fragment", [(None, "no such file"), (b"", "empty"),
                                               (b"ply\nnot a mesh\n", "cannot read")])
def test_a_bad_object_file_is_refused(tmp_path, content, fragment):
    path = tmp_path / "thing.ply"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ValueError, match=fragment) as info:
        read_object(str(path))
    assert str(info.value).startswith(f"--object {path}")


def test_objects_sit_on_the_floor_and_the_truth_sees_them(tmp_path):
    """The first scene (by seed) whose drawn objects reach into the left view: the object is
    merged into the mesh where it was drawn, and the rays of the pixels of its top vertices hit
    the object's triangles first (a pipe on the floor is seen from above)."""
    from measure.geometry.projection import project

    pipe = _pipe(tmp_path / "pipe.ply")
    for seed in range(60):
        scene = draw_scene(seed, SeaRanges(size=(160, 128), objects=(pipe,), waters=("clear",)))
        folder = tmp_path / f"s{seed}"
        folder.mkdir()
        floor = write_sea_scene(str(folder), scene, spp=2)
        count = floor.x.size * floor.y.size
        objects = floor.mesh.vertices[count:]
        uv = project(scene.rig.left, scene.rig.view_port(0), objects)
        if floor.objects and np.any(scene.rig.left.in_image(uv, 2.0)):
            break
    else:
        pytest.fail("no scene of 60 put an object in the left view")
    floor_triangles = 2 * (floor.x.size - 1) * (floor.y.size - 1)
    assert floor.mesh.triangles.shape[0] == floor_triangles + 48 * len(floor.objects)
    assert floor.texture_shape[0] > 256
    R, t = scene.to_reference
    sea = (objects - t) @ R  # back into the seabed frame
    first = sea[:48]
    np.testing.assert_allclose((first[:, :2].min(axis=0) + first[:, :2].max(axis=0)) / 2,
                               floor.objects[0]["at_mm"], atol=1e-2)
    assert floor.objects[0]["sunk_mm"] == pytest.approx(SINK_SHARE * 240.0)
    # centroids of the object's upward faces, 20 mm above the floor there and in view: the
    # rays of their pixels meet the object first
    grid = ((floor.mesh.vertices[:count] - t) @ R)[:, 2].reshape(floor.y.size, floor.x.size)
    faces = floor.mesh.triangles[floor_triangles:] - count
    corners = sea[faces]
    centroids = corners.mean(axis=1)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    up = normals[:, 2] / np.linalg.norm(normals, axis=1) > 0.5
    rows = np.abs(floor.y[None, :] - centroids[:, 1:2]).argmin(axis=1)
    cols = np.abs(floor.x[None, :] - centroids[:, 0:1]).argmin(axis=1)
    uv_c = project(scene.rig.left, scene.rig.view_port(0), centroids @ R.T + t)
    chosen = up & scene.rig.left.in_image(uv_c, 2.0) & (centroids[:, 2] > grid[rows, cols] + 20)
    tracer = MeshTracer(str(folder / MESH_FILE), floor.mesh.vertices, floor.mesh.triangles)
    water = scene.rig.trace(0, scene.rig.left.rays(uv_c[chosen]))
    hit = tracer.first_triangles(water.origins, water.directions)
    assert chosen.any() and np.mean(hit >= floor_triangles) > 0.9
