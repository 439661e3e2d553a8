"""The shared core of the ``eval`` commands: typed error statistics (:mod:`.results`), point
cloud and surface metrics with Open3D (:mod:`.cloud_metrics`, :mod:`.surface_metrics`), the rig
a measurement believes (:mod:`.assumption`), the analytic forward model and its errors
(:mod:`.analytic`), and the per-point scipy Fermat reference (:mod:`.fermat_reference`).

Nothing here parses a command line; every command package may import it.
"""
