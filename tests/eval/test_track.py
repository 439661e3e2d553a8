"""``synth sequence`` and ``eval track``: a docking frame rendered approaching the rig (small
images), followed through its frames with the refractive pose and scored against its true
poses.

Reference: the true poses the sequence was rendered with, and the TUM file against the CSV.
Bound: the raw detections lie 0.02–0.07 px from the simulator's pixels at this size (the
disks' perspective eccentricity: a bias both views share), which moves the pose 0.1–0.3 mm in
depth at 1.3–1.8 m; 0.5 mm holds that with margin, while a marker lost or given another's
detection moves it by tens of mm. Corrected for the eccentricity (the default), the pose is
several times nearer the truth than on the raw centroids."""

from __future__ import annotations

import json

import numpy as np
import pytest

from eval.cli import main as eval_main
from synth.commands import main as synth_main

SEQUENCE = ["scenes/small_grid.xml", "-D", "width=640", "-D", "height=536", "--approach",
            "1800,1300", "--frames", "6", "--yaw", "5", "--spp", "16", "--marker-radius-mm",
            "15", "--no-progress"]


@pytest.mark.slow
def test_sequence_is_tracked_against_its_true_poses(tmp_path, capsys):
    seq = tmp_path / "seq"
    assert synth_main(["sequence", *SEQUENCE, "--out", str(seq)]) == 0
    assert len(list((seq / "frames").glob("*.png"))) == 12
    truth = np.genfromtxt(seq / "poses.csv", delimiter=",", names=True)
    np.testing.assert_allclose(truth["tz_mm"], np.linspace(1800, 1300, 6))
    np.testing.assert_allclose(2 * np.degrees(np.arcsin(truth["qy"])), np.linspace(0, 5, 6))
    tum = np.loadtxt(seq / "poses_tum.txt")
    np.testing.assert_allclose(tum[:, 3], truth["tz_mm"] / 1000.0, atol=1e-9)  # metres
    out = tmp_path / "track"
    assert eval_main(["track", str(seq), "--out", str(out), "--no-progress"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["summary"]["tracked"] == 6
    lock = report["lock_on"]  # from the first frame's detections, no guess: the true turn
    assert lock["mode"] == "detect" and lock["frame"] == 0 and lock["markers"] >= 10, lock
    assert lock["position_error_mm"] < 20.0 and lock["rotation_error_rad"] < 0.02, lock
    for frame in report["frames"]:
        assert frame["observations"] >= 20, frame
        assert frame["position_error_mm"] <= 0.5, frame
        assert frame["rotation_error_rad"] <= 1e-3, frame
    estimated = np.genfromtxt(out / "poses.csv", delimiter=",", names=True, dtype=None,
                              encoding="utf-8")
    assert list(estimated["reason"]) == ["OK"] * 6
    assert np.loadtxt(out / "poses_tum.txt").shape == (6, 8)
    assert (out / "track.png").stat().st_size > 10_000
    for name, alone in report["summary"]["per_camera"].items():  # one view: depth is weaker
        assert alone["posed"] == 6, (name, alone)
        assert (report["summary"]["position_error_mm"]["median"]
                <= alone["position_error_mm"]["median"] <= 5.0), (name, alone)
    absorbed = report["summary"]["absorbed"]  # pinhole cameras that absorb the port
    assert absorbed["posed"] == 6
    assert (absorbed["position_error_pct"]["median"]
            > 10 * report["summary"]["position_error_pct"]["median"]), absorbed
    assert (absorbed["aligned_position_error_pct"]["median"]
            > 10 * report["summary"]["position_error_pct"]["median"]), absorbed
    raw = tmp_path / "raw"
    assert eval_main(["track", str(seq), "--out", str(raw), "--no-eccentricity",
                      "--no-absorbed", "--no-progress"]) == 0
    assert "absorbed" not in json.loads((raw / "report.json").read_text())["summary"]
    uncorrected = json.loads((raw / "report.json").read_text())["summary"]
    corrected = report["summary"]
    assert (corrected["position_error_mm"]["median"]
            < 0.5 * uncorrected["position_error_mm"]["median"])
    assert corrected["coverage_95"] > uncorrected["coverage_95"]


def test_refusals_are_one_line(tmp_path, capsys):
    assert eval_main(["track", str(tmp_path), "--out", str(tmp_path / "out"),
                      "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "manifest.json" in err[0], err
    assert eval_main(["track", str(tmp_path), "--no-absorbed", "--absorbed-calib", "x.yaml",
                      "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--absorbed-calib" in err[0] and "--no-absorbed" in err[0], err
    assert synth_main(["sequence", *SEQUENCE[:5], "--approach", "50,1000", "--frames", "2",
                       "--out", str(tmp_path / "near"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not in the water" in err[0], err
    assert not (tmp_path / "near").exists()


@pytest.mark.slow
def test_a_jump_is_locked_on_again_not_posed_from_the_few_left(tmp_path):
    """A jump of 1 m between two frames: the last pose predicts the markers far from where
    they are and few detections associate. The frame is not posed from the few left (a pose
    1.28 m off passed as OK once); the object is found again with no guess and the frame
    tracked (it was LOST, exit 1: the lock-on never ran again)."""
    seq = tmp_path / "jump"
    assert synth_main(["sequence", *SEQUENCE[:5], "--approach", "2000,1000", "--frames", "2",
                       "--spp", "4", "--marker-radius-mm", "15", "--no-progress",
                       "--out", str(seq)]) == 0
    out = tmp_path / "track"
    assert eval_main(["track", str(seq), "--out", str(out), "--no-progress",
                      "--no-absorbed"]) == 0
    report = json.loads((out / "report.json").read_text())
    frames = report["frames"]
    assert [f["reason"] for f in frames] == ["OK", "OK"]
    assert frames[0]["locked_on"] and frames[1]["locked_on"]  # the lock-on ran again
    assert [a["frame"] for a in report["lock_on"]["again"]] == [1]
    assert frames[1]["markers_associated"] == frames[1]["markers_expected"] >= 20
    assert frames[1]["position_error_mm"] <= 0.5, frames[1]


@pytest.mark.slow
def test_a_black_frame_loses_one_frame_not_the_rest(tmp_path, capsys):
    """A frame made black after ``synth sequence`` wrote it (both views), in a coarse approach
    (2000 → 1000 mm in 4 frames, 333 mm a frame): that frame is LOST and the lock-on finds the
    object again in the next one, so 3 of 4 are tracked (1 of 4 before: every later frame was
    predicted from frame 0's pose). The changed frames are named, not read as untouched; a
    changed truth file is refused."""
    import cv2

    seq = tmp_path / "black"
    assert synth_main(["sequence", *SEQUENCE[:5], "--approach", "2000,1000", "--frames", "4",
                       "--spp", "4", "--marker-radius-mm", "15", "--no-progress",
                       "--out", str(seq)]) == 0
    for view in ("left", "right"):
        path = str(seq / "frames" / f"0001_{view}.png")
        cv2.imwrite(path, np.zeros_like(cv2.imread(path, cv2.IMREAD_ANYDEPTH)))
    capsys.readouterr()
    out = tmp_path / "track"
    assert eval_main(["track", str(seq), "--out", str(out), "--no-progress",
                      "--no-absorbed"]) == 1
    captured = capsys.readouterr()
    notes = [line for line in captured.err.splitlines() if line.startswith("note:")]
    assert len(notes) == 1 and "frames/0001_left.png" in notes[0], captured.err
    assert "tracked 3 of 4" in captured.out, captured.out
    report = json.loads((out / "report.json").read_text())
    assert report["changed_since_written"] == ["frames/0001_left.png", "frames/0001_right.png"]
    frames = report["frames"]
    assert [f["reason"] for f in frames] == ["OK", "LOST", "OK", "OK"]
    assert frames[2]["locked_on"] and [a["frame"] for a in report["lock_on"]["again"]] == [2, 3]
    for frame in (frames[0], *frames[2:]):
        assert frame["position_error_mm"] <= 0.5, frame
    poses = seq / "poses.csv"
    poses.write_text(poses.read_text().replace("2000.0", "2001.0", 1))
    assert eval_main(["track", str(seq), "--out", str(tmp_path / "no"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "poses.csv: changed since synth sequence wrote it" in err[0], err
    assert not (tmp_path / "no").exists()


def test_sequences_that_cannot_be_tracked_are_refused(tmp_path, capsys):
    """Disks that overlap (a side marker and a post marker 374.2 mm apart, radius 200 mm) and
    an approach whose frames show no camera four marker centres (a 5 m frame at 1–1.3 m: every
    marker beyond the field of view): one line each, exit 2, nothing written."""
    base = [*SEQUENCE[:5], "--frames", "2", "--no-progress"]
    assert synth_main(["sequence", *base, "--approach", "1800,1300", "--marker-radius-mm",
                       "200", "--out", str(tmp_path / "overlap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "overlap" in err[0] and "374.2 mm apart" in err[0], err
    assert synth_main(["sequence", *base, "--approach", "1300,1000", "--size-mm", "5000",
                       "--out", str(tmp_path / "wide")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "frame 0" in err[0] and "field of view" in err[0], err
    assert not (tmp_path / "overlap").exists() and not (tmp_path / "wide").exists()


@pytest.mark.slow
def test_a_sequence_along_a_given_trajectory(tmp_path, capsys):
    """``--trajectory``: the TUM file of one sequence rendered again gives the same poses (to the
    file's 1e-9 m), its own irregular time stamps, and a track of every frame; options that the
    file replaces are refused."""
    first = tmp_path / "first"
    assert synth_main(["sequence", *SEQUENCE[:5], "--approach", "1800,1300", "--frames", "3",
                       "--yaw", "4", "--spp", "16", "--marker-radius-mm", "15", "--out",
                       str(first), "--no-progress"]) == 0
    tum = np.loadtxt(first / "poses_tum.txt")
    tum[:, 0] = [0.0, 0.25, 1.0]  # irregular times
    path = tmp_path / "moved.txt"
    np.savetxt(path, tum, fmt="%.12f", header="timestamp tx ty tz qx qy qz qw")
    again = tmp_path / "again"
    assert synth_main(["sequence", *SEQUENCE[:5], "--trajectory", str(path), "--spp", "16",
                       "--marker-radius-mm", "15", "--out", str(again), "--no-progress"]) == 0
    a = np.genfromtxt(first / "poses.csv", delimiter=",", names=True)
    b = np.genfromtxt(again / "poses.csv", delimiter=",", names=True)
    for column in ("tx_mm", "ty_mm", "tz_mm", "qx", "qy", "qz", "qw"):
        np.testing.assert_allclose(b[column], a[column], atol=1e-6)
    np.testing.assert_allclose(b["time_s"], [0.0, 0.25, 1.0])
    out = tmp_path / "track"
    assert eval_main(["track", str(again), "--out", str(out), "--no-progress"]) == 0
    np.testing.assert_allclose(np.loadtxt(out / "poses_tum.txt")[:, 0], [0.0, 0.25, 1.0])
    capsys.readouterr()
    for extra in (["--frames", "3"], ["--yaw", "5"], ["--approach", "1800,1300"]):
        assert synth_main(["sequence", *SEQUENCE[:5], "--trajectory", str(path), *extra,
                           "--out", str(tmp_path / "no"), "--no-progress"]) == 2
    bad = tmp_path / "bad.txt"
    bad.write_text("0 0 0 1.5 0 0 0 2\n")
    assert synth_main(["sequence", *SEQUENCE[:5], "--trajectory", str(bad), "--out",
                       str(tmp_path / "no"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and "norm is 2" in err[-1], err
    assert not (tmp_path / "no").exists()
