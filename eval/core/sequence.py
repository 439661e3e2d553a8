"""A ``synth sequence`` folder read for ``python -m eval track`` (its files checked against
the SHA-256 its manifest records) and the known object's markers found among one frame's
detections: predicted from the last pose, or locked on again with no guess
(:func:`measure.stereo.lockon.lock_on`) where the track has no pose of the frame before or the
prediction loses the frame."""

from __future__ import annotations

import json
import os
import time

import numpy as np

from synth.infra.cli import CLIError


def read_sequence(path):
    """``(manifest, rig, object_points (M, 3), truth (frames, R, t), pixels (F, 2, M, 2))`` of a
    sequence folder (``pixels``: the Fermat simulator's, for the detections' error);
    CLIError naming the file for anything missing or malformed."""
    from synth.products.dataset import DatasetError, read_calib
    from synth.products.sequence import COMMAND as SEQUENCE, read_poses

    if not os.path.isdir(path):
        raise CLIError(f"{path}: no such folder")
    manifest_path = os.path.join(path, "manifest.json")
    try:
        with open(manifest_path) as fh:
            manifest = json.load(fh)
    except (OSError, ValueError) as exc:
        raise CLIError(f"{manifest_path}: cannot be read ({exc})") from None
    if manifest.get("command") != SEQUENCE:
        raise CLIError(f"{path}: not a folder written by python -m {SEQUENCE}")
    try:
        rig = read_calib(os.path.join(path, "calib.yaml"))["rig"]
    except DatasetError as exc:
        raise CLIError(str(exc)) from None
    object_path = os.path.join(path, "object.csv")
    try:
        data = np.genfromtxt(object_path, delimiter=",", names=True, ndmin=1)
        obj = np.column_stack([data["x_mm"], data["y_mm"], data["z_mm"]])
    except (OSError, ValueError, KeyError) as exc:
        raise CLIError(f"{object_path}: not an object.csv ({exc})") from None
    try:
        truth = read_poses(os.path.join(path, "poses.csv"))
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    pixels_path = os.path.join(path, "pixels.csv")
    try:
        data = np.genfromtxt(pixels_path, delimiter=",", names=True, ndmin=1)
        pixels = np.full((len(truth[0]), 2, obj.shape[0], 2), np.nan)
        f, i = np.asarray(data["frame"], dtype=int), np.asarray(data["id"], dtype=int)
        pixels[f, 0, i] = np.column_stack([data["u_left"], data["v_left"]])
        pixels[f, 1, i] = np.column_stack([data["u_right"], data["v_right"]])
    except (OSError, ValueError, KeyError, IndexError) as exc:
        raise CLIError(f"{pixels_path}: not a sequence's pixels.csv ({exc})") from None
    return manifest, rig, obj, truth, pixels


#: The files of a sequence that hold its truth (what the frames are scored against): one changed
#: since ``synth sequence`` wrote it is refused.
TRUTH_FILES = ("calib.yaml", "object.csv", "poses.csv", "pixels.csv")


def changed_frames(path, manifest) -> list[str]:
    """The frames of the sequence folder ``path`` whose SHA-256 is not the one its manifest
    records (changed since ``synth sequence`` wrote them: they are read as they are now, and
    named); CLIError for a file the manifest lists that is missing, or a truth file
    (:data:`TRUTH_FILES`) that changed. A manifest without digests checks nothing."""
    from synth.infra.fileio import file_sha256
    from synth.products.sequence import COMMAND as SEQUENCE

    digests = manifest.get("sha256")
    if not isinstance(digests, dict):
        return []
    changed = []
    for name in sorted(digests):
        file = os.path.join(path, name)
        if not os.path.isfile(file):
            raise CLIError(f"{file}: no such file (the sequence's manifest.json lists it)")
        if file_sha256(file) == digests[name]:
            continue
        if name in TRUTH_FILES:
            raise CLIError(f"{file}: changed since {SEQUENCE} wrote it (its SHA-256 is not the "
                           f"one manifest.json records): the frames would be scored against a "
                           f"truth they were not rendered with; render the sequence again "
                           f"with python -m {SEQUENCE}")
        changed.append(name)
    return changed


def associate(predicted, detections, gate_px: float) -> np.ndarray:
    """``(M, 2)``: for each marker's predicted pixel ``(M, 2)`` the detection ``(D, 2)`` the
    optimal assignment gives it within ``gate_px`` (NaN: none)."""
    from scipy.optimize import linear_sum_assignment

    out = np.full(predicted.shape, np.nan)
    ok = np.flatnonzero(np.all(np.isfinite(predicted), axis=1))
    if ok.size == 0 or detections.shape[0] == 0:
        return out
    cost = np.linalg.norm(predicted[ok, None, :] - detections[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(np.where(cost <= gate_px, cost, 1e9))
    keep = cost[rows, cols] <= gate_px
    out[ok[rows[keep]]] = detections[cols[keep]]
    return out


#: A frame whose detections meet fewer than this share of the markers the last pose puts inside
#: the images is lost (no pose; the run exits 1): a pose from the few left could be anywhere.
LOST_FRACTION = 0.5
def predicted_detections(rig, obj, found, R, t, gate_px: float):
    """``(pixels (2, M, 2), expected, associated)``: each marker's detection in each view
    (:func:`associate`, NaN: none) where the pose ``R``, ``t`` puts it through the port, how
    many markers that pose puts inside the images and how many were given a detection."""
    from measure.geometry.projection import project

    pixels = np.full((2, obj.shape[0], 2), np.nan)
    expected = 0
    for v in range(2):
        predicted = project(rig.cameras[v], rig.view_port(v), obj @ R.T + t)
        pixels[v] = associate(predicted, found[v], gate_px)
        expected += int(rig.cameras[v].in_image(predicted).sum())
    return pixels, expected, int(np.all(np.isfinite(pixels), axis=2).sum())


def locate_markers(rig, obj, found, track, gate_px: float, frame: int, seconds, log):
    """One frame's markers among its detections ``found`` (per view ``(D, 2)``):
    ``(pixels (2, M, 2), expected, associated, lost, lock)``. Where the track has a pose of the
    frame before, each marker is looked for where that pose moved on at ``track["velocity"]``
    puts it; where it has none (the first frame, or the frame before was lost), or where that
    prediction loses the frame (fewer than :data:`LOST_FRACTION` of the expected markers
    found), the object is found again with no guess (:func:`measure.stereo.lockon.lock_on`,
    the turn nearest the last pose's) and the markers are looked for where that pose puts them.
    ``lock``: the lock-on used (None: the prediction); ``track["R"]``/``["t"]`` take its pose.
    ``lost``: no pixels are kept (all NaN)."""
    from measure.stereo.lockon import lock_on

    def attempt_lock():
        t0 = time.perf_counter()
        attempt = lock_on(rig, obj, found[0], found[1], prefer=track["R"])
        seconds["lock_on"] += time.perf_counter() - t0
        log(f"frame {frame}: lock-on " + (
            attempt.reason if attempt.reason else
            f"{attempt.assigned} markers, fit RMS {attempt.rms_mm:.3g} mm, "
            f"{attempt.ambiguous} equally good turn(s)"))
        return attempt if attempt.reason is None else None

    empty = np.full((2, obj.shape[0], 2), np.nan)
    result = (empty, 0, 0)
    lock = None
    if track["R"] is not None and track["fresh"]:
        result = predicted_detections(rig, obj, found, track["R"], track["t"] + track["velocity"],
                                      gate_px)
    if track["R"] is None or not track["fresh"] or result[2] < LOST_FRACTION * result[1]:
        lock = attempt_lock()
        if lock is not None:
            track["R"], track["t"] = lock.R, lock.t
            result = predicted_detections(rig, obj, found, lock.R, lock.t, gate_px)
        elif track["R"] is not None and not track["fresh"]:  # the last pose, however old
            result = predicted_detections(rig, obj, found, track["R"], track["t"], gate_px)
    pixels, expected, associated = result
    lost = track["R"] is None or associated < LOST_FRACTION * expected
    return (empty if lost else pixels), expected, associated, lost, lock


__all__ = ["LOST_FRACTION", "TRUTH_FILES", "associate", "changed_frames", "locate_markers",
           "predicted_detections", "read_sequence"]
