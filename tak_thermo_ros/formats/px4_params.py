"""PX4's temperature compensation parameters (``TC_*``) in QGroundControl's ``.params`` format.

PX4 (``src/modules/temperature_compensation/TemperatureCompensation.cpp``) subtracts, per axis
``i`` of instance ``n``, ``X0_i + X1_i dT + X2_i dT^2 + X3_i dT^3`` with
``dT = clamp(T, TMIN, TMAX) - TREF`` from the raw sample of the sensor whose ``device_id``
equals ``TC_An_ID`` (``TC_Gn_ID``), when ``TC_A_ENABLE`` (``TC_G_ENABLE``) is 1; the module
recomputes the offset only when the temperature has moved by more than 1 C since it last did.
The file: comment lines, then ``vehicle-id component-id name value type`` per line,
tab-separated, type 6 an int32, 9 a float (``MAV_PARAM_TYPE``), as ``Tools/process_sensor_caldata.py``
writes it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from tak_thermo_ros.core.link.model import AXES, UnitCalibration
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.core.link.offset_cubic import OffsetCubic, offset_cubic
from tak_thermo_ros.formats.firmware import not_carried, size

INT32, FLOAT = 6, 9
"""QGroundControl's value types (``MAV_PARAM_TYPE_INT32``, ``MAV_PARAM_TYPE_REAL32``)."""
LETTERS = {'accel': 'A', 'gyro': 'G'}
UPDATE_STEP_C = 1.0
"""PX4 recomputes a sensor's thermal offset when its temperature has moved by more than this (``update_offsets_*``)."""


@dataclass(frozen=True)
class ParameterSet:
    """Parameters for a firmware: name -> (value, QGroundControl type), in order, and what they leave out."""

    values: dict[str, tuple[float | int, int]]
    lines: tuple[str, ...]
    cubics: dict[str, OffsetCubic]


def px4_parameters(unit: UnitCalibration, *, instance: int) -> ParameterSet:
    """The ``TC_A<instance>_*`` and ``TC_G<instance>_*`` sets (and the enables) of a driver calibration."""
    source = unit.source or {}
    values: dict[str, tuple[float | int, int]] = {}
    lines: list[str] = []
    cubics = {}
    for sensor, letter in LETTERS.items():
        calibration = unit.sensor(sensor)
        cubic = offset_cubic(calibration, about=float(calibration.temp_code_ref))
        cubics[sensor] = cubic
        prefix = f'TC_{letter}{instance}_'
        device_id = int(source.get(f'{sensor}_device_id', 0))
        values[f'TC_{letter}_ENABLE'] = (1, INT32)
        values[f'{prefix}ID'] = (device_id, INT32)
        values[f'{prefix}TMIN'] = (cubic.low, FLOAT)
        values[f'{prefix}TMAX'] = (cubic.high, FLOAT)
        values[f'{prefix}TREF'] = (cubic.about, FLOAT)
        for order in range(4):
            for axis, name in enumerate(AXES):
                values[f'{prefix}X{order}_{axis}'] = (float(cubic.coefficients[order, axis]), FLOAT)
        if not device_id:
            lines.append(f'{SENSOR_NAMES[sensor]}: no device ID (fitted from a bag): set {prefix}ID, or PX4 applies '
                         f'none of it')
        lines.extend(not_carried(unit, sensor, cubic, 'PX4'))
        steepest = float(cubic.steepest.max())
        if calibration.needs_temperature:
            lines.append(f'{SENSOR_NAMES[sensor]}: PX4 updates the offset per {UPDATE_STEP_C:g} C change: up to '
                         f'{size(steepest * UPDATE_STEP_C, sensor)} between updates')
    if unit.mag is not None:
        lines.append('magnetometer: not exported (PX4\'s TC_M is against the magnetometer\'s own thermometer)')
    return ParameterSet(values=values, lines=tuple(lines), cubics=cubics)


def params_text(parameters: ParameterSet, *, header: str = '') -> str:
    """The ``.params`` file's text (QGroundControl loads it; vehicle and component 1)."""
    lines = ['# Onboard parameters for Vehicle 1', '#', *(f'# {line}' for line in header.splitlines() if line),
             '#', '# Vehicle-Id Component-Id Name Value Type']
    for name, (value, kind) in parameters.values.items():
        text = str(int(value)) if kind == INT32 else repr(float(value))
        lines.append(f'1\t1\t{name}\t{text}\t{kind}')
    return '\n'.join(lines) + '\n'


def write_px4_params(path: str | os.PathLike[str], parameters: ParameterSet, *, header: str = '') -> None:
    """Write the ``.params`` file atomically."""
    from tak_thermo_ros.formats.files import write_text_atomic
    write_text_atomic(path, params_text(parameters, header=header))


def read_px4_params(text: str) -> dict[str, float]:
    """The parameters of a ``.params`` text (ours or PX4's script's): name -> value."""
    values = {}
    for line in text.splitlines():
        fields = line.split('\t') if '\t' in line else line.split()
        if line.startswith('#') or len(fields) < 4:
            continue
        values[fields[2]] = float(fields[3])
    return values
