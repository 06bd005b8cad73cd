"""A sensor's numbers as a reader wants them: in its own unit, with significant figures.

The tools compute in SI (m/s^2, rad/s, tesla) or in the paper's codes; a person reads an
accelerometer's error in mg, a gyroscope's bias in deg/h and a magnetometer's field in uT.
:func:`readable` turns a value of a unit into that reading, to a few significant figures (not a
fixed number of decimals, which prints ``0.001 0.001 0.001`` for a gyroscope's residual).
The report (:mod:`tak_thermo_ros.report`) and the command line (:mod:`tak_thermo_ros.cli.common`)
print through it.
"""

from __future__ import annotations

import math

STANDARD_GRAVITY = 9.80665
"""m/s^2 per g (the standard value, as the rest of the package)."""
READABLE = {
    'm/s^2': ('mg', 1000.0 / STANDARD_GRAVITY),
    'rad/s': ('deg/h', 180.0 / math.pi * 3600.0),
    'T': ('uT', 1e6),
    'counts': ('counts', 1.0),
}
"""An SI (or code) unit -> the unit a reader wants and the factor to it."""
DIGITS = 3
"""Significant figures shown by default."""


def reader_unit(unit: str) -> str:
    """The unit a reader wants for values of ``unit`` (the unit itself when none is known)."""
    return READABLE.get(unit, (unit, 1.0))[0]


def in_reader_unit(value: float, unit: str) -> float:
    """``value`` (in ``unit``) in :func:`reader_unit`."""
    return float(value) * READABLE.get(unit, (unit, 1.0))[1]


def significant(value: float, digits: int = DIGITS) -> str:
    """``value`` to ``digits`` significant figures (``0.000123``, ``12.3``, ``1.23e+05``); ``nan`` said so."""
    if not math.isfinite(value):
        return 'nan' if value != value else ('inf' if value > 0 else '-inf')
    if 10 ** digits <= abs(value) < 1e6:  # 1003 deg/h, not 1.00e+03
        return f'{value:.0f}'
    text = f'{value:#.{digits}g}'  # '#': trailing zeros are figures too (0.2000, not 0.2)
    return text[:-1] if text.endswith('.') else text


def readable(value: float, unit: str, digits: int = DIGITS) -> str:
    """``'362 deg/h'``: a value of ``unit`` in the reader's unit, to ``digits`` significant figures."""
    return f'{significant(in_reader_unit(value, unit), digits)} {reader_unit(unit)}'


def readables(values, unit: str, digits: int = DIGITS) -> str:
    """``'362 170 412 deg/h'``: several values of one unit, the reader's unit said once."""
    return ' '.join(significant(in_reader_unit(v, unit), digits) for v in values) + f' {reader_unit(unit)}'
