"""The calibration file's key lists and the checks its parts share: keys present and known, numbers, bounds.

:func:`_check_keys` names the first missing or unknown key; :data:`LIMITS` holds what a calibration
of each input kind may hold (:func:`_check_limits`). Used by the link's mapping
(:mod:`~tak_thermo_ros.formats.calibration_link`), the optional sections
(:mod:`~tak_thermo_ros.formats.calibration_sections`) and the file (:mod:`~tak_thermo_ros.formats.calibration_file`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from tak_thermo_ros.core.link.model import AXES, Calibration, InputKind
from tak_thermo_ros.core.values import finite_number
from tak_thermo_ros.errors import CalibrationError

AXIS_KEYS = ('scale', 'offset', 'offset_span', 'offset_shape', 'scale_shape')
OPTIONAL_AXIS_KEYS = ('residual_rms', 'scale_observable')
MAX_ORDER = 8


def _coefficients(value: Any, key: str) -> tuple[float, ...]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)):
        msg = f'{key}: expected a list of numbers, got {type(value).__name__} {value!r}'
        raise CalibrationError(msg)
    if not 1 <= len(value) <= MAX_ORDER:
        msg = f'{key}: expected 1 to {MAX_ORDER} coefficients, got {len(value)}'
        raise CalibrationError(msg)
    return tuple(finite_number(item, f'{key}[{i}]') for i, item in enumerate(value))


def _check_keys(raw: Mapping, key: str, required: Sequence[str], optional: Sequence[str] = (), *,
                unknown_why: Mapping[str, str] | None = None) -> None:
    """Every ``required`` key in ``raw`` and no key beyond ``required`` and ``optional``.

    :param unknown_why: words after ``unknown key`` for some keys (why they do not belong here).
    :raises CalibrationError: ``KEY.NAME: missing`` (the first in ``required``'s order), else
        ``KEY.NAME: unknown key`` (the first by name).
    """
    for name in required:
        if name not in raw:
            msg = f'{key}.{name}: missing'
            raise CalibrationError(msg)
    unknown = sorted(str(name) for name in set(raw) - set(required) - set(optional))
    if unknown:
        msg = f'{key}.{unknown[0]}: unknown key{(unknown_why or {}).get(unknown[0], "")}'
        raise CalibrationError(msg)


def _strings(value: Any, key: str) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        msg = f'{key}: expected a list of strings'
        raise CalibrationError(msg)
    return tuple(value)


def _numbers(value: Any, key: str, count: int) -> tuple[float, ...]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or len(value) != count:
        msg = f'{key}: expected a list of {count} numbers'
        raise CalibrationError(msg)
    return tuple(finite_number(item, f'{key}[{i}]') for i, item in enumerate(value))


@dataclass(frozen=True)
class Limits:
    """What a calibration of one input kind may hold: bounds that follow from the physics.

    :param value: largest ``|offset|``, ``offset_span`` and ``residual_rms``, output units
        (counts: the 16-bit code range; imu: m/s^2 or rad/s far beyond any MEMS full scale).
    :param scale: open interval of ``K0`` (counts: counts per m/s^2; imu: a driver's factory
        scale is off by percent, not by a factor of two).
    :param temperature: interval of the temperature input (counts: codes; imu: degrees C,
        from absolute zero to a soldering iron).
    :param temperature_name: the keys' stem in the file (``temp_code`` or ``temperature``).
    """

    value: float
    scale: tuple[float, float]
    temperature: tuple[float, float]
    temperature_name: str


LIMITS = {
    InputKind.COUNTS: Limits(value=65536.0, scale=(0.0, 1.0e6), temperature=(-1.0e7, 1.0e7),
                             temperature_name='temp_code'),
    InputKind.IMU: Limits(value=1.0e4, scale=(0.5, 2.0), temperature=(-273.15, 1000.0),
                          temperature_name='temperature'),
}


def _check_limits(calibration: Calibration, limits: Limits, key: str) -> None:
    """Everything later computed from the calibration is finite, and the values are physical."""
    for end, value in (('ref', calibration.temp_code_ref), ('min', calibration.temp_code_min),
                       ('max', calibration.temp_code_max)):
        if not limits.temperature[0] <= value <= limits.temperature[1]:
            msg = (f'{key}.{limits.temperature_name}_{end}: {value:g} is outside '
                   f'{limits.temperature[0]:g}..{limits.temperature[1]:g}')
            raise CalibrationError(msg)
    n_low, n_high = calibration.code_offset_range()
    grid = np.linspace(n_low, n_high, 1001)
    for name, axis in zip(AXES, calibration.axes):
        low, high = limits.scale
        if not low < axis.scale < high:
            msg = f'{key}.{name}.scale: {axis.scale:g} is outside {low:g}..{high:g} (exclusive)'
            raise CalibrationError(msg)
        for field_name in ('offset', 'offset_span', 'residual_rms'):
            value = getattr(axis, field_name)
            if value is not None and abs(value) > limits.value:
                msg = f'{key}.{name}.{field_name}: |{value:g}| is beyond {limits.value:g}'
                raise CalibrationError(msg)
        with np.errstate(all='ignore'):
            drift = axis.offset_drift(grid)
            gain = axis.scale * axis.scale_factor(grid)
        if not (np.all(np.isfinite(drift)) and np.all(np.abs(drift) <= 2.0 * limits.value)):
            msg = f'{key}.{name}.offset_shape: the offset drift leaves +-{2.0 * limits.value:g} in the calibrated range'
            raise CalibrationError(msg)
        if not np.all(np.isfinite(gain)):
            msg = f'{key}.{name}.scale_shape: the scale is not finite in the calibrated range'
            raise CalibrationError(msg)
