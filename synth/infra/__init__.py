"""Infrastructure both command lines share (``python -m synth`` and ``python -m eval``): the
parser house style, atomic output, interruption, the grammar of a spec of many runs, the Dask
cluster, tables, seeds and provenance. It lives in ``synth`` because ``synth`` may not import
``eval``, and ``eval`` imports ``synth``."""
