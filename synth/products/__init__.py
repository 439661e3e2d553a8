"""What synth makes for others to measure: datasets, calibration boards, benchmark suites (and
their generated scenes), photos as a camera stores them, truth maps and dense pairs, and the
cross-check of detections against the simulator."""
