"""The per-point SciPy baseline of the benchmark solves the same problem as measure.geometry.projection."""

import numpy as np

from eval.cli import main
from eval.core.fermat_reference import fermat_pixel_scipy
from synth.scene.layouts import paper_plane
from measure.geometry.projection import project


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


def test_bench_sizes_option_and_a_small_run(capsys, tmp_path):
    from eval.bench import batch_sizes, format_table, run_bench

    assert batch_sizes("1e3,10^4,100000") == (1000, 10000, 100000)
    assert main(["bench", "--sizes", "1e8"]) == 2
    assert "--sizes" in capsys.readouterr().err
    results = run_bench(200, 5, 1, 0, progress=lambda text: None, sizes=(100,))
    rows = {(r["measurement"], r["port"]) for r in results["per_size"]}
    assert ("project_fermat_jacobian", "air-water") in rows
    assert ("triangulate_optical_path", "air-glass-water") in rows
    text = format_table(results)
    assert "machine:" in text and "load average" in text and "× project" in text
