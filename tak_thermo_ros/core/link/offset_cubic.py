"""A calibration's static offset curve as the cubic a flight firmware applies.

PX4 and ArduPilot subtract, per axis, an offset cubic in the temperature (clamped to the
calibrated range) from the raw sample. :func:`offset_cubic` is the least-squares cubic of a
calibration's static offset curve (its effects left out) over its calibrated range; the parameter
writers (:mod:`tak_thermo_ros.formats.firmware`) and ``diagnose``'s lag profile use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.link.model import Calibration

GRID_POINTS = 401
"""Temperatures at which the static curve is evaluated over the calibrated range."""


@dataclass(frozen=True)
class OffsetCubic:
    """A sensor's static offset curve as a cubic in ``T - about`` per axis.

    :param coefficients: ``(4, 3)``: constant, linear, square, cube term per axis (x, y, z).
    :param about: the temperature the powers are counted from, degrees C.
    :param low: lower end of the calibrated range (the firmware clamps below it).
    :param high: upper end.
    :param deviation: ``(3,)`` the largest difference between the cubic and the curve over the range
        (0 up to rounding unless the calibration's order is above 3).
    :param steepest: ``(3,)`` the largest ``|d offset / dT|`` over the range, per degree C.
    """

    coefficients: np.ndarray
    about: float
    low: float
    high: float
    deviation: np.ndarray
    steepest: np.ndarray

    def evaluate(self, temperature: np.ndarray) -> np.ndarray:
        """The cubic at the clamped ``temperature`` ``(k,)``: ``(k, 3)``."""
        t = (np.clip(np.asarray(temperature, dtype=float), self.low, self.high) - self.about)[:, None]
        c0, c1, c2, c3 = self.coefficients
        return c0 + (c1 + (c2 + c3 * t) * t) * t


def static_offset(calibration: Calibration, temperature: np.ndarray) -> np.ndarray:
    """``(k, 3)``: the link's offset ``b0 + D F_s(T - T_ref)`` at ``temperature`` (no effect, no clamp)."""
    n = np.asarray(temperature, dtype=float) - calibration.temp_code_ref
    return np.column_stack([axis.offset + axis.offset_drift(n) for axis in calibration.axes])


def offset_cubic(calibration: Calibration, about: float) -> OffsetCubic:
    """The calibration's static offset curve as a cubic about ``about`` over its calibrated range.

    A link without a range (no temperature terms: a sensor held at nominal, a record at one
    temperature) is its constant offset: no slope, nothing departs.
    """
    low, high = float(calibration.temp_code_min), float(calibration.temp_code_max)
    if not high > low:
        coefficients = np.zeros((4, 3))
        coefficients[0] = static_offset(calibration, np.array([low]))[0]
        return OffsetCubic(coefficients=coefficients, about=float(about), low=low, high=high, deviation=np.zeros(3),
                           steepest=np.zeros(3))
    grid = np.linspace(low, high, GRID_POINTS)
    curve = static_offset(calibration, grid)
    t = grid - about
    design = np.column_stack([np.ones_like(t), t, t ** 2, t ** 3])
    coefficients, *_ = np.linalg.lstsq(design, curve, rcond=None)
    deviation = np.max(np.abs(design @ coefficients - curve), axis=0)
    slope = np.abs(np.gradient(curve, grid, axis=0)) if len(grid) > 1 else np.zeros((1, 3))
    return OffsetCubic(coefficients=coefficients, about=float(about), low=low, high=high, deviation=deviation,
                       steepest=np.max(slope, axis=0))
