"""``python -m eval run SCENE``: render (or reuse a dataset), detect, match, triangulate, score.

:mod:`.command` (parser and main), :mod:`.config` (the typed :class:`~eval.run.config.RunConfig`),
:mod:`.inputs` (scene, images, rigs), :mod:`.pipeline` (the stages and :func:`run_pipeline`),
:mod:`.report` (tables, report.md, PLY and figure files), :mod:`.figures`; dense surfaces:
:mod:`.dense`, :mod:`.dense_figures`.
"""
