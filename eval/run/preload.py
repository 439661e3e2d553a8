"""The modules a run needs after its render, imported on a thread while the render runs.

Mitsuba's render releases the GIL and keeps the cores busy with its own threads; what a run
imports after it — Open3D for the cloud scores and the PLY files, matplotlib for the figures —
costs about a second of one core on a quiet machine (Open3D 0.45 s, of which its plotting
modules 0.3 s; matplotlib 0.3 s). Imported beside the render, that second is not waited for
at its end. Python's per-module import locks make the main thread wait for a module the thread
is still importing, so nothing is imported twice or seen half-made; the thread imports only
modules the render itself never imports.
"""

from __future__ import annotations

import importlib
import threading

#: Imported beside every render: the cloud scores and the PLY files.
SCORES = ("open3d",)
#: Also imported when the run draws its figures.
FIGURES = ("eval.core.figures", "eval.run.figures")


def start(figures: bool) -> threading.Thread:
    """A started daemon thread importing :data:`SCORES` (and :data:`FIGURES` with ``figures``);
    an import that fails there fails again, with its own message, where the run imports it."""
    names = SCORES + (FIGURES if figures else ())

    def run():
        for name in names:
            try:
                importlib.import_module(name)
            except Exception:  # the run's own import says what went wrong
                return

    thread = threading.Thread(target=run, name="preload", daemon=True)
    thread.start()
    return thread
