"""``python -m eval calibrate DIR``: in-air and housing calibration from rendered boards.

:mod:`.command` (parser and main), :mod:`.report` (summaries, calib.yaml, figures, report.md).
"""
