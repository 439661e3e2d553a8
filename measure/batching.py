"""Run a row-wise vectorized function over large batches in chunks on all cores.

NumPy releases the GIL inside its array loops, so chunks of a few ten thousand rows processed by
a thread pool use every core and stay in cache. The results go straight into output arrays of
all rows (given, or allocated once when the first chunk is done), written by the thread that
computed the chunk while it is still in cache: no concatenation at the end. The output is
identical (bit for bit) to one call on the whole batch.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

DEFAULT_CHUNK_ROWS = 32768


def map_row_chunks(function, arrays, chunk_rows: int = DEFAULT_CHUNK_ROWS,
                   workers: int | None = None, outputs=None):
    """Apply ``function`` to consecutive row chunks of ``arrays``; the results, stacked along
    the rows as one call on all rows would give them.

    Without ``outputs``, ``function(*row_slices)`` returns a tuple of arrays whose first axis is
    the rows of its chunk (the same trailing shapes and dtypes for every chunk). With
    ``outputs`` (a list of arrays whose first axis is all rows), ``function(*row_slices, out)``
    fills ``out``, the list of the chunk's row slices of ``outputs``; ``outputs`` is returned.
    """
    n_rows = arrays[0].shape[0]
    if n_rows <= chunk_rows:
        if outputs is None:
            return function(*arrays)
        function(*arrays, outputs)
        return outputs
    starts = range(0, n_rows, chunk_rows)
    workers = workers or os.cpu_count() or 1
    filled = [] if outputs is None else list(outputs)
    lock = threading.Lock()

    def run(start):
        rows = slice(start, start + chunk_rows)
        if outputs is not None:
            function(*(a[rows] for a in arrays), [o[rows] for o in outputs])
            return
        parts = function(*(a[rows] for a in arrays))
        with lock:
            if not filled:
                filled.extend(np.empty((n_rows, *p.shape[1:]), dtype=p.dtype) for p in parts)
        for output, part in zip(filled, parts):
            output[rows] = part

    with ThreadPoolExecutor(max_workers=workers) as pool:
        for _ in pool.map(run, starts):  # re-raises the first exception of a chunk
            pass
    return tuple(filled) if outputs is None else outputs
