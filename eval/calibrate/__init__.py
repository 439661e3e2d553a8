"""``python -m eval calibrate DIR``: in-air and housing calibration from rendered boards.

:mod:`.command` (main: which calibration a folder gets; its parser in :mod:`.options`),
:mod:`.report` (summaries, calib.yaml, figures, report.md).
"""
