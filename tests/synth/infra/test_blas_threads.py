"""A command's BLAS runs on one thread unless the user says otherwise
(:func:`synth.infra.blas.one_blas_thread`, called by every command's ``process_main``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from synth.infra.blas import BLAS_THREAD_VARIABLES

#: After NumPy has loaded OpenBLAS (as ``synth.commands`` does on import): the threads each
#: BLAS library reports, as threadpoolctl reads them from the library itself.
PROBE = ("import json, numpy\n"
         "from synth.infra.blas import one_blas_thread\n"
         "from threadpoolctl import threadpool_info\n"
         "one_blas_thread()\n"
         "print(json.dumps([i['num_threads'] for i in threadpool_info() "
         "if i['user_api'] == 'blas']))\n")


def _blas_threads(**variables) -> list:
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    env.update(variables)
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True,
                         check=True, timeout=120).stdout
    return json.loads(out)


def test_numpys_blas_is_limited_to_one_thread():
    threads = _blas_threads()
    if not threads:
        pytest.skip("NumPy reports no BLAS library to threadpoolctl")
    assert threads == [1] * len(threads)


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: BLAS has one thread anyway")
def test_a_users_own_setting_is_kept():
    threads = _blas_threads(OPENBLAS_NUM_THREADS="2")
    if not threads:
        pytest.skip("NumPy reports no BLAS library to threadpoolctl")
    assert max(threads) == 2
