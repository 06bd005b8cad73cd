"""Records: streams as arrays and their alignment, static runs, CSV logs, the calibration file, atomic outputs."""
