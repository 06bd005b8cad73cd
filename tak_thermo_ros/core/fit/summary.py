"""What a fit says of itself: the lines of :meth:`~tak_thermo_ros.core.fit.model.FitResult.summary`.

lmfit's ``fit_report`` and statsmodels' ``summary()`` print a result from the result alone; so does
a :class:`~tak_thermo_ros.core.fit.model.FitResult` here. A sensor's summary is its link, one
quantity per line and x y z on each (the residual, the scale, the offset at the reference
temperature, the offset's span over the calibrated range), then one line per effect parameter
with its standard error (and a line before them saying what the errors assume), or what was held.

Every value is in the sensor's unit with the one a person reads beside it (mg beside m/s^2, deg/h
beside rad/s, a magnetometer's tesla in uT; the paper's codes with mg beside), to significant
figures (:mod:`tak_thermo_ros.units`). ``tak_calib fit`` prints these lines as they are.
"""

from __future__ import annotations

import re
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.link.model import AXES, Calibration
from tak_thermo_ros.units import amount, display_unit, in_si, numbers, reader_unit, significant, with_error


def axes_lines(sensor: str, calibration: Calibration, residual_rms: Sequence[float], unit: str) -> list[str]:
    """A sensor's fitted link, one quantity per line, x y z: residual, scale, offset, offset span.

    :param sensor: the sensor's name as printed (``'accelerometer'``, ``'magnetometer'``).
    :param unit: the unit of the link's output (``'counts'``, ``'m/s^2'``, ``'rad/s'``, ``'T'``).
    """
    axes = calibration.axes
    scales = np.array([axis.scale for axis in axes])
    held = [name for name, axis in zip(AXES, axes) if not axis.scale_observable]
    per = ' counts/(m/s^2)' if unit == 'counts' else ''
    at = (f'at N_t,ref {calibration.temp_code_ref:.0f}' if unit == 'counts'
          else f'at {calibration.temp_code_ref:.3g} C')
    return [f'{sensor}, per axis x y z:',
            f'  residual RMS  {amount(residual_rms, unit)}{in_si(np.asarray(residual_rms) / scales, unit)}',
            f'  scale         {numbers(scales, 6)}{per}'
            + (f' (held on {" ".join(held)}: see the note)' if held else ''),
            f'  offset        {amount([axis.offset for axis in axes], unit)} {at}',
            f'  offset span   {amount([axis.offset_span for axis in axes], unit)} over the calibrated range']


def effect_unit(unit: str, sensor_unit: str) -> str:
    """An effect parameter's unit for the sensor's input: the library states it for codes.

    With a driver's input, counts are the sensor's unit (m/s^2, rad/s, or uT for a magnetometer's
    tesla), its input is in the same unit, and the temperature code is the temperature in degrees C.
    """
    if sensor_unit == 'counts':
        return unit
    sensor_unit = display_unit(sensor_unit)[0]
    unit = re.sub(r'\bm/s\^2\b', '@', unit)
    unit = re.sub(r'\bcodes?\b', 'C', unit)
    return unit.replace('counts', sensor_unit).replace('@', sensor_unit)


def effect_lines(calibration: Calibration, errors: dict[str, float], basis, unit_name: str) -> list[str]:
    """One line per fitted effect parameter: its value with its standard error and unit.

    A line before them says what the errors assume (:class:`~tak_thermo_ros.core.fit.uncertainty.ErrorBasis`,
    ``basis``; ``None``: one sigma, the residual taken as white). A parameter in the sensor's unit
    (an amplitude, a slope per degree) is printed as the sensor is: a magnetometer's in uT, with mg
    or deg/h beside m/s^2 or rad/s. An amplitude held at zero on some axes is said so.
    """
    lines = []
    shown_unit, factor = display_unit(unit_name)
    reader = reader_unit(unit_name)
    if calibration.effects and errors:
        lines.append(f'  effects, +- {basis.text() if basis is not None else "1 sigma, residual taken as white"}:')
    for effect in calibration.effects:
        held = effect.held_names()
        for p in effect.parameters:
            if p.name in held:
                lines.append(f'  effect {effect.name}: {p.name} held at 0 (fitted on {effect.fitted_axes_text()} only)')
                continue
            unit = effect_unit(p.unit, unit_name) if p.unit else ''
            in_sensor_unit = unit_name != 'counts' and 'counts' in (p.unit or '')
            scale = factor if in_sensor_unit else 1.0
            error = errors.get(f'{effect.name}.{p.name}')
            text = with_error(p.value * scale, error * scale if error is not None else None)
            text += f' {unit}' if unit else ''
            if in_sensor_unit and reader is not None:
                rest = unit[len(shown_unit):] if unit.startswith(shown_unit) else ''
                value = p.value * scale * reader[1]
                shown = (with_error(value, error * scale * reader[1], 3) if error is not None
                         else significant(value, 3))
                text += f' ({shown} {reader[0]}{rest})'
            # A driver's temperature is in degrees C: a parameter the library names in codes is named by it.
            name = p.name.removesuffix('_codes') if unit_name != 'counts' and p.name.endswith('_codes') else p.name
            lines.append(f'  effect {effect.name}: {name} {text}')
    return lines
