"""How large a seed may be: the seeds the project accepts are the seeds it can honour.

Where a seed goes. One seed, one meaning: the scene's ``seed`` parameter (``-D seed=S``, or
``--seed S`` of ``eval run``, ``synth render``, ``synth dataset``; ``synth scene --seed`` writes
it into a scene) seeds

* Mitsuba's sampler: ``mi.render(seed=…)`` takes an **unsigned 32-bit** seed, and pass ``k`` of
  view ``i`` is rendered with ``S + i + 2^21·k`` (:func:`synth.rendering.render.pass_seed`; ``synth boards
  --seed S`` renders pose ``p`` as the scene seed ``S + 2p``). A sum beyond 2³² − 1 used to wrap
  silently — ``--seed 4294967296`` rendered the bytes of seed 0 — so the largest seed is what
  leaves room for the largest offset: ``2^32 − 1 − offset`` (:func:`largest_seed`).
* numpy (``numpy.random.default_rng``): the added pixel noise, the sensor noise, the plane fit's
  RANSAC, the board poses. numpy takes any non-negative integer: seeds that go only there
  (``eval paper --seed``, ``eval bench --seed``, ``synth scene --layout-seed`` and
  ``--speckle-seed``, a sweep's ``seed``) have no upper bound.

So a scene seed is at most :data:`MAX_SEED` = 2³² − 2 (a one-pass render seeds its right view
``S + 1``), checked with every scene parameter (:func:`synth.scene.check_params`) and by the
``--seed`` options (:func:`synth.infra.cli.scene_seed`); a render of several passes per view (an
adaptive render's pilot is pass 0 and its masked calls or full-film fallback passes 1, 2, …; a
full-film render takes more than one pass above 36 × 2448 × 2048 samples per view) or of several
board poses lowers it further, which :func:`synth.rendering.render.check_render_request` checks before
rendering, stating the bound (for an adaptive render, the most passes it could take).
"""

from __future__ import annotations

#: Mitsuba's sampler seeds are unsigned 32-bit integers: 0 … SEED_LIMIT − 1.
SEED_LIMIT = 1 << 32
#: Seed stride between the passes of one view (:func:`synth.rendering.render.pass_seed`).
PASS_SEED_STRIDE = 1 << 21
#: The largest scene seed of all: a one-pass render seeds its views ``S`` and ``S + 1``.
MAX_SEED = SEED_LIMIT - 2


def render_offset(passes_per_view, extra: int = 0) -> int:
    """The largest amount the renderer adds to the scene seed: view ``i`` (0 left, 1 right)
    rendered in ``passes_per_view[i]`` passes adds ``i + 2^21·(passes − 1)``, plus ``extra``
    (``synth boards``: ``2·(poses − 1)``)."""
    return int(extra) + max(view + PASS_SEED_STRIDE * (int(passes) - 1)
                            for view, passes in enumerate(passes_per_view))


def largest_seed(offset: int) -> int:
    """The largest seed ``S`` with ``S + offset`` a 32-bit sampler seed (negative: none)."""
    return SEED_LIMIT - 1 - int(offset)


def seed_range_text() -> str:
    """``0 … 4294967294`` and why, for error messages."""
    return (f"0 to {MAX_SEED} (Mitsuba's sampler seed is 32-bit and the right view renders with "
            f"seed + 1)")


__all__ = ["MAX_SEED", "PASS_SEED_STRIDE", "SEED_LIMIT", "largest_seed", "render_offset",
           "seed_range_text"]
