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

from synth.infra import interrupt

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


class _Columns:
    """Numeric columns of the rows as float arrays (NaN where missing), built once each."""

    def __init__(self, rows):
        self.rows, self.cache = rows, {}

    def __getitem__(self, column):
        import numpy as np

        if column not in self.cache:
            self.cache[column] = np.array([row.get(column) if _number(row.get(column))
                                           else np.nan for row in self.rows], dtype=float)
        return self.cache[column]


def _groups(rows, param, others, split, x_values, numeric) -> dict:
    """``{combo or None: [(x position, row indices)]}``: the rows of each point of each line."""
    import numpy as np

    where = {x: i for i, x in enumerate(x_values)}
    found = {}
    for index, row in enumerate(rows):
        x = row.get(param) if numeric else _label(row.get(param))
        combo = _series_key(row, others) if split else None
        found.setdefault(combo, {}).setdefault(where[x], []).append(index)
    return {combo: [(x_values[i] if numeric else i, np.array(found[combo][i]))
                    for i in sorted(found[combo])] for combo in found}


def _panel(ax, lines: dict, groups: dict, columns: _Columns, x_values, numeric):
    """One metric: ``lines`` ``{label: (combo, column)}``; a point is the mean of the column
    over its rows, the error bar ± one standard deviation."""
    import numpy as np

    for label, (combo, column) in lines.items():
        values = columns[column]
        xs, means, stds = [], [], []
        for x, index in groups.get(combo, []):
            ys = values[index]
            ys = ys[np.isfinite(ys)]
            if ys.size:
                xs.append(x)
                means.append(float(ys.mean()))
                stds.append(float(ys.std(ddof=1)) if ys.size > 1 else 0.0)
        if xs:
            ax.errorbar(xs, means, yerr=stds, marker="o", ms=3, capsize=0, lw=1, elinewidth=0.8,
                        label=label)
    if not numeric:
        ax.set_xticks(range(len(x_values)))
        ax.set_xticklabels(x_values, rotation=30, fontsize=7)


def _figure(path, title, panels, draw, columns: int = 4):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    n = len(panels)
    cols = min(columns, n)
    lines = -(-n // cols)
    # a Figure on the Agg canvas, not pyplot's: pyplot's close runs the garbage collector over
    # the whole heap (about a second per figure beside Mitsuba's and Dask's objects)
    fig = Figure(figsize=(3.6 * cols + 2.0, 2.6 * lines + 0.6))
    FigureCanvasAgg(fig)
    axes = fig.subplots(lines, cols, squeeze=False)
    for ax, panel in zip(axes.ravel(), panels):
        draw(ax, panel)
        ax.set_title(panel, fontsize=8, y=1.0)  # placed, not fitted round the tick labels
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        # at most 5 ticks up the side: a figure has a panel per varying column (over a hundred
        # in a sweep of the paper's settings) and every tick is a text and a line to draw
        ax.yaxis.set_major_locator(MaxNLocator(5))
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    handles, labels = axes.ravel()[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper right", fontsize=8)
    fig.suptitle(title, fontsize=10, y=1 - 0.15 / fig.get_figheight(), va="top")  # above the panels
    # a fixed layout: tight_layout took seconds per figure of fifty panels
    fig.subplots_adjust(left=0.05, right=0.82 if handles else 0.97, bottom=0.4 / (lines + 0.3),
                        top=1 - 0.6 / (2.6 * lines + 0.6), hspace=0.55, wspace=0.35)
    directory, name = os.path.split(path)
    tmp = os.path.join(directory, f".{name}.{os.getpid()}.tmp")
    try:
        fig.savefig(tmp, dpi=72, format="png")
        os.replace(tmp, path)
    except BaseException:  # Ctrl-C included: no half-written figure left behind
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


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
    values = _Columns(rows)
    for param in swept:
        others = [p for p in swept if p != param]
        combos = sorted({_series_key(row, others) for row in rows})
        split = bool(others) and len(combos) <= MAX_SERIES_COMBINATIONS
        note = ("" if not others else
                f"; one line per {', '.join(others)}" if split else
                f"; averaged over {', '.join(others)}")
        x_values, numeric = _x_axis(rows, param)
        groups = _groups(rows, param, others, split, x_values, numeric)
        line_combos = combos if split else [None]

        def name_of(label, combo):
            parts = [] if label is None else [label]
            if combo is not None:
                parts.append(", ".join(f"{k}={v}" for k, v in combo))
            return " | ".join(parts) or "all"

        def draw(ax, metric, groups=groups, x_values=x_values, numeric=numeric,
                 line_combos=line_combos, param=param):
            lines = {name_of(label, combo): (combo, column)
                     for label, column in method_columns[metric].items()
                     for combo in line_combos}
            _panel(ax, lines, groups, values, x_values, numeric)
            ax.set_xlabel(param, fontsize=8)

        def draw_cell(ax, column, groups=groups, x_values=x_values, numeric=numeric,
                      line_combos=line_combos, param=param):
            lines = {name_of(None, combo): (combo, column) for combo in line_combos}
            _panel(ax, lines, groups, values, x_values, numeric)
            ax.set_xlabel(param, fontsize=8)

        for suffix, panels, drawer, what in (("methods", list(method_columns), draw, "method"),
                                             ("cell", other_columns, draw_cell, "cell")):
            if not panels:
                continue
            path = os.path.join(directory, f"{_safe(param)}__{suffix}.png")
            interrupt.check()  # a figure takes seconds: stop between them
            _figure(path, f"{spec.name}: {what} metrics against {param} (mean ± 1 std over "
                          f"repeats{note})", panels, drawer)
            paths.append(path)
    return paths


__all__ = ["write_figures"]
