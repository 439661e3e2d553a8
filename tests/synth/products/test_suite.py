"""python -m synth suite: spec checks (the key and the file named), a small suite rendered on a
local cluster (index, suite.json, README, readable datasets), a rerun that does nothing, a resume
after a dataset is lost, the same suite through a real ``dask scheduler`` + ``dask worker`` pair
(the same bytes), an unreachable scheduler. Images 96 x 80 px at 2 spp; nothing is timed."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import socket
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from synth.commands import main
from synth.infra.grid import SpecError
from synth.products.suite import TIMING_COLUMNS, load_suite_spec
from tests.conftest import REPO
from tests.eval.sweep.test_sweep import dask_cluster  # noqa: F401  (a fixture)

SPEC = """
name = "tiny"
description = "two tiny target datasets"
seed = 5
scenes = ["{scene}"]
render = "targets"
render_width = 96

[fixed]
spp = 2

[grid]
"D.target_z" = [900, 1100]
"""


def _spec(tmp_path: Path, text: str = SPEC) -> Path:
    path = tmp_path / "suite.toml"
    path.write_text(text.replace("{scene}", str(REPO / "scenes" / "small_grid.xml")))
    return path


def _index(out: Path) -> list:
    rows = pq.read_table(out / "index.parquet").to_pylist()
    return [{k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in rows]


def _digests(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_the_committed_specs_expand():
    smoke = load_suite_spec(REPO / "suites" / "smoke.toml")
    assert len(smoke.entries) == 4 and smoke.swept == ["D.target_z", "D.n_water"]
    for name in ("targets_distance_water_tilt.toml", "surfaces_small.toml", "boards_small.toml",
                 "generated_small.toml"):
        spec = load_suite_spec(REPO / "suites" / name)
        assert spec.entries
    assert len(load_suite_spec(REPO / "suites" / "targets_distance_water_tilt.toml").entries) >= 24


@pytest.mark.parametrize("text, fragment", [
    ('scenes = ["{scene}"]\ncolour = 3', "unknown key 'colour'"),
    ('scenes = ["{scene}"]\n[grid]\n"D.nope" = [1]', "D.nope"),
    ('scenes = ["{scene}"]\n[grid]\nnoise_px = [1]', "unknown parameter 'noise_px'"),
    ('scenes = ["{scene}"]\nrender = "surface"', "is a target scene"),
    ('scenes = ["{scene}"]\n[fixed]\nsensor = "nikon"', "sensor = 'nikon'"),
    ('scenes = ["{scene}"]\n[fixed]\nspp = 0', "spp = 0"),
    ('scenes = ["{scene}"]\n[grid]\n"D.target_z" = []', "[grid] D.target_z is empty"),
    ('scenes = ["{scene}"]\n[fixed]\n"D.seed" = 3', "own seed"),
    ("scenes = [", "not a valid TOML file"),
])
def test_spec_errors_name_the_key_and_the_file(tmp_path, text, fragment):
    path = _spec(tmp_path, text)
    with pytest.raises(SpecError) as info:
        load_suite_spec(path)
    assert str(info.value).startswith(str(path)) and fragment in str(info.value)


def test_bad_spec_on_the_command_line_is_one_line(tmp_path, capsys):
    path = _spec(tmp_path, 'scenes = ["{scene}"]\n[grid]\n"D.nope" = [1]')
    assert main(["suite", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {path}") and "D.nope" in err[0]
    assert not (tmp_path / "out").exists()


def test_unreachable_scheduler_is_one_line(tmp_path, capsys):
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    out = tmp_path / "out"
    assert main(["suite", str(_spec(tmp_path)), "--out", str(out), "--scheduler",
                 f"tcp://127.0.0.1:{port}", "--connect-timeout", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --scheduler") and "answered" in err[0]
    assert not out.exists()


@pytest.fixture(scope="module")
def local_suite(tmp_path_factory):
    folder = tmp_path_factory.mktemp("suite")
    spec = _spec(folder)
    out = folder / "local"
    assert main(["suite", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    return spec, out


@pytest.mark.slow
def test_local_suite_writes_datasets_index_and_readme(local_suite, capsys):
    from synth.products.dataset import read_dataset

    spec, out = local_suite
    rows = pq.read_table(out / "index.parquet").to_pylist()
    assert [r["D.target_z"] for r in rows] == [900, 1100]
    assert all(r["status"] == "ok" and r["render_seconds"] > 0 for r in rows)
    assert (out / "index.csv").read_text().startswith('"folder","key","render"')
    info = json.loads((out / "suite.json").read_text())
    assert info["versions"]["python"] and [d["status"] for d in info["datasets"]] == ["ok"] * 2
    readme = (out / "README.md").read_text()
    assert "2 datasets" in readme and "eval score" in readme and "D.target_z" in readme
    for row in rows:
        dataset = read_dataset(out / row["folder"])
        assert dataset.manifest["seed"] == row["seed"] and dataset.left.shape == (80, 96)
    # a rerun of a finished suite does nothing
    capsys.readouterr()
    assert main(["suite", str(spec), "--out", str(out), "--no-progress"]) == 0
    assert "2 done before, 0 rendered now" in capsys.readouterr().out


@pytest.mark.slow
def test_the_count_and_progress_lines_without_a_terminal(tmp_path, capsys):
    """A suite says how many datasets it will render before it starts, and — its stderr not a
    terminal, where tqdm draws nothing — a progress line as it goes (1000 entries rendered with
    no word before)."""
    spec = _spec(tmp_path)
    assert main(["suite", str(spec), "--out", str(tmp_path / "s"), "--workers", "1"]) == 0
    err = capsys.readouterr().err
    assert ": 2 datasets, 2 to render now (0 done before)" in err
    assert "suite: 2/2 datasets (100 %), 0 failed" in err


@pytest.mark.slow
def test_a_lost_dataset_is_rendered_again_and_the_index_is_the_same(local_suite, tmp_path):
    spec, out = local_suite
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    before = _index(copy)
    folder = before[1]["folder"]
    (copy / folder / "left.png").write_bytes(b"cut")  # a damaged dataset is not finished
    assert main(["suite", str(spec), "--out", str(copy), "--workers", "1", "--no-progress"]) == 0
    assert _index(copy) == before
    assert _digests(copy / folder)["left.png"] == _digests(out / folder)["left.png"]


@pytest.mark.slow
def test_a_dask_cluster_renders_the_same_bytes(local_suite, dask_cluster, tmp_path):  # noqa: F811
    spec, out = local_suite
    remote = tmp_path / "remote"
    assert main(["suite", str(spec), "--out", str(remote), "--scheduler", dask_cluster,
                 "--no-progress"]) == 0
    assert _index(remote) == _index(out)
    for row in _index(out):
        mine, theirs = _digests(out / row["folder"]), _digests(remote / row["folder"])
        varying = {"manifest.json", ".refractive-stereo-output.json"}  # times, dates
        assert {k: v for k, v in mine.items() if k not in varying} == \
            {k: v for k, v in theirs.items() if k not in varying}
        m1 = json.loads((out / row["folder"] / "manifest.json").read_text())
        m2 = json.loads((remote / row["folder"] / "manifest.json").read_text())
        assert m1["sha256"] == m2["sha256"] and m1["request_key"] == m2["request_key"]


def test_another_spec_for_the_same_folder_is_refused(tmp_path, capsys):
    from synth.products.suite_folder import SuiteDir

    spec = load_suite_spec(_spec(tmp_path))
    out = SuiteDir(tmp_path / "out")
    out.open(spec, None, "token")
    (tmp_path / "out" / "suite.json").write_text(json.dumps({"spec_hash": "other"}))
    assert main(["suite", str(_spec(tmp_path)), "--out", str(tmp_path / "out")]) == 2
    assert "another spec" in capsys.readouterr().err


@pytest.mark.slow
def test_a_full_disk_is_one_error_line_and_what_finished_is_kept(tmp_path):
    """Files larger than RLIMIT_FSIZE cannot be written (EFBIG, SIGXFSZ ignored): the first
    small dataset fits, the second's noisy sensor images do not."""
    import resource
    import signal
    import subprocess
    import sys

    spec = _spec(tmp_path, SPEC.replace('"D.target_z" = [900, 1100]',
                                        '"D.width" = [96, 640]\n"D.height" = [80, 536]\n'
                                        'sensor = ["", "imx174"]').replace("[grid]", "[zip]"))

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, 60_000))

    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "synth", "suite", str(spec), "--out", str(out),
                           "--workers", "1", "--no-progress"], cwd=REPO, capture_output=True,
                          text=True, preexec_fn=limit, timeout=120)
    # (libpng, in the worker process, also says "libpng error: Write Error")
    err = [line for line in done.stderr.strip().splitlines() if "libpng" not in line]
    assert done.returncode == 2 and len(err) == 1, done.stderr
    assert err[0].startswith(f"error: --out {out}: cannot write") and "kept" in err[0]
    finished = list((out / "entries").glob("*.json"))
    assert len(finished) == 1 and "the 1 dataset(s) finished are kept" in err[0]
    assert not [p for p in out.iterdir() if ".staging-" in p.name]
    assert main(["suite", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0


@pytest.mark.slow
def test_a_worker_that_does_not_see_the_folder_sends_the_files_back(local_suite, tmp_path,
                                                                    monkeypatch):
    """The path of a cluster without a shared file system: the worker renders into a temporary
    folder and returns the bytes; the client writes them as a synth dataset output."""
    from synth.infra import cluster
    from synth.products.suite_folder import SuiteDir, render_task

    spec_path, out = local_suite
    spec = load_suite_spec(spec_path)
    entry = spec.entries[0]
    scene = spec.scenes[entry.scene]
    monkeypatch.setattr(cluster, "_SETUP_DONE", True)  # keep this process's thread counts
    result = render_task({"key": entry.key, "scene_sha": scene.sha256, "scene_data": scene.data,
                          "scene_path": scene.path, "params": entry.params,
                          "defines": entry.defines, "seed": entry.seed,
                          "out": str(tmp_path / "elsewhere" / entry.folder), "token": "other"})
    assert result["status"] == "ok" and "left.png" in result["files"]
    assert "colmap/cameras.txt" in result["files"]
    assert not (tmp_path / "elsewhere").exists()
    target = SuiteDir(tmp_path / "suite")
    target.write_dataset_files(entry.folder, result["files"], result["request_key"])
    varying = {"manifest.json", ".refractive-stereo-output.json"}
    mine = {k: v for k, v in _digests(out / entry.folder).items() if k not in varying}
    assert {k: v for k, v in _digests(tmp_path / "suite" / entry.folder).items()
            if k not in varying} == mine


@pytest.mark.slow
def test_a_suite_of_board_sequences(tmp_path):
    from synth.products.boards import read_boards

    spec = _spec(tmp_path, SPEC.replace('render = "targets"', 'render = "boards"').replace(
        "spp = 2", "spp = 2\nposes = 2\nsquares = \"7x4\"\nsquare_mm = 60").replace(
        '"D.target_z" = [900, 1100]', "air = [false, true]"))
    out = tmp_path / "boards"
    assert main(["suite", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    rows = pq.read_table(out / "index.parquet").to_pylist()
    assert [r["air"] for r in rows] == [False, True] and [r["poses"] for r in rows] == [2, 2]
    for row in rows:
        boards = read_boards(out / row["folder"])
        assert boards.manifest["air"] == row["air"] and boards.manifest["board"]["squares"] == [7, 4]


@pytest.mark.slow
def test_a_suite_of_a_scene_of_three_cameras_renders_every_camera(tmp_path):
    """A scene of three cameras (each behind its own port): each entry is a dataset of three
    camera folders with the truth of all three — never the first two as a stereo pair — and
    the index says how many cameras."""
    from synth.products.dataset import read_dataset

    scene = tmp_path / "three.xml"
    assert main(["scene", "--cameras", "3", "--port", "per-camera", "--layout", "grid",
                 "--spacing", "300", "--half-width", "600", "--target-radius", "15",
                 "--size", "96", "80", "--out", str(scene)]) == 0
    spec = tmp_path / "suite.toml"
    spec.write_text(SPEC.replace("{scene}", str(scene)))
    out = tmp_path / "three"
    assert main(["suite", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    rows = pq.read_table(out / "index.parquet").to_pylist()
    assert [r["cameras"] for r in rows] == [3, 3] and all(r["status"] == "ok" for r in rows)
    for row in rows:
        data = read_dataset(out / row["folder"])
        assert data.names == ("cam0", "cam1", "cam2") and len(data.images) == 3
        assert data.targets[0, 2] == row["D.target_z"]


@pytest.mark.parametrize("text, fragment", [
    ('render = "boards"\n[fixed]\nsensor = "imx174"', "board sequences have no sensor"),
    ('[fixed]\nposes = 3', "a parameter of board sequences"),
    ('render = "boards"\n[fixed]\nsquares = "1x1"', "squares"),
    ('render = "boards"\n[grid]\n"D.target_z" = [1000]', "does not apply to board sequences"),
])
def test_board_parameters_are_checked(tmp_path, text, fragment):
    path = _spec(tmp_path, 'scenes = ["{scene}"]\n' + text)
    with pytest.raises(SpecError, match=re.escape(fragment)):
        load_suite_spec(path)


def test_another_spec_after_a_suite_stopped_before_its_suite_json_is_refused(tmp_path, capsys):
    """A suite interrupted before its first ``suite.json`` (only the marker, ``spec.toml`` and
    ``entries/``), then another spec on the same ``--out``: refused (it was accepted, two suites
    mixed in one folder and ``spec.toml`` overwritten); the same spec resumes."""
    from synth.products.suite_folder import SuiteDir

    first = tmp_path / "a"
    first.mkdir()
    spec = load_suite_spec(_spec(first))
    out = SuiteDir(tmp_path / "out")
    out.open(spec, None, "token")
    out._lock.close()  # the process was stopped: its lock is gone
    assert not (tmp_path / "out" / "suite.json").exists()
    spec_toml = (tmp_path / "out" / "spec.toml").read_text()
    other = _spec(tmp_path, SPEC.replace("[900, 1100]", "[800, 1200]"))
    assert main(["suite", str(other), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds a suite of another spec" in err[0], err
    assert str(first / "suite.toml") in err[0]
    assert (tmp_path / "out" / "spec.toml").read_text() == spec_toml
    assert SuiteDir(tmp_path / "out").check()["spec_hash"] == spec.spec_hash()
