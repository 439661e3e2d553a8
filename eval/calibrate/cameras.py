"""``python -m eval calibrate BOARDS`` of a ``synth boards`` folder of N > 2 cameras: every camera
and every board pose jointly, in air (:func:`measure.calibration.multi_air.calibrate_rig_in_air`,
intrinsics free) or the shared flat port under water given that in-air calibration
(:func:`measure.calibration.multi_housing.calibrate_rig_housing`), each estimate beside the
folder's truth with its error in σ.

Writes ``calib.yaml`` (N cameras, :mod:`synth.products.rig_file`, with the calibration's
covariance as its ``uncertainty`` map: in air every camera pose and intrinsic, under water the
port's free numbers), ``report.json`` and ``report.md``. Units px, mm, rad (printed in degrees);
the reference frame is the first camera's.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from types import SimpleNamespace

from eval.calibrate.causes import FIT_ERRORS, housing_failure
from eval.cli import CLIError

#: Options of a two-camera calibration that a calibration of N cameras does not take.
#: (``--encoding`` last: it applies to photos.)
NOT_FOR_N_CAMERAS = (("dome_radius", "--dome-radius"),
                     ("dome_thickness", "--dome-thickness"),
                     ("air_uncertainty", "--air-uncertainty"), ("encoding", "--encoding"))


def _detect(board, images, names):
    """:class:`measure.calibration.air.Detections` of N views per pose."""
    from measure.calibration.air import Detections, detect_images

    n = len(names)
    found = detect_images(board, [img for views in images for img in views])
    ids = [[found[n * k + v][0] for v in range(n)] for k in range(len(images))]
    pixels = [[found[n * k + v][1] for v in range(n)] for k in range(len(images))]
    return Detections(ids, pixels)


def _air_errors(rig, truth) -> dict:
    """Each camera parameter's estimate − truth, named as
    :func:`measure.calibration.multi_air.camera_parameter_names` names them."""
    from scipy.spatial.transform import Rotation

    from measure.calibration.multi_air import DISTORTION_NAMES

    out = {}
    for v, (name, camera, true) in enumerate(zip(rig.names, rig.cameras, truth.cameras)):
        if v > 0:
            phi = Rotation.from_matrix(camera.R @ true.R.T).as_rotvec()
            for k in range(3):
                out[f"{name}.rotation[{k}]"] = float(phi[k])
                out[f"{name}.center[{k}]"] = float(camera.t[k] - true.t[k])
        for p, (r, c) in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2))):
            out[f"{name}.{p}"] = float(camera.K[r, c] - true.K[r, c])
        true_dist = np.zeros(8)
        if true.dist is not None:
            true_dist[:np.ravel(true.dist).size] = np.ravel(true.dist)[:8]
        for k, value in enumerate(np.ravel(camera.dist)):
            out[f"{name}.{DISTORTION_NAMES[k]}"] = float(value - true_dist[k])
    return out


def estimate_value(rig, name: str):
    """The estimate a parameter name of the covariance stands for (``cam1.rotation[0]``: the
    rotation vector of camera-to-reference, rad; ``cam1.center[2]``: mm; ``cam0.fx``: px;
    ``cam0.k1``; ``port.distance``, ``cam2.port.thickness`` mm; ``port.n_water``); None for a
    tilt (the normal is reported whole)."""
    from scipy.spatial.transform import Rotation

    from measure.calibration.multi_air import DISTORTION_NAMES

    owner, _, param = name.partition(".")
    if owner == "port" or param.startswith("port."):
        port = rig.ports[0 if owner == "port" else rig.names.index(owner)]
        key = param.removeprefix("port.")
        return {"distance": port.distance, "n_water": port.n_water,
                "thickness": port.thicknesses[0] if port.thicknesses else None}.get(key)
    camera = rig.cameras[rig.names.index(owner)]
    key, _, index = param.partition("[")
    if key in ("rotation", "center"):
        vector = Rotation.from_matrix(camera.R).as_rotvec() if key == "rotation" else camera.t
        return float(vector[int(index.rstrip("]"))])
    if key in ("fx", "fy", "cx", "cy"):
        return float(camera.K[{"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[key]])
    dist = np.zeros(8) if camera.dist is None else np.ravel(camera.dist)
    k = DISTORTION_NAMES.index(key)
    return float(dist[k]) if k < dist.size else 0.0


def _value(v) -> str:
    return "—" if v is None else f"{v:.6g}"


def _markdown(folder, names, kind, poses, found, rms, rows, values, report) -> str:
    """``report.md`` of N cameras: every estimate with its σ (against the truth where the
    folder has one) and, under water, the port(s) whole."""
    head = (f"# eval calibrate: {len(names)} cameras, {kind}\n\n"
            f"Boards: `{folder}` ({poses} poses); found per camera: "
            + ", ".join(f"{n} {c}" for n, c in found.items())
            + f". Reprojection RMS {rms:.4f} px.\n\n")
    units = ("rotation: the rotation vector of camera-to-reference, rad; centre, distance, "
             "thickness: mm; focal, principal point: px")
    if report.get("within_3_sigma") is not None:
        table = (f"Every estimate against the folder's truth ({units}):\n\n"
                 "| parameter | estimate | estimate − truth | σ | error / σ |\n|---|---|---|---|---|\n"
                 + "".join(f"| {n} | {_value(values[n])} | {e:+.4g} | {s:.3g} | {e / s:+.2f} |\n"
                           for n, e, s in rows)
                 + f"\n{report['within_3_sigma']} of {len(rows)} within 3 σ.\n")
    else:
        table = (f"No truth (photos): every estimate and its σ ({units}):\n\n"
                 "| parameter | estimate | σ |\n|---|---|---|\n"
                 + "".join(f"| {n} | {_value(values[n])} | {s:.3g} |\n" for n, _, s in rows))
    port = report.get("port")
    ports = {"port": port} if port and "normal" in port else (port or {})
    lines = "".join(f"- {n}: distance {p['distance_mm']:.4f} mm, normal "
                    + ", ".join(f"{v:.6f}" for v in p["normal"])
                    + (f", n_water {p['indices'][-1]:.6f}" if "indices" in p else "") + "\n"
                    for n, p in ports.items() if isinstance(p, dict) and "normal" in p)
    return head + table + (f"\nThe port{'s' if len(ports) > 1 else ''}:\n\n{lines}" if lines
                           else "")


def boards_source(boards):
    """What :func:`calibrate_cameras_main` calibrates, from a ``synth boards`` folder of N
    cameras (:func:`synth.products.boards.read_boards`): with its truth."""
    truth = boards.calib["multirig"]
    return SimpleNamespace(path=boards.path, images=boards.images, board=boards.board,
                           air=boards.air, names=boards.calib["names"], truth=truth,
                           size=boards.calib["size"], photos=False,
                           own_ports=len(set(truth.ports)) > 1,
                           captures=[f"{k:02d}" for k in range(len(boards.images))])


def photos_source(path, names, board, air: bool, encoding: str):
    """What :func:`calibrate_cameras_main` calibrates, from a user's photo folder of N cameras
    (``cam0/``, ``cam1/``, … matched by file name): no truth."""
    from eval.core.photos import PhotoError, read_camera_photos

    try:
        images, size, stems = read_camera_photos(path, names, encoding)
    except PhotoError as exc:
        raise CLIError(str(exc)) from None
    return SimpleNamespace(path=path, images=images, board=board, air=air, names=names,
                           truth=None, size=size, photos=True, own_ports=False,
                           captures=list(stems))


def read_air_rig(path, folder, names, size):
    """``(rig, covariance)`` of the in-air ``calib.yaml`` of N cameras that ``--intrinsics``
    names, checked against the boards of ``folder`` (``names``, image ``size``) before any
    detection: a file of another count of cameras (a pair's calib.yaml, one camera's
    camera.yaml), other names, another image size or one that holds a port is refused with
    one line naming the file and the likely cause."""
    from synth.products.dataset import DatasetError
    from synth.products.rig_file import read_rig_covariance, read_rig_file

    where = f"--intrinsics {path}"
    if os.path.isdir(path):
        inside = os.path.join(path, "calib.yaml")
        raise CLIError(f"{where}: a folder; give its calibration file"
                       + (f" ({inside})" if os.path.isfile(inside) else " (calib.yaml)"))
    try:
        air = read_rig_file(path)
    except DatasetError as exc:
        raise CLIError(f"{where}: {str(exc).removeprefix(f'{path}: ')}") from None
    if len(air.names) != len(names):
        raise CLIError(f"{where}: a calibration of {len(air.names)} cameras "
                       f"({', '.join(air.names)}), but {folder} holds {len(names)} "
                       f"({', '.join(names)}): another rig's file? Give the calib.yaml of "
                       f"eval calibrate on in-air boards of these {len(names)} cameras")
    if air.names != names:
        raise CLIError(f"{where}: cameras {', '.join(air.names)}, but {folder} holds "
                       f"{', '.join(names)}")
    if tuple(air.cameras[0].size) != tuple(size):
        raise CLIError(f"{where}: image size {air.cameras[0].size[0]}x{air.cameras[0].size[1]} "
                       f"px, but the images are {size[0]}x{size[1]} px: another camera's "
                       f"calibration?")
    if air.refracts:
        raise CLIError(f"{where}: already holds a port (an underwater calibration); give the "
                       f"in-air calibration")
    try:
        return air, read_rig_covariance(path)
    except DatasetError as exc:
        raise CLIError(f"{where}: {str(exc).removeprefix(f'{path}: ')}") from None


def calibrate_cameras_main(args, output, log, start, boards, design) -> int:
    """``eval calibrate`` of N cameras (module docs): ``boards`` from :func:`boards_source` or
    :func:`photos_source`; ``design``: the starting flat port under water (normal along the
    first camera's axis; None in air)."""
    from measure.calibration.air import CalibrationError
    from synth.infra.fileio import atomic_write_json, jsonable
    from synth.products.rig_file import write_rig_file

    names, truth = boards.names, boards.truth
    where = f"{args.dir} ({len(names)} cameras{', photos' if boards.photos else ''})"
    water = _checked_options(args, boards, where)
    log(f"detect the boards in {boards.path} ({len(boards.images)} poses × {len(names)} "
        f"cameras) …")
    t = time.perf_counter()
    detections = _detect(boards.board, boards.images, names)
    if boards.photos:  # a --squares smaller than the board: a different part of it per photo
        from eval.calibrate import photos as trust

        larger = trust.larger_board(boards.board, [views[:2] for views in boards.images],
                                    detections.found(0))
        if larger:
            raise CLIError(f"{where}: {larger}")
    timings = {"detect": time.perf_counter() - t}
    found = {name: len(detections.found(v)) for v, name in enumerate(names)}
    report = {"boards": os.path.abspath(boards.path), "air": boards.air, "cameras": list(names),
              "board": boards.board.to_dict(), "poses": len(boards.images), "found": found}
    t = time.perf_counter()
    try:
        if boards.air:
            cal, rig, covariance, rows, rms = _calibrate_in_air(args, boards, detections, report,
                                                                log)
        else:
            cal, rig, covariance, rows, rms = _calibrate_housing(args, boards, detections,
                                                                 design, water, report, log)
    except CalibrationError as exc:
        if boards.air:
            raise CLIError(f"{where}: {exc}") from None
        raise housing_failure(where, exc, args) from None
    except FIT_ERRORS as exc:  # a port moved behind a camera, singular equations
        if boards.air:
            raise
        raise housing_failure(where, exc, args) from None
    timings["calibrate"] = time.perf_counter() - t
    scored = truth is not None
    z = np.array([e / s for _, e, s in rows]) if scored else np.zeros(0)
    values = {n: estimate_value(rig, n) for n, _, _ in rows}
    report.update({
        "estimates": {n: ({"value": values[n], "error": e, "sigma": s, "error_in_sigma": e / s}
                          if scored else {"value": values[n], "sigma": s}) for n, e, s in rows},
        "within_3_sigma": int(np.sum(np.abs(z) <= 3)) if scored else None,
        "parameters": len(rows),
        "largest_error_in_sigma": float(np.abs(z).max()) if z.size else None,
        "timings_s": {**timings, "total": time.perf_counter() - start}})
    report = jsonable(report)
    kind = ("in air" if boards.air else "the shared port" if cal.shared
            else "each camera's own port")
    with output.staged() as tmp:
        write_rig_file(os.path.join(tmp, "calib.yaml"), rig, covariance)
        atomic_write_json(os.path.join(tmp, "report.json"), report)
        with open(os.path.join(tmp, "report.md"), "w") as fh:
            fh.write(_markdown(args.dir, names, kind, len(boards.images), found, rms, rows,
                               values, report))
    if getattr(args.n_water, "note", None):  # the index --n-water T=…,S=… computed
        print(args.n_water.note, file=sys.stderr, flush=True)
    _print_summary(boards, names, kind, rms, rows, report, found,
                   None if boards.air else water[0], None if boards.air else cal.shared)
    print(f"wrote {output.path} (calib.yaml of {len(names)} cameras with its covariance, "
          f"report.json, report.md)")
    if report.get("left_out"):
        from synth.infra.cli import EXIT_CHECK_FAILED

        print(f"failed: {where}: " + "; ".join(
            f"{view} does not belong with the others ({why}): left out"
            for view, why in report["left_out"].items())
              + f" (the calibration in {output.path} is without it)", file=sys.stderr)
        return EXIT_CHECK_FAILED
    return 0


def _checked_options(args, boards, where):
    """The options refused for these boards (N cameras; a boards folder; in air or water);
    under water ``(free, air rig, its covariance)`` read from ``--intrinsics``, in air None."""
    from measure.calibration.multi_housing import PARAMETERS
    from eval.calibrate.options import refuse_for_boards_folder
    from synth.infra.cli import given

    for dest, flag in NOT_FOR_N_CAMERAS[:-1] if boards.photos else NOT_FOR_N_CAMERAS:
        if given(args, dest):
            raise CLIError(f"{flag} does not apply to {where}: the calibration of N cameras "
                           f"models one flat port they share, its σ propagates the in-air "
                           f"covariance")
    refuse_for_boards_folder(args, boards, board_options=not boards.photos)
    if boards.air:
        if args.intrinsics:
            raise CLIError(f"{args.dir}: in-air boards calibrate the intrinsics themselves; "
                           f"--intrinsics is for underwater boards")
        if args.lens == "fisheye":
            raise CLIError(f"--lens fisheye does not apply to {where}: the joint adjustment of "
                           f"N cameras projects with OpenCV's Brown–Conrady model (standard, "
                           f"k3, rational, radial)")
        return None
    if given(args, "lens"):
        raise CLIError("--lens does not apply underwater: the lens model is the in-air "
                       "calibration's (--intrinsics)")
    _require_flat_truth(boards, where)
    if not args.intrinsics:
        raise CLIError(f"{where}: underwater boards need --intrinsics (the calib.yaml of "
                       f"eval calibrate on in-air boards of the same cameras)")
    free = tuple(n.strip() for n in args.free.split(",") if n.strip())
    unknown = [n for n in free if n not in PARAMETERS]
    if not free or unknown:
        raise CLIError(f"--free {args.free!r}: the housing of N cameras estimates "
                       f"{', '.join(PARAMETERS)}")
    air, air_cov = read_air_rig(args.intrinsics, args.dir, boards.names, boards.size)
    return free, air, air_cov


def _require_flat_truth(boards, where) -> None:
    """CLIError for underwater boards whose truth is not behind flat ports (N cameras each in
    its own dome, ``synth scene --cameras N --port dome``): the housing of N cameras is one
    flat port they share or a flat port each."""
    from measure.geometry.port import require_flat_port

    if boards.truth is None:
        return
    try:
        for name, port in zip(boards.names, boards.truth.ports):
            if port is not None:
                require_flat_port(port, f"{name}'s port is not flat; the housing calibration "
                                        f"of N cameras fits one flat port they share or a "
                                        f"flat port each (no domes yet)")
    except ValueError as exc:
        raise CLIError(f"{where}: {exc}") from None


def _calibrate_in_air(args, boards, detections, report, log):
    """``(cal, rig, covariance, rows, rms)`` of every camera and pose jointly in air; the
    report gains the RMS, the poses used and the views left out."""
    from measure.calibration.multi_air import calibrate_rig_in_air
    from synth.infra.cli import given

    names, truth = boards.names, boards.truth
    lens = args.lens if given(args, "lens") else "standard"
    log("calibrate every camera and pose jointly (OpenCV per camera, then one bundle "
        "adjustment) …")
    cal = calibrate_rig_in_air(boards.board, detections, boards.size, names,
                               lens_model=lens, intrinsics="free")
    rig, sigmas = cal.rig, cal.sigmas()
    errors = _air_errors(rig, truth) if truth is not None else {}
    rows = [(n, errors.get(n), sigmas[n]) for n in cal.parameter_names]
    report.update({"rms_px": cal.rms_px, "joint_rms_px": cal.joint_rms_px,
                   "poses_used": cal.poses_used,
                   "left_out": {f"{names[v]}/{boards.captures[k]}": why
                                for (k, v), why in sorted(cal.left_out.items())}})
    return cal, rig, (cal.parameter_names, cal.covariance), rows, cal.joint_rms_px


def _calibrate_housing(args, boards, detections, design, water, report, log):
    """``(cal, rig, covariance, rows, rms)`` of the shared port, or each camera's own
    (``--port-distance`` or the boards' truth), from every camera's corners; the report gains
    the port(s), the RMS per camera, the uncertainty and the design."""
    from measure.calibration.multi_housing import calibrate_rig_housing
    from measure.stereo.rig import Rig
    from synth.infra.cli import given

    names = boards.names
    free, air, air_cov = water
    per_camera = given(args, "port_distance") or boards.own_ports
    if per_camera:  # each camera behind its own port, ⟂ its axis, D from its centre
        from measure import FlatPort

        from eval.calibrate.port_lengths import lengths_for
        from synth.scene.windows import DEFAULT_PAIR_DISTANCE_MM

        distances = lengths_for(args.port_distance or (DEFAULT_PAIR_DISTANCE_MM,), len(names))
        starts = [FlatPort(c.R[:, 2], d + float(c.R[:, 2] @ c.center),
                           design.thicknesses, design.indices)
                  for c, d in zip(air.cameras, distances)]
    else:
        starts = [design] * len(names)
    start_rig = Rig(air.cameras, starts, names)
    log(f"{'each camera' + chr(39) + 's own port' if per_camera else 'the shared port'}"
        f": {', '.join(free)} from every camera's corners …")
    air_names, air_matrix = air_cov if air_cov is not None else ((), None)
    cal = calibrate_rig_housing(start_rig, boards.board, detections, free, air_names,
                                air_matrix, per_camera=bool(per_camera))
    rig = cal.rig
    covariance = (tuple(f"port.{n}" if cal.shared else n.replace(".", ".port.", 1)
                        if "." in n else f"port.{n}" for n in cal.labels),
                  cal.covariance)
    rows = _port_rows(cal, rig, boards.truth, names, free, report)
    port = rig.ports[0]
    report["port"] = (port.describe() if cal.shared else
                      {n: p.describe() for n, p in zip(names, rig.ports)})
    report.update({"rms_px": cal.rms_px_per, "joint_rms_px": cal.rms_px,
                   "uncertainty": cal.uncertainty,
                   "sigmas_conditional": cal.sigmas_conditional,
                   "design": design.describe()})
    return cal, rig, covariance, rows, cal.rms_px


def _port_rows(cal, rig, truth, names, free, report) -> list:
    """``[(name, error or None, σ)]`` of every free port number (each camera's with its own
    ports); the normals' angle from the truth goes into ``report["normal_error_deg"]``."""
    rows = []
    slots = [None] if cal.shared else list(range(len(names)))
    for s_ in slots:
        v = 0 if s_ is None else s_
        port = rig.ports[v]
        true_port = truth.ports[v] if truth is not None else None
        label = "port" if s_ is None else f"{names[v]}.port"

        def pick(entry, s_=s_):
            return entry if s_ is None else entry[s_]

        def diff(value, port=port, true_port=true_port):
            return None if true_port is None else value(port) - value(true_port)

        if "distance" in free:
            rows.append((f"{label}.distance", diff(lambda q: q.distance),
                         pick(cal.sigmas["distance"])))
        if "normal" in free:
            axes = np.asarray(cal.normal_axes if s_ is None else cal.normal_axes[s_])
            tilt = (None if true_port is None
                    else axes @ (port.normal - true_port.normal))
            rows += [(f"{label}.tilt[{k}]", None if tilt is None else float(tilt[k]),
                      pick(cal.sigmas["normal"])[k]) for k in range(2)]
            if true_port is not None:
                report.setdefault("normal_error_deg", {})[label] = float(np.degrees(
                    np.arctan2(np.linalg.norm(np.cross(port.normal, true_port.normal)),
                               port.normal @ true_port.normal)))
        if "thickness" in free:
            rows.append((f"{label}.thickness", diff(lambda q: q.thicknesses[0]),
                         pick(cal.sigmas["thickness"])))
    if "n_water" in free:
        rows.append(("port.n_water", None if truth is None
                     else rig.ports[0].n_water - truth.ports[0].n_water,
                     cal.sigmas["n_water"]))
    return rows


def _print_summary(boards, names, kind, rms, rows, report, found, free, shared) -> None:
    """The one line of the calibration: against the truth when the boards have one, else the
    board found per camera and the port(s)."""
    water = not boards.air
    if boards.truth is not None:
        print(f"{len(names)} cameras, {kind}: RMS {rms:.4f} px; {report['within_3_sigma']} of "
              f"{len(rows)} estimates within 3 σ of the truth (largest "
              f"{report['largest_error_in_sigma']:.2f} σ)"
              + (f"; D {rows[0][1]:+.4f} mm (σ {rows[0][2]:.3g}), normal "
                 f"{report['normal_error_deg']['port']:.4f}° from the truth"
                 if water and "distance" in free and "normal" in free
                 and "port" in report.get("normal_error_deg", {}) else "")
              + ("; each camera's port: " + ", ".join(
                  f"{n.split('.')[0]} D {e:+.4f} mm ({e / sg:+.2f} σ)" for n, e, sg in rows
                  if n.endswith(".port.distance"))
                 if water and "distance" in free and not shared else ""))
        return
    port_line = ""
    if water and "distance" in free and shared:
        port_line = (f"; the port: D {report['port']['distance_mm']:.4f} ± "
                     f"{rows[0][2]:.3g} mm, normal "
                     + ", ".join(f"{v:.5f}" for v in report["port"]["normal"]))
    elif water and "distance" in free:
        port_line = "; each camera's port: " + ", ".join(
            f"{n} D {report['port'][n]['distance_mm']:.4f} ± {sg:.3g} mm"
            for n, (_, _, sg) in zip(names, [r for r in rows
                                             if r[0].endswith(".port.distance")]))
    print(f"{len(names)} cameras, {kind}: RMS {rms:.4f} px, the board found per camera "
          + ", ".join(f"{n} {c}" for n, c in found.items()) + port_line)

__all__ = ["calibrate_cameras_main"]
