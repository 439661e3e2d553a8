"""``python -m eval sweep SPEC.toml``: many runs over a grid of parameters, on Dask.

:mod:`.command` (parser, main, the sweep directory and its table), :mod:`.spec` (the TOML
grammar), :mod:`.cells` (what a worker does with a cell), :mod:`.figures`.
"""
