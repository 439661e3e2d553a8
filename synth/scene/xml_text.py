"""The text of numbers in the scene files :mod:`synth.scene.write` writes: the shortest text
that reads back as the same float (mm, indices, fractions; ``1.0`` is ``1``)."""

from __future__ import annotations


def number_text(x: float) -> str:
    """Shortest round-trip text of a float (``1.0`` -> ``"1"``)."""
    x = float(x)
    if x == 0:
        return "0"
    if x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return repr(x)


def vector_text(v) -> str:
    """The numbers of ``v`` as :func:`number_text`, separated by ``", "``."""
    return ", ".join(number_text(x) for x in v)

