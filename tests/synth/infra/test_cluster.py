"""The local Dask cluster: its workers start without Dask's ``MALLOC_TRIM_THRESHOLD_`` (which
doubles the CPU time of NumPy code that makes large arrays: synth.infra.cluster)."""

from __future__ import annotations

import os

from synth.infra.cluster import connect


def _no_probe() -> bool:
    return True


def _environment() -> tuple:
    return os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("OMP_NUM_THREADS")


def test_local_workers_keep_glibcs_dynamic_mmap_threshold():
    client, cluster, where = connect(None, 1, 5.0, _no_probe, "nothing")
    try:
        found = list(client.run(_environment).values())
    finally:
        client.close()
        cluster.close()
    assert where == "1 local single-threaded worker(s)"
    assert found == [(None, "1")]  # Dask's other settings stay: one thread per worker
