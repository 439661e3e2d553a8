"""The names a rig of N cameras had before there was one rig class: :class:`MultiRig` is
:class:`measure.stereo.rig.Rig` (the one rig: N ≥ 1 cameras, a port per camera, named; a pair
is a rig of two), and the helpers live in :mod:`measure.stereo.rig`."""

from __future__ import annotations

from .rig import OVERLAP_MM, Rig, ViewPorts, default_names, in_glass

#: The one rig class (:class:`measure.stereo.rig.Rig`) under its former name.
MultiRig = Rig

__all__ = ["MultiRig", "OVERLAP_MM", "ViewPorts", "default_names", "in_glass"]
