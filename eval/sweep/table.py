"""The tables of ``python -m eval sweep``: one row per cell of the spec that has a record, in the
spec's order — its parameters, status, error, seconds and the scalar leaves of its report —
written as ``results.parquet`` and ``results.csv``."""

from __future__ import annotations

import re

from synth.infra.tables import write_table

#: Columns that differ from run to run of the same cell (left out when comparing tables).
TIMING_COLUMNS = re.compile(r"^(seconds$|timings_s\.)")


def _param_columns(cells) -> list:
    return sorted({k for c in cells for k in c.params})


def table_rows(spec, records: dict) -> list:
    """One row per cell of the spec that has a record, in the spec's order."""
    rows = []
    for cell in spec.cells:
        record = records.get(cell.key)
        if record is None:
            continue
        row = {"key": cell.key, "kind": cell.kind, "scene": cell.scene, "repeat": cell.repeat,
               "sample": cell.sample, "seed": cell.seed}
        row.update({k: _cell_value(v) for k, v in cell.params.items()})
        row["status"] = record["status"]
        row["error"] = record["error"]
        row["seconds"] = record.get("seconds")
        row.update(record.get("metrics") or {})
        rows.append(row)
    return rows


def _cell_value(value):
    if isinstance(value, list):
        return " ".join(str(v) for v in value)
    return value


def table_columns(spec, rows: list) -> list:
    fixed = ["key", "kind", "scene", "repeat", "sample", "seed", *_param_columns(spec.cells),
             "status", "error", "seconds"]
    rest = sorted({k for row in rows for k in row} - set(fixed))
    return fixed + rest


def write_tables(directory: str, spec, records: dict) -> int:
    """``results.parquet`` and ``results.csv`` from the records; returns the number of rows."""
    rows = table_rows(spec, records)
    write_table(directory, "results", rows, table_columns(spec, rows))
    return len(rows)


__all__ = ["TIMING_COLUMNS", "table_columns", "table_rows", "write_tables"]
