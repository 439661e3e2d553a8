"""Numbers as text for the tables and reports of every command."""

from __future__ import annotations


def format_number(value, digits: int = 3) -> str:
    """``value`` with ``digits`` decimals when it is a float, ``–`` when it is None or NaN, else
    ``str(value)``."""
    if value is None or (isinstance(value, float) and value != value):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


__all__ = ["format_number"]
