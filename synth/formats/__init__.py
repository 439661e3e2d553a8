"""Files other tools read: calibmar's and the COLMAP fork's calibration formats, the exchange
files of a dataset (cameras.json, COLMAP text model, depth and flow), point-cloud files."""
