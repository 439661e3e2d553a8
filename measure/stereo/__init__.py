"""Stereo: the rig and its triangulators, target matching, reprojection refinement, the
covariance of a rig's named parameters (:mod:`.rig_covariance`) and of every triangulated
point (:mod:`.uncertainty`)."""
