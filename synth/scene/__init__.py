"""Mitsuba 3 scene files as the single source of truth of a run: write them, read them back.

A scene written here is a genuine Mitsuba 3 XML scene (``mi.load_file`` loads it with no plugin
of ours), in millimetres, in the reference frame (the left camera's, OpenCV axes). One module per
job:

* :mod:`synth.scene.model` -- what a scene says (:class:`SceneSpec`), :class:`SceneError`, the
  defaults and ids shared by writer and reader;
* :mod:`synth.scene.write` -- :func:`write_scene`: the XML of cameras, port, targets or surface;
* :mod:`synth.scene.glass` -- how a scene holds the glass of a port per camera (domes,
  windows): checks, XML, Mitsuba shapes; :mod:`synth.scene.xml_text` -- the text of its numbers;
* :mod:`synth.scene.params` -- the ``<default>`` parameters and their ``-D`` overrides;
* :mod:`synth.scene.read` -- :func:`load_scene`: the rig, port and targets read back through
  Mitsuba's own parser;
* :mod:`synth.scene.dome` -- dome ports: the two domes of a rig, the field-of-view check, the
  Mitsuba spheres;
* :mod:`synth.scene.windows` -- two housings: a flat port per camera, each a finite window
  sized to its camera's field of view and kept out of the other's.

This package re-exports the names the rest of the project uses; the others live in the modules.
"""

from __future__ import annotations

from synth.scene.model import (DEFAULT_FULL_FILM_SPP, DEFAULT_SPP, DEFAULT_TARGET_RADIUS_MM,
                               SURFACE_ID, SceneError, SceneSpec, SurfaceFiles)
from synth.scene.params import (apply_seed, apply_spp, check_params, declared_defaults,
                                parse_defines)
from synth.scene.read import load_scene
from synth.scene.write import (LIGHT_INTENSITY, LIT_TARGET_ALBEDO, interface_placements,
                               light_placements, write_scene)

__all__ = [
    "DEFAULT_FULL_FILM_SPP", "DEFAULT_SPP", "DEFAULT_TARGET_RADIUS_MM", "LIGHT_INTENSITY",
    "LIT_TARGET_ALBEDO",
    "SURFACE_ID", "SceneError", "SceneSpec", "SurfaceFiles", "apply_seed", "apply_spp",
    "check_params",
    "declared_defaults", "interface_placements", "light_placements", "load_scene", "parse_defines",
    "write_scene"
]
