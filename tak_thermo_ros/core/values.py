"""Shared leaves: the one test of a finite number (calibration file, effects) and physical constants."""

from __future__ import annotations

import math

import numpy as np

from tak_thermo_ros.errors import CalibrationError

STANDARD_GRAVITY = 9.80665
"""Standard gravity, m/s^2 (the simulator's and the static reference's default)."""
SENSOR_NAMES = {'accel': 'accelerometer', 'gyro': 'gyroscope', 'mag': 'magnetometer'}
"""Each sensor's name as a person reads it."""
EARTH_RATE = 7.2921159e-5
"""The Earth's rotation rate, rad/s (WGS 84)."""
DEG_PER_H = 180.0 / math.pi * 3600.0
"""deg/h per rad/s."""
MG = 1e3 / STANDARD_GRAVITY
"""mg per m/s^2."""


def normal_gravity(latitude_deg: float) -> float:
    """Gravity on the WGS-84 ellipsoid at a latitude, m/s^2 (Somigliana's formula).

    9.7803 m/s^2 at the equator, 9.8322 at the poles; a place's height lowers it by about 3.1e-6
    m/s^2 per metre (not included: give ``--gravity`` for a measured value).
    """
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    return 9.7803253359 * (1.0 + 0.00193185265241 * s2) / math.sqrt(1.0 - 0.00669437999013 * s2)


def finite_number(value: object, key: str) -> float:
    """A finite float from a number (Python or numpy; not a bool), or a one-line error naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        msg = f'{key}: expected a number, got {type(value).__name__} {value!r}'
        raise CalibrationError(msg)
    try:
        number = float(value)
    except OverflowError:  # a Python int beyond float range (YAML reads 400 digits as an int)
        number = math.inf
    if not math.isfinite(number):
        msg = f'{key}: must be finite, got {number}'
        raise CalibrationError(msg)
    return number


def random_walk_unit(unit: str) -> str:
    """The unit of a random walk ``K`` of a signal in ``unit`` (Allan variance ``K^2 tau / 3``): one spelling.

    Kalibr's: ``rad/s^2/sqrt(Hz)`` for a gyroscope, ``m/s^3/sqrt(Hz)`` for an accelerometer;
    ``<unit>/s/sqrt(Hz)`` otherwise (codes, uT). The same dimension as ``<unit>*sqrt(Hz)``.
    """
    return {'rad/s': 'rad/s^2/sqrt(Hz)', 'm/s^2': 'm/s^3/sqrt(Hz)'}.get(unit, f'{unit}/s/sqrt(Hz)')
