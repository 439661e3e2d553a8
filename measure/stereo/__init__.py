"""Stereo: the rig and its triangulators, target matching, reprojection refinement, the
covariance of every triangulated point."""
