"""The fixtures of tools/probe_pass.py: small renders made with the commands themselves, and the
spoiled copies, detections files and photos it makes with OpenCV (names in capitals)."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[1]
SMALL = "-D width=320 -D height=268"
BOARD = "--squares 7x6 --square-mm 60 --distance 450 900 --poses 10"
PHOTO_BOARD = "--squares 7x6 --square-mm 60"
GRID = "--layout grid --spacing 150 --half-width 600 --target-radius 10"  # targets of 2+ px

#: (the path it makes, the command after ``python -m``), run in order in the scratch folder;
#: a fixture whose path exists is kept (``--keep`` resumes). Each must exit 0.
FIXTURES = [
    ("three.xml", f"synth scene --cameras 3 {GRID} --size 320 268 --out three.xml"),
    ("four.xml", "synth scene --cameras 4 --size 612 512 --focal 275 --out four.xml"),
    ("pair.xml", "synth scene --size 612 512 --focal 275 --out pair.xml"),
    ("housings.xml", f"synth scene --port per-camera --port-distance 60,70 {GRID} --size 320 "
                     f"268 --out housings.xml"),
    ("domes.xml", f"synth scene --port dome {GRID} --size 320 268 --out domes.xml"),
    ("house612.xml", "synth scene --port per-camera --port-distance 60,70 --size 612 512 "
                     "--focal 275 --out house612.xml"),
    ("dome.xml", "synth scene --port dome --dome-offset 2 0 0 --size 480 402 --focal 225 "
                 "--out dome.xml"),
    ("ds2", f"synth dataset {REPO}/scenes/small_grid.xml {SMALL} --spp 8 --out ds2 "
            f"--no-progress"),
    ("dspair", "synth dataset pair.xml --spp 4 --out dspair --no-progress"),
    ("ds3", "synth dataset three.xml --spp 16 --out ds3 --no-progress"),
    ("dsdome", "synth dataset domes.xml --spp 16 --out dsdome --no-progress"),
    ("dshouse", "synth dataset housings.xml --spp 16 --out dshouse --no-progress"),
    ("dssurf", f"synth dataset {REPO}/scenes/speckle_plane.xml {SMALL} --spp 8 --out dssurf "
               f"--no-progress"),
    ("b2air", f"synth boards pair.xml {BOARD} --air --seed 1 --out b2air --no-progress"),
    ("b2water", f"synth boards pair.xml {BOARD} --seed 2 --out b2water --no-progress"),
    ("b4air", f"synth boards four.xml {BOARD} --air --seed 1 --out b4air --no-progress"),
    ("b4water", f"synth boards four.xml {BOARD} --seed 2 --out b4water --no-progress"),
    ("bhouse", f"synth boards house612.xml {BOARD} --seed 2 --out bhouse --no-progress"),
    ("bdome", "synth boards dome.xml --squares 7x6 --square-mm 60 --distance 450 650 --poses 8 "
              "--seed 3 --out bdome --no-progress"),
    ("bdomeair", "synth boards dome.xml --squares 7x6 --square-mm 60 --distance 350 600 "
                 "--poses 8 --seed 5 --air --out bdomeair --no-progress"),
    ("c2air", "eval calibrate b2air --out c2air --no-progress"),
    ("c4air", "eval calibrate b4air --out c4air --no-progress"),
    ("p2air", "synth photos b2air --out p2air"),
    ("p2water", "synth photos b2water --out p2water"),
    ("p4air", "synth photos b4air --out p4air"),
    ("p4water", "synth photos b4water --out p4water"),
    ("phouse", "synth photos bhouse --out phouse"),
    ("ph2", "synth photos ds2 --out ph2"),
    ("cdomeair", "eval calibrate bdomeair --out cdomeair --no-progress"),
    ("c1air", f"eval calibrate p2air/left --air {PHOTO_BOARD} --out c1air --no-progress"),
    ("seq", f"synth sequence {REPO}/scenes/small_grid.xml -D width=640 -D height=536 "
            f"--approach 1800,1300 --frames 3 --spp 4 --marker-radius-mm 15 --out seq "
            f"--no-progress"),
    ("RUN2", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --out RUN2 "
             "--no-progress"),
    ("SURF", "eval measure --calib dssurf/calib.yaml dssurf/left.png dssurf/right.png --dense "
             "--depth-range 900,1100 --out SURF --no-progress"),
    ("RUN3", "eval measure --calib ds3/calib.yaml ds3/cam0/image.png ds3/cam1/image.png "
             "ds3/cam2/image.png --out RUN3 --no-progress"),
    ("ABS", "eval calibrate b2water --model absorbed --out ABS --no-progress"),
    ("RECT", "eval rectify --calib ds2/calib.yaml --distance 1000 ds2/left.png ds2/right.png "
             "--out RECT --no-progress"),
]

#: Fixtures of the shared real photos (``REAL`` is that folder), made only where it exists.
REAL_FIXTURES = [
    ("couc", "eval calibrate REAL/ouc_flat/air --air --inner-corners 6x5 --square-mm 33.8 "
             "--out couc --no-progress"),
    ("csix", "eval calibrate REAL/sixer51_dome/air --air --inner-corners 8x6 --square-mm 30 "
             "--out csix --no-progress"),
    ("cstereo", "eval calibrate REAL/opencv_stereo --air --inner-corners 9x6 --square-mm 30 "
                "--out cstereo --no-progress"),
]


def _copy(root: Path, source: str, name: str) -> Path:
    if not (root / name).exists():
        shutil.copytree(root / source, root / name)
    return root / name


def _edit_image(path: Path, how) -> None:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), how(image))


def spoil_photos(root: Path) -> None:
    """Copies of the rendered photo folders with one thing wrong each."""
    if not (root / "SWAPPED").exists():
        (root / "SWAPPED").mkdir()
        shutil.copytree(root / "p2water" / "left", root / "SWAPPED" / "right")
        shutil.copytree(root / "p2water" / "right", root / "SWAPPED" / "left")
    if not (root / "SAME").exists():
        (root / "SAME").mkdir()
        shutil.copytree(root / "p2air" / "left", root / "SAME" / "left")
        shutil.copytree(root / "p2air" / "left", root / "SAME" / "right")
    turn = lambda image: cv2.rotate(image, cv2.ROTATE_180)  # noqa: E731
    mirror = lambda image: cv2.flip(image, 1)  # noqa: E731
    black = lambda image: np.zeros_like(image)  # noqa: E731
    for name, source, photo, how in (
            ("TURNED", "p2air", "left/03.jpg", turn), ("TURNED1", "p2air/left", "03.jpg", turn),
            ("MIRROR1", "p2air/left", "04.jpg", mirror),
            ("TURNED4", "p4air", "cam2/03.jpg", mirror), ("TURN4", "p4air", "cam1/05.jpg", turn),
            ("TURNW", "p2water", "right/02.jpg", turn), ("TURNW4", "p4water", "cam3/02.jpg", turn),
            ("TURNH", "phouse", "left/02.jpg", turn), ("BLACK2", "ph2", "left/pair.jpg", black)):
        if not (root / name).exists():
            _edit_image(_copy(root, source, name) / photo, how)
    if not (root / "fotos ä").exists():  # a folder name with a space and a non-ASCII letter
        _copy(root, "p2air", "fotos ä")
    if not (root / "DUPS1").exists():
        _copy(root, "p2air/left", "DUPS1")
        for path in sorted((root / "DUPS1").glob("*.jpg")):
            shutil.copy(path, path.with_name("dup_" + path.name))


def spoil_outputs(root: Path) -> None:
    """Sequences, calibrations and outputs changed as a user might change them."""
    for name in ("BLACKSEQ", "EDITEDSEQ"):
        _copy(root, "seq", name)
    for view in ("left", "right"):
        path = root / "BLACKSEQ" / "frames" / f"0001_{view}.png"
        _edit_image(path, np.zeros_like)
    poses = root / "EDITEDSEQ" / "poses.csv"
    poses.write_text(poses.read_text().replace("1800.0", "1801.0", 1))
    if not (root / "SCALED.xyz").exists():
        import open3d as o3d

        points = np.asarray(o3d.io.read_point_cloud(str(root / "RUN2" / "points.ply")).points)
        np.savetxt(root / "SCALED.xyz", points / 1000.0)
        np.savetxt(root / "SHIFTED.xyz", points + [50.0, 0.0, 0.0])
        np.savetxt(root / "DOUBLED.xyz", np.vstack([points, points]))
    calib = (root / "ds2" / "calib.yaml").read_text()
    (root / "NOPORT.yaml").write_text(calib.replace("indices:", "indexes:"))  # no port indices
    (root / "TRUNC.yaml").write_text(calib[: len(calib) // 2])
    (root / "EMPTY.yaml").write_text("")
    report = _copy(root, "c1air", "EDITED1") / "report.md"  # a file the user edited
    if not report.read_text().endswith("my notes\n"):
        report.write_text(report.read_text() + "\nmy notes\n")
    if not (root / "RESEAL.xml").exists():
        shutil.copy(root / "pair.xml", root / "RESEAL.xml")
    if not (root / "EDITED.xml").exists():
        text = (root / "pair.xml").read_text().replace('"n_water" value="1.33"',
                                                        '"n_water" value="1.34"')
        (root / "EDITED.xml").write_text(text)


def _project_views(K, size, points, n_views, rng, distance=450.0):
    """``n_views`` poses of a planar point set seen whole by a camera ``K`` of ``size``."""
    views, centre = [], points.mean(axis=0)
    while len(views) < n_views:
        R = Rotation.from_rotvec(rng.uniform(-0.5, 0.5, 3)).as_matrix()
        t = np.array([0, 0, distance]) + rng.uniform(-40, 40, 3) - R @ centre
        world = points @ R.T + t
        uv = cv2.projectPoints(world, np.zeros(3), np.zeros(3), K, None)[0].reshape(-1, 2)
        if np.all(uv > 20) and np.all(uv < np.array(size) - 20):
            views.append((R, t, uv))
    return views


def detections(root: Path) -> None:
    """One camera's circle-grid detections (8x6 dots, 30 mm), a pair's chessboard detections
    (7x6 inner corners, 30 mm) and a copy with one file's order turned; a circle-grid photo set."""
    from measure.calibration.board import Board

    K, size, rng = np.array([[800.0, 0, 319.5], [0, 800, 239.5], [0, 0, 1]]), (640, 480), \
        np.random.default_rng(5)
    if not (root / "CIRCDETS").exists():
        (root / "CIRCDETS").mkdir()
        grid = Board("circles", (8, 6), 30.0).corners()
        for k, (_, _, uv) in enumerate(_project_views(K, size, grid, 8, rng)):
            lines = [f"{i} {u:.6f} {v:.6f}" for i, (u, v) in enumerate(uv)]
            (root / "CIRCDETS" / f"view{k:02d}.txt").write_text("\n".join(lines) + "\n")
    if not (root / "DETS2").exists():
        corners = Board("chessboard", (8, 7), 30.0).corners()
        R_lr, t_lr = Rotation.from_rotvec([0, 0.1, 0]).as_matrix(), np.array([-100.0, 0, 0])
        for side in ("left", "right"):
            (root / "DETS2" / side).mkdir(parents=True)
        k = 0
        for R, t, uv in _project_views(K, size, corners, 40, rng, 800.0):
            right = (corners @ R.T + t) @ R_lr.T + t_lr
            uv_r = cv2.projectPoints(right, np.zeros(3), np.zeros(3), K, None)[0].reshape(-1, 2)
            if k == 10 or np.any(uv_r < 20) or np.any(uv_r > np.array(size) - 20):
                continue
            k += 1
            for side, pix in (("left", uv), ("right", uv_r)):
                text = "\n".join(f"{u:.6f} {v:.6f}" for u, v in pix) + "\n"
                (root / "DETS2" / side / f"view{k - 1:02d}.txt").write_text(text)
        shutil.copytree(root / "DETS2", root / "DETSTURN")
        path = root / "DETSTURN" / "left" / "view03.txt"
        path.write_text("\n".join(path.read_text().splitlines()[::-1]) + "\n")
        shutil.copytree(root / "DETS2", root / "DETSNAN")
        path = root / "DETSNAN" / "left" / "view01.txt"
        path.write_text(path.read_text().replace(path.read_text().split()[0], "nan", 1))
    circle_photos(root, K, size, rng)


def circle_photos(root: Path, K, size, rng) -> None:
    """One camera's photos of OpenCV's asymmetric 4x11 grid (20 mm pitch, 10 mm dots)."""
    if (root / "CIRCPH").exists():
        return
    (root / "CIRCPH").mkdir()
    scale = 8.0  # canvas pixels per mm
    points = np.array([[(2 * j + i % 2) * 20.0, i * 20.0, 0] for i in range(11)
                       for j in range(4)])
    canvas = np.full((int(260 * scale), int(200 * scale)), 255, np.uint8)
    for x, y, _ in points:
        cv2.circle(canvas, (int((x + 20) * scale), int((y + 20) * scale)), int(5 * scale), 0, -1,
                   cv2.LINE_AA)
    plane = np.array([[-20, -20, 0], [180, -20, 0], [180, 240, 0], [-20, 240, 0]], float)
    for k, (R, t, _) in enumerate(_project_views(K, size, points, 8, rng, 600.0)):
        corners = cv2.projectPoints(plane @ R.T + t, np.zeros(3), np.zeros(3), K, None)[0]
        src = np.float32([[0, 0], [canvas.shape[1], 0], [canvas.shape[1], canvas.shape[0]],
                          [0, canvas.shape[0]]])
        H = cv2.getPerspectiveTransform(src, corners.reshape(-1, 2).astype(np.float32))
        photo = cv2.warpPerspective(canvas, H, size, borderValue=90, flags=cv2.INTER_AREA)
        cv2.imwrite(str(root / "CIRCPH" / f"{k:02d}.png"), photo)


def make(root: Path, run, real: Path | None) -> None:
    """Every fixture below ``root``; ``run(argv, cwd)`` runs one command line."""
    import shlex

    lines = FIXTURES + (REAL_FIXTURES if real else [])
    for name, line in lines:
        if (root / name).exists():
            continue
        line = line.replace("REAL/", f"{real}/") if real else line
        code, _, err, seconds = run(shlex.split(line), root)
        if code != 0:
            raise SystemExit(f"fixture failed ({code}): {line}\n{err}")
        print(f"fixture {seconds:5.1f} s  {line[:100]}", flush=True)
    spoil_photos(root)
    spoil_outputs(root)
    detections(root)
    if real and not (root / "REALTURN").exists():
        shutil.copytree(real / "opencv_stereo", root / "REALTURN",
                        ignore=shutil.ignore_patterns("*.json", "*.yml", "*.txt"))
        _edit_image(root / "REALTURN" / "left" / "03.jpg",
                    lambda im: cv2.rotate(im, cv2.ROTATE_180))
