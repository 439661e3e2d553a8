"""``python -m eval measure``: measure a user's stereo photos with a calibration and no truth.

Modules: :mod:`eval.measure.command` (the command line), :mod:`eval.measure.inputs` (the
calibration and the photo pairs, checked), :mod:`eval.measure.pipeline` (detect, match,
triangulate one pair; or dense matching), :mod:`eval.measure.report` (statistics, plane fit,
``report.json`` / ``report.md`` / ``points.csv`` / ``points.ply``),
:mod:`eval.measure.figures` (``views.png``).
"""
