"""Dense stereo: the refractive plane sweep and its sub-pixel refinement (:mod:`.match`) over
the warps of :mod:`.warp`."""
