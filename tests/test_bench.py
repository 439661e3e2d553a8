"""The per-point SciPy baseline of the benchmark solves the same problem as measure.projection."""

import numpy as np

from eval.cli import main
from eval.fermat_reference import fermat_pixel_scipy
from synth.layouts import paper_plane
from measure.projection import project


def test_scipy_reference_agrees_with_the_vectorized_fermat_solver(rig):
    points = paper_plane(1000.0)[::40]
    for camera in rig.cameras:
        reference = np.array([fermat_pixel_scipy(camera, rig.port, p) for p in points])
        # BFGS stops on its gradient tolerance; 1e-3 px is far below anything that matters and
        # far above the vectorized solver's own error (1e-12 px against the Snell solver).
        assert np.max(np.abs(reference - project(camera, rig.port, points))) < 1e-3


def test_bench_rejects_bad_arguments(capsys):
    assert main(["bench", "--points", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "--points" in err[0]
