"""``python -m eval paper``: section 3 of Li et al. 2024 on the analytic simulator — the
experiments (:mod:`eval.paper.experiments`), the claims, the report and figures 4-10."""

from __future__ import annotations

import time
from pathlib import Path

from eval.cli import non_negative_int, positive_int
from eval.paper.settings import NAME
from synth.infra.cli import add_out_option, add_progress_option


def add_parser(subparsers) -> None:
    """``python -m eval paper [--out DIR] [--trials N] [--seed S] [--no-progress]``."""
    parser = subparsers.add_parser(
        NAME, help="reproduce section 3 of Li et al. 2024 on the analytic simulator",
        description="Reproduce section 3 of Li et al. 2024 (ray gap, ideal, pixel noise, "
                    "water-index deviation) on the analytic simulator; writes report.json, "
                    "report.md and figures 4-10 (PNG) into --out.")
    add_out_option(parser, f"eval {NAME}", "out/paper")
    parser.add_argument("--trials", type=positive_int, default=100, metavar="N",
                        help="Monte-Carlo noise trials (default: 100)")
    parser.add_argument("--seed", type=non_negative_int, default=0, metavar="S",
                        help="seed of the pixel noise (default: 0)")
    add_progress_option(parser)


def main(args) -> int:
    """Run the experiments and write the report and figures into ``args.out`` (whole or not at
    all; the ``--out`` rule of :class:`synth.infra.fileio.OutputDir` is checked first)."""
    from eval.paper.figures import write_figures  # matplotlib: only when needed
    from eval.paper.report import write_reports
    from eval.paper.experiments import run_experiments
    from synth.infra.fileio import OutputDir

    start = time.perf_counter()
    output = OutputDir(args.out, f"eval {NAME}").claim()
    results = run_experiments(args.trials, args.seed, progress=not args.no_progress)
    with output.staged() as tmp:
        figures = write_figures(results, tmp)
        results["wall_seconds"] = time.perf_counter() - start
        paths = write_reports(results, tmp, figures)
    held = sum(c["holds"] for c in results["claims"])
    print(f"paper: {held}/{len(results['claims'])} claims hold; wrote "
          f"{', '.join(str(Path(p).name) for p in paths)} and {len(figures)} figures to "
          f"{output.path} in {time.perf_counter() - start:.1f} s")
    return 0
