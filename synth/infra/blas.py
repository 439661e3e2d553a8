"""How many threads a command's dense algebra (BLAS: OpenBLAS, MKL, OpenMP) runs on."""

from __future__ import annotations

import os
import sys

#: The variables that set how many threads BLAS (OpenBLAS, MKL, OpenMP) uses.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """A command's dense algebra on one BLAS thread, unless the user set one of
    :data:`BLAS_THREAD_VARIABLES`: the variables for what loads BLAS later (and for the
    processes the command starts), ``threadpoolctl`` for a BLAS NumPy has already loaded. The
    fits' matrices are small (a housing fit of a real rig: 16,224 × 42); OpenBLAS's second
    thread only spun while it waited, taking the core from the command's other threads (that fit
    took 18.0 s and 25.7 s of CPU with it, 14.0 s and 13.5 s without, on the 2-core machine
    with nothing else running: docs/speed.md)."""
    if any(os.environ.get(name) for name in BLAS_THREAD_VARIABLES):
        return
    for name in BLAS_THREAD_VARIABLES:
        os.environ[name] = "1"
    if "numpy" in sys.modules:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1, user_api="blas")


__all__ = ["BLAS_THREAD_VARIABLES", "one_blas_thread"]
