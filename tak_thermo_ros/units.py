"""A sensor's numbers as a reader wants them: in its own unit, with significant figures.

The tools compute in SI (m/s^2, rad/s, tesla) or in the paper's codes; a person reads an
accelerometer's error in mg, a gyroscope's bias in deg/h and a magnetometer's field in uT. The
command line prints a value in the sensor's unit with the reader's beside it
(:func:`amount`: ``0.001756 rad/s (362 deg/h)``); the report's tables show the reader's unit
alone (:func:`readable`). Both to significant figures, not a fixed number of decimals (which
prints ``0.001 0.001 0.001`` for a gyroscope's residual). The one place for these rules:
:mod:`tak_thermo_ros.cli.common`, :mod:`tak_thermo_ros.reports.diagnose` and a result's own
summary (:mod:`tak_thermo_ros.core.fit.summary`) print through it. A leaf: it imports only
:mod:`tak_thermo_ros.core.values`, so every room may import it, the maths included.
"""

from __future__ import annotations

import math
import re

import numpy as np

from tak_thermo_ros.core.values import STANDARD_GRAVITY

DEG = 180.0 / math.pi
"""Degrees per radian."""
DIGITS = 3
"""Significant figures of a reader's value (mg, deg/h) by default."""


def reader_unit(unit: str) -> tuple[str, float] | None:
    """The unit a person reads a sensor's small values in, and the factor from the data's unit.

    Accelerometer errors in mg beside m/s^2, gyroscope biases and errors in deg/h beside rad/s;
    ``None`` for the magnetometer (printed in uT, :func:`display_unit`) and for codes.
    """
    return {'m/s^2': ('mg', 1e3 / STANDARD_GRAVITY), 'rad/s': ('deg/h', DEG * 3600.0)}.get(unit)


def display_unit(unit: str) -> tuple[str, float]:
    """The unit a sensor's values are printed in, and the factor from the data's unit (tesla -> uT)."""
    return ('uT', 1e6) if unit == 'T' else (unit, 1.0)


def significant(value: float, digits: int = 4, *, sign: bool = False) -> str:
    """A value to ``digits`` significant figures: ``0.000397``, ``1.64e-05``, ``1003`` (not ``1e+03``)."""
    value = float(value) + 0.0  # no -0
    plus = '+' if sign else ''
    if math.isfinite(value) and 10.0 ** digits <= abs(value) < 1e15:
        return f'{value:{plus}.0f}'
    return f'{value:{plus}.{digits}g}'


def with_error(value: float, error: float | None, digits: int = 4) -> str:
    """A value and its standard error to the same decimal place: the error's second significant figure.

    ``-1188 +- 3.6``, ``0.01035 +- 8.4e-05`` becomes ``0.010350 +- 0.000084``, ``217.7 +- 110`` becomes
    ``220 +- 110``; without an error (or
    a non-finite one, or an error beyond the value) the value alone to ``digits`` figures.
    """
    if error is None or not math.isfinite(error) or error <= 0.0 or not math.isfinite(value):
        text = significant(value, digits)
        return text if error is None else f'{text} +- {error:.2g}'
    place = 1 - math.floor(math.log10(error))  # decimals of the error's second significant figure
    if place < 0 and error < 1e15 and abs(value) < 1e15:  # 217.7 +- 110 is 220 +- 110
        return f'{round(value, place) + 0.0:.0f} +- {round(error, place):.0f}'
    if place > 12 or error > abs(value) > 0.0 and place > 6:
        return f'{significant(value, digits)} +- {error:.2g}'
    return f'{value + 0.0:.{place}f} +- {error:.{place}f}'


def numbers(values, digits: int = 4, *, sign: bool = False) -> str:
    """Values to ``digits`` significant figures (:func:`significant`), space-separated."""
    return ' '.join(significant(v, digits, sign=sign) for v in np.atleast_1d(values))


def amount(value, unit: str, digits: int = 4) -> str:
    """One value or a triple in a sensor's unit, with the unit a person reads beside it.

    ``0.001756 rad/s (362 deg/h)``, ``0.00397 0.00401 0.00495 m/s^2 (0.405 0.409 0.505 mg)``,
    ``0.1954 uT`` (a magnetometer's tesla printed in uT), ``1.521 counts``.
    """
    shown, factor = display_unit(unit)
    values = np.atleast_1d(np.asarray(value, dtype=float)) * factor
    text = f'{numbers(values, digits)} {shown}'
    reader = reader_unit(unit)
    if reader is not None:
        text += f' ({numbers(values * reader[1], 3)} {reader[0]})'
    return text


def in_si(value, unit: str) -> str:
    """A counts residual (already divided by the scale, so in m/s^2) in mg beside it; nothing for SI units."""
    if unit != 'counts':
        return ''
    small, factor = reader_unit('m/s^2')
    return f' ({numbers(np.asarray(value, dtype=float) * factor, 3)} {small})'


def readable_unit(unit: str) -> tuple[str, float]:
    """The one unit a table shows values of ``unit`` in, and the factor: mg, deg/h, uT, else ``unit`` itself."""
    return reader_unit(unit) or display_unit(unit)


def readable(value: float, unit: str, digits: int = DIGITS) -> str:
    """``'362 deg/h'``: a value of ``unit`` in the reader's unit, to ``digits`` significant figures."""
    shown, factor = readable_unit(unit)
    return f'{significant(float(value) * factor, digits)} {shown}'


def in_driver_words(text: str) -> str:
    """A text written for the paper's codes, said of a driver's temperature in degrees C."""
    text = re.sub(r'\btemperature codes\b', 'temperatures', text)
    text = re.sub(r'\btemperature code\b', 'temperature', text)
    return re.sub(r'\b(\w+)_codes\b', r'\1_codes (in C here)', text)
