"""``python -m eval paper``: section 3 of Li et al. 2024 on the analytic simulator.

:mod:`.command` (parser and main), :mod:`.experiments`, :mod:`.claims`, :mod:`.report`,
:mod:`.figures`, :mod:`.settings` (the paper's numbers).
"""
