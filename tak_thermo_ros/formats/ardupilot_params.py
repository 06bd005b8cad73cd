"""ArduPilot's IMU temperature calibration (``INS_TCALn_*``) as a parameter file (``NAME VALUE`` per line).

ArduPilot (``libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp``) corrects every raw
sample of IMU ``n`` (``INS_TCALn_ENABLE`` 1) by ``v -= P(clamp(T) - 35); v += P(clamp(CALTEMP) - 35)``
with ``P(t) = (c1 + (c2 + c3 t) t) t``, ``ck = INS_TCALn_ACCk`` (``GYRk``) ``/ 1e6`` per axis,
``clamp`` to ``TMIN..TMAX`` and ``CALTEMP`` the temperature of the ordinary offset calibration
(``INS_ACCn_CALTEMP``, ``INS_GYRn_CALTEMP``), whose offsets supply the constant term. The file is
what ``Tools/scripts/tempcal_IMU.py`` writes (``tcal.parm``).
"""

from __future__ import annotations

import os

from tak_thermo_ros.core.link.model import AXES, UnitCalibration
from tak_thermo_ros.formats.dataflash import SCALE_FACTOR, TEMP_REFERENCE
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.core.link.offset_cubic import offset_cubic
from tak_thermo_ros.formats.firmware import not_carried
from tak_thermo_ros.formats.px4_params import FLOAT, INT32, ParameterSet

CODES = {'accel': 'ACC', 'gyro': 'GYR'}


def ardupilot_parameters(unit: UnitCalibration, *, instance: int) -> ParameterSet:
    """The ``INS_TCAL<instance + 1>_*`` set of a driver calibration (ArduPilot numbers IMUs from 1)."""
    prefix = f'INS_TCAL{instance + 1}_'
    values: dict[str, tuple[float | int, int]] = {f'{prefix}ENABLE': (1, INT32)}
    lines: list[str] = []
    cubics = {sensor: offset_cubic(unit.sensor(sensor), about=TEMP_REFERENCE) for sensor in CODES}
    # one calibrated range for both sensors, as the firmware has: the narrower of the two (of those
    # with temperature terms: a sensor held at nominal has no range)
    ranged = [cubics[sensor] for sensor in CODES if unit.sensor(sensor).needs_temperature] or list(cubics.values())
    low = max(cubic.low for cubic in ranged)
    high = min(cubic.high for cubic in ranged)
    values[f'{prefix}TMIN'] = (low, FLOAT)
    values[f'{prefix}TMAX'] = (high, FLOAT)
    for sensor, code in CODES.items():
        cubic = cubics[sensor]
        for order in (1, 2, 3):
            for axis, name in enumerate(AXES):
                coefficient = float(cubic.coefficients[order, axis]) * SCALE_FACTOR
                values[f'{prefix}{code}{order}_{name.upper()}'] = (coefficient, FLOAT)
        lines.extend(not_carried(unit, sensor, cubic, 'ArduPilot'))
        lines.append(f'{SENSOR_NAMES[sensor]}: no constant in INS_TCAL: the offsets INS_{code}OFFS '
                     f'(at INS_{code}{instance + 1}_CALTEMP) hold it')
    if any((low, high) != (cubic.low, cubic.high) for cubic in ranged):
        lines.append(f'both sensors clamp to {low:.1f}..{high:.1f} C: ArduPilot has one range per IMU')
    if unit.mag is not None:
        lines.append('magnetometer: not exported (ArduPilot calibrates no compass against temperature)')
    return ParameterSet(values=values, lines=tuple(lines), cubics=cubics)


def parm_text(parameters: ParameterSet, *, header: str = '') -> str:
    """The parameter file's text: ``NAME VALUE`` per line (Mission Planner and MAVProxy load it)."""
    lines = [f'# {line}' for line in header.splitlines() if line]
    for name, (value, kind) in parameters.values.items():
        lines.append(f'{name} {int(value)}' if kind == INT32 else f'{name} {float(value):.9g}')
    return '\n'.join(lines) + '\n'


def write_ardupilot_params(path: str | os.PathLike[str], parameters: ParameterSet, *, header: str = '') -> None:
    """Write the parameter file atomically."""
    from tak_thermo_ros.formats.files import write_text_atomic
    write_text_atomic(path, parm_text(parameters, header=header))


def read_ardupilot_params(text: str) -> dict[str, float]:
    """The parameters of a ``NAME VALUE`` text (ours or ``tempcal_IMU.py``'s): name -> value."""
    values = {}
    for line in text.splitlines():
        fields = line.replace(',', ' ').split()
        if line.lstrip().startswith('#') or len(fields) < 2:
            continue
        values[fields[0]] = float(fields[1])
    return values
