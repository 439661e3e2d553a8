"""Figures of ``python -m eval sweep``: every metric against every swept parameter.

For each parameter that takes more than one value (``spec.swept``) two PNG files go into
``DIR/figures``:

* ``<param>__methods.png`` — one panel per metric of the methods (``methods.<m>.<metric>`` of
  the table, and ``self_calibration.methods.<m>.<metric>`` after self-calibration), one line per
  method;
* ``<param>__cell.png`` — one panel per other numeric column that varies (matching counts,
  cross-check, self-calibration estimates, …).

A point is the mean over the cells with that value (the repeats, and the values of the other
swept parameters unless a line is drawn for each of their combinations: up to
:data:`MAX_SERIES_COMBINATIONS`); the error bar is ± one standard deviation over the same cells.
Failed cells are left out.
"""

from __future__ import annotations

import math
import os
import re

MAX_SERIES_COMBINATIONS = 4
_METHOD = re.compile(r"^(?P<prefix>self_calibration\.)?methods\.(?P<method>[^.]+)\.(?P<metric>.+)$")
_META = {"key", "kind", "scene", "repeat", "sample", "seed", "status", "error", "seconds"}


def _number(value) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value))


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _varying(rows, column) -> bool:
    values = {row.get(column) for row in rows if _number(row.get(column))}
    return len(values) > 1


def _series_key(row, others):
    return tuple((name, _label(row.get(name))) for name in others)


def _label(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    return "off" if value in ("", None) else str(value)


def _x_axis(rows, param):
    values = [row.get(param) for row in rows]
    if all(_number(v) for v in values):
        return sorted(set(values)), True
    order = []
    for v in values:
        if _label(v) not in order:
            order.append(_label(v))
    return order, False


def _panel(ax, rows, param, series, column_of, x_values, numeric):
    """Draw one metric: ``series`` ``{label: filter(row) -> bool}``, ``column_of(label)`` the
    column of that line."""
    import numpy as np

    for k, (label, keep) in enumerate(series.items()):
        column = column_of(label)
        xs, means, stds = [], [], []
        for i, x in enumerate(x_values):
            ys = [row[column] for row in rows if keep(row) and _number(row.get(column))
                  and (row.get(param) == x if numeric else _label(row.get(param)) == x)]
            if ys:
                xs.append(x if numeric else i)
                means.append(float(np.mean(ys)))
                stds.append(float(np.std(ys, ddof=1)) if len(ys) > 1 else 0.0)
        if xs:
            ax.errorbar(xs, means, yerr=stds, marker="o", ms=3, capsize=2, lw=1, label=label)
    if not numeric:
        ax.set_xticks(range(len(x_values)))
        ax.set_xticklabels(x_values, rotation=30, fontsize=7)


def _figure(path, title, panels, draw, columns: int = 4):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(panels)
    cols = min(columns, n)
    lines = -(-n // cols)
    fig, axes = plt.subplots(lines, cols, figsize=(3.6 * cols + 2.0, 2.6 * lines + 0.6),
                             squeeze=False)
    for ax, panel in zip(axes.ravel(), panels):
        draw(ax, panel)
        ax.set_title(panel, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    handles, labels = axes.ravel()[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper right", fontsize=8)
    fig.suptitle(title, fontsize=10)
    # a fixed layout: tight_layout took seconds per figure of fifty panels
    fig.subplots_adjust(left=0.05, right=0.82 if handles else 0.97, bottom=0.4 / (lines + 0.3),
                        top=1 - 0.6 / (2.6 * lines + 0.6), hspace=0.55, wspace=0.35)
    directory, name = os.path.split(path)
    tmp = os.path.join(directory, f".{name}.{os.getpid()}.tmp")
    fig.savefig(tmp, dpi=80, format="png")
    plt.close(fig)
    os.replace(tmp, path)


def write_figures(directory: str, spec, rows: list) -> list:
    """Draw the figures of ``rows`` (the table's rows) into ``directory``; returns the paths."""
    rows = [row for row in rows if row.get("status") == "ok"]
    swept = spec.swept
    if not rows or not swept:
        return []
    os.makedirs(directory, exist_ok=True)
    columns = sorted({k for row in rows for k in row})
    params = {k for c in spec.cells for k in c.params}
    method_columns = {}
    for column in columns:
        match = _METHOD.match(column)
        if match and _varying(rows, column):
            label = match["method"] + (" self-cal" if match["prefix"] else "")
            method_columns.setdefault(match["metric"], {})[label] = column
    other_columns = [c for c in columns if not _METHOD.match(c) and c not in _META
                     and c not in params and not c.startswith("timings_s.")
                     and _varying(rows, c)]
    paths = []
    for param in swept:
        others = [p for p in swept if p != param]
        combos = sorted({_series_key(row, others) for row in rows})
        split = others and len(combos) <= MAX_SERIES_COMBINATIONS
        note = ("" if not others else
                f"; one line per {', '.join(others)}" if split else
                f"; averaged over {', '.join(others)}")
        x_values, numeric = _x_axis(rows, param)
        metrics = list(method_columns)
        if metrics:
            def draw(ax, metric, param=param, combos=combos, split=split, others=others,
                     x_values=x_values, numeric=numeric):
                series, column_of = {}, {}
                for label, column in method_columns[metric].items():
                    for combo in (combos if split else [None]):
                        name = label if combo is None else (
                            label + " | " + ", ".join(f"{k}={v}" for k, v in combo))
                        series[name] = (lambda row, combo=combo: combo is None
                                        or _series_key(row, others) == combo)
                        column_of[name] = column
                _panel(ax, rows, param, series, column_of.get, x_values, numeric)
                ax.set_xlabel(param, fontsize=8)

            path = os.path.join(directory, f"{_safe(param)}__methods.png")
            _figure(path, f"{spec.name}: method metrics against {param} (mean ± 1 std over "
                          f"repeats{note})", metrics, draw)
            paths.append(path)
        if other_columns:
            def draw_cell(ax, column, param=param, combos=combos, split=split, others=others,
                          x_values=x_values, numeric=numeric):
                series = {}
                for combo in (combos if split else [None]):
                    name = "all" if combo is None else ", ".join(f"{k}={v}" for k, v in combo)
                    series[name] = (lambda row, combo=combo: combo is None
                                    or _series_key(row, others) == combo)
                _panel(ax, rows, param, series, lambda _: column, x_values, numeric)
                ax.set_xlabel(param, fontsize=8)

            path = os.path.join(directory, f"{_safe(param)}__cell.png")
            _figure(path, f"{spec.name}: cell metrics against {param} (mean ± 1 std over "
                          f"repeats{note})", other_columns, draw_cell)
            paths.append(path)
    return paths


__all__ = ["write_figures"]
