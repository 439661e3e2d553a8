"""Whether a pair's in-air calibration describes its underwater photos, and whether the
housing those photos give is the only one.

:func:`rig_inconsistency`: when the housing fit with the in-air intrinsics and stereo pose
held leaves a large RMS, each camera is fitted alone through its own port (its intrinsics
held, :func:`measure.calibration.housing.calibrate_camera_housing`). A camera that fits alone
but not with the other says the stereo pose no longer holds (the rig changed between the
calibrations, or the two photos of a pair were not taken at one moment); a camera that fits
badly alone says its own intrinsics do not describe its photos. On the Minions rig (a real
underwater stereo rig, f ≈ 12,000 px): held, the ports leave about 4 px where an absorbed
pinhole pair leaves 0.49 px.

:func:`uniqueness`: with the stereo pose freed (``--free …,extrinsics``), the same fit from
other starting port distances (:data:`START_FACTORS` × the design's); solutions that fit as
well (within :data:`SAME_FIT`) but put D more than :data:`DIFFERENT_SIGMAS` σ apart say the
port distance is not determined by these photos — a narrow view trades the ports against the
stereo pose.

Units: mm, px; the reference frame is the left camera's.
"""

from __future__ import annotations

import numpy as np

#: A camera fits alone when its RMS through its own port is at most this fraction of the
#: joint fit's; the joint fit is inconsistent when it exceeds the worse camera alone by this
#: many px.
ALONE_FRACTION, JOINT_EXCESS_PX = 0.5, 0.5
#: Starting port distances of a camera fitted alone, as factors of the design's (the best fit
#: is kept: on the Minions rig a start at 20 units ran to the bound at 0, 0.27 px, where 180
#: found 186 units, 0.23 px).
ALONE_STARTS = (1.0, 3.0, 9.0)
#: Starting port distances of :func:`uniqueness`, as factors of the design's.
START_FACTORS = (0.25, 4.0)
#: Two solutions fit alike when their RMS differ by at most this fraction of the better one's,
#: and differ when their port distances lie this many σ (the main fit's) apart.
SAME_FIT, DIFFERENT_SIGMAS = 0.1, 3.0


def _camera_alone(rig, view: int):
    """``(camera at the origin, its port in its own frame)`` of view ``view`` of ``rig``."""
    from measure import Camera

    camera, port = rig.cameras[view], rig.view_port(view)
    normal = camera.R.T @ port.normal
    moved = port.replace(normal=normal, distance=float(port.distance - port.normal @ camera.t))
    return Camera(camera.K, camera.size, camera.dist,
                  distortion_model=camera.distortion_model), moved


def _alone(rig, board, detections, view: int):
    """``(rms px, port in the reference frame)`` of camera ``view`` fitted alone through its
    own port (its intrinsics held), or ``(None, None)``."""
    from measure.calibration.air import CalibrationError, Detections
    from measure.calibration.housing import calibrate_camera_housing

    empty = (np.empty(0, int), np.empty((0, 2)))
    one = Detections([[ids[view], empty[0]] for ids in detections.ids],
                     [[px[view], empty[1]] for px in detections.pixels])
    camera, port = _camera_alone(rig, view)
    fits = []
    for factor in ALONE_STARTS:  # one camera's fit has a minimum at the distance's bound too
        try:
            fit = calibrate_camera_housing(camera, port.replace(distance=factor * port.distance),
                                           board, one, ("distance", "normal"))
        except (CalibrationError, ValueError):
            continue
        if fit.converged and fit.identifiable:
            fits.append(fit)
    if not fits:
        return None, None
    fit = min(fits, key=lambda f: f.rms_px)
    own, placed = fit.rig.view_port(0), rig.cameras[view]
    normal = placed.R @ own.normal
    return float(fit.rms_px), own.replace(normal=normal,
                                          distance=float(own.distance + normal @ placed.t))


#: A pair's housing that leaves more than this many times the worse camera's absorbed pinhole
#: RMS plus this margin (px) does not describe the photos at all (photos behind two housings
#: fitted as one shared port: 1.88 px against 0.035 px).
GROSS_FACTOR, GROSS_MARGIN_PX = 3.0, 0.15


def gross_misfit(housing, board, detections, size, two_housings: bool) -> str | None:
    """Why a pair's housing fit cannot be the photos' (its RMS far above what each camera
    calibrated as a pinhole that absorbs the port leaves, :data:`GROSS_FACTOR`), or None.
    ``two_housings``: the fit had a port per camera (else the hint says to try that)."""
    from measure.calibration.air import CalibrationError, calibrate_camera

    corners = board.corners().astype(np.float32)
    absorbed = []
    for view in (0, 1):
        poses = detections.found(view)
        try:
            out = calibrate_camera([corners[detections.ids[k][view]] for k in poses],
                                   [detections.pixels[k][view].astype(np.float32) for k in poses],
                                   size, "standard")[0]
        except (CalibrationError, ValueError):
            return None
        absorbed.append(float(out[0]))
    if housing.rms_px <= GROSS_FACTOR * max(absorbed) + GROSS_MARGIN_PX:
        return None
    hint = ("" if two_housings else " — photos behind two housings? give --port-distance "
            "LEFT,RIGHT (a port per camera)")
    return (f"the housing fit leaves {housing.rms_px:.3g} px where each camera calibrated as a "
            f"pinhole that absorbs the port leaves {absorbed[0]:.3g} / {absorbed[1]:.3g} px: "
            f"the port model does not describe these photos{hint}")


def cameras_alone(rig, board, detections) -> list:
    """``[(rms px, port in the reference frame)]`` of each camera of ``rig`` fitted alone
    through its own port (:func:`_alone`; ``(None, None)`` where it has no fit)."""
    return [_alone(rig, board, detections, v) for v in (0, 1)]


def start_from_cameras(rig, alone):
    """A rig of two housings (:class:`measure.geometry.flat_pair.FlatPair`) started from each
    camera's own port (``alone``: :func:`cameras_alone`), or None where a camera has no such
    fit or the rig is not of two housings: a start from the photos where the design's distance
    is far from the truth (the Minions rig: design 20, its cameras alone 186 and 150 units)."""
    from measure import StereoRig
    from measure.geometry.flat_pair import FlatPair

    if not isinstance(rig.port, FlatPair) or any(port is None for _, port in alone):
        return None
    return StereoRig(rig.left, rig.right, FlatPair(*[port for _, port in alone]))


def _joint_from(rig, ports, board, detections, free) -> float | None:
    """The RMS (px) of the held rig's housing fit started from ``ports`` (one per camera)."""
    from measure import StereoRig
    from measure.calibration.air import CalibrationError
    from measure.calibration.housing import calibrate_housing
    from measure.geometry.flat_pair import FlatPair

    try:
        fit = calibrate_housing(StereoRig(rig.left, rig.right, FlatPair(*ports)), board,
                                detections, free)
    except (CalibrationError, ValueError):
        return None
    return float(fit.rms_px)


def rig_inconsistency(housing, start_rig, board, detections, free,
                      fits=None) -> str | None:
    """Why the in-air rig does not describe these photos (module docs), or None when the
    failed housing fit ``housing`` is not of that kind (the stereo pose freed, or a fit that
    did not leave a large RMS). ``detections``: the pair's, before any was left out as an
    outlier of the failed fit; ``fits``: :func:`cameras_alone` where already had (a fit
    started from them is then taken to be ``housing``)."""
    from measure.calibration.housing import FIT_RMS_LIMIT_PX
    from measure.geometry.flat_pair import FlatPair

    if "extrinsics" in free or housing.rms_px <= FIT_RMS_LIMIT_PX:
        return None
    joint = housing.rms_px
    if fits is None:
        fits = cameras_alone(start_rig, board, detections)
        if all(port is not None for _, port in fits) and isinstance(start_rig.port, FlatPair):
            again = _joint_from(start_rig, [port for _, port in fits], board, detections, free)
            joint = min(joint, again) if again is not None else joint
    alone = [rms for rms, _ in fits]
    said = ", ".join(f"{name} {'no fit' if r is None else f'{r:.3f} px'}"
                     for name, r in zip(("left", "right"), alone))
    bad = [name for name, r in zip(("left", "right"), alone)
           if r is None or r > ALONE_FRACTION * joint]
    if bad:
        return (f"the in-air calibration does not describe these photos: with its intrinsics "
                f"and stereo pose held the ports leave {joint:.3g} px, and the {' and '.join(bad)} "
                f"camera's own intrinsics do not fit its photos through a port either (each "
                f"camera alone: {said}) — another camera, another lens setting or focus, or a "
                f"calibration of another rig")
    if joint > max(alone) + JOINT_EXCESS_PX:
        return (f"the in-air stereo pose does not describe these photos: with the in-air "
                f"intrinsics and stereo pose held the ports leave {joint:.3g} px, while each "
                f"camera alone fits its own photos through its port ({said}); the cameras' "
                f"relative pose changed since the in-air calibration (or the two photos of a "
                f"pair were not taken at one moment) — calibrate the rig again in air, or free "
                f"the stereo pose with --free …,extrinsics")
    return None


def uniqueness(housing, start_rig, board, detections, free, air_covariance,
               uncertainty) -> dict:
    """The fit from other starting port distances (module docs): ``{"main", "starts":
    [{factor, rms_px, distance, baseline_mm, angle_deg, identifiable}], "note"}``; the note
    (None when every fit as good as the main one lands on its port distances, within
    :data:`DIFFERENT_SIGMAS` σ or 1 mm where there is no σ) says the solution is not unique."""
    from measure.calibration.air import CalibrationError
    from measure.calibration.housing import calibrate_housing

    main = _summary(housing)
    sigma = np.atleast_1d(housing.sigmas["distance"]) if housing.sigmas.get("distance") \
        is not None else np.ones(2)
    starts = []
    for factor in START_FACTORS:
        try:
            fit = calibrate_housing(_scaled_start(start_rig, factor), board, detections, free,
                                    air_covariance, uncertainty)
        except (CalibrationError, ValueError):
            continue
        if fit.converged:
            starts.append({"factor": factor, **_summary(fit)})
    every = [main] + starts
    best = min(s["rms_px"] for s in every)
    alike = [s for s in every if s["rms_px"] <= (1 + SAME_FIT) * best]
    apart = np.ptp(np.array([s["distance"] for s in alike]), axis=0) > DIFFERENT_SIGMAS * sigma
    note = None
    if len(alike) > 1 and (apart.any() or not main["identifiable"]):
        note = (f"the solution is not unique: from {len(every)} starting port distances the "
                f"fits that leave {min(s['rms_px'] for s in alike):.3f}–"
                f"{max(s['rms_px'] for s in alike):.3f} px put the ports "
                f"{_span([d for s in alike for d in s['distance']])} mm from their cameras, the "
                f"baseline at {_span([s['baseline_mm'] for s in alike], 1)} mm and the "
                f"convergence at {_span([s['angle_deg'] for s in alike], 2)}°: these photos do "
                f"not determine the port distance (a σ would not say so)")
    return {"main": main, "starts": starts, "note": note}


def _span(values, digits: int = 0) -> str:
    return f"{min(values):.{digits}f}–{max(values):.{digits}f}"


def _summary(fit) -> dict:
    """RMS, each port's distance from its camera, baseline and convergence angle where a
    housing fit stopped (``fit.fitted``), and whether it is identifiable."""
    rig = fit.fitted
    R = rig.right.R
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    distance = [float(rig.view_port(v).distance - rig.view_port(v).normal @ rig.cameras[v].t)
                for v in (0, 1)]
    return {"rms_px": float(fit.rms_px), "distance": distance,
            "baseline_mm": float(np.linalg.norm(rig.right.t)), "angle_deg": angle,
            "identifiable": bool(fit.identifiable)}


def _scaled_start(rig, factor: float):
    """``rig`` with every port's starting distance from its camera times ``factor``."""
    from measure import StereoRig
    from measure.geometry.flat_pair import FlatPair

    def scaled(port, camera):
        own = port.distance - port.normal @ camera.t       # from the camera's centre
        return port.replace(distance=float(port.normal @ camera.t + factor * own))

    if isinstance(rig.port, FlatPair):
        port = FlatPair(scaled(rig.port.view(0), rig.left), scaled(rig.port.view(1), rig.right))
    else:
        port = scaled(rig.port, rig.left)
    return StereoRig(rig.left, rig.right, port)


__all__ = ["GROSS_FACTOR", "GROSS_MARGIN_PX", "cameras_alone", "gross_misfit",
           "rig_inconsistency", "start_from_cameras", "uniqueness"]
