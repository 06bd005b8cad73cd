"""What PX4's and ArduPilot's temperature parameters can carry of a calibration, and what they cannot.

Both firmwares subtract an offset polynomial in the temperature from the raw sample, per axis,
the temperature clamped to the calibrated range: PX4 a cubic ``X0 + X1 dT + X2 dT^2 + X3 dT^3``
about ``TREF`` (``TemperatureCompensation.cpp``), ArduPilot a cubic without constant about
35 C (``AP_InertialSensor_tempcal.cpp``). Neither has a scale term, an effect with memory
(a lag) or more than three orders. :func:`offset_cubic` is the calibration's static offset
curve (its effects left out) as such a cubic; :func:`not_carried` says in one line each, with
its size, what the parameters leave out (:mod:`tak_thermo_ros.formats.px4_params`,
:mod:`tak_thermo_ros.formats.ardupilot_params` write them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.link.model import Calibration, UnitCalibration
from tak_thermo_ros.core.values import STANDARD_GRAVITY

DEG = 180.0 / math.pi
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
    """The calibration's static offset curve as a cubic about ``about`` over its calibrated range."""
    low, high = float(calibration.temp_code_min), float(calibration.temp_code_max)
    grid = np.linspace(low, high, GRID_POINTS)
    curve = static_offset(calibration, grid)
    t = grid - about
    design = np.column_stack([np.ones_like(t), t, t ** 2, t ** 3])
    coefficients, *_ = np.linalg.lstsq(design, curve, rcond=None)
    deviation = np.max(np.abs(design @ coefficients - curve), axis=0)
    slope = np.abs(np.gradient(curve, grid, axis=0)) if len(grid) > 1 else np.zeros((1, 3))
    return OffsetCubic(coefficients=coefficients, about=float(about), low=low, high=high, deviation=deviation,
                       steepest=np.max(slope, axis=0))


def size(value: float, sensor: str) -> str:
    """An offset-sized number in the sensor's own units: mg, deg/h, uT."""
    if sensor == 'accel':
        return f'{value / STANDARD_GRAVITY * 1000.0:.3g} mg'
    if sensor == 'gyro':
        return f'{value * DEG * 3600.0:.3g} deg/h'
    return f'{value * 1e6:.3g} uT'


SENSOR_NAMES = {'accel': 'accelerometer', 'gyro': 'gyroscope', 'mag': 'magnetometer'}


def not_carried(unit: UnitCalibration, sensor: str, cubic: OffsetCubic, firmware: str) -> list[str]:
    """One line each for what the firmware's parameters leave out of a sensor's calibration, with its size."""
    calibration = unit.sensor(sensor)
    name = SENSOR_NAMES[sensor]
    source = unit.source or {}
    lines = []
    worst = float(np.max(cubic.deviation))
    if worst > 1e-9 * max(1.0, float(np.max(np.abs(cubic.coefficients)))):
        lines.append(f'{name}: its offset curve is above 3rd order: the cubic departs by up to {size(worst, sensor)}')
    lines.append(_scale_line(calibration, sensor, source, firmware))
    for effect in calibration.effects:
        lines.extend(_effect_line(effect, sensor, source, firmware).splitlines())
    lines.append(f'{name}: outside {cubic.low:.1f}..{cubic.high:.1f} C {firmware} clamps to the edge, as apply does')
    return [line for line in lines if line]


def _scale_line(calibration: Calibration, sensor: str, source: dict, firmware: str) -> str:
    """The scale drift the firmware has no term for: its error at 1 g, or at the run's largest rate."""
    name = SENSOR_NAMES[sensor]
    if not any(axis.scale_observable for axis in calibration.axes):
        return f'{name}: no scale drift fitted (one input per axis); {firmware} has no scale term'
    grid = np.linspace(calibration.temp_code_min, calibration.temp_code_max, GRID_POINTS) - calibration.temp_code_ref
    drift = max(float(np.max(np.abs(axis.scale_factor(grid) - 1.0))) for axis in calibration.axes
                if axis.scale_observable)
    if sensor == 'accel':
        return f'{name}: scale drift not carried ({firmware} has no scale term): up to {drift * 1000.0:.3g} mg at 1 g'
    rate = float(source.get('rate_max', 0.0))
    at = (f'{size(drift * rate, sensor)} at {rate * DEG:.3g} deg/s (the run\'s largest)' if rate > 0.0
          else 'no rate in the run to size it at')
    return f'{name}: scale drift not carried: {drift * 1e6:.3g} ppm, {at}'


def _effect_line(effect, sensor: str, source: dict, firmware: str) -> str:
    """An effect the firmware cannot apply (two lines for a lag): the export holds the static curve; what it leaves."""
    name = SENSOR_NAMES[sensor]
    amplitudes = np.abs(np.array([a for axis in effect.amplitudes() for a in axis], dtype=float))
    largest = float(amplitudes.max()) if amplitudes.size else 0.0
    if effect.name.startswith('thermal_lag'):
        values = effect.values
        taus = [v for k, v in values.items() if k.startswith('tau_s')]
        tau = max(taus) if taus else 0.0
        rate = float(source.get('temperature_rate_max', 0.0))
        return (f'{name}: {effect.name} not carried ({firmware} has no lag): the export holds the static curve\n'
                f'{name}: a ramp at the log\'s fastest {rate * 60.0:.3g} C/min still leaves up to '
                f'{size(largest * rate * tau, sensor)} ({tau:.3g} s lag)')
    return f'{name}: {effect.name} not carried: up to {size(largest, sensor)} per unit of its basis signal'
