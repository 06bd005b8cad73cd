"""The magnetometer: the thermal and iron calibration of its channel, and the carrier method (Poisson's model)."""
