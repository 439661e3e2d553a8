"""Rendering: Mitsuba's set-up and the refracted-path integrator, the stereo render and its
adaptive passes, its image files, the camera ↔ Mitsuba sensor conversion, the sensor model
(exposure, noise, bit depth), pixel noise, speckle textures and the water's optical types."""
