"""One printed board in front of one camera, rendered with Mitsuba: a flat or bent sheet, matte
or laminated, lit by one lamp — the renders of ``tools/ouc_twin.py`` and
``tools/effects_atlas.py``.

:mod:`synth.products.boards` renders a scene's rig; this module renders the board alone, for
studies of what the board and its light do to a detector. The board is a triangle mesh (an
OBJ written to a temporary folder) over ``extent = (x0, x1, y0, y1)`` mm in the board frame of
:mod:`measure.calibration.board` (x right, y down, z away from whoever looks at the printed
side), textured with a reflectance image whose row 0 is ``y0`` and column 0 is ``x0``
(nearest-texel lookup). A **sag** bends it along x like a plate held at its two side edges:
``z(x) = −sag · (1 − ((x − x_c) / (W/2))²)`` mm, the middle ``sag`` mm nearer the viewer than
the side edges (:func:`sag_z`); the corners' truth is bent with it (:func:`bent_points`).
A **laminate** is Mitsuba's ``roughplastic`` (a dielectric coat of index 1.5 and GGX roughness
``alpha`` over the printed diffuse reflectance): a highlight where the coat mirrors the lamp.

Frames and units: ``pose = (R, t)`` maps the board frame to the camera's (OpenCV axes, mm),
``X_cam = R·X_board + t``; the camera sits at the origin of the reference frame. Images are
float32 ``(H, W)`` linear radiance as rendered.
"""

from __future__ import annotations

import os
import tempfile

import numpy as np

#: Mesh vertices along the board's x (its bend) and y (straight: two are enough, but a few
#: more keep the triangles' shapes sane).
MESH_X, MESH_Y = 64, 8
#: The laminate's coat: index of refraction (PET / PVC film).
COAT_IOR = 1.5


def sag_z(x, extent, sag_mm: float) -> np.ndarray:
    """The bent board's z (mm, board frame) at board x (mm): ``−sag`` at the middle of
    ``extent``'s x range, 0 at its two ends (module docs)."""
    x0, x1 = extent[0], extent[1]
    s = (np.asarray(x, float) - (x0 + x1) / 2) / ((x1 - x0) / 2)
    return -sag_mm * (1.0 - s * s)


def bent_points(points_board, extent, sag_mm: float) -> np.ndarray:
    """Board points ``(N, 3)`` (mm, printed on the flat sheet) where they lie on the bent one.
    The sheet bends without stretching only approximately: the points keep their x and y (a
    sag of 2 mm over 300 mm shortens the sheet's x by 0.04 mm), z is :func:`sag_z`."""
    p = np.array(points_board, dtype=np.float64, copy=True)
    p[:, 2] = p[:, 2] + sag_z(p[:, 0], extent, sag_mm)
    return p


def write_board_obj(path: str, extent, sag_mm: float) -> None:
    """An OBJ of the (bent) board over ``extent`` mm in the board frame, uv (0, 0) at
    ``(x0, y1)`` so that the texture's row 0 lies at ``y0`` (Mitsuba's bitmaps have v up)."""
    x0, x1, y0, y1 = extent
    u, v = np.meshgrid(np.linspace(0, 1, MESH_X), np.linspace(0, 1, MESH_Y))
    x, y = x0 + u * (x1 - x0), y0 + v * (y1 - y0)
    z = sag_z(x, extent, sag_mm)
    lines = [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in zip(x.ravel(), y.ravel(), z.ravel())]
    lines += [f"vt {a:.6f} {1 - b:.6f}" for a, b in zip(u.ravel(), v.ravel())]
    i, j = np.meshgrid(np.arange(MESH_Y - 1), np.arange(MESH_X - 1), indexing="ij")
    a = (i * MESH_X + j).ravel() + 1
    for p, q, r, s in zip(a, a + 1, a + MESH_X + 1, a + MESH_X):
        lines.append(f"f {p}/{p} {q}/{q} {r}/{r}")
        lines.append(f"f {p}/{p} {r}/{r} {s}/{s}")
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def bsdf_dict(mi, texture: np.ndarray, laminate_alpha: float | None = None) -> dict:
    """The printed surface: ``texture`` (reflectance, float32 ``(H, W, 1)``) as a two-sided
    diffuse BSDF, or under a laminate of GGX roughness ``laminate_alpha`` (module docs)."""
    bitmap = {"type": "bitmap", "data": mi.TensorXf(texture), "raw": True,
              "filter_type": "nearest"}
    if laminate_alpha is None:
        inner = {"type": "diffuse", "reflectance": bitmap}
    else:
        inner = {"type": "roughplastic", "distribution": "ggx", "alpha": float(laminate_alpha),
                 "int_ior": COAT_IOR, "diffuse_reflectance": bitmap, "nonlinear": False}
    return {"type": "twosided", "bsdf": inner}


def render_board(camera, pose, texture, extent, emitter: dict, spp: int, seed: int,
                 sag_mm: float = 0.0, laminate_alpha: float | None = None) -> np.ndarray:
    """The linear render (float32 ``(H, W)``) of the board at ``pose`` (module docs) seen by
    ``camera`` (a :class:`measure.Camera` at the origin; its distortion rendered as every
    distorted camera is, :func:`synth.rendering.render.render_view_counted`) and lit by
    ``emitter`` (a Mitsuba emitter dict in the camera's frame)."""
    from measure import Camera
    from synth.rendering.mitsuba_setup import import_mitsuba
    from synth.rendering.render import render_view_counted, sensor_dict

    mi, _ = import_mitsuba(None)
    R, t = pose
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, t
    w, h = camera.size
    # a placeholder pinhole of square pixels: render_view_counted renders a distorted camera, or
    # one of fx ≠ fy, on an oversampled ideal film of its own and warps it
    K = camera.K if camera.dist is None else np.array([[camera.K[0, 0], 0, (w - 1) / 2],
                                                       [0, camera.K[0, 0], (h - 1) / 2],
                                                       [0, 0, 1.0]])
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "board.obj")
        write_board_obj(path, extent, sag_mm)
        scene = mi.load_dict({
            "type": "scene", "integrator": {"type": "path", "max_depth": 3},
            "sensor": sensor_dict(mi, Camera(K, camera.size),
                                  {"type": "independent", "sample_count": 4, "seed": 0}),
            "board": {"type": "obj", "filename": path,
                      "to_world": mi.ScalarTransform4f(M.tolist()),
                      "bsdf": bsdf_dict(mi, texture, laminate_alpha)},
            "lamp": emitter})
    return render_view_counted(scene, mi, 0, camera, spp, seed, adaptive=False)[0]
