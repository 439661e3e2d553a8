"""python -m eval sweep: spec checks, a local run, the same sweep through a real Dask cluster
(a ``dask scheduler`` and two ``dask worker`` processes on localhost), a sweep killed with
SIGKILL half-way and rerun, and bad input. Small images (320 x 268, 4 spp); nothing is timed."""

from __future__ import annotations

import collections
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
import pytest

from eval.cli import main
from eval.sweep.table import TIMING_COLUMNS
from eval.sweep.spec import SpecError, load_spec
from tests.conftest import REPO

BIN = Path(sys.executable).parent

#: 16 cells: 8 render (eval run) and 8 analytic; the render cells with a matching gate of
#: 1e-6 mm match nothing and fail (their rows say why), the sweep goes on.
SPEC = """
name = "tiny"
seed = 3
repeats = 2
scenes = ["{scene}"]
methods = ["optical_path", "su", "regular"]

[fixed]
spp = 4

[grid]
kind = ["render", "analytic"]
noise_px = [0.0, 0.1]
gate_mm = [0.5, 1e-6]

[zip]
"assume.n_water" = [1.332]
"""


def _spec(tmp_path: Path, scene: str, text: str = SPEC, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(text.replace("{scene}", scene))
    return path


def _table(out: Path) -> list:
    rows = pq.read_table(out / "results.parquet").to_pylist()
    return [{k: v for k, v in row.items() if not TIMING_COLUMNS.match(k)} for row in rows]


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return env


@pytest.fixture(scope="module")
def spec_file(small_scene, tmp_path_factory):
    return _spec(tmp_path_factory.mktemp("spec"), small_scene)


@pytest.fixture(scope="module")
def local_run(spec_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("local") / "out"
    code = main(["sweep", str(spec_file), "--out", str(out), "--workers", "2", "--no-progress",
                 "--no-figures"])
    return out, code


# ------------------------------------------------------------------------------------------------
# the spec


def test_spec_expands_into_keyed_seeded_cells(spec_file):
    spec = load_spec(spec_file)
    assert len(spec.cells) == 16
    assert len({c.key for c in spec.cells}) == 16 and len({c.seed for c in spec.cells}) == 16
    assert load_spec(spec_file).cells == spec.cells  # deterministic
    assert spec.swept == ["kind", "noise_px", "gate_mm"]
    assert {c.repeat for c in spec.cells} == {0, 1}


def test_random_samples_and_zip(small_scene, tmp_path):
    text = """
scenes = ["{scene}"]
repeats = 2

[fixed]
kind = "analytic"

[zip]
"D.target_z" = [900, 1100]
"D.target_radius" = [14, 18]

[random]
samples = 3
seed = 7
noise_px = { uniform = [0.0, 0.2] }
self_calibrate = { choice = [false, true] }

[grid]
gate_mm = [0.5, 1.0]
"""
    spec = load_spec(_spec(tmp_path, small_scene, text))
    assert len(spec.cells) == 2 * 3 * 2 * 2  # zip x samples x grid x repeats
    pairs = {(c.params["D.target_z"], c.params["D.target_radius"]) for c in spec.cells}
    assert pairs == {(900, 14), (1100, 18)}
    noise = sorted({c.params["noise_px"] for c in spec.cells})
    assert len(noise) == 3 and all(0 <= v <= 0.2 for v in noise)
    assert {c.params["self_calibrate"] for c in spec.cells} <= {"", "n_water"}
    assert load_spec(tmp_path / "spec.toml").cells == spec.cells


def test_detection_options_reach_eval_run(small_scene, tmp_path):
    """The detection options of a spec become eval run's options of the same names."""
    from eval.sweep.cells import run_config

    text = ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\nmax_elongation = 3\n'
            'max_area_ratio = 6\nmedian_filter = 3\n')
    cell = load_spec(_spec(tmp_path, small_scene, text)).cells[0]
    config = run_config({"params": cell.params, "seed": 1, "methods": ["optical_path"],
                         "defines": {}}, "scene.xml")
    assert config.max_elongation == 3 and config.max_area_ratio == 6
    assert config.median_filter == 3


@pytest.mark.parametrize("text, fragment", [
    ("scenes = [", "not a valid TOML"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\n[grid]\nfoo = [1]', "unknown parameter 'foo'"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\n"D.nope" = 1', "unknown parameter D.nope"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\n"assume.nope" = 1', "assume.nope"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\n[grid]\nnoise_px = []', "empty"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\nnoise_px = -1', "noise_px = -1"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\n"D.n_water" = -1.3', "n_water"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\n"assume.n_water" = 0.5', "index >= 1"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\n"D.seed" = 3', "own seed"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "magic"', "kind"),
    ('scenes = ["{scene}"]\n[zip]\nkind = ["render"]\nnoise_px = [0, 1]', "one length"),
    ('scenes = ["missing.xml"]\n[fixed]\nkind = "render"', "missing.xml"),
    ('scenes = ["{scene}"]\nrepeats = 0\n[fixed]\nkind = "render"', "repeats"),
    ('scenes = ["{scene}"]\n[random]\nnoise_px = { normal = [0, 1] }', "uniform"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\nmedian_filter = 4', "median_filter"),
    ('scenes = ["{scene}"]\n[fixed]\nkind = "render"\nmax_elongation = 1', "max_elongation"),
])
def test_bad_specs_exit_2_with_one_line(small_scene, tmp_path, capsys, text, fragment):
    spec = _spec(tmp_path, small_scene, text)
    with pytest.raises(SpecError):
        load_spec(spec)
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0], err
    assert not out.exists()


# ------------------------------------------------------------------------------------------------
# a local run


@pytest.mark.slow
def test_local_run_writes_one_row_per_cell(local_run, spec_file):
    out, code = local_run
    assert code == 1  # the failing render cells make the exit code say so
    rows = _table(out)
    spec = load_spec(spec_file)
    assert [r["key"] for r in rows] == [c.key for c in spec.cells]
    csv_rows = pa_csv.read_csv(out / "results.csv").to_pylist()
    assert len(csv_rows) == 16 and [r["key"] for r in csv_rows] == [r["key"] for r in rows]
    failed = [r for r in rows if r["status"] == "failed"]
    assert len(failed) == 4
    assert all(r["kind"] == "render" and r["gate_mm"] == 1e-6 for r in failed)
    assert all("NothingMatched" in r["error"] for r in failed)
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) == 12
    for row in ok:
        assert row["noise_px"] in (0.0, 0.1) and row["seed"] is not None
        for method in ("optical_path", "su", "regular"):
            assert row[f"methods.{method}.rms_dp_mm"] > 0
    render = [r for r in ok if r["kind"] == "render"]
    assert all(r["matching.wrong"] == 0 and r["matching.correct"] > 0 for r in render)
    analytic = [r for r in ok if r["kind"] == "analytic"]
    # the analytic cells see all 81 targets; the measurement assumes a water index 0.15 % too
    # high, and the depth comes out about 1.6 mm too far at 1 m
    assert all(r["methods.optical_path.n"] == 81 for r in analytic)
    clean = [r for r in analytic if r["noise_px"] == 0]
    assert all(0.5 < r["methods.optical_path.mean_dz_mm"] < 3 for r in clean)
    assert all(r["methods.optical_path.std_dz_mm"] < 1 for r in clean)
    # the per-cell reports: eval run's report for render cells
    record = json.loads((out / "cells" / f"{render[0]['key']}.json").read_text())
    assert record["report"]["matching"]["pairs"] > 0 and record["run_id"]
    assert (out / "sweep.json").exists() and (out / "spec.toml").exists()


@pytest.mark.slow
def test_render_cell_equals_eval_run(local_run, small_scene, tmp_path):
    """A render cell is eval run with the same arguments: the same numbers."""
    out, _ = local_run
    row = next(r for r in _table(out) if r["kind"] == "render" and r["status"] == "ok"
               and r["noise_px"] == 0.1)
    run_out = tmp_path / "run"
    code = main(["run", small_scene, "--out", str(run_out), "--no-progress", "--spp", "4",
                 "--seed", str(row["seed"]), "--noise-px", "0.1", "--assume", "n_water=1.332",
                 "-D", "width=320", "-D", "height=268"])
    report = json.loads((run_out / "report.json").read_text())
    # eval run's exit code is its verdict's (a cell with fewer than half matched fails the run;
    # the sweep records its numbers all the same)
    assert code == (0 if report["verdict"]["passed"] else 1)
    for method in ("optical_path", "su", "regular"):
        assert report["methods"][method]["rms_dp_mm"] == row[f"methods.{method}.rms_dp_mm"]
    assert report["matching"]["correct"] == row["matching.correct"]


@pytest.mark.slow
def test_a_render_cell_keeps_what_save_asks_for_and_draws_no_figure_for_ply(small_scene,
                                                                           tmp_path,
                                                                           monkeypatch):
    """``save = ["ply"]``: the point clouds and covariance tables, and no figure drawn for
    nothing; ``save = ["figures"]``: the figures only."""
    import eval.run.figures
    from eval.sweep.cells import render_cell

    text = 'scenes = ["{scene}"]\n[fixed]\nkind = "render"\nspp = 4\n'
    cell = load_spec(_spec(tmp_path, small_scene, text)).cells[0]
    record = {"params": cell.params, "seed": 1, "methods": ["optical_path"], "defines": {},
              "scene": small_scene}
    drawn, views = [], eval.run.figures.views_figure
    monkeypatch.setattr(eval.run.figures, "views_figure",
                        lambda path, *args: drawn.append(path) or views(path, *args))
    _, ply = render_cell(record, small_scene, ("ply",))
    assert drawn == []
    assert sorted(ply) == ["points_optical_path.ply", "points_optical_path_all.ply",
                           "uncertainty_optical_path.csv", "uncertainty_optical_path.ply"]
    _, figures = render_cell(record, small_scene, ("figures",))
    assert len(drawn) == 1
    assert sorted(figures) == ["ellipses.png", "error_maps.png", "histograms.png", "views.png"]


@pytest.mark.slow
def test_rerun_does_nothing_and_changed_spec_is_refused(local_run, spec_file, small_scene,
                                                        tmp_path, capsys):
    out, _ = local_run
    before = (out / "completions.log").read_text()
    assert main(["sweep", str(spec_file), "--out", str(out), "--no-progress",
                 "--no-figures"]) == 1
    assert (out / "completions.log").read_text() == before  # no cell ran again
    assert "16 done before, 0 ran now" in capsys.readouterr().out
    changed = _spec(tmp_path, small_scene, SPEC.replace("seed = 3", "seed = 4"))
    assert main(["sweep", str(changed), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another spec" in err[0] and "--allow-changed-spec" in err[0]
    assert (out / "completions.log").read_text() == before


@pytest.mark.slow
def test_figures(local_run, spec_file, tmp_path):
    from eval.sweep.directory import SweepDir
    from eval.sweep.table import table_rows
    from eval.sweep.figures import write_figures

    out, _ = local_run
    spec = load_spec(spec_file)
    rows = table_rows(spec, SweepDir(out).load_records([c.key for c in spec.cells]))
    spec.grid = {"noise_px": spec.grid["noise_px"]}  # one swept parameter: two figures
    paths = write_figures(str(tmp_path), spec, rows)
    assert sorted(Path(p).name for p in paths) == ["noise_px__cell.png", "noise_px__methods.png"]
    assert all(Path(p).stat().st_size > 5000 for p in paths)


def test_foreign_directory_is_refused(spec_file, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["sweep", str(spec_file), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "did not write" in err[0]
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


# ------------------------------------------------------------------------------------------------
# a real cluster on localhost


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """``dask scheduler`` and two single-threaded ``dask worker`` processes; torn down always."""
    folder = tmp_path_factory.mktemp("dask")
    scheduler_file = folder / "scheduler.json"
    processes = []
    try:
        processes.append(subprocess.Popen(
            [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0",
             "--no-dashboard", "--scheduler-file", str(scheduler_file)],
            env=_env(), cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True))
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        for _ in range(2):
            processes.append(subprocess.Popen(
                [str(BIN / "dask"), "worker", address, "--nthreads", "1", "--nworkers", "1",
                 "--no-dashboard"], env=_env(), cwd=folder, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL, start_new_session=True))
        yield address
    finally:
        for process in reversed(processes):
            process.terminate()
        for process in reversed(processes):
            try:
                process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()


@pytest.mark.slow
def test_cluster_run_equals_local_run_cell_by_cell(local_run, spec_file, dask_cluster,
                                                   tmp_path, capsys):
    out, _ = local_run
    remote = tmp_path / "remote"
    assert main(["sweep", str(spec_file), "--out", str(remote), "--scheduler", dask_cluster,
                 "--no-progress", "--no-figures", "--connect-timeout", "30"]) == 1
    assert f"of {dask_cluster}" in capsys.readouterr().out
    local_rows, remote_rows = _table(out), _table(remote)
    assert len(remote_rows) == 16
    for a, b in zip(local_rows, remote_rows):
        assert a == b


def test_a_service_that_is_not_a_scheduler(spec_file, tmp_path, capsys):
    """Something answers at the address, but not in Dask's protocol: one error line, exit 2,
    no traceback (Dask reads the reply as an exabyte message length: a MemoryError)."""
    import socket
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(4)
    port = server.getsockname()[1]

    def answer():
        while True:
            try:
                connection, _ = server.accept()
            except OSError:
                return
            try:
                connection.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" * 4)
            except OSError:
                pass

    threading.Thread(target=answer, daemon=True).start()
    out = tmp_path / "out"
    try:
        code = main(["sweep", str(spec_file), "--out", str(out), "--no-progress",
                     "--scheduler", f"tcp://127.0.0.1:{port}", "--connect-timeout", "2"])
    finally:
        server.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error:"), err
    assert "Dask" in err[0] and not out.exists()


def test_unreachable_scheduler_fails_fast(spec_file, tmp_path, capsys):
    with socket.socket() as s:  # a port where nothing listens
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "out"
    start = time.monotonic()
    assert main(["sweep", str(spec_file), "--out", str(out), "--no-progress",
                 "--scheduler", f"tcp://127.0.0.1:{port}", "--connect-timeout", "2"]) == 2
    assert time.monotonic() - start < 30
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --scheduler") and "answered" in err[0]
    assert not out.exists()


@pytest.mark.parametrize("extra, fragment", [
    (["--scheduler", "not an address"], "tcp://HOST:PORT"),
    (["--scheduler", "tcp://127.0.0.1:1", "--workers", "2"], "--workers"),
    (["--workers", "0"], "--workers"),
    (["--workers", "100000"], "per core"),
])
def test_bad_options(spec_file, tmp_path, capsys, extra, fragment):
    out = tmp_path / "out"
    assert main(["sweep", str(spec_file), "--out", str(out), "--no-progress", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and fragment in err[0]
    assert not out.exists()


# ------------------------------------------------------------------------------------------------
# killed half-way


@pytest.mark.slow
def test_sigkill_half_way_then_rerun_equals_uninterrupted(local_run, spec_file, tmp_path):
    out, _ = local_run
    killed = tmp_path / "killed"
    process = subprocess.Popen(
        [sys.executable, "-m", "eval", "sweep", str(spec_file), "--out", str(killed),
         "--workers", "1", "--no-progress", "--no-figures"], cwd=REPO, env=_env(),
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and process.poll() is None:
            cells = list((killed / "cells").glob("*.json")) if (killed / "cells").exists() else []
            if len(cells) >= 4:
                break
            time.sleep(0.05)
        assert process.poll() is None, "the sweep ended before it could be killed"
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    done_before = len(list((killed / "cells").glob("*.json")))
    assert 4 <= done_before < 16
    assert main(["sweep", str(spec_file), "--out", str(killed), "--workers", "2",
                 "--no-progress", "--no-figures"]) == 1
    assert _table(killed) == _table(out)
    completions = [line.split() for line in (killed / "completions.log").read_text().splitlines()]
    counts = collections.Counter(key for key, _ in completions)
    assert len(counts) == 16 and max(counts.values()) == 1  # no cell completed twice
    runs = {run for _, run in completions}
    assert len(runs) == 2
    assert not [p for p in killed.rglob("*") if re.match(r"^\..*\.tmp$", p.name)]


ANALYTIC = """
name = "analytic"
seed = 1
repeats = 1
scenes = ["{scene}"]
methods = ["optical_path"]

[grid]
kind = ["analytic"]
noise_px = [0.0, 0.1]
"""


@pytest.mark.slow
def test_the_time_said_is_the_runs_and_a_finished_sweep_is_not_drawn_again(
        small_scene, tmp_path, capsys, monkeypatch):
    """The printed time covers the figures ("in 12.9 s" was said of a 47.9 s run); a rerun of
    a finished sweep keeps the figures drawn from the same table (it drew them again: 31 s to
    do nothing); a missing figure is drawn again."""
    import re
    import time as time_module

    import eval.sweep.figures as figures_module

    drawn = []

    def slow_figures(directory, spec, rows):
        drawn.append(len(rows))
        time_module.sleep(1.5)
        os.makedirs(directory, exist_ok=True)
        path = os.path.join(directory, "noise_px__cell.png")
        Path(path).write_bytes(b"png")
        return [path]

    monkeypatch.setattr(figures_module, "write_figures", slow_figures)
    spec = _spec(tmp_path, small_scene, ANALYTIC)
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    said = capsys.readouterr().out
    assert drawn == [2]
    assert float(re.search(r" in ([0-9.]+) s", said).group(1)) >= 1.5, said
    assert main(["sweep", str(spec), "--out", str(out), "--no-progress"]) == 0
    said = capsys.readouterr().out
    assert drawn == [2] and "2 done before, 0 ran now" in said and "1 figure(s)" in said
    assert float(re.search(r" in ([0-9.]+) s", said).group(1)) < 1.5
    (out / "figures" / "noise_px__cell.png").unlink()
    assert main(["sweep", str(spec), "--out", str(out), "--no-progress"]) == 0
    assert drawn == [2, 2] and (out / "figures" / "noise_px__cell.png").is_file()
