"""eval — the command line (``python -m eval <command>``), the paper's experiments, reports.

Subcommands live in their own modules (see :mod:`eval.cli`); ``paper`` reproduces section 3 of
Li et al. 2024 on the analytic simulator (:mod:`eval.paper`).
"""
