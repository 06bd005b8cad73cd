"""A sensor's noise: Allan variance, the IEEE 952 model and its fit, Kalibr-style imu.yaml files.

``allan`` (overlapping Allan variance, in memory and streamed), ``model`` (:class:`NoiseModel`,
:func:`fit_noise_model`), ``kalibr`` (read and write imu.yaml). numpy only at import; scipy is
imported inside the functions that need it.
"""
