"""Ctrl-C of a real process: ``python -m eval sweep``, ``eval run``, ``synth dataset`` get a
SIGINT at several moments — as a terminal sends it, to the whole process group (the Dask
workers included) — and each must end with exit 130, exactly one line on stderr,
``error: interrupted``, no traceback and nothing on stdout; an interrupted sweep keeps the
cells it finished (a rerun resumes); an interrupted ``eval run`` or ``synth dataset`` leaves
nothing behind.

The moments are observed, not guessed: a sweep's worker processes appearing (the cluster
starting), its first cell file (cells running), all cells on disk and the workers gone (the
tables and figures). The sweeps here are analytic (no render: ``make test-fast`` runs them);
those that render are marked ``slow``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import REPO

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(),
                                reason="watches the sweep's processes through /proc (Linux)")

#: 100 analytic cells, one per task: a few seconds of cells between the cluster and the figures.
ANALYTIC_SPEC = """
name = "interrupt"
seed = 0
repeats = 5
scenes = ["{scene}"]
methods = ["optical_path", "su", "regular"]
cells_per_task = 1

[grid]
kind = ["analytic"]
noise_px = [0.0, 0.05, 0.1, 0.2]
"assume.n_water" = [1.33, 1.331, 1.332, 1.333, 1.334]
"""
ANALYTIC_CELLS = 100


#: Marks the processes a test starts (and the workers they start): found in /proc/*/environ.
TAG = "REFSTEREO_INTERRUPT_TEST"


def _env(tag: str = "") -> dict:
    path = os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    return dict(os.environ, PYTHONPATH=path, **{TAG: tag})


def _tagged(tag: str) -> list:
    """The processes still running with ``tag`` in their environment."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and f"{TAG}={tag}".encode() in (entry / "environ").read_bytes():
                found.append(int(entry.name))
        except OSError:
            continue
    return found


def _workers(pid: int) -> int:
    """How many multiprocessing workers (``spawn_main``) the process ``pid`` has started."""
    count = 0
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid and b"spawn_main" in cmdline:
            count += 1
    return count


def _interrupt(argv, cwd, ready, timeout=240.0):
    """Run ``python -m *argv`` in its own process group, wait until ``ready(process)`` is true,
    send SIGINT to the whole group (what a terminal's Ctrl-C does) and return
    ``(returncode, stdout, stderr, whether the signal was sent before the process ended)``."""
    tag = f"{os.getpid()}-{time.monotonic_ns()}"
    process = subprocess.Popen([sys.executable, "-m", *argv], cwd=cwd, env=_env(tag),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    sent = False
    try:
        deadline = time.monotonic() + timeout
        while process.poll() is None and time.monotonic() < deadline:
            if ready(process):
                break
            time.sleep(0.02)
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGINT)
            sent = True
        out, err = process.communicate(timeout=timeout)
        # nothing it started is left running (Dask's workers exit with it)
        deadline = time.monotonic() + 10
        while _tagged(tag) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _tagged(tag), "processes of the command outlived it"
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
        for pid in _tagged(tag):
            os.kill(pid, signal.SIGKILL)
    return process.returncode, out, err, sent


def _assert_interrupted(code, out, err, sent):
    assert sent, "the command ended before the signal could be sent"
    assert code == 130, err
    assert err.splitlines() == ["error: interrupted"], err
    assert out == "", out


def _after(seconds):
    start = time.monotonic()
    return lambda process: time.monotonic() - start >= seconds


def _cells(out: Path) -> int:
    return len(list((out / "cells").glob("*.json"))) if (out / "cells").is_dir() else 0


@pytest.fixture
def analytic_spec(tmp_path):
    path = tmp_path / "interrupt.toml"
    path.write_text(ANALYTIC_SPEC.replace("{scene}", str(REPO / "scenes" / "small_grid.xml")))
    return path


MOMENTS = {
    # while the modules load and the spec is read, before any worker exists
    "start-up": lambda out: _after(1.0),
    # the local cluster is starting: its worker processes have just appeared
    "cluster start-up": lambda out: lambda process: _workers(process.pid) > 0,
    # cells are coming in
    "cells running": lambda out: lambda process: _cells(out) >= 1,
    # every cell is on disk and the cluster is gone: the tables and figures are being made
    "tables and figures": lambda out: (lambda process: _cells(out) == ANALYTIC_CELLS
                                       and _workers(process.pid) == 0),
}


@pytest.mark.parametrize("moment", list(MOMENTS))
def test_sweep_interrupted(moment, analytic_spec, tmp_path):
    """Before this was fixed: a 30-line Dask traceback before ``error: interrupted`` (the
    workers got the signal too), an ``AssertionError: Status.init`` from Dask's ``atexit`` after
    an interrupted cluster start, ``Exception ignored … KeyboardInterrupt`` and exit 0 (the
    interrupt swallowed in a finalizer), or ``error: Invalid affine transformation matrix``
    (matplotlib's disguise of it) and exit 2."""
    from eval.sweep.directory import SweepDir
    from eval.sweep.spec import load_spec

    out = tmp_path / "out"
    code, stdout, stderr, sent = _interrupt(
        ["eval", "sweep", str(analytic_spec), "--out", str(out), "--workers", "2",
         "--no-progress"], tmp_path, MOMENTS[moment](out))
    _assert_interrupted(code, stdout, stderr, sent)
    if moment == "cells running":
        assert 1 <= _cells(out) < ANALYTIC_CELLS
    if moment == "tables and figures":
        assert _cells(out) == ANALYTIC_CELLS
    # what it finished is on disk, whole, and a rerun may use the directory (resumable)
    if out.exists():
        directory = SweepDir(out)
        assert directory.check() is not None
        keys = [cell.key for cell in load_spec(str(analytic_spec)).cells]
        assert len(directory.load_records(keys)) == _cells(out)


@pytest.mark.slow
def test_sweep_of_render_cells_interrupted_then_resumed(small_scene, tmp_path):
    """Render cells: the workers render with Mitsuba, whose own SIGINT handler printed
    ``WARN [integrator_v.cpp:38] Received interrupt signal, winding down..`` on stdout and cut
    the render short; now the workers never see the terminal's Ctrl-C. The rerun does the rest."""
    from eval.cli import main

    spec = tmp_path / "render.toml"
    spec.write_text(f'name = "render"\nseed = 0\nrepeats = 3\nscenes = ["{small_scene}"]\n'
                    f'methods = ["optical_path"]\n\n[fixed]\nspp = 16\n\n[grid]\n'
                    f'kind = ["render"]\nnoise_px = [0.0, 0.1]\n')
    out = tmp_path / "out"
    code, stdout, stderr, sent = _interrupt(
        ["eval", "sweep", str(spec), "--out", str(out), "--workers", "2", "--no-progress"],
        tmp_path, lambda process: _cells(out) >= 1)
    _assert_interrupted(code, stdout, stderr, sent)
    done = _cells(out)
    assert 1 <= done < 6
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "2", "--no-progress",
                 "--no-figures"]) == 0
    log = (out / "completions.log").read_text().split()
    assert _cells(out) == 6 and len(log) == 2 * 6  # each cell completed once


@pytest.mark.slow
@pytest.mark.parametrize("argv", [
    ["synth", "dataset", "{scene}", "--out", "out", "--spp", "1024", "--full-film", "--quiet"],
    ["eval", "run", "{scene}", "--out", "out", "--spp", "1024", "--full-film", "--no-progress"],
], ids=["synth dataset", "eval run"])
@pytest.mark.parametrize("seconds", [1.5, 4.0])
def test_render_commands_interrupted(argv, seconds, small_scene, tmp_path):
    """During Mitsuba's import, the scene's load or a render pass: one line, exit 130, no
    output directory and no staging directory left behind. (Before: ``error: internal error:
    NameError: name '_drjit_ext' is not defined`` and exit 1 when the signal came while Dr.Jit
    was being imported; Mitsuba's warnings on stdout.) 1024 spp make the render passes last
    far beyond the last moment (at 256 spp a fast CI machine had written its output within 4 s
    and exited 0); the signal ends them, so the test does not pay for them."""
    argv = [a.replace("{scene}", small_scene) for a in argv]
    code, stdout, stderr, sent = _interrupt(argv, tmp_path, _after(seconds))
    _assert_interrupted(code, stdout, stderr, sent)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.slow
def test_render_bench_stops_at_once(tmp_path):
    """Ctrl-C during eval render-bench's adaptive renders waited for the Dr.Jit kernel under
    way (13–46 s): the measurements run on a thread the command leaves, so it ends at once —
    one line, exit 130, nothing written."""
    stopped = {}

    def ready(process):
        if time.monotonic() - stopped.setdefault("start", time.monotonic()) >= 8.0:
            stopped["signal"] = time.monotonic()
            return True
        return False

    code, stdout, stderr, sent = _interrupt(
        ["eval", "render-bench", str(REPO / "scenes" / "paper_plane.xml"), "--parts", "adaptive",
         "--out", "rb", "--no-progress"], tmp_path, ready)
    waited = time.monotonic() - stopped["signal"]
    _assert_interrupted(code, stdout, stderr, sent)
    assert waited < 5.0, waited
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.slow
def test_mitsubas_interrupt_warning_stays_off_stdout(tmp_path):
    """A SIGINT while ``mi.render`` runs meets Mitsuba's own handler, which logged
    ``Received interrupt signal, winding down..`` to stdout; :func:`synth.rendering.mitsuba_setup.render`
    holds Mitsuba to errors during the call. The integrator below sends the signal from inside
    the render call; Dr.Jit then reports the interrupt as a RuntimeError, which
    :mod:`synth.infra.interrupt` still knows for what it is."""
    script = tmp_path / "render_interrupted.py"
    script.write_text('''
import os, signal, sys
from synth.infra import interrupt
from synth.rendering.mitsuba_setup import import_mitsuba, render
mi, _ = import_mitsuba()

class Interrupting(mi.SamplingIntegrator):
    def sample(self, scene, sampler, ray, medium=None, active=True):
        os.kill(os.getpid(), signal.SIGINT)
        return mi.Spectrum(1.0), mi.Bool(True), []

mi.register_integrator("interrupting", lambda props: Interrupting(props))
scene = mi.load_dict({"type": "scene", "sensor": {"type": "perspective",
                      "film": {"type": "hdrfilm", "width": 8, "height": 8}}})
call = render if sys.argv[1] == "quiet" else (lambda mi, s, **kw: mi.render(s, **kw))
with interrupt.handling():
    try:
        call(mi, scene, spp=1, integrator=mi.load_dict({"type": "interrupting"}))
    except BaseException:
        pass
    print("interrupted" if interrupt.requested() else "not interrupted", file=sys.stderr)
''')
    runs = {how: subprocess.run([sys.executable, str(script), how], cwd=tmp_path, env=_env(),
                                capture_output=True, text=True, timeout=240)
            for how in ("plain", "quiet")}
    # what the test guards against; Mitsuba's log goes to stderr (synth.rendering.mitsuba_setup.
    # log_to_stderr), so even a plain mi.render keeps it off stdout
    assert "Received interrupt signal" in runs["plain"].stderr
    assert "Received interrupt signal" not in runs["plain"].stdout
    assert runs["quiet"].stdout == "" and runs["quiet"].stderr.strip() == "interrupted"
