"""What start-up loads: ``import measure`` and every command's ``--help`` and argument errors
(both command lines) import none of the heavy modules — they load when the work needs them.

Each check runs in a fresh interpreter and reads its ``sys.modules``; nothing is timed here (the
times are measured by ``tools/bench_speed.py``, docs/speed.md)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.conftest import REPO

#: Loaded by neither command line before a command runs.
HEAVY = ("scipy", "mitsuba", "drjit", "open3d", "matplotlib", "dask", "distributed", "pyarrow")

#: Run ``CODE`` in a fresh interpreter, then print the top-level names of the modules loaded.
PROBE = """
import json, sys
{code}
print(json.dumps(sorted(set(sys.modules))))
"""


def loaded_modules(code: str) -> set:
    """Every module in ``sys.modules`` after ``code`` ran in a fresh interpreter."""
    env = dict(os.environ, PYTHONPATH=str(REPO))  # this checkout, not another editable one
    done = subprocess.run([sys.executable, "-c", PROBE.format(code=code)], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.splitlines()[-1]))


def heavy_among(modules: set, heavy=HEAVY) -> list:
    """The packages of ``heavy`` that ``modules`` hold (a submodule counts for its package)."""
    return sorted({m.split(".")[0] for m in modules} & set(heavy))


def test_import_measure_loads_no_numerical_library():
    modules = loaded_modules("import measure")
    assert "measure" in modules
    assert heavy_among(modules, HEAVY + ("numpy", "cv2")) == []


def test_measure_public_names_load_what_they_need_and_no_optimizer():
    """``from measure import …`` of the README's names gives the very objects of their modules
    and loads neither SciPy's optimizer, its sparse matrices nor its statistics."""
    modules = loaded_modules(
        "from measure import Camera, FlatPort, StereoRig, triangulate, detect_targets\n"
        "import measure.geometry.camera as c, measure.stereo.triangulate as t\n"
        "assert Camera is c.Camera and StereoRig is t.StereoRig and triangulate is t.triangulate")
    assert {"numpy", "cv2", "measure.stereo.triangulate"} <= modules
    assert heavy_among(modules, ("mitsuba", "open3d", "matplotlib")) == []
    assert not {"scipy.optimize", "scipy.sparse", "scipy.stats"} & modules


def test_measure_public_names_all_resolve():
    import measure

    for name in measure.__all__:
        assert getattr(measure, name) is not None, name
    assert set(measure.__all__) <= set(dir(measure))
    with pytest.raises(AttributeError, match="no_such_name"):
        measure.no_such_name  # noqa: B018


#: Every command's --help, then an unknown option (an argument error), run in one interpreter.
HELP_AND_ERRORS = """
import argparse, contextlib, io
from {module} import build_parser, main
commands = next(a for a in build_parser()._actions
                if isinstance(a, argparse._SubParsersAction)).choices
assert len(commands) >= {at_least}, commands
for argv in [["--help"]] + [[c, "--help"] for c in commands] + [[c, "--no-such-option"]
                                                               for c in commands]:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as stop:
            code = stop.code
    assert code == (0 if argv[-1] == "--help" else 2), (argv, code)
"""


@pytest.mark.parametrize("module, at_least", [("eval.cli", 11), ("synth.commands", 8)])
def test_help_and_argument_errors_load_no_heavy_module(module, at_least):
    modules = loaded_modules(HELP_AND_ERRORS.format(module=module, at_least=at_least))
    assert heavy_among(modules) == []


def test_eval_run_help_through_python_m():
    """``python -m eval run --help`` as a user types it."""
    modules = loaded_modules("import runpy\nsys.argv = ['eval', 'run', '--help']\n"
                             "try:\n    runpy.run_module('eval', run_name='__main__')\n"
                             "except SystemExit as stop:\n    assert stop.code == 0, stop.code")
    assert "eval.run.command" in modules
    assert heavy_among(modules) == []


@pytest.mark.parametrize("option", [["--depth-range", "5"], ["--sensor", "nikon"]])
def test_eval_run_refuses_a_bad_option_before_loading_the_pipeline(option, tmp_path):
    """An option ``eval run`` checks itself (not argparse) is refused before SciPy, Open3D or
    Mitsuba load, and nothing is written."""
    out = tmp_path / "out"
    argv = ["run", "scenes/paper_plane.xml", "--out", str(out), "--no-progress", *option]
    modules = loaded_modules("import contextlib, io\nfrom eval.cli import main\n"
                             "with contextlib.redirect_stderr(io.StringIO()):\n"
                             f"    assert main({argv!r}) == 2")
    assert heavy_among(modules) == [] and not out.exists()
