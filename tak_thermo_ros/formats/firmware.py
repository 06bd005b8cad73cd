"""What PX4's and ArduPilot's temperature parameters can carry of a calibration, and what they cannot.

Both firmwares subtract an offset polynomial in the temperature from the raw sample, per axis,
the temperature clamped to the calibrated range: PX4 a cubic ``X0 + X1 dT + X2 dT^2 + X3 dT^3``
about ``TREF`` (``TemperatureCompensation.cpp``), ArduPilot a cubic without constant about
35 C (``AP_InertialSensor_tempcal.cpp``). Neither has a scale term, an effect with memory
(a lag) or more than three orders. :func:`~tak_thermo_ros.core.link.offset_cubic.offset_cubic`
is the calibration's static offset curve (its effects left out) as such a cubic;
:func:`not_carried` says in one line each, with
its size, what the parameters leave out (:mod:`tak_thermo_ros.formats.px4_params`,
:mod:`tak_thermo_ros.formats.ardupilot_params` write them).
"""

from __future__ import annotations

import numpy as np

from tak_thermo_ros.core.link.model import Calibration, UnitCalibration
from tak_thermo_ros.core.link.offset_cubic import GRID_POINTS, OffsetCubic
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.units import DEG, readable_unit


def size(value: float, sensor: str) -> str:
    """An offset-sized number in the sensor's own units: mg, deg/h, uT."""
    shown, factor = readable_unit({'accel': 'm/s^2', 'gyro': 'rad/s', 'mag': 'T'}[sensor])
    return f'{value * factor:.3g} {shown}'


def not_carried(unit: UnitCalibration, sensor: str, cubic: OffsetCubic, firmware: str) -> list[str]:
    """One line each for what the firmware's parameters leave out of a sensor's calibration, with its size."""
    calibration = unit.sensor(sensor)
    name = SENSOR_NAMES[sensor]
    source = unit.source or {}
    if not calibration.needs_temperature:
        why = calibration.notes[0] if calibration.notes else f'thermal: {calibration.thermal}'
        return [f'{name}: no temperature terms in the calibration ({why}): the parameters hold its constant offset']
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
