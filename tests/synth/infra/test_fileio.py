"""The one atomic-output helper: the --out rule, staging, stale staging of dead processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from synth.infra.fileio import (MARKER_NAME, OutputDir, OutputError, atomic_write_json,
                          check_file_output, read_marker, remove_stale_staging)
from tests.conftest import REPO


def _write(out, command="eval run", files=("a.txt",)):
    with OutputDir(out, command).staged() as tmp:
        for name in files:
            with open(os.path.join(tmp, name), "w") as handle:
                handle.write(name)


def test_new_output_appears_whole_with_its_marker(tmp_path):
    out = tmp_path / "out"
    _write(out, files=("a.txt", "b.txt"))
    marker = read_marker(out)
    assert marker["command"] == "eval run" and marker["project"] == "refractive-stereo"
    assert marker["files"] == ["a.txt", "b.txt"]
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_earlier_output_of_the_same_command_is_replaced(tmp_path):
    out = tmp_path / "out"
    _write(out, files=("a.txt",))
    _write(out, files=("b.txt",))
    assert sorted(os.listdir(out)) == sorted([MARKER_NAME, "b.txt"])
    assert sorted(os.listdir(tmp_path)) == ["out"]


@pytest.mark.parametrize("setup", ["stranger_file", "other_command", "added_file", "marker_only_foreign"])
def test_foreign_directories_are_refused_untouched(tmp_path, setup):
    out = tmp_path / "out"
    if setup == "stranger_file":
        out.mkdir()
        (out / "mine.txt").write_text("keep")
    elif setup == "other_command":
        _write(out, command="synth dataset")
    elif setup == "added_file":
        _write(out)
        (out / "mine.txt").write_text("keep")
    else:
        out.mkdir()
        (out / MARKER_NAME).write_text(json.dumps({"project": "someone-else", "command": "eval run"}))
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with pytest.raises(OutputError, match="exists and holds files this command did not write"):
        OutputDir(out, "eval run").claim()
    with pytest.raises(OutputError):
        _write(out)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_output_that_is_a_file_or_under_a_file_is_refused(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match="not a directory"):
        OutputDir(blocker, "eval run").claim()
    with pytest.raises(OutputError, match="not a directory"):
        OutputDir(blocker / "out", "eval run").claim()
    assert blocker.read_text() == "x"


def test_an_error_while_writing_leaves_the_old_output(tmp_path):
    out = tmp_path / "out"
    _write(out, files=("a.txt",))
    with pytest.raises(RuntimeError):
        with OutputDir(out, "eval run").staged() as tmp:
            (open(os.path.join(tmp, "b.txt"), "w")).close()
            raise RuntimeError("boom")
    assert sorted(os.listdir(out)) == sorted([MARKER_NAME, "a.txt"])
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_stale_staging_of_a_killed_process_is_removed(tmp_path):
    """A real process is killed with SIGKILL while it holds a staging directory."""
    out = tmp_path / "out"
    code = ("import sys, time; sys.path.insert(0, sys.argv[2]);"
            "from synth.infra.fileio import OutputDir\n"
            "with OutputDir(sys.argv[1], 'eval run').staged() as tmp:\n"
            "    open(tmp + '/partial.txt', 'w').write('x'); print('staged', flush=True);"
            " time.sleep(60)\n")
    repo = str(REPO)
    proc = subprocess.Popen([sys.executable, "-c", code, str(out), repo], stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "staged"
    proc.kill()
    proc.wait()
    stale = [n for n in os.listdir(tmp_path) if n.startswith(".out.staging-")]
    assert len(stale) == 1 and not out.exists()
    # A live process's staging directory is left alone; a dead one's is removed.
    live = tmp_path / f".out.staging-{os.getppid()}-abc"
    live.mkdir()
    assert remove_stale_staging(out) == stale
    _write(out)
    assert sorted(os.listdir(tmp_path)) == sorted(["out", live.name])


def test_single_files(tmp_path):
    path = tmp_path / "r.json"
    atomic_write_json(path, {"x": float("nan"), "y": [1.5]})
    assert json.loads(path.read_text()) == {"x": None, "y": [1.5]}
    assert sorted(os.listdir(tmp_path)) == ["r.json"]
    with pytest.raises(OutputError, match="is a directory"):
        check_file_output(tmp_path, "--json")
    with pytest.raises(OutputError, match="does not exist"):
        check_file_output(tmp_path / "missing" / "x.json", "--json")
    with pytest.raises(OutputError, match="not a file this command wrote"):
        check_file_output(path, "--out", may_replace=lambda p: False)
    assert check_file_output(path, "--out", may_replace=lambda p: True) == str(path)


def test_an_output_is_intact_only_when_every_file_it_wrote_is_whole(tmp_path):
    """The marker records each file's size and SHA-256: a deleted, truncated or changed file
    makes the output damaged (issue 22: a rerun of a dataset whose left.png was deleted said
    'up to date')."""
    out = tmp_path / "out"
    _write(out, files=("a.txt", "b.txt"))
    output = OutputDir(out, "eval run")
    assert output.damage() is None
    (out / "a.txt").write_text("a.")  # same size, other bytes
    assert output.damage() == "a.txt changed since it was written"
    (out / "a.txt").write_text("a")
    assert output.damage() == "a.txt changed since it was written"
    (out / "a.txt").unlink()
    assert output.damage() == "a.txt is missing"
    marker = read_marker(out)
    del marker["sha256"]
    (out / MARKER_NAME).write_text(json.dumps(marker))
    assert "no record" in output.damage()


def test_atomic_create_never_replaces(tmp_path):
    from synth.infra.fileio import atomic_create_bytes

    path = tmp_path / "f.bin"
    atomic_create_bytes(path, b"first")
    with pytest.raises(FileExistsError):
        atomic_create_bytes(path, b"second")
    assert path.read_bytes() == b"first" and sorted(p.name for p in tmp_path.iterdir()) == ["f.bin"]


@pytest.mark.parametrize("path", ["", "  "])
def test_an_empty_output_path_is_named(tmp_path, monkeypatch, path):
    """The empty path is not "the current directory, which holds files of someone else"."""
    from synth.infra.fileio import check_file_output

    monkeypatch.chdir(tmp_path)
    with pytest.raises(OutputError, match="--out: the path is empty"):
        OutputDir(path, "eval run")
    with pytest.raises(OutputError, match="--out: the path is empty"):
        check_file_output(path, "--out")


def test_files_edited_by_hand_are_kept_before_a_rerun_replaces_them(tmp_path, capsys):
    """A rerun replaces its earlier output whole; a file the user changed since (notes added
    to a report, a tuned calibration) is copied to ``OUT.edited/`` first, and a note says so
    (issue 53: edited files were lost). Unchanged and missing files leave no copy."""
    out = OutputDir(tmp_path / "out", "eval test")
    for text in ("first", "second"):
        with out.staged() as tmp:
            for name in ("report.md", "calib.yaml", "sub/plot.txt"):
                os.makedirs(os.path.dirname(os.path.join(tmp, name)), exist_ok=True)
                with open(os.path.join(tmp, name), "w") as fh:
                    fh.write(f"{text} {name}\n")
        if text == "first":
            (tmp_path / "out" / "report.md").write_text("first report.md\nmy notes\n")
            (tmp_path / "out" / "sub" / "plot.txt").unlink()
            capsys.readouterr()
    assert (tmp_path / "out.edited" / "report.md").read_text() == "first report.md\nmy notes\n"
    assert sorted(p.name for p in (tmp_path / "out.edited").rglob("*") if p.is_file()) == [
        "report.md"]
    assert (tmp_path / "out" / "report.md").read_text() == "second report.md\n"
    assert "report.md in" in capsys.readouterr().err


def test_a_scene_edited_by_hand_is_not_overwritten(tmp_path, capsys):
    from synth.__main__ import main as synth_main

    scene = tmp_path / "mine.xml"
    argv = ["scene", "--layout", "grid", "--size", "320", "268", "--out", str(scene)]
    assert synth_main(argv) == 0 and synth_main(argv) == 0     # its own file: replaced
    scene.write_text(scene.read_text().replace('name="n_water" value="1.33"',
                                               'name="n_water" value="1.34"'))
    assert synth_main(argv) == 2
    assert "was edited since synth scene wrote it" in capsys.readouterr().err
    assert 'value="1.34"' in scene.read_text()


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_a_folder_that_takes_no_new_files_is_refused_at_the_claim(tmp_path):
    """``--out /proc/x``: root passes ``os.access`` there, and the refusal came only when the
    output was written, after the work (6 s of detection, issue 53). The claim now makes (and
    removes) a folder where the output would go, and a single file's check a file."""
    from synth.infra.fileio import check_file_output

    with pytest.raises(OutputError, match=r"--out /proc/x cannot be (created|replaced)"):
        OutputDir("/proc/x", "eval run").claim()
    with pytest.raises(OutputError, match=r"--out /proc/x.json: (no file can be written in "
                                          r"/proc|directory /proc is not writable)"):
        check_file_output("/proc/x.json", "--out")
    OutputDir(tmp_path / "fine", "eval run").claim()  # where a folder can be made: no probe left
    assert sorted(os.listdir(tmp_path)) == []
    assert check_file_output(str(tmp_path / "x.json"), "--out") and os.listdir(tmp_path) == []
