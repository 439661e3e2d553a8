"""``python -m eval interface PHOTOS --intrinsics camera.yaml --squares COLSxROWS --square-mm S
--media air,glass:10,water:300,glass:10,air --out DIR [--free normal,thickness:water]
[--distance MM]``: the flat layers in front of one camera — a tank's walls and water, a window —
and the known board's pose in every photo, from the photos of the board through them
(:func:`measure.calibration.interface.estimate_interface`, after Agrawal et al., CVPR 2012, "A
theory of multi-layer flat refractive geometry").

``--media`` lists the media from the camera outwards, each ``NAME[:THICKNESS_MM]``: ``air``
(1.0), ``glass`` (1.54), ``acrylic`` (1.49), ``water`` (1.33) or an index (``1.52:8``). The
first (the camera's) and the last (the board's) take no thickness; every layer between needs
one, a design value where it is estimated. The board may be in the water (``air,glass:10,
water``: a tank wall, a window) or beyond the tank in air (``air,glass:10,water:300,glass:10,
air``).

``--free`` (comma list): ``normal`` (always: the interface's tilt, two angles), ``distance`` (of
the first interface from the camera centre along the normal) and ``thickness:LAYER`` (a layer
between the first and the last medium, by its position among them from 0 or by its medium's name
where one layer has it). Default: ``normal``, with ``distance`` where the first and last media
differ. Between equal media (a tank with air on both sides) the distance is refused: parallel
layers between two equal media only shift a ray, by an amount set by their thicknesses and
indices wherever the stack stands, so no photo fixes where it stands (it is held at ``--distance``
and does not change a pixel).

Start: Agrawal et al.'s — the normal in closed form from the flat refraction constraint, the
distance by a one-dimensional search (:func:`measure.calibration.interface.interface_start`) —
unless ``--distance`` is given: then the design interface, ⟂ the camera's optical axis at that
distance. Then one least-squares adjustment of the interface and every pose on the refractive
reprojection error; σ from the residuals.

Beside it, on the same corners: a pinhole pose per photo with the in-air intrinsics and no
interface (``cv2.solvePnP``: what ignoring the tank gives). The run fails (exit 1, files
written) when the interface fit leaves a larger RMS than that pinhole fit, or more than the
in-air calibration's RMS + 0.15 px (where ``--intrinsics`` carries it): the layers given do not
fit these photos.

Writes to ``--out``: ``report.json``, ``report.md``, ``poses.csv`` (per photo the board's pose,
``X_camera = R · X_board + t``, mm, R as a quaternion ``qx qy qz qw``, and its RMS in px),
``camera.yaml`` (the in-air camera with the estimated layers as a ``port`` node, mm, the camera's
frame — what ``eval measure`` reads for one camera) and ``residuals.png``.
"""

from __future__ import annotations

import csv
import os
import sys
import time

import numpy as np

from eval.cli import CLIError

COMMAND = "eval interface"
#: Indices of the media ``--media`` knows by name.
MEDIA = {"air": 1.0, "glass": 1.54, "acrylic": 1.49, "water": 1.33}
#: The interface fit may leave at most this much more RMS than the in-air calibration (px).
RMS_MARGIN_PX = 0.15
POSES_HEADER = ["photo", "name", "tx_mm", "ty_mm", "tz_mm", "qx", "qy", "qz", "qw", "corners",
                "rms_px"]


#: A free thickness at or below this (mm) ran into its bound at 0: not determined.
THICKNESS_BOUND_MM = 1e-6


def parse_media(text: str) -> tuple[tuple, tuple, tuple]:
    """``(names, indices, thicknesses)`` of ``--media`` (module docs); CLIError naming the
    item that is not one."""
    items = [s.strip() for s in text.split(",")]
    if len(items) < 3:
        raise CLIError(f"--media {text}: at least three media (the camera's, one layer, the "
                       f"board's), e.g. air,glass:10,water")
    names, indices, thicknesses = [], [], []
    for position, item in enumerate(items):
        name, _, thickness = item.partition(":")
        outer = position in (0, len(items) - 1)
        try:
            index = MEDIA[name] if name in MEDIA else float(name)
        except ValueError:
            raise CLIError(f"--media {text}: {name!r} is not a medium ({', '.join(MEDIA)}) or "
                           f"a refractive index") from None
        if not 1.0 <= index < 3.0:
            raise CLIError(f"--media {text}: index {index:g} of {item!r} is not a refractive "
                           f"index of a real medium (1 to 3)")
        if outer and thickness:
            raise CLIError(f"--media {text}: {item!r}: the first and the last medium take no "
                           f"thickness (they extend to the camera and beyond the board)")
        if not outer:
            try:
                value = float(thickness)
            except ValueError:
                raise CLIError(f"--media {text}: {item!r} needs a thickness in mm "
                               f"(NAME:MM, e.g. glass:10)") from None
            if not 0 < value < float("inf"):
                raise CLIError(f"--media {text}: {item!r}: the thickness must be positive")
            thicknesses.append(value)
        names.append(name)
        indices.append(index)
    for a, b, ia, ib in zip(items, items[1:], indices, indices[1:]):
        if ia == ib:
            raise CLIError(f"--media {text}: {a!r} and {b!r} have one index: no interface "
                           f"between them (merge them into one layer)")
    return tuple(names), tuple(indices), tuple(thicknesses)


def parse_free(text: str | None, names, indices) -> tuple[bool, tuple]:
    """``(free_distance, free_layers)`` of ``--free`` (module docs); CLIError for an item that
    is not one, a layer that is not there, or a distance no photo can fix."""
    inner = list(names[1:-1])
    equal_ends = indices[0] == indices[-1]
    if text is None:
        return not equal_ends, ()
    items = [s.strip() for s in text.split(",") if s.strip()]
    if "normal" not in items:
        raise CLIError(f"--free {text}: the normal is always estimated; list normal (with "
                       f"distance and thickness:LAYER as wanted)")
    free_distance, layers = False, []
    for item in items:
        if item == "normal":
            continue
        if item == "distance":
            if equal_ends:
                raise CLIError(f"--free {text}: the distance cannot be estimated with "
                               f"{names[0]} on both sides of the layers: parallel layers "
                               f"between equal media only shift a ray, by the same amount "
                               f"wherever they stand (give its value with --distance)")
            free_distance = True
            continue
        kind, _, layer = item.partition(":")
        if kind != "thickness" or not layer:
            raise CLIError(f"--free {text}: {item!r}: choose from normal, distance, "
                           f"thickness:LAYER")
        if layer.isdigit():
            j = int(layer)
            if j >= len(inner):
                raise CLIError(f"--free {text}: {item!r}: the layers between the first and the "
                               f"last medium are 0 … {len(inner) - 1} ({', '.join(inner)})")
        else:
            matches = [j for j, name in enumerate(inner) if name == layer]
            if len(matches) != 1:
                raise CLIError(f"--free {text}: {item!r}: {len(matches)} layers of "
                               f"{layer!r} between the first and the last medium "
                               f"({', '.join(inner)}); name one by its position, "
                               f"thickness:0 … thickness:{len(inner) - 1}")
            j = matches[0]
        if j in layers:
            raise CLIError(f"--free {text}: layer {j} ({inner[j]}) given twice")
        layers.append(j)
    return free_distance, tuple(layers)


def add_parser(subparsers) -> None:
    from eval.core.photos import add_encoding_option
    from synth.infra.cli import (add_board_options, add_out_option, add_progress_option,
                                 positive_float)

    p = subparsers.add_parser(
        "interface", help="the flat layers in front of one camera (a tank, a window) and the "
                          "board's poses, from photos of the board through them",
        description="Estimate a multi-layer flat interface (normal, distance, layer "
                    "thicknesses) in front of one camera and the known board's pose in each "
                    "photo, given the camera's in-air calibration (Agrawal et al. 2012).")
    p.add_argument("dir", help="folder of one camera's photos of the board through the layers")
    p.add_argument("--intrinsics", required=True, metavar="camera.yaml",
                   help="the camera's in-air calibration: camera.yaml of eval calibrate PHOTOS "
                        "--air, calibmar's one-camera YAML or a one-camera cameras.txt")
    p.add_argument("--media", required=True, metavar="NAME[:MM],…",
                   help="the media from the camera outwards, each NAME[:THICKNESS_MM] "
                        f"(names {', '.join(f'{k} {v:g}' for k, v in MEDIA.items())}, or an "
                        "index); the first and last take no thickness, e.g. "
                        "air,glass:10,water:300,glass:10,air")
    p.add_argument("--free", default=None, metavar="normal[,distance][,thickness:LAYER]",
                   help="what is estimated besides the poses: normal (always), distance, "
                        "thickness:LAYER (a layer between the first and last medium, by its "
                        "position from 0 or its medium's name); default normal, and distance "
                        "where the first and last media differ")
    p.add_argument("--distance", type=positive_float, default=None, metavar="MM",
                   help="the design distance of the first interface from the camera centre "
                        "(mm): the start ⟂ the optical axis (default: Agrawal et al.'s start, "
                        "no design value needed); with equal first and last media, the value "
                        "held")
    add_board_options(p, defaults=False, needed="required")
    add_encoding_option(p)
    add_out_option(p, COMMAND)
    add_progress_option(p)


def board_pixels(detections, found, n_corners: int) -> np.ndarray:
    """``(F, M, 2)`` px of the board's corners in the photos ``found`` (NaN where a corner was
    not detected)."""
    from eval.calibrate.single import VIEW

    pixels = np.full((len(found), n_corners, 2), np.nan)
    for f, k in enumerate(found):
        pixels[f, detections.ids[k][VIEW]] = detections.pixels[k][VIEW]
    return pixels


def pinhole_rms(camera, corners, pixels) -> tuple[float, np.ndarray]:
    """``(RMS px over every corner, per photo RMS)`` of a pinhole pose per photo with the
    in-air camera and no interface (``cv2.solvePnP``; fisheye lenses through
    ``cv2.fisheye.undistortPoints``)."""
    import cv2

    per, squares, count = [], 0.0, 0
    for uv in pixels:
        seen = np.all(np.isfinite(uv), axis=1)
        obj, img = corners[seen].astype(np.float64), uv[seen].astype(np.float64)
        dist = np.zeros(5) if camera.dist is None else np.asarray(camera.dist, np.float64)
        if camera.distortion_model == "fisheye":
            normal = cv2.fisheye.undistortPoints(img.reshape(-1, 1, 2), camera.K, dist)
            ok, rvec, tvec = cv2.solvePnP(obj, normal, np.eye(3), None)
            ok, rvec, tvec = cv2.solvePnP(obj, normal, np.eye(3), None, rvec, tvec, True,
                                          cv2.SOLVEPNP_ITERATIVE)
            back, _ = cv2.fisheye.projectPoints(obj.reshape(-1, 1, 3), rvec, tvec, camera.K,
                                                dist)
        else:
            ok, rvec, tvec = cv2.solvePnP(obj, img, camera.K, dist)
            ok, rvec, tvec = cv2.solvePnP(obj, img, camera.K, dist, rvec, tvec, True,
                                          cv2.SOLVEPNP_ITERATIVE)
            back, _ = cv2.projectPoints(obj, rvec, tvec, camera.K, dist)
        r = back.reshape(-1, 2) - img
        per.append(float(np.sqrt(np.mean(np.sum(r * r, axis=1)))))
        squares += float(np.sum(r * r))
        count += len(r)
    return float(np.sqrt(squares / count)), np.array(per)


def main(args) -> int:
    from measure import FlatPort
    from measure.calibration.interface import estimate_interface, interface_start
    from measure.stereo.multiview import View

    from eval.calibrate import report as report_lib
    from eval.calibrate.single import VIEW, read_and_detect, write_camera_files
    from eval.calibrate.single_housing import read_intrinsics
    from synth.infra.cli import board_from_args
    from synth.infra.fileio import OutputDir, atomic_write_json, atomic_write_text, jsonable

    start = time.perf_counter()
    names, indices, thicknesses = parse_media(args.media)
    free_distance, layers = parse_free(args.free, names, indices)
    if args.squares is None and getattr(args, "inner_corners", None) is None:
        raise CLIError("--squares (or --inner-corners) and --square-mm: the board is needed")
    if args.square_mm is None:
        raise CLIError("--square-mm: the board's square side (mm) is needed")
    board = board_from_args(args)
    intrinsics = read_intrinsics(args.intrinsics)
    camera = intrinsics["camera"]
    output = OutputDir(args.out, COMMAND).claim()
    log = (lambda text: None) if args.no_progress else (
        lambda text: print(text, file=sys.stderr, flush=True))
    photo_names, _, size, detections, timings, aside = read_and_detect(
        args, board, log, camera.size, f"--intrinsics {args.intrinsics}")
    for k, why in sorted(aside.items()):
        print(f"warning: {photo_names[k]}: {why}", file=sys.stderr)
    found = detections.found(VIEW)
    if len(found) < 2:
        raise CLIError(f"{args.dir}: the board was found in {len(found)} photo(s); the "
                       f"interface needs at least 2 (better 8 or more, at several distances "
                       f"and tilts)")
    corners = board.corners()
    pixels = board_pixels(detections, found, len(corners))
    design = FlatPort(camera.R[:, 2], args.distance or 100.0, thicknesses, indices)
    view = View(camera, design)
    t = time.perf_counter()
    if args.distance is None:
        log("the interface's start (Agrawal et al.: the normal in closed form, the distance by "
            "a search) …")
        begun = interface_start(view, corners, pixels)
        if begun is None:
            raise CLIError(f"{args.dir}: these photos do not fix a starting interface (the "
                           f"refraction axis or a distance at which every photo has a pose); "
                           f"give the design distance with --distance")
        start_port, start_kind = begun, "agrawal"
    else:
        start_port, start_kind = design, "design"
    timings["start"] = time.perf_counter() - t
    log("adjust the interface and every pose on the refractive reprojection error …")
    t = time.perf_counter()
    found_interface = estimate_interface(View(camera, start_port), corners, pixels,
                                         free_thicknesses=layers, free_distance=free_distance,
                                         camera_covariance=intrinsics["covariance"])
    timings["adjustment"] = time.perf_counter() - t
    pinhole, pinhole_per = pinhole_rms(camera, corners, pixels)
    report = _report(args, board, names, indices, photo_names, found, pixels, start_port,
                     start_kind, found_interface, pinhole, pinhole_per, intrinsics, layers,
                     free_distance)
    report["timings_s"] = {**timings, "total": time.perf_counter() - start}
    report = jsonable(report)
    with output.staged() as tmp:
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        atomic_write_text(os.path.join(tmp, "report.md"), markdown(report))
        if found_interface.valid:
            _write_poses(os.path.join(tmp, "poses.csv"), photo_names, found, found_interface,
                         pixels)
            write_camera_files(tmp, camera, intrinsics["lens_model"], found_interface.rms_px,
                               {}, port=found_interface.port, other_formats=False)
            res = found_interface.residuals_px
            rows = [(k, i, *res[f, i]) for f, k in enumerate(found)
                    for i in np.flatnonzero(np.all(np.isfinite(res[f]), axis=1))]
            report_lib.residual_figure(tmp, detections, {VIEW: rows}, size, views=("camera",))
    print(summary(report, args.out))
    return 1 if report["failures"] else 0


def _write_poses(path, photo_names, found, estimate, pixels) -> None:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(estimate.R).as_quat()
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(POSES_HEADER)
        for f, k in enumerate(found):
            r = estimate.residuals_px[f]
            seen = np.all(np.isfinite(r), axis=1)
            rms = float(np.sqrt(np.mean(np.sum(r[seen] ** 2, axis=1))))
            writer.writerow([k, photo_names[k], *(repr(float(v)) for v in estimate.t[f]),
                             *(repr(float(v)) for v in q[f]), int(seen.sum()), f"{rms:.6f}"])


def _report(args, board, names, indices, photo_names, found, pixels, start_port, start_kind,
            estimate, pinhole, pinhole_per, intrinsics, layers, free_distance) -> dict:
    from measure import Reason

    in_air = intrinsics["rms_px"]
    failures, warnings, values = [], [], {}
    if estimate.valid:
        values = _estimates(args, estimate, names, indices, intrinsics["camera"].R[:, 2],
                            free_distance)
        failures = _fit_failures(estimate, values, pinhole, in_air)
    else:
        failures.append(f"no interface: {Reason(estimate.reason).name} "
                        f"({_reason_text(estimate.reason)})")
    if in_air is None:
        warnings.append(f"--intrinsics {args.intrinsics} carries no in-air RMS: the fit's RMS "
                        f"is not checked against it")
    if len(found) < 8:
        warnings.append(f"only {len(found)} photo(s) with the board; 8 or more at several "
                        f"distances and tilts fix the layers better")
    per_photo = []
    for f, k in enumerate(found):
        row = {"photo": k, "name": photo_names[k],
               "corners": int(np.all(np.isfinite(pixels[f]), axis=1).sum()),
               "pinhole_rms_px": float(pinhole_per[f])}
        if estimate.valid:
            r = estimate.residuals_px[f]
            seen = np.all(np.isfinite(r), axis=1)
            row["rms_px"] = float(np.sqrt(np.mean(np.sum(r[seen] ** 2, axis=1))))
            row["distance_mm"] = float(np.linalg.norm(estimate.t[f]))
        per_photo.append(row)
    return {
        "command": COMMAND, "photos": os.path.abspath(args.dir),
        "intrinsics": os.path.abspath(args.intrinsics), "board": board.to_dict(),
        "media": {"names": list(names), "indices": list(indices),
                  "thicknesses_design_mm": list(start_port.thicknesses)},
        "free": ["normal"] + (["distance"] if free_distance else [])
        + [f"thickness:{j}" for j in layers],
        "start": {"kind": start_kind, "normal": start_port.normal,
                  "distance_mm": start_port.distance},
        "reason": Reason(estimate.reason).name,
        "estimates": values,
        "port": ({"normal": estimate.port.normal, "distance": estimate.port.distance,
                  "thicknesses": list(estimate.port.thicknesses),
                  "indices": list(estimate.port.indices)} if estimate.valid else None),
        "covariance": ({"names": list(estimate.names), "matrix": estimate.covariance}
                       if estimate.valid else None),
        "sigma_holds": ("the pixel noise (from the residuals) and the in-air calibration's "
                        "covariance (--intrinsics' covariance node), propagated"
                        if intrinsics["covariance"] is not None else
                        "the pixel noise (from the residuals) only: --intrinsics carries no "
                        "covariance, σ is conditional on the intrinsics"),
        "rms_px": {"interface": estimate.rms_px, "pinhole_no_interface": pinhole,
                   "in_air": in_air, "sigma_px": estimate.sigma_px,
                   "margin_px": RMS_MARGIN_PX},
        "photos_found": len(found), "photos_total": len(photo_names),
        "per_photo": per_photo, "failures": failures, "warnings": warnings,
    }


def _estimates(args, estimate, names, indices, axis, free_distance) -> dict:
    """The report's ``estimates``: distance (mm; held when not free, and why), the free
    layers' thicknesses (mm) and the normal (its tilt from the optical ``axis``), each with
    its σ."""
    sigma = np.sqrt(np.diag(estimate.covariance))
    port = estimate.port
    values = {}
    for name, s in zip(estimate.names, sigma):
        if name == "port.distance":
            values["distance"] = {"estimate": port.distance, "sigma": s, "unit": "mm"}
        elif name.startswith("port.thickness"):
            j = int(name[len("port.thickness["):-1])
            values[f"thickness:{j}"] = {"estimate": port.thicknesses[j], "sigma": s,
                                        "unit": "mm", "medium": names[1 + j]}
    tilt = sigma[[i for i, n in enumerate(estimate.names) if n.startswith("port.tilt")]]
    values["normal"] = {"estimate": port.normal, "unit": "unit vector (camera frame)",
                        "tilt_from_axis_deg": float(np.degrees(np.arccos(np.clip(
                            port.normal @ axis, -1.0, 1.0)))),
                        "sigma_deg": np.degrees(tilt)}
    if not free_distance:
        values["distance"] = {"estimate": port.distance, "sigma": None, "unit": "mm",
                              "held": "not estimated (" + (
                                  "equal media on both sides: no photo fixes it, any value "
                                  "gives the same pixels; "
                                  if indices[0] == indices[-1] else "not in --free; ")
                              + ("--distance" if args.distance else "the start's")
                              + ")"}
    return values


def _fit_failures(estimate, values, pinhole, in_air) -> list:
    """Why the fit is not to be trusted: a thickness at its bound, an RMS above a pinhole pose
    with no interface or above the in-air calibration's by more than :data:`RMS_MARGIN_PX`."""
    failures = []
    for key, value in values.items():
        if key.startswith("thickness:") and value["estimate"] <= THICKNESS_BOUND_MM:
            failures.append(f"{key} ({value['medium']}) ran into its bound at 0 mm: these "
                            f"photos do not determine it (free fewer thicknesses, or give "
                            f"its value in --media)")
    if estimate.rms_px > pinhole:
        failures.append(f"the interface fit leaves a reprojection RMS of "
                        f"{estimate.rms_px:.4f} px, more than a pinhole pose with no "
                        f"interface ({pinhole:.4f} px): the layers given do not fit these "
                        f"photos")
    if in_air is not None and estimate.rms_px > in_air + RMS_MARGIN_PX:
        failures.append(f"the interface fit leaves a reprojection RMS of "
                        f"{estimate.rms_px:.4f} px, more than the in-air calibration's "
                        f"{in_air:.4f} px + {RMS_MARGIN_PX:g} px: the media, their indices "
                        f"or thicknesses, or the in-air calibration do not fit these photos")
    return failures


def _reason_text(reason: int) -> str:
    from measure import Reason

    return {Reason.DEGENERATE: "these photos do not fix the parameters freed: free fewer, or "
                               "photograph the board at more distances and tilts",
            Reason.NOT_CONVERGED: "the adjustment did not converge: give --distance near the "
                                  "true one, or check --media"}.get(
        Reason(reason), "a photo has no starting pose through the starting interface")


def markdown(report: dict) -> str:
    from eval.calibrate.report import format_value as _f

    r = report["rms_px"]
    media = report["media"]
    stack = " | ".join(f"{n} ({i:g})" for n, i in zip(media["names"], media["indices"]))
    lines = [f"# {COMMAND}: {report['photos']}", "",
             f"Media from the camera: {stack}; "
             f"design thicknesses {report['media']['thicknesses_design_mm']} mm.",
             f"Free: {', '.join(report['free'])}; start: {report['start']['kind']}. "
             f"Result: {report['reason']}. σ holds {report['sigma_holds']}.", "",
             "| parameter | estimate | σ | unit |", "|---|---|---|---|"]
    for name, v in report["estimates"].items():
        sigma = v.get("sigma_deg", v.get("sigma"))
        lines.append(f"| {name} | {_f(v['estimate'], 7)} | {_f(sigma)} | "
                     f"{v['unit'] if 'sigma_deg' not in v else 'unit vector; σ in deg'}"
                     f"{' — ' + v['held'] if v.get('held') else ''} |")
    lines += ["", "| reprojection RMS | px |", "|---|---|",
              f"| interface fit | {_f(r['interface'])} |",
              f"| pinhole pose, no interface (cv2.solvePnP) | {_f(r['pinhole_no_interface'])} |",
              f"| in-air calibration | {_f(r['in_air'])} |", "",
              "| photo | corners | RMS px | pinhole RMS px | distance mm |", "|---|---|---|---|---|"]
    for row in report["per_photo"]:
        lines.append(f"| {row['name']} | {row['corners']} | {_f(row.get('rms_px'))} | "
                     f"{_f(row['pinhole_rms_px'])} | {_f(row.get('distance_mm'), 6)} |")
    for title, items in (("Failures", report["failures"]), ("Warnings", report["warnings"])):
        if items:
            lines += ["", f"## {title}", "", *(f"- {s}" for s in items)]
    return "\n".join(lines) + "\n"


def summary(report: dict, out) -> str:
    r = report["rms_px"]
    parts = []
    for name, v in report["estimates"].items():
        if name == "normal":
            parts.append(f"normal tilt {v['tilt_from_axis_deg']:.4f}° (σ "
                         f"{max(v['sigma_deg']):.4f}°)")
        elif v.get("sigma") is not None:
            parts.append(f"{name} {v['estimate']:.3f} ± {v['sigma']:.3f} mm")
    verdict = "FAILED (below)" if report["failures"] else report["reason"]
    head = (f"wrote {out}: {report['photos_found']}/{report['photos_total']} photos, "
            f"{verdict}")
    lines = [head + (": " + ", ".join(parts) if parts else "")]
    lines.append(f"RMS {r['interface']:.4f} px through the layers, {r['pinhole_no_interface']:.4f}"
                 f" px as a pinhole with no interface"
                 + (f", {r['in_air']:.4f} px in air" if r["in_air"] is not None else ""))
    lines += [f"FAIL: {s}" for s in report["failures"]]
    lines += [f"warning: {s}" for s in report["warnings"]]
    return "\n".join(lines)
