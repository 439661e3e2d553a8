"""Tables of many runs written as Parquet and CSV side by side (``eval sweep``'s results,
``synth suite``'s index): rows of scalars, columns in a given order, each file atomically."""

from __future__ import annotations

import os


def write_table(directory: str, stem: str, rows: list, columns: list) -> None:
    """``DIR/<stem>.parquet`` and ``DIR/<stem>.csv`` from ``rows`` (dicts) in the order of
    ``columns``: a column of ints and floats is float, a column of mixed kinds is text, a missing
    value is null. Each file is written to a temporary name and renamed."""
    import pyarrow as pa
    import pyarrow.csv as pa_csv
    import pyarrow.parquet as pq

    arrays = {}
    for name in columns:
        values = [row.get(name) for row in rows]
        kinds = {type(v) for v in values if v is not None}
        if kinds <= {int, float} and int in kinds and float in kinds:
            values = [None if v is None else float(v) for v in values]
        elif len(kinds) > 1:
            values = [None if v is None else str(v) for v in values]
        arrays[name] = pa.array(values, type=None if kinds else pa.null())
    table = pa.table(arrays)
    for name, writer in ((f"{stem}.parquet", pq.write_table), (f"{stem}.csv", pa_csv.write_csv)):
        tmp = os.path.join(directory, f".{name}.{os.getpid()}.tmp")
        writer(table, tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, os.path.join(directory, name))


__all__ = ["write_table"]
