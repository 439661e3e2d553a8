"""The end of an ``eval calibrate`` of a pair: the calibration files it writes
(:func:`write_calibrations`), the lines it prints once they are written (:func:`print_written`,
:func:`written_line`, the water index's note) and its exit code when the calibration is known
wrong (:func:`failed`: one ``failed: …`` line on stderr, exit 1)."""

from __future__ import annotations

import os
import sys

from synth.infra.cli import EXIT_CHECK_FAILED

#: What the printed summary says of ``cameras.txt`` (its header says it too).
COLMAP_NOTE = "upstream COLMAP and pycolmap read it without an error and drop the port"


def write_calibrations(directory, rig, housing, report: dict, start_rig,
                       air_covariance=None) -> None:
    """The calibration files (:func:`eval.calibrate.report.write_calibration`) into
    ``directory``; underwater (``start_rig`` given: the in-air cameras with the design port)
    also ``calib_in_air_only.yaml`` (with the in-air covariance, the port exact).
    ``air_covariance``: the in-air calibration's (in air: written to calib.yaml)."""
    from eval.calibrate import report as report_lib

    report_lib.write_calibration(directory, rig, start_rig is not None, housing, report,
                                 covariance=air_covariance if housing is None else None)
    if housing is not None:
        report_lib.write_calibration(os.path.join(directory, "calib_in_air_only.yaml"),
                                     start_rig, True, None, None, single=True,
                                     covariance=air_covariance)


def print_written(output, summary: str, args, has_port: bool) -> int:
    """Print the water index's note, the summary and what was written; exit code 0."""
    print_n_water_note(args)
    print(summary)
    print(written_line(output.path, has_port))
    return 0


def written_line(path, has_port: bool) -> str:
    """The last printed line: what was written; the COLMAP caveat only when there is a port to
    drop (an in-air cameras.txt holds none)."""
    colmap = (f"the refractive COLMAP fork — {COLMAP_NOTE}" if has_port else
              "COLMAP (in air: no port)")
    return (f"wrote {path} (calib.yaml; calibmar.yaml + calibmar_stereo.yaml; cameras.txt + "
            f"rig_config.json for {colmap})")


def print_n_water_note(args) -> None:
    """The index computed from ``--n-water T=…,S=…`` (on stderr), once the calibration is
    written: a refused command prints its one ``error:`` line and nothing else."""
    if getattr(args.n_water, "note", None):
        print(args.n_water.note, file=sys.stderr, flush=True)


def failed(where, failures, out) -> int:
    """0, or — the calibration being known wrong — one line ``failed: …`` on stderr and 1 (the
    report in ``out`` says the same under its verdict)."""
    if not failures:
        return 0
    print(f"failed: {where}: {'; '.join(failures)} (report in {out})", file=sys.stderr)
    return EXIT_CHECK_FAILED
