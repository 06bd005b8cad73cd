"""What a sample may hold: the bag contract's limits, and why a sample or a held input is dropped.

A counts sample within the 16-bit range (:data:`COUNTS_MIN`, :data:`COUNTS_MAX`), a driver's
value below :data:`VALUE_LIMIT`, a temperature within :data:`TEMPERATURE_RANGE`, a reference
below :data:`REFERENCE_LIMIT`: the rules (:func:`counts_problem`, :func:`values_problem`,
:func:`temp_code_problem` and their array forms) that ``align()``
(:mod:`tak_thermo_ros.core.records.record`) and the node's online pipeline share.
"""

from __future__ import annotations

from math import isfinite

import numpy as np

COUNTS_MIN = -32768.0
COUNTS_MAX = 32767.0
TEMP_CODE_LIMIT = 1e7
"""Largest magnitude of a plausible temperature-sensor code (beyond any 24-bit code, 2**23).

A code at or beyond it is a corrupted message, not a temperature: it is ignored like a
non-finite one (the last good code stays held).
"""
TEMPERATURE_RANGE = {'counts': (-TEMP_CODE_LIMIT, TEMP_CODE_LIMIT), 'imu': (-273.15, 1000.0)}
"""Plausible temperature inputs by input kind: codes, or degrees Celsius (from absolute zero to
a soldering iron). A value outside is ignored as ``implausible``; the calibration file refuses
a calibrated range outside it."""
REFERENCE_LIMIT = 2000.0
"""Largest plausible reference component, m/s^2 (about 200 g, beyond any turntable or centrifuge).

A reference message with a component at or beyond it, or NaN or infinite, is corrupt: it is
ignored (the previous good reference stays held).
"""
DROP_REASONS = ('non_finite', 'non_integer', 'saturated', 'non_physical')
"""Why a sample is never corrected, in the order the checks run (counts: the first three; a
driver's values: ``non_finite`` and ``non_physical``)."""
VALUE_LIMIT = 1.0e4
"""Magnitude from which a driver's value (m/s^2, rad/s, tesla) is non-physical: 1000 g, or
95,000 rpm, beyond the full scale of any IMU (the calibration file's limit on offsets). Such a
message is dropped (``non_physical``), never corrected: a corrupt field, not a measurement."""
TEMP_CODE_PROBLEMS = ('non_finite', 'implausible')
"""Why a temperature code is ignored (not held)."""


def counts_problem(x: float, y: float, z: float) -> str | None:
    """Why one counts sample cannot be corrected, or ``None``; the node's per-message check.

    Same rules, same order as the vectorised :func:`counts_problems`.
    """
    if not (isfinite(x) and isfinite(y) and isfinite(z)):
        return 'non_finite'
    for value in (x, y, z):
        if value != round(value):
            return 'non_integer'
    for value in (x, y, z):
        if value <= COUNTS_MIN or value >= COUNTS_MAX:
            return 'saturated'
    return None


def values_problem(*values: float, _low: float = -VALUE_LIMIT, _high: float = VALUE_LIMIT) -> str | None:
    """Why one driver sample (any number of channels) cannot be corrected, or ``None``.

    Driver values are already in SI units: a NaN or an infinity (``non_finite``) or a magnitude
    of :data:`VALUE_LIMIT` or more (``non_physical``) is refused, as by :func:`counts_problems`
    with ``whole_codes=False``. (``_low`` and ``_high`` are the limit as local names: the node
    asks this of every message.)
    """
    for value in values:
        if not _low < value < _high:  # also false for NaN
            for other in values:
                if not isfinite(other):
                    return 'non_finite'
            return 'non_physical'
    return None


def counts_problems(counts: np.ndarray, *, whole_codes: bool = True) -> dict[str, np.ndarray]:
    """Masks ``(k,)`` per reason of :data:`DROP_REASONS`, each excluding earlier reasons.

    :param counts: ``(k, c)`` values, one row per sample.
    :param whole_codes: the paper's codes (whole numbers inside the 16-bit range); ``False``
        for a driver's values, where ``non_finite`` and ``non_physical`` apply.
    """
    finite = np.all(np.isfinite(counts), axis=1)
    safe = np.where(np.isfinite(counts), counts, 0.0)
    nothing = np.zeros(len(counts), dtype=bool)
    if not whole_codes:
        large = np.any(np.abs(safe) >= VALUE_LIMIT, axis=1)
        return {'non_finite': ~finite, 'non_integer': nothing, 'saturated': nothing.copy(),
                'non_physical': finite & large}
    integer = np.all(safe == np.round(safe), axis=1)
    rail = np.any((safe <= COUNTS_MIN) | (safe >= COUNTS_MAX), axis=1)
    return {'non_finite': ~finite,
            'non_integer': finite & ~integer,
            'saturated': finite & integer & rail,
            'non_physical': nothing}


def temp_code_problem(temp_code: float, input_kind: str = 'counts') -> str | None:
    """Why one temperature input is ignored, or ``None``.

    NaN or infinite (``non_finite``), or outside :data:`TEMPERATURE_RANGE` of the input kind (``implausible``).
    """
    if not isfinite(temp_code):
        return 'non_finite'
    low, high = TEMPERATURE_RANGE[input_kind]
    if not low < temp_code < high:
        return 'implausible'
    return None


def temp_code_problems(temp_code: np.ndarray, input_kind: str = 'counts') -> dict[str, np.ndarray]:
    """Masks ``(m,)`` per reason of :data:`TEMP_CODE_PROBLEMS`; same rules as :func:`temp_code_problem`."""
    temp_code = np.asarray(temp_code, dtype=float)
    finite = np.isfinite(temp_code)
    low, high = TEMPERATURE_RANGE[input_kind]
    safe = np.where(finite, temp_code, 0.0)
    return {'non_finite': ~finite, 'implausible': finite & ~((safe > low) & (safe < high))}


def reference_problems(reference: np.ndarray) -> dict[str, np.ndarray]:
    """Masks ``(r,)`` per reason a reference message is ignored.

    ``non_finite`` (a component NaN or infinite) or ``implausible`` (a component of magnitude :data:`REFERENCE_LIMIT`
    or more).
    """
    reference = np.asarray(reference, dtype=float).reshape(-1, 3)
    finite = np.all(np.isfinite(reference), axis=1)
    large = np.any(np.abs(np.where(np.isfinite(reference), reference, 0.0)) >= REFERENCE_LIMIT, axis=1)
    return {'non_finite': ~finite, 'implausible': finite & large}
