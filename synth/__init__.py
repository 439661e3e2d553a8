"""synth — from 3D to pixels: the Fermat simulator, target layouts, noise, Mitsuba scenes."""
