"""The settings of ``python -m eval paper`` that its modules share (a leaf: imports nothing of
``eval``): the paper's distances, noise and index deviation, the claims' yardsticks, the method
and component names, the reference."""

NAME = "paper"
DISTANCES_MM = (1000.0, 2000.0)
NOISE_VARIANCE_PX2 = 0.01
INDEX_RELATIVE = 0.0015
GAP_THRESHOLD_MM = 1e-6
IDEAL_TOLERANCE_MM = 1e-9
SEM_FACTOR = 3.0  # "near zero" / "beyond the noise": |mean| against 3 standard errors of the mean
SHIFT_AGREEMENT_MM = 0.1  # optical_path and su index-deviation shifts "alike": within 0.1 mm
NOISE_METHODS = ("optical_path", "su", "regular_in_air")
INDEX_METHODS = ("optical_path", "su")
INDEX_SIDES = ("simulation", "measurement")
COMPONENTS = ("dX", "dY", "dZ", "dP")

PAPER_REFERENCE = ("Li et al., 'Underwater Refractive Stereo Vision Measurement and Simulation "
                   "Imaging Model Based on Optical Path', J. Mar. Sci. Eng. 2024, 12(11), 1955, "
                   "doi:10.3390/jmse12111955")
