"""A sensor's noise: overlapping Allan variance (``allan``), the IEEE 952 model and its fit (``model``),
Kalibr-style imu.yaml files (``kalibr``). numpy only at import (scipy inside the functions that need it)."""
